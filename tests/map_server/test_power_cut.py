"""Power loss, not only SIGKILL: the store's file operations are recorded while a map server
merges and compacts, and every disk state a power cut could leave at every instant (unsynced
data and folder names dropped, torn or zeroed tails; swarm.bench.crash_model says what is and
is not modelled) is opened by a new server: every delta acked before the cut is in its map,
exactly once. The same check finds the losses of a store that skips its fsyncs."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from map_server.store import Store
from map_server.wal_file import WAL_HEADER, read_wal
from swarm.bench import durability
from swarm.bench.crash_model import RecordingFiles, trees_after
from tests.support.store_identity import IDENTITY


@pytest.fixture(autouse=True)
def quiet_recoveries(caplog):
    caplog.set_level(logging.ERROR, "swarm.server")  # hundreds of recoveries, each says what it cut


def test_the_model_drops_what_was_not_synced(tmp_path: Path):
    files = RecordingFiles(tmp_path)
    folder = tmp_path / "d"
    files.make_dir(folder)  # the folder's name is synced in its parent
    files.write_file(folder / "a", lambda f: f.write(b"synced"))  # data synced, name not yet
    at_cut = trees_after(files.ops)
    assert at_cut["synced"] == {"d": None}  # a new name is lost until its folder is synced
    assert at_cut["all"] == at_cut["names"] == {"d": None, "d/a": b"synced"}
    files.fsync_dir(folder)
    fd = files.open_append(folder / "a")
    files.append(fd, b"+more!")  # appended, not synced
    at_cut = trees_after(files.ops)
    assert at_cut["synced"]["d/a"] == b"synced" and at_cut["all"]["d/a"] == b"synced+more!"
    assert at_cut["torn"]["d/a"] == b"synced+mo" and at_cut["zeros"]["d/a"] == b"synced" + bytes(6)
    files.fsync(fd)
    files.close(fd)
    files.write_file(folder / "b.tmp", lambda f: f.write(b"new"))
    files.replace(folder / "b.tmp", folder / "a")  # renamed over, folder not synced
    at_cut = trees_after(files.ops)
    assert at_cut["synced"]["d/a"] == b"synced+more!" and "d/b.tmp" not in at_cut["synced"]
    assert at_cut["names"]["d/a"] == b"new"


def test_a_log_whose_header_never_reached_the_disk_is_an_empty_log(tmp_path: Path):
    store, _ = Store.open(tmp_path / "s", IDENTITY)
    store.close()
    wal = tmp_path / "s" / "wal-000001.log"
    for image in (bytes(len(WAL_HEADER)), WAL_HEADER[:5] + bytes(7), b""):
        wal.write_bytes(image)
        assert read_wal(wal, truncate=False) == ([], len(image))
        store, recovered = Store.open(tmp_path / "s", IDENTITY)
        store.append([b"after the cut"])  # the header is written again before the record
        store.close()
        assert read_wal(wal) == ([b"after the cut"], 0)


@pytest.mark.slow
def test_no_acked_delta_is_lost_at_any_power_cut():
    report = durability.power_cuts(per_robot=6)
    assert report.failures == []
    assert (report.lost, report.doubled, report.unopenable) == (0, 0, 0)
    assert report.acked == 12 and report.states > 200  # every delta acked, many states checked


@pytest.mark.slow
@pytest.mark.parametrize("broken", ["no fsync of the log", "no fsync of folders"])
def test_the_check_finds_a_store_that_skips_its_syncs(monkeypatch, broken):
    server = {}
    if broken == "no fsync of the log":
        server["fsync"] = False
    else:
        monkeypatch.setattr(RecordingFiles, "fsync_dir", lambda self, path: None)
    report = durability.power_cuts(per_robot=3, **server)
    assert report.lost > 0, report
