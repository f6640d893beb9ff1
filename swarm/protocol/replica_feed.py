"""One map server's ``merged`` stream as a team replica follows it (docs/sharding.md).

An unsharded map service is one server; a sharded one is ``N`` servers, each owning a slab of
the grid (``swarm.map.shard_layout``), each with its own numbered ``merged`` stream, its own
ledger of applied deltas (a robot has one epoch and one seq series per shard) and its own
``map/snapshot``. A :class:`ShardFeed` is what a replica keeps per server: the stream position,
the payloads queued for the owner's thread, whether a catch-up is due and when the last one
was, the record of applied deltas, and the server's slab (its grid and the global flat index
of its voxel 0). :class:`swarm.protocol.team_replica.TeamReplica` holds one feed per shard.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.protocol.applied_deltas import AppliedDeltas
from swarm.protocol.merged_stream import StreamPosition
from swarm.protocol.wire import Snapshot

#: ``unshared``: called before a snapshot is asked for; returns what to add on top of it.
Unshared = Callable[[], Callable[[Snapshot], Iterable[Delta]]]


@dataclass
class ShardFeed:
    """What a replica follows of one server: ``shard`` (0 unsharded), its ``grid`` (the slab;
    the mission grid when unsharded) and ``offset`` (global flat index of its local index 0).

    ``own()``: the (robot, epoch) of this server whose merged deltas the owner holds already;
    ``fetch()``: this server's snapshot (on ``grid``); ``unshared``: what the owner holds that
    this server may not (local indices of ``grid``); each may be None.
    """

    shard: int
    grid: Grid
    offset: int = 0
    own: Callable[[], tuple[str, int] | None] | None = None
    fetch: Callable[[], Snapshot] | None = None
    unshared: Unshared | None = None
    stream: StreamPosition = field(default_factory=StreamPosition)
    applied: AppliedDeltas = field(default_factory=AppliedDeltas)
    queue: deque = field(default_factory=deque)
    resync_due: threading.Event = field(default_factory=threading.Event)
    last_resync: float = -math.inf
    resync_wait: float = 0.0  # the longer wait after failed tries (0: none)

    @property
    def size(self) -> int:
        """Voxels of this server's slab."""
        return self.grid.size

    def to_global(self, idx: np.ndarray) -> np.ndarray:
        """This server's local flat indices as the team map's (int64)."""
        return np.asarray(idx, dtype=np.int64) + self.offset

    def globalised(self, delta: Delta) -> Delta:
        """``delta`` (local indices) in the team map's indices (the same delta when unsharded)."""
        if self.offset == 0:
            return delta
        return Delta(self.to_global(delta.idx), delta.dlam, delta.deta)

    def label(self, name: str) -> str:
        """``name`` for log lines, with the shard when there are several."""
        return name if self.offset == 0 and self.shard == 0 else f"{name} (shard {self.shard})"


def feeds_for(
    grid: Grid,
    layout,
    own,
    fetch,
    unshared,
) -> list[ShardFeed]:
    """The feeds of a replica of ``grid``: one when ``layout`` is None or has one shard (``own``,
    ``fetch``, ``unshared`` callables or None), else one per shard of the ``ShardLayout``, whose
    ``own``/``fetch``/``unshared`` are then sequences with one callable (or None) per shard, or
    None. Raises ValueError when a sequence's length is not the shard count, or the layout is
    over another grid."""
    if layout is None or layout.count == 1:
        return [ShardFeed(0, grid, 0, own, fetch, unshared)]
    if not grid.matches(layout.grid):
        raise ValueError(f"the shard layout's grid {layout.grid} is not the replica's {grid}")
    per_shard = {}
    for what, given in (("own", own), ("fetch", fetch), ("unshared", unshared)):
        values = [None] * layout.count if given is None else list(given)
        if len(values) != layout.count:
            raise ValueError(f"{what}: {len(values)} given for {layout.count} shards")
        per_shard[what] = values
    return [
        ShardFeed(
            k,
            layout.grid_of(k),
            layout.offset(k),
            per_shard["own"][k],
            per_shard["fetch"][k],
            per_shard["unshared"][k],
        )
        for k in range(layout.count)
    ]
