"""A full disk, for real: the store on a small tmpfs mounted for the test. Filled up, the
server pauses its acks ("disk full: acks paused", then at most a line per 10 s, not one per
failure), a compaction that fails leaves no temporary snapshot, and once space returns the acks
resume by themselves; nothing acked is lost and the map is the central fusion of the acked
deltas. Needs root (mount); skipped with the reason otherwise."""

from __future__ import annotations

import errno
import logging
import os
import subprocess
from pathlib import Path

import pytest

from map_server.options import ServerOptions
from map_server.server import MapServer
from map_server.store_files import StoreFiles
from tests.support.map_server_mission import (
    assert_maps_equal,
    central_fusion,
    encode_all,
    robot_batches,
    signed,
    small_mission,
)

DISK_BYTES = 3 << 20


@pytest.fixture
def small_disk(tmp_path: Path):
    """A tmpfs of DISK_BYTES mounted at tmp_path/disk for the test."""
    mount = tmp_path / "disk"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={DISK_BYTES}", "tmpfs", str(mount)],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(path: Path) -> None:
    """Write ``path`` until the file system is full."""
    with open(path, "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\xff" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC


def acked(server: MapServer) -> dict[str, int]:
    return {r: max(e.values(), default=0) for r, e in server.team.acks().items()}


def offer_unacked(server: MapServer, sent) -> int:
    """An agent's resend: every delta not acked yet, in one batch per robot; how many applied."""
    done = acked(server)
    return sum(
        server.merge(signed(server, [(r, s, p) for r, s, p in sent if r == rid and s > done.get(rid, 0)]))
        for rid in sorted({r for r, _, _ in sent})
    )


def test_a_full_disk_pauses_the_acks_and_space_back_resumes_them(small_disk: Path, caplog, monkeypatch):
    caplog.set_level(logging.INFO, "swarm.server")
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, robots=2, per_robot=12, rays=200, seed=9)
    sent = encode_all(grid, batches)
    store = small_disk / "store"
    options = ServerOptions(compact_records=1000, log_reserve_bytes=64 << 10)
    server = MapServer(mission, store, options=options)
    first = [x for x in sent if x[1] <= 4]
    assert server.merge(signed(server, first)) == len(first)
    before = acked(server)
    assert before == {"r1": 4, "r2": 4}

    fill(small_disk / "filler")
    caplog.clear()
    for _ in range(200):  # the agents resend, over and over
        assert offer_unacked(server, sent) == 0
    assert server._disk.paused and acked(server) == before
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert lines[0].startswith("disk full: acks paused")
    assert len(lines) <= 2, lines  # one line, and at most one more per 10 s: not one per failure

    failures = []  # a spy on what the compactions met (and then handled as ever)
    real = server._disk.compaction_failed
    monkeypatch.setattr(server._disk, "compaction_failed", lambda exc: failures.append(exc) or real(exc))
    server._compact()  # no room for a snapshot: put off, nothing written
    assert not list(store.glob("*.tmp"))
    with monkeypatch.context() as mp:  # a file system whose free-space figure lies (mock of statvfs)
        mp.setattr(StoreFiles, "free_bytes", lambda self, path: 1 << 40)
        server._disk._compact_after = 0.0
        server._compact()  # starts writing, meets the full disk
    assert not list(store.glob("*.tmp")), "a failed compaction left its temporary snapshot"
    put_off = [r.getMessage() for r in caplog.records if "compaction put off" in r.getMessage()]
    assert len(put_off) == 1 and "MB free; a snapshot needs" in put_off[0], put_off  # the second: within 10 s
    assert isinstance(failures[-1], OSError) and failures[-1].errno == errno.ENOSPC, failures

    (small_disk / "filler").unlink()  # space returns
    applied = offer_unacked(server, sent)
    assert not server._disk.paused and applied == len(sent) - len(first)
    assert any("acks resumed" in r.getMessage() for r in caplog.records)
    assert acked(server) == {"r1": 12, "r2": 12}
    server.stop()

    again = MapServer(mission, store)  # nothing acked lost, each applied once
    assert acked(again) == {"r1": 12, "r2": 12}
    assert_maps_equal(again.team.cmap.lam, again.team.cmap.eta, central_fusion(grid, sensor, batches))
    again.store.close()
