"""The map server's store: the write-ahead log survives a torn tail, compaction is atomic,
recovery rebuilds the map and acks, and a store of another mission or grid is refused."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from map_server.ledger import validate_delta
from map_server.options import ServerOptions
from map_server.server import MapServer
from map_server.store import Store, StoreError, StoreIdentity
from map_server.team_map import MergedMap
from map_server.wal_file import RECORD_HEADER, WAL_HEADER, encode_records, read_wal
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from tests.support.map_server_mission import (
    EPOCH,
    assert_maps_equal,
    central_fusion,
    encode_all,
    robot_batches,
    signed,
    small_mission,
)
from tests.support.store_identity import GRID, IDENTITY


def payloads(n: int) -> list[bytes]:
    return [bytes([i]) * (10 + 7 * i) for i in range(n)]


@pytest.mark.parametrize(
    "tail",
    [
        b"\x05",  # part of a record header
        RECORD_HEADER.pack(100, 0) + b"x" * 40,  # a payload cut short
        RECORD_HEADER.pack(3, 12345) + b"abc",  # a whole record with a wrong CRC
        RECORD_HEADER.pack(1 << 31, 0),  # an absurd length
    ],
)
def test_wal_with_a_torn_tail_recovers_the_good_prefix(tmp_path: Path, tail: bytes):
    store, rec = Store.open(tmp_path / "s", IDENTITY)
    assert rec.wal_payloads == [] and rec.lam is None
    store.append(payloads(3))
    store.append(payloads(5)[3:])
    store.close()
    wal = tmp_path / "s" / "wal-000001.log"
    good_size = wal.stat().st_size
    with open(wal, "ab") as f:
        f.write(tail)
    store, rec = Store.open(tmp_path / "s", IDENTITY)
    assert rec.wal_payloads == payloads(5)
    assert rec.torn_bytes == len(tail)
    assert wal.stat().st_size == good_size  # the tail is cut off the file
    store.append([b"after"])  # and the log goes on after the good prefix
    store.close()
    assert read_wal(wal)[0] == [*payloads(5), b"after"]


def test_a_failed_append_leaves_no_partial_record(tmp_path: Path, monkeypatch):
    import errno
    import os

    store, _ = Store.open(tmp_path / "s", IDENTITY)
    store.append(payloads(2))
    wal = tmp_path / "s" / "wal-000001.log"
    size = wal.stat().st_size
    real_write = os.write

    def disk_full(fd, data):  # writes a little, then the disk is full
        real_write(fd, bytes(data[:5]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("map_server.store_files.os.write", disk_full)
    with pytest.raises(OSError, match="No space"):
        store.append([b"lost"])
    monkeypatch.undo()
    assert wal.stat().st_size == size and store.wal_records == 2
    store.append([b"kept"])
    store.close()
    assert read_wal(wal) == ([*payloads(2), b"kept"], 0)


def test_corruption_in_the_middle_keeps_the_records_before_it(tmp_path: Path):
    store, _ = Store.open(tmp_path / "s", IDENTITY)
    store.append(payloads(4))
    store.close()
    wal = tmp_path / "s" / "wal-000001.log"
    data = bytearray(wal.read_bytes())
    second = len(WAL_HEADER) + len(encode_records(payloads(1)))
    data[second + RECORD_HEADER.size + 2] ^= 0xFF  # flip a byte of record 2's payload
    wal.write_bytes(bytes(data))
    records, torn = read_wal(wal, truncate=False)
    assert records == payloads(1) and torn == len(data) - second


def test_a_file_that_is_not_a_wal_is_refused(tmp_path: Path):
    store, _ = Store.open(tmp_path / "s", IDENTITY)
    store.close()
    (tmp_path / "s" / "wal-000001.log").write_bytes(b"NOTAWAL!" + struct.pack("<I", 1))
    with pytest.raises(StoreError, match="wal-000001.log.*not a swarm write-ahead log"):
        Store.open(tmp_path / "s", IDENTITY)


def test_a_store_of_another_mission_or_grid_is_refused_naming_the_folder(tmp_path: Path):
    Store.open(tmp_path / "s", IDENTITY)[0].close()
    for other in (
        StoreIdentity("elsewhere", GRID, SensorModel()),
        StoreIdentity("srvtest", Grid((0.0, 0.0, 0.0), 0.1, (30, 20, 11)), SensorModel()),
        StoreIdentity("srvtest", GRID, SensorModel(max_range=4.0)),
    ):
        with pytest.raises(
            StoreError, match=f"{tmp_path / 's'}: this store was written for mission 'srvtest'"
        ):
            Store.open(tmp_path / "s", other)
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "notes.txt").write_text("hello")
    with pytest.raises(StoreError, match="junk.*not a map store"):
        Store.open(tmp_path / "junk", IDENTITY)


def test_compaction_starts_a_new_log_and_recovery_replays_only_what_follows(tmp_path: Path):
    lam = np.arange(GRID.size, dtype=np.float32) + 1
    store, _ = Store.open(tmp_path / "s", IDENTITY)
    store.append(payloads(2))
    store.compact(GRID, lam, lam * 0.5, '[["r1", 7, 2, []]]', {"updates": {"r1": 9}})
    assert store.generation == 2 and store.wal_records == 0
    store.append([b"later"])
    store.close()
    names = sorted(p.name for p in (tmp_path / "s").iterdir())
    assert names == ["snapshot.npz", "store.json", "store.lock", "wal-000002.log"]
    store, rec = Store.open(tmp_path / "s", IDENTITY)
    store.close()
    np.testing.assert_array_equal(rec.lam, lam)
    assert rec.ledger_json == '[["r1", 7, 2, []]]' and rec.counters == {"updates": {"r1": 9}}
    assert rec.wal_payloads == [b"later"]
    # a crash after the snapshot was replaced but before the old log was deleted: the old
    # log is already in the snapshot and is dropped; a leftover temporary file too
    (tmp_path / "s" / "wal-000001.log").write_bytes(WAL_HEADER + encode_records([b"stale"]))
    (tmp_path / "s" / "snapshot.npz.tmp").write_bytes(b"half a snapshot")
    store, rec = Store.open(tmp_path / "s", IDENTITY)
    store.close()
    assert rec.wal_payloads == [b"later"]
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == names


def test_server_recovers_map_and_acks_from_snapshot_plus_log(tmp_path: Path):
    """Without Zenoh: merge through MapServer.merge, compact midway, reopen, compare."""
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=5, seed=8)
    sent = encode_all(grid, batches)
    server = MapServer(mission, tmp_path / "s", options=ServerOptions(compact_records=4))
    server._merged_pub = _NullPublisher()
    for i in range(0, len(sent), 3):
        server.merge(signed(server, sent[i : i + 3]))
    assert server.store.snapshots_written >= 2 and server.store.wal_records > 0
    server.store.close()  # as if killed: no final compaction
    again = MapServer(mission, tmp_path / "s")
    again.store.close()
    assert again.recovered[0] > 0 and again.recovered[1] > 0  # some from each
    assert_maps_equal(again.team.cmap.lam, again.team.cmap.eta, central_fusion(grid, sensor, batches))
    assert again.team.acks() == {rid: {EPOCH: 5} for rid in batches}
    assert again.team.stats()["updates_merged"] == sum(len(d) for ds in batches.values() for d in ds)
    # replaying the same payloads again changes nothing
    team = MergedMap(grid, sensor, again.team.cmap.lam.copy(), again.team.cmap.eta.copy(), again.team.ledger)
    assert not any(team.admit(validate_delta(p, grid)) for _, _, p in sent)


class _NullPublisher:
    def put(self, _payload: bytes) -> None:
        pass
