"""The chunks of a streamed ``map/snapshot`` or ``map/region`` answer (docs/protocol.md,
"Streamed answers"), and their assembly. Pure: no I/O.

A map server answers a whole-map query with a **stream**: one consistent copy of the answer
(the map at one point of its ledger, or a region's beliefs at one moment), held under a
``stream`` id (16 hex digits) and cut into ``chunks`` chunks of ``per`` voxels each (the last
one shorter). Chunk ``i`` holds the voxels ``i * per`` up to ``(i + 1) * per`` of the answer:
for a snapshot the flat voxel indices themselves (``lam``, ``eta``), for a region the region's
own voxels in ascending flat order (``idx``, ``mu``, ``sigma``, ``expected_coverage``,
``entropy``). Every chunk repeats the head (stream, chunk, chunks, per, voxels, grid, and a
snapshot's ``deltas``); chunk 0 of a snapshot alone carries ``acks`` and ``above``, the exact
set of deltas the copy holds (its consistent point).

:class:`ChunkAssembler` takes the chunks of one stream in any order, each at most once, and
gives the whole :class:`~swarm.protocol.map_messages.Snapshot` or
:class:`~swarm.protocol.map_messages.Region` once every chunk is in. Malformed chunks, and
chunks of another stream or disagreeing with the first one's head, raise ``WireError``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from swarm.map.grid import Grid
from swarm.protocol import codec
from swarm.protocol.codec import WireError
from swarm.protocol.map_messages import Region, Snapshot, check_beliefs, grid_field, ledger_fields

#: Voxel data per chunk (bytes) the map server cuts an answer into: well under Zenoh's 1 MiB
#: of queued batches per link and its received-message bound (64 MiB at least), so a chunk
#: never waits long behind others and a lost one costs little to ask again.
CHUNK_BYTES = 256 << 10
#: Bytes per voxel: a snapshot's ``lam`` + ``eta``; a region's ``idx`` and 4 float32 values.
SNAPSHOT_VOXEL_BYTES = 8
REGION_VOXEL_BYTES = 20
#: Chunks one query is answered with when it does not say (``count``), and at most.
WINDOW = 16
MAX_WINDOW = 64
#: What the server's error reply says when it no longer holds (or never held) the stream asked
#: for: the client starts the answer again, without ``stream``.
EXPIRED = ": expired: "
STREAM_ID_HEX = 16

SNAPSHOT_KIND = "snapshot_chunk"
REGION_KIND = "region_chunk"
_REGION_VALUES = ("mu", "sigma", "expected_coverage", "entropy")


def voxels_per_chunk(kind: str, chunk_bytes: int = CHUNK_BYTES) -> int:
    """Voxels of one chunk of ``kind`` (``snapshot_chunk`` / ``region_chunk``), at least 1."""
    per_voxel = SNAPSHOT_VOXEL_BYTES if kind == SNAPSHOT_KIND else REGION_VOXEL_BYTES
    return max(1, chunk_bytes // per_voxel)


def chunk_count(voxels: int, per: int) -> int:
    """Chunks of ``per`` voxels that hold ``voxels`` (an empty region: one empty chunk)."""
    return max(1, -(-voxels // per))


@dataclass
class Chunk:
    """One chunk of a stream: the head and ``arrays`` (name -> numpy array, ``count`` long).

    ``kind``: ``snapshot_chunk`` or ``region_chunk``. ``voxels``: the whole answer's voxels
    (the grid's for a snapshot, the region's for a region). ``deltas``: a snapshot's ledger
    position (deltas applied in the copy; 0 for a region). ``acks``/``above``: as
    ``Snapshot``'s, in chunk 0 of a snapshot only (empty otherwise).
    """

    kind: str
    stream: str
    chunk: int
    chunks: int
    per: int
    voxels: int
    grid: Grid
    arrays: dict[str, np.ndarray]
    deltas: int = 0
    acks: dict[str, dict[int, int]] = field(default_factory=dict)
    above: dict[str, dict[int, list[int]]] = field(default_factory=dict)

    @property
    def first(self) -> int:
        """Offset of this chunk's first voxel in the answer."""
        return self.chunk * self.per

    @property
    def count(self) -> int:
        """Voxels this chunk holds."""
        return max(0, min(self.per, self.voxels - self.first))

    def encode(self) -> bytes:
        names = ("lam", "eta") if self.kind == SNAPSHOT_KIND else ("idx", *_REGION_VALUES)
        fields: dict[str, Any] = {
            "stream": self.stream,
            "chunk": int(self.chunk),
            "chunks": int(self.chunks),
            "per": int(self.per),
            "voxels": int(self.voxels),
            "grid": self.grid.to_dict(),
        }
        for name in names:
            array = self.arrays[name]
            if len(array) != self.count:
                raise WireError(f"{self.kind}: {name} holds {len(array)} voxels, expected {self.count}")
            fields[name] = codec.le(array, "<u4" if name == "idx" else "<f4")
        if self.kind == SNAPSHOT_KIND:
            fields["deltas"] = int(self.deltas)
            if self.chunk == 0:
                fields |= ledger_fields(self.acks, self.above)
        return codec.pack(self.kind, fields)

    @classmethod
    def decode(cls, payload: Any, kind: str) -> Chunk:
        """One chunk of ``kind``; WireError naming the field for anything malformed."""
        msg = codec.unpack(payload, kind)
        grid = grid_field(codec.require(msg, "grid", kind), kind)
        stream = codec.text(codec.require(msg, "stream", kind), "stream", kind)
        if not is_stream_id(stream):
            raise WireError(f"{kind}: stream must be {STREAM_ID_HEX} hex digits, got {codec.short(stream)}")
        chunks = codec.integer(codec.require(msg, "chunks", kind), "chunks", kind, 1)
        chunk = codec.integer(codec.require(msg, "chunk", kind), "chunk", kind)
        per = codec.integer(codec.require(msg, "per", kind), "per", kind, 1)
        voxels = codec.integer(codec.require(msg, "voxels", kind), "voxels", kind)
        if chunk >= chunks:
            raise WireError(f"{kind}: chunk {chunk} of {chunks} chunks")
        if chunks != chunk_count(voxels, per):
            raise WireError(f"{kind}: {chunks} chunks cannot hold {voxels} voxels of {per} per chunk")
        head = cls(kind, stream, chunk, chunks, per, voxels, grid, {})
        n = head.count
        if kind == SNAPSHOT_KIND:
            if voxels != grid.size:
                raise WireError(f"{kind}: {voxels} voxels, the grid holds {grid.size}")
            head.deltas = codec.integer(codec.require(msg, "deltas", kind), "deltas", kind)
            lam = codec.raw(codec.require(msg, "lam", kind), "<f4", n, "lam", kind)
            eta = codec.raw(codec.require(msg, "eta", kind), "<f4", n, "eta", kind)
            check_beliefs(lam, eta, kind)
            head.arrays = {"lam": lam, "eta": eta}
            if chunk == 0:
                head.acks, head.above = Snapshot.ledger_of(msg, kind)
        else:
            if voxels > grid.size:
                raise WireError(f"{kind}: a region of {voxels} voxels in a grid of {grid.size}")
            idx = codec.indices(codec.require(msg, "idx", kind), kind, grid.size)
            if len(idx) != n:
                raise WireError(f"{kind}: idx holds {len(idx)} voxels, expected {n}")
            if n > 1 and np.any(np.diff(idx.astype(np.int64)) <= 0):
                raise WireError(f"{kind}: idx must be ascending")
            head.arrays = {"idx": idx}
            head.arrays |= {
                name: codec.raw(codec.require(msg, name, kind), "<f4", n, name, kind)
                for name in _REGION_VALUES
            }
        return head


def is_stream_id(text: str) -> bool:
    """Whether ``text`` is a stream id: STREAM_ID_HEX lower-case hex digits."""
    return len(text) == STREAM_ID_HEX and all(c in "0123456789abcdef" for c in text)


def snapshot_chunk(stream: str, snap: Snapshot, chunk: int, per: int, deltas: int) -> Chunk:
    """Chunk ``chunk`` of the snapshot ``snap`` cut into chunks of ``per`` voxels (views, no copy)."""
    lam, eta = np.ravel(snap.lam), np.ravel(snap.eta)
    n = len(lam)
    lo, hi = chunk * per, min(n, (chunk + 1) * per)
    first = chunk == 0
    return Chunk(
        SNAPSHOT_KIND,
        stream,
        chunk,
        chunk_count(n, per),
        per,
        n,
        snap.grid,
        {"lam": lam[lo:hi], "eta": eta[lo:hi]},
        deltas,
        snap.acks if first else {},
        snap.above if first else {},
    )


def region_chunk(stream: str, region: Region, chunk: int, per: int) -> Chunk:
    """Chunk ``chunk`` of ``region`` cut into chunks of ``per`` of its voxels (views, no copy)."""
    n = len(region)
    lo, hi = chunk * per, min(n, (chunk + 1) * per)
    arrays = {"idx": region.idx[lo:hi]} | {name: getattr(region, name)[lo:hi] for name in _REGION_VALUES}
    return Chunk(REGION_KIND, stream, chunk, chunk_count(n, per), per, n, region.grid, arrays)


class ChunkAssembler:
    """Puts the chunks of one stream of ``kind`` together (see the module doc).

    :meth:`add` takes a decoded chunk; :meth:`next_missing` is the cursor to ask for next;
    :meth:`snapshot` / :meth:`region` give the whole answer once :attr:`complete`.
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.head: Chunk | None = None
        self._parts: dict[int, Chunk] = {}
        #: a snapshot's lam and eta (float32, grid.size), filled as its chunks come (``_place``)
        self._map: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def stream(self) -> str | None:
        return None if self.head is None else self.head.stream

    @property
    def received(self) -> int:
        return len(self._parts)

    @property
    def chunks(self) -> int | None:
        return None if self.head is None else self.head.chunks

    @property
    def complete(self) -> bool:
        return self.head is not None and len(self._parts) == self.head.chunks

    def add(self, chunk: Chunk) -> bool:
        """Keep ``chunk``; False when it was held already. WireError when it is of another kind
        or stream, or its head (chunks, per, voxels, grid, deltas) differs from the first one's."""
        if chunk.kind != self.kind:
            raise WireError(f"{self.kind}: a {chunk.kind} in the stream")
        head = self.head
        if head is None:
            self.head = head = chunk
        elif chunk.stream != head.stream:
            raise WireError(f"{self.kind}: chunk of stream {chunk.stream}, assembling {head.stream}")
        elif (chunk.chunks, chunk.per, chunk.voxels, chunk.deltas) != (
            head.chunks,
            head.per,
            head.voxels,
            head.deltas,
        ) or not chunk.grid.matches(head.grid):
            raise WireError(
                f"{self.kind}: chunk {chunk.chunk} of stream {head.stream} disagrees with its head"
            )
        if chunk.chunk in self._parts:
            return False
        if self.kind == SNAPSHOT_KIND:
            chunk = self._place(chunk)
        self._parts[chunk.chunk] = chunk
        return True

    def _place(self, chunk: Chunk) -> Chunk:
        """A snapshot chunk's lam and eta, copied to their place in the whole map's arrays (made
        at the first chunk): the chunk is kept without them, so that a large map is held once
        while it comes in, not twice (chunks, then joined: the campus floor's 68 MB each)."""
        if self._map is None:
            self._map = (np.empty(chunk.voxels, "<f4"), np.empty(chunk.voxels, "<f4"))
        lo, hi = chunk.first, chunk.first + chunk.count
        self._map[0][lo:hi], self._map[1][lo:hi] = chunk.arrays["lam"], chunk.arrays["eta"]
        return replace(chunk, arrays={})

    def next_missing(self) -> int:
        """The lowest chunk not held (0 before any; ``chunks`` once complete)."""
        n = 0
        while n in self._parts:
            n += 1
        return n

    def _joined(self, name: str, dtype: str) -> np.ndarray:
        if not self.complete:
            raise ValueError(f"{self.kind}: {self.received} of {self.chunks} chunks held")
        parts = [self._parts[i].arrays[name] for i in range(self.head.chunks)]
        return np.concatenate(parts).astype(dtype, copy=False) if parts else np.zeros(0, dtype)

    def snapshot(self) -> Snapshot:
        """The whole snapshot (lam, eta float32 of grid.size; acks and above of chunk 0); its
        arrays are the assembler's own (a second call gives the same)."""
        if not self.complete:
            raise ValueError(f"{self.kind}: {self.received} of {self.chunks} chunks held")
        first = self._parts[0]
        return Snapshot(self.head.grid, *self._map, first.acks, first.above)

    def region(self) -> Region:
        """The whole region (idx ascending uint32, the four float32 values)."""
        idx = self._joined("idx", "<u4")
        if len(idx) > 1 and np.any(np.diff(idx.astype(np.int64)) <= 0):
            raise WireError(f"{self.kind}: the chunks' idx are not ascending across chunks")
        return Region(self.head.grid, idx, *(self._joined(name, "<f4") for name in _REGION_VALUES))
