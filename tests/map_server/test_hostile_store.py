"""The map server killed mid-save: a crash at every step of a compaction (the snapshot half
written, before and after it replaces the old one, before the next log exists, before the old
log is deleted) and of a store's creation leaves a store the next start loads, with every
delta acked before the crash in its map, applied once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import map_server.store as store_module
from map_server.server import MapServer
from map_server.store_files import StoreFiles
from tests.support.hostile_oracle import oracle
from tests.support.map_server_mission import EPOCH, encode_all, robot_batches, signed, small_mission


class Killed(BaseException):
    """The process dies here (BaseException: no handler of the server catches it)."""


def crash_at(monkeypatch, target, name: str, after: int = 0):
    """Make ``target.name`` die on its call number ``after`` (0: the first)."""
    real = getattr(target, name)
    calls = {"n": 0}

    def dying(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > after:
            raise Killed(name)
        return real(*args, **kwargs)

    monkeypatch.setattr(target, name, dying)


_SAVEZ = np.savez


def half_written_savez(f, **arrays):
    """np.savez that dies after writing half of the file."""
    import io

    buffer = io.BytesIO()
    _SAVEZ(buffer, **arrays)
    data = buffer.getvalue()
    f.write(data[: len(data) // 2])
    f.flush()
    raise Killed("savez")


CRASHES = {
    "snapshot half written": lambda mp: mp.setattr(store_module.np, "savez", half_written_savez),
    "before the snapshot replaces the old": lambda mp: crash_at(mp, StoreFiles, "replace"),
    "before the folder is synced": lambda mp: crash_at(mp, StoreFiles, "fsync_dir"),
    "before the next log exists": lambda mp: crash_at(mp, store_module.Store, "_open_wal"),
    "before the old log is deleted": lambda mp: crash_at(mp, StoreFiles, "unlink"),
}


@pytest.mark.parametrize("crash", sorted(CRASHES))
def test_a_server_killed_mid_compaction_restarts_with_every_acked_delta(tmp_path: Path, monkeypatch, crash):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    sent = encode_all(grid, robot_batches(grid, sensor, robots=2, per_robot=4, rays=60, seed=5))
    first, second = sent[:4], sent[4:]
    server = MapServer(mission, tmp_path / "store")
    assert server.merge(signed(server, first)) == len(first)
    server._compact()  # one good compaction: a snapshot and a log to lose
    assert server.merge(signed(server, second)) == len(second)  # durable: acked
    with monkeypatch.context() as mp:
        CRASHES[crash](mp)
        with pytest.raises(Killed):
            server._compact()
    server.store.close()  # what the kernel does for a killed process: its files and lock go

    again = MapServer(mission, tmp_path / "store")
    expected = oracle(mission, [p for _, _, p in sent])
    np.testing.assert_array_equal(again.team.cmap.lam, expected.cmap.lam)
    np.testing.assert_array_equal(again.team.cmap.eta, expected.cmap.eta)
    assert again.team.acks() == {"r1": {EPOCH: 4}, "r2": {EPOCH: 4}}
    assert again.merge(signed(again, sent)) == 0  # every one applied already
    again._compact()  # and the store keeps working
    again.store.close()
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == [
        "epochs.json",
        "snapshot.npz",
        "store.json",
        "store.lock",
        f"wal-{again.store.generation:06d}.log",
    ]


def test_a_server_killed_while_it_creates_its_store_starts_again(tmp_path: Path, monkeypatch):
    """Killed before store.json replaced its temporary file: the folder held only
    store.json.tmp and every later start refused it as 'not a map store'."""
    mission = small_mission()
    with monkeypatch.context() as mp:
        crash_at(mp, StoreFiles, "replace")
        with pytest.raises(Killed):
            MapServer(mission, tmp_path / "store")
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == ["store.json.tmp", "store.lock"]
    server = MapServer(mission, tmp_path / "store")
    server.store.close()
    assert (tmp_path / "store" / "store.json").exists()
