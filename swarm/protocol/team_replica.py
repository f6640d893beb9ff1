"""A replica of the team map, kept from the map server's ``merged`` stream (docs/architecture.md).

Every client that holds a copy of the team map (an agent, the coordinator, ``swarm view``,
``swarm map ros2``, the mission runner's monitor) holds one :class:`TeamReplica`: the coverage
map (information form, float32), its per-voxel entropy cache, the record of applied deltas
(each (robot, epoch, seq) at most once), the check and apply of a ``merged`` payload, and the
catch-up from ``map/snapshot``.

Two threads meet in it. Zenoh's callback calls :meth:`receive` (or :meth:`on_sample`): it
notes the sample's place in the numbered stream (``swarm.protocol.merged_stream``) and queues
the payload within a byte budget. The owner's thread calls :meth:`drain`: it applies what is
queued and, when a sample was missed (a number skipped, a new server run, or a payload the
budget could not take), first starts again from a fresh snapshot, at most once per
``resync_interval_s``. What the owner added to its map that the snapshot cannot hold yet (an
agent's own information not acked) comes back through ``unshared``: called before the
snapshot is asked for, it returns a function of the snapshot that gives that information as
deltas, added on top in order. Counts (``counts``): ``applied``, ``duplicate``, ``own`` (the owner's
own deltas, skipped), ``rejected`` (and ``rejected_<kind>``), ``dropped`` (over the budget),
``resyncs``, ``resync_failed``.

A sharded map service (``layout``: a ``swarm.map.shard_layout.ShardLayout`` of several shards)
is several servers, each with its own ``merged`` stream, ledger and snapshot over its slab:
the replica keeps one :class:`~swarm.protocol.replica_feed.ShardFeed` per shard (subscribe them
all with :meth:`TeamReplica.follow`), applies each shard's deltas at the slab's offset, and
catches up a shard that missed a sample from that shard's snapshot alone (docs/sharding.md).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence

import numpy as np
import zenoh

from swarm.map import heap
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import EntropyTable, default_table
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.applied_deltas import AppliedDeltas
from swarm.protocol.byte_budget import MAX_QUEUED_MERGED_BYTES, ByteBudget
from swarm.protocol.codec import short
from swarm.protocol.merged_stream import StreamPosition
from swarm.protocol.replica_feed import ShardFeed, Unshared, feeds_for
from swarm.protocol.wire import DeltaMessage, Snapshot, WireError

log = logging.getLogger("swarm.replica")

#: Seconds between two catch-ups from ``map/snapshot`` (each costs the server a whole-map query).
RESYNC_INTERVAL_S = 2.0
#: After a failed catch-up the wait doubles, up to this many seconds (no server answers: the
#: owner's thread, which waits for each try, is not held back every interval).
MAX_RESYNC_INTERVAL_S = 30.0

__all__ = ["TeamReplica", "Unshared"]


class TeamReplica:
    """The team map as one client holds it (see the module doc).

    ``grid``/``sensor``: the mission's (the sensor sets the prior). ``own()``: the (robot,
    epoch) whose merged deltas the owner's map holds already (skipped, counted ``own``), or
    None. ``fetch()``: the server's snapshot (raises when none answers); None: no catch-up.
    ``cmap``/``entropy``: a map and its entropy cache to keep (an agent's, which its explorer
    fuses into); default the prior's. ``on_applied(msg, idx, size)``: called after each applied
    delta (see :meth:`applied_hook`).
    ``peer_log``: a ``swarm.log_limit.LogLimiter`` (one line per reason per interval), else
    the module's logger. ``apply`` and ``load_snapshot`` take ``lock``. ``layout``: the map
    service's ``ShardLayout`` (None or one shard: unsharded); with several shards ``own``,
    ``fetch`` and ``unshared`` are sequences, one callable (or None) per shard, each about that
    shard's server (its epochs, its snapshot on its slab, local indices).
    ``entropy_per_delta``: True (default), the entropy is brought up to date after each applied
    delta, so an ``on_applied`` hook reads the entropy with that delta in (the mission monitor's
    curve); False, :meth:`drain` brings it up to date once, for everything it applied, under
    one hold of the lock (one table pass instead of one per delta: the agents and the
    coordinator, which apply a delta of every teammate each frame).
    """

    def __init__(
        self,
        grid: Grid,
        sensor: SensorModel,
        *,
        own: Callable[[], tuple[str, int] | None] | Sequence | None = None,
        fetch: Callable[[], Snapshot] | Sequence | None = None,
        unshared: Unshared | Sequence | None = None,
        max_queued_bytes: int = MAX_QUEUED_MERGED_BYTES,
        table: EntropyTable | None = None,
        cmap: CoverageMap | None = None,
        entropy: EntropyCache | None = None,
        on_applied: Callable[[DeltaMessage, np.ndarray, int], None] | None = None,
        peer_log=None,
        name: str = "replica",
        layout=None,
        entropy_per_delta: bool = True,
    ) -> None:
        self.grid = grid
        #: one per map server followed (one unsharded): stream, queue, ledger, catch-up timing
        self.feeds: list[ShardFeed] = feeds_for(grid, layout, own, fetch, unshared)
        self.map = cmap if cmap is not None else CoverageMap(grid, sensor)
        self.table = table or default_table()
        if entropy is None:
            entropy = EntropyCache.from_information(self.map.lam, self.map.eta, table=self.table)
        self.entropy = entropy
        self.on_applied = on_applied
        self.counts: Counter[str] = Counter()
        self.lock = threading.RLock()
        self.name = name
        self.budget = ByteBudget(max_queued_bytes)
        self.resync_interval_s = RESYNC_INTERVAL_S
        self.peer_log = peer_log
        self.entropy_per_delta = entropy_per_delta
        #: inside a batched drain: the voxels applied whose entropy is not brought up to date yet
        self._stale: list[np.ndarray] | None = None

    # -- the unsharded replica's one feed, by its old names -------------------------------------
    @property
    def sharded(self) -> bool:
        return len(self.feeds) > 1

    def _only(self) -> ShardFeed:
        if self.sharded:
            raise AttributeError("a sharded replica has one feed per shard: use replica.feeds[k]")
        return self.feeds[0]

    @property
    def fetch(self) -> Callable[[], Snapshot] | None:
        return self._only().fetch

    @fetch.setter
    def fetch(self, fetch: Callable[[], Snapshot] | None) -> None:
        self._only().fetch = fetch

    @property
    def applied(self) -> AppliedDeltas:
        return self._only().applied

    @property
    def stream(self) -> StreamPosition:
        return self._only().stream

    # -- the receiving side (Zenoh's callback thread) -----------------------------------------
    def subscribe(self, session: zenoh.Session, key_expr: str, shard: int = 0) -> zenoh.Subscriber:
        """Subscribe :meth:`on_sample` to ``key_expr`` (shard ``shard``'s ``merged``)."""
        return session.declare_subscriber(key_expr, lambda sample: self.on_sample(sample, shard))

    def follow(self, session: zenoh.Session, mission: str) -> list[zenoh.Subscriber]:
        """Subscribe every feed to its server's ``merged`` (``bus.shard_mission`` of ``mission``):
        the subscribers, one per shard (undeclare them to stop)."""
        count = len(self.feeds)
        return [
            self.subscribe(session, bus.key(bus.shard_mission(mission, k, count), "merged"), k)
            for k in range(count)
        ]

    def on_sample(self, sample: zenoh.Sample, shard: int = 0) -> None:
        """Zenoh's callback: :meth:`receive` the sample's payload and attachment; never raises."""
        try:
            attachment = None if sample.attachment is None else sample.attachment.to_bytes()
            self.receive(sample.payload.to_bytes(), attachment, shard)
        except Exception:  # noqa: BLE001 (a callback must never raise into Zenoh)
            log.exception("%s: merged callback failed", self.name)

    def receive(self, payload: bytes, attachment: bytes | None = None, shard: int = 0) -> bool:
        """Queue one ``merged`` payload of shard ``shard`` for :meth:`drain`; False when the
        waiting ones fill the budget (dropped, counted, and that shard's catch-up due). A
        skipped number or a new server run in ``attachment`` makes a catch-up due too."""
        feed = self.feeds[shard]
        missed = feed.stream.observe(attachment)
        name = feed.label(self.name)
        if missed is not None:
            self._warn(f"missed:{missed}", "%s: merged samples missed (%s): catching up", name, missed)
            feed.resync_due.set()
        if not self.budget.take(len(payload)):
            self.counts["dropped"] += 1
            feed.resync_due.set()
            self._warn("dropped", "%s: merged delta dropped (queue full): catching up", name)
            return False
        feed.queue.append(payload)
        return True

    @property
    def queued(self) -> int:
        """Payloads waiting for :meth:`drain`."""
        return sum(len(feed.queue) for feed in self.feeds)

    @property
    def resync_due(self) -> bool:
        """Whether a sample of any shard was missed since its last catch-up."""
        return any(feed.resync_due.is_set() for feed in self.feeds)

    # -- the owner's thread ---------------------------------------------------------------------
    def drain(self, max_s: float | None = None) -> int:
        """Catch up first when due (and allowed), then apply the queued payloads (for at most
        ``max_s`` seconds when given); returns how many were applied. A refused payload is
        counted and logged, never raised."""
        for feed in self.feeds:
            if feed.resync_due.is_set() and feed.fetch is not None:
                self.resync(shard=feed.shard)
        deadline = None if max_s is None else time.monotonic() + max_s
        applied = 0
        with self.lock if not self.entropy_per_delta else contextlib.nullcontext():
            if not self.entropy_per_delta:
                self._stale = []
            try:
                for feed in self.feeds:
                    while feed.queue and (deadline is None or time.monotonic() < deadline):
                        applied += self._apply_queued(feed)
            finally:
                self._settle_entropy()
        return applied

    def _apply_queued(self, feed: ShardFeed) -> bool:
        """Apply the next payload of ``feed``'s queue; whether it was applied."""
        payload = feed.queue.popleft()
        self.budget.give(len(payload))
        try:
            return self.apply_payload(payload, feed.shard) == "applied"
        except WireError as exc:
            name = feed.label(self.name)
            self._warn(f"rejected:{exc.kind}", "%s: rejected merged delta: %s", name, exc)
            return False

    def _settle_entropy(self) -> None:
        """Bring the entropy of the voxels a batched drain applied up to date (under the lock)."""
        stale, self._stale = self._stale, None
        if stale:
            idx = np.concatenate(stale)
            self.entropy.update_information(idx, self.map.lam[idx], self.map.eta[idx])

    def apply_payload(self, payload: bytes, shard: int = 0) -> str:
        """Check and apply one ``merged`` payload: "applied", "duplicate" or "own". Raises
        WireError (counted ``rejected`` and ``rejected_<kind>``, the map unchanged) for a
        malformed message, one on another grid, one that changes nothing (the server never
        sends one), or one that would leave a voxel out of range (``CoverageMap.apply_received``)."""
        grid = self.feeds[shard].grid
        try:
            msg = DeltaMessage.decode(payload)
            if not grid.matches(msg.grid):
                raise WireError(f"delta: grid {msg.grid} is not the team map's {grid}", "other_grid")
            if not msg.carries_information():
                raise WireError(f"delta of {short(msg.robot, 40)} changes nothing", "no_information")
            return self.apply_message(msg, len(payload), shard)
        except WireError as exc:
            self.counts["rejected"] += 1
            self.counts[f"rejected_{exc.kind}"] += 1
            raise

    def apply_message(self, msg: DeltaMessage, size: int = 0, shard: int = 0) -> str:
        """Apply a decoded delta of shard ``shard`` (on its grid) once (see :meth:`apply_payload`;
        ``size``: its payload's bytes, for :meth:`applied_hook`). Raises WireError
        ``out_of_range`` (not counted here)."""
        feed = self.feeds[shard]
        own = feed.own() if feed.own is not None else None
        if own is not None and (msg.robot, msg.epoch) == own:
            self.counts["own"] += 1
            return "own"
        with self.lock:
            if (msg.robot, msg.epoch, msg.seq) in feed.applied:
                self.counts["duplicate"] += 1
                return "duplicate"
            if self.sharded and msg.idx.size and int(msg.idx.max()) >= feed.size:
                # at the slab's offset it would land in another shard's voxels
                outside = f"delta of {short(msg.robot, 40)}: a voxel outside shard {shard}"
                raise WireError(outside, "out_of_range")
            delta = feed.globalised(Delta(msg.idx, msg.dlam, msg.deta))
            try:  # whole or nothing: the map is as it was when a voxel would leave its range
                self.map.apply_received(delta)
            except ValueError as exc:
                raise WireError(f"delta of {short(msg.robot, 40)}: {exc}", "out_of_range") from exc
            feed.applied.add(msg.robot, msg.epoch, msg.seq)
            idx = delta.idx.astype(np.int64)
            if self._stale is not None:
                self._stale.append(idx)
            else:
                self.entropy.update_information(idx, self.map.lam[idx], self.map.eta[idx])
            self.counts["applied"] += 1
            self.applied_hook(msg, idx, size)
        return "applied"

    def applied_hook(self, msg: DeltaMessage, idx: np.ndarray, size: int) -> None:
        """Called under ``lock`` after each applied delta (``idx``: its voxels in the team map's
        indices, int64; ``msg``: as its server sent it, local indices when sharded); a
        subclass keeps what it derives from the map here (attribution, dirty voxels); by
        default it calls ``on_applied``."""
        if self.on_applied is not None:
            self.on_applied(msg, idx, size)

    def add_local(self, delta: Delta) -> None:
        """Add information the owner gathered itself (an agent's fused frame): map and entropy."""
        with self.lock:
            self.map.apply(delta)
            idx = delta.idx.astype(np.int64)
            self.entropy.update_information(idx, self.map.lam[idx], self.map.eta[idx])

    def load_snapshot(self, snap: Snapshot, keep: Iterable[Delta] = (), shard: int = 0) -> None:
        """Start from a server snapshot (prior included) plus ``keep`` (what the owner holds that
        the snapshot does not, in the snapshot's indices); the deltas its acks cover count as
        applied. The arrays are written in place, so whoever holds ``map`` or ``entropy`` sees the
        new team map. Sharded: ``snap`` is shard ``shard``'s, over its slab, and only the slab
        is written. Raises ValueError for a snapshot on another grid."""
        feed = self.feeds[shard]
        if not feed.grid.matches(snap.grid):
            raise ValueError(f"the snapshot's grid {snap.grid} is not the team map's {feed.grid}")
        start, stop = feed.offset, feed.offset + feed.size
        with self.lock:
            self.map.lam[start:stop] = np.asarray(snap.lam, np.float32).reshape(-1)
            self.map.eta[start:stop] = np.asarray(snap.eta, np.float32).reshape(-1)
            for delta in keep:
                self.map.apply(feed.globalised(delta))
            if self.sharded:
                slab = np.arange(start, stop, dtype=np.int64)
                self.entropy.update_information(slab, self.map.lam[start:stop], self.map.eta[start:stop])
            else:
                self.entropy.refill_information(self.map.lam, self.map.eta)
            feed.applied = AppliedDeltas()
            feed.applied.cover(snap.acks, snap.above)
            self.loaded_hook(snap)
        heap.trim()  # the pages the snapshot's chunks held (swarm.map.heap)

    def loaded_hook(self, snap: Snapshot) -> None:
        """Called under ``lock`` after :meth:`load_snapshot` (a subclass resets what it derives)."""

    def resync(self, force: bool = False, shard: int = 0) -> bool:
        """Catch shard ``shard`` up from its ``fetch()`` now, unless its last catch-up is under
        ``resync_interval_s`` old (``force``: anyway); True when the snapshot was loaded. On
        failure the map stays as it is, the catch-up stays due, it is counted ``resync_failed``
        and logged, and the wait before the next try doubles (up to MAX_RESYNC_INTERVAL_S)."""
        feed = self.feeds[shard]
        now = time.monotonic()
        wait = max(self.resync_interval_s, feed.resync_wait)
        if feed.fetch is None or (not force and now - feed.last_resync < wait):
            return False
        feed.last_resync = now
        feed.resync_due.clear()
        finish = feed.unshared() if feed.unshared is not None else None
        name = feed.label(self.name)
        try:
            snap = feed.fetch()
            self.load_snapshot(snap, finish(snap) if finish is not None else (), shard)
        except Exception as exc:  # noqa: BLE001 (no server, a bad reply: keep the map, try later)
            feed.resync_due.set()
            feed.resync_wait = min(2 * wait, MAX_RESYNC_INTERVAL_S)
            self.counts["resync_failed"] += 1
            self._warn("resync_failed", "%s: cannot catch up from map/snapshot: %s", name, short(exc, 200))
            return False
        feed.resync_wait = 0.0
        self.counts["resyncs"] += 1
        self._warn(
            "resync", "%s: caught up from map/snapshot (%d catch-ups so far)", name, self.counts["resyncs"]
        )
        return True

    # -- reading -------------------------------------------------------------------------------
    def copy(self) -> tuple[CoverageMap, np.ndarray]:
        """A consistent copy of the map and its per-voxel entropy (to plan without the lock)."""
        with self.lock:
            return self.map.copy(), self.entropy.values.copy()

    @property
    def entropy_bits(self) -> float:
        """The map's entropy (bits)."""
        return float(self.entropy.total)

    def _warn(self, reason: str, msg: str, *args) -> None:
        if self.peer_log is not None:
            self.peer_log.warning(reason, msg, *args)
        else:
            log.warning(msg, *args)
