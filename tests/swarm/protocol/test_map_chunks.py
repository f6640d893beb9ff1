"""The chunks of a streamed map/snapshot or map/region answer (swarm/protocol/map_chunks.py):
cut and put together again in any order they give exactly the original; a duplicate chunk is
kept once; a chunk of another stream, kind or head, or a malformed one, raises WireError."""

from __future__ import annotations

import random

import msgpack
import numpy as np
import pytest

from swarm.map.grid import Grid
from swarm.protocol.codec import WireError
from swarm.protocol.map_chunks import (
    REGION_KIND,
    SNAPSHOT_KIND,
    Chunk,
    ChunkAssembler,
    chunk_count,
    region_chunk,
    snapshot_chunk,
)
from swarm.protocol.map_messages import Region, Snapshot

GRID = Grid((0.0, 0.0, 0.0), 0.1, (7, 5, 3))  # 105 voxels
STREAM = "0123456789abcdef"
OTHER = "fedcba9876543210"


def _snapshot(seed: int = 0) -> Snapshot:
    rng = np.random.default_rng(seed)
    lam = rng.uniform(0.5, 4.0, GRID.size).astype(np.float32)
    eta = rng.normal(0.0, 1.0, GRID.size).astype(np.float32)
    return Snapshot(GRID, lam, eta, {"r1": {1: 4, 2: 1}, "r2": {1: 7}}, {"r1": {1: [6, 9]}})


def _region(n: int = 40, seed: int = 0) -> Region:
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(GRID.size, n, replace=False)).astype(np.uint32)
    values = [rng.uniform(0, 1, n).astype(np.float32) for _ in range(4)]
    return Region(GRID, idx, *values)


def _snapshot_chunks(snap: Snapshot, per: int, stream: str = STREAM, deltas: int = 12) -> list[bytes]:
    n = chunk_count(GRID.size, per)
    return [snapshot_chunk(stream, snap, i, per, deltas).encode() for i in range(n)]


def _region_chunks(region: Region, per: int, stream: str = STREAM) -> list[bytes]:
    return [region_chunk(stream, region, i, per).encode() for i in range(chunk_count(len(region), per))]


def _assemble(kind: str, payloads: list[bytes]) -> ChunkAssembler:
    assembler = ChunkAssembler(kind)
    for payload in payloads:
        assembler.add(Chunk.decode(payload, kind))
    return assembler


@pytest.mark.parametrize("per", [1, 8, 50, 104, 105, 1000])
def test_a_snapshot_cut_into_chunks_assembles_to_exactly_itself_in_any_order(per: int):
    snap = _snapshot()
    payloads = _snapshot_chunks(snap, per)
    random.Random(per).shuffle(payloads)
    assembler = _assemble(SNAPSHOT_KIND, payloads)
    assert assembler.complete and assembler.chunks == chunk_count(GRID.size, per)
    got = assembler.snapshot()
    assert got.grid.matches(GRID)
    assert got.lam.tobytes() == snap.lam.tobytes() and got.eta.tobytes() == snap.eta.tobytes()
    assert got.acks == snap.acks and got.above == snap.above
    assert assembler.head.deltas == 12


@pytest.mark.parametrize(("n", "per"), [(0, 10), (1, 10), (40, 7), (40, 40), (105, 13)])
def test_a_region_cut_into_chunks_assembles_to_exactly_itself_in_any_order(n: int, per: int):
    region = _region(n)
    payloads = _region_chunks(region, per)
    random.Random(n + per).shuffle(payloads)
    got = _assemble(REGION_KIND, payloads).region()
    for name in ("idx", "mu", "sigma", "expected_coverage", "entropy"):
        assert getattr(got, name).tobytes() == getattr(region, name).tobytes(), name
    assert got.idx.dtype == np.uint32


def test_a_duplicate_chunk_is_kept_once_and_the_cursor_is_the_first_missing():
    payloads = _snapshot_chunks(_snapshot(), 10)  # 11 chunks
    assembler = ChunkAssembler(SNAPSHOT_KIND)
    assert assembler.next_missing() == 0
    assert assembler.add(Chunk.decode(payloads[0], SNAPSHOT_KIND))
    assert assembler.add(Chunk.decode(payloads[2], SNAPSHOT_KIND))
    assert not assembler.add(Chunk.decode(payloads[2], SNAPSHOT_KIND))
    assert assembler.received == 2 and assembler.next_missing() == 1 and not assembler.complete
    with pytest.raises(ValueError):
        assembler.snapshot()


def test_a_chunk_of_another_stream_raises():
    assembler = _assemble(SNAPSHOT_KIND, _snapshot_chunks(_snapshot(), 10)[:1])
    with pytest.raises(WireError, match="stream"):
        assembler.add(Chunk.decode(_snapshot_chunks(_snapshot(), 10, stream=OTHER)[1], SNAPSHOT_KIND))


def test_a_chunk_of_another_kind_raises():
    assembler = ChunkAssembler(SNAPSHOT_KIND)
    chunk = Chunk.decode(_region_chunks(_region(), 10)[0], REGION_KIND)
    with pytest.raises(WireError, match="region_chunk"):
        assembler.add(chunk)
    with pytest.raises(WireError):  # nor does a region chunk decode as a snapshot chunk
        Chunk.decode(_region_chunks(_region(), 10)[0], SNAPSHOT_KIND)


def test_a_chunk_whose_head_disagrees_with_the_first_raises():
    snap = _snapshot()
    assembler = _assemble(SNAPSHOT_KIND, _snapshot_chunks(snap, 10, deltas=12)[:1])
    later = Chunk.decode(_snapshot_chunks(snap, 10, deltas=13)[1], SNAPSHOT_KIND)  # another ledger point
    with pytest.raises(WireError, match="disagrees"):
        assembler.add(later)
    other_per = Chunk.decode(_snapshot_chunks(snap, 21)[1], SNAPSHOT_KIND)  # 5 chunks, not 11
    with pytest.raises(WireError, match="disagrees"):
        assembler.add(other_per)


def test_region_chunks_whose_voxels_are_not_ascending_across_chunks_raise():
    region = _region(20)
    a = region_chunk(STREAM, region, 0, 10)
    b = region_chunk(STREAM, region, 1, 10)
    a.chunk, b.chunk = 1, 0  # each ascending on its own, out of order together
    assembler = ChunkAssembler(REGION_KIND)
    assembler.add(Chunk.decode(a.encode(), REGION_KIND))
    assembler.add(Chunk.decode(b.encode(), REGION_KIND))
    with pytest.raises(WireError, match="ascending"):
        assembler.region()


def _tampered(payload: bytes, **changes) -> bytes:
    msg = msgpack.unpackb(payload, raw=False)
    for name, value in changes.items():
        if value is None:
            del msg[name]
        else:
            msg[name] = value
    return msgpack.packb(msg, use_bin_type=True)


@pytest.mark.parametrize(
    "changes",
    [
        {"chunk": 11},  # past the last chunk
        {"chunk": -1},
        {"chunks": 3},  # 3 chunks of 10 cannot hold 105 voxels
        {"per": 0},
        {"voxels": 104},  # not the grid's
        {"stream": "XYZ"},
        {"stream": None},
        {"deltas": None},
        {"lam": b"\x00" * 8},  # 2 voxels, the chunk holds 10
        {"lam": np.full(10, -1.0, "<f4").tobytes()},  # lam must be > 0
        {"eta": np.full(10, np.nan, "<f4").tobytes()},
        {"grid": {"origin": [0, 0, 0]}},
    ],
)
def test_a_malformed_snapshot_chunk_raises_wire_error(changes: dict):
    payload = _snapshot_chunks(_snapshot(), 10)[1]
    with pytest.raises(WireError):
        Chunk.decode(_tampered(payload, **changes), SNAPSHOT_KIND)


@pytest.mark.parametrize("payload", [b"", b"\xc1", msgpack.packb([1, 2, 3]), msgpack.packb({"v": 1})])
def test_garbage_raises_wire_error(payload: bytes):
    for kind in (SNAPSHOT_KIND, REGION_KIND):
        with pytest.raises(WireError):
            Chunk.decode(payload, kind)


def test_a_region_chunk_with_descending_or_outside_indices_raises():
    payload = _region_chunks(_region(20), 10)[0]
    idx = np.frombuffer(msgpack.unpackb(payload, raw=False)["idx"], "<u4")
    with pytest.raises(WireError, match="ascending"):
        Chunk.decode(_tampered(payload, idx=idx[::-1].tobytes()), REGION_KIND)
    outside = idx.copy()
    outside[-1] = GRID.size
    with pytest.raises(WireError):
        Chunk.decode(_tampered(payload, idx=outside.tobytes()), REGION_KIND)
