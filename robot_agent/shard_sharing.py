"""One agent's delta sharing with a sharded map service (docs/sharding.md; notes/shard_design.md).

The map service is ``N`` ordinary map servers, shard ``k`` owning the slab
``layout.span(k)`` of the mission grid's flat indices, under the key prefix
``bus.shard_mission(mission, k, N)`` (the mission's own name when ``N == 1``). Per shard the
agent keeps a :class:`ShardLink`: its own outbox over the slab's voxels (local indices),
its own :class:`DeltaSender` (grid ``layout.grid_of(k)``, the shard's prefix, its own epoch
and seq series) and its own :class:`AckPoller` on the shard's ``map/acks``.
:class:`ShardedSharing` splits each fused frame's global delta by owner
(``layout.split``) into the links' outboxes, and each link takes what is worth sending from
the slab's views of the map's lam/eta (contiguous flat ranges: no copy). With ``N == 1``
there is one link over the whole grid under the mission's own keys: today's agent exactly.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
import zenoh

from robot_agent.ack_poller import AckPoller
from robot_agent.delta_sender import DeltaSender
from robot_agent.sharing import DeltaOutbox, OutboxStats
from swarm.config import Mission
from swarm.map.delta import Delta
from swarm.map.entropy_table import EntropyTable
from swarm.map.shard_layout import ShardLayout
from swarm.protocol import bus
from swarm.protocol.applied_deltas import AppliedDeltas
from swarm.protocol.wire import Snapshot


class ShardLink:
    """One shard's sharing: outbox (slab voxels), sender, ack poller and the epoch it issued.

    ``clock()`` is the time (s) stamped on each delta sent (the agent's latest frame time).
    """

    def __init__(
        self,
        session: zenoh.Session,
        mission: Mission,
        robot_id: str,
        layout: ShardLayout,
        shard: int,
        table: EntropyTable,
        clock: Callable[[], float],
    ) -> None:
        self.shard = shard
        self.start_stop = layout.span(shard)
        self.grid = layout.grid_of(shard)
        #: the shard's key prefix: the mission's name when unsharded, else <mission>/shard/<k>
        self.prefix = bus.shard_mission(mission.mission, shard, layout.count)
        #: the epoch the shard's server issued (map/epoch/<rid>); None until it has
        self.epoch: int | None = None
        self._clock = clock
        sharing = mission.sharing
        self.outbox = DeltaOutbox(
            self.grid.size,
            sharing.share_min_bits,
            table,
            max_held_bits=math.inf if sharing.max_held_bits is None else sharing.max_held_bits,
        )
        self.sender = DeltaSender(session, self.prefix, robot_id, self.grid, self._sent, self._granted)
        acks_key = bus.key(self.prefix, "map", "acks")
        self.acks = AckPoller(
            session, acks_key, robot_id, self.outbox, self.sender, lambda: self.epoch, self.publish
        )

    def take(self, lam: np.ndarray, eta: np.ndarray, flush: bool = False) -> None:
        """Send what the slab's outbox finds worth it, judged on the global (flat) ``lam``/``eta``
        sliced to the slab (views)."""
        start, stop = self.start_stop
        taken = self.outbox.take(lam[start:stop], eta[start:stop], flush=flush)
        if taken is not None:
            self.publish(*taken)

    def publish(self, seq: int, delta: Delta) -> None:
        """Hand ``delta`` (local indices) over to the sender (never blocks)."""
        self.sender.send(seq, self._clock(), delta)

    def _sent(self, _seq: int, size: int) -> None:
        self.outbox.stats.bytes_sent += size

    def _granted(self, grant) -> None:
        self.epoch = grant.epoch


class ShardedSharing:
    """The agent's :class:`ShardLink` per shard of ``layout`` (one when unsharded)."""

    def __init__(
        self,
        session: zenoh.Session,
        mission: Mission,
        robot_id: str,
        layout: ShardLayout,
        table: EntropyTable,
        clock: Callable[[], float],
    ) -> None:
        self.layout = layout
        self.robot_id = robot_id
        self.links = [
            ShardLink(session, mission, robot_id, layout, k, table, clock) for k in range(layout.count)
        ]

    @property
    def count(self) -> int:
        return len(self.links)

    # -- the frame loop ----------------------------------------------------------------------
    def add(self, delta: Delta) -> None:
        """A fused frame's delta (global indices, sorted unique) into its owners' outboxes."""
        if self.count == 1:
            self.links[0].outbox.add(delta)
            return
        for shard, part in self.layout.split(delta).items():
            self.links[shard].outbox.add(part)

    def share(self, lam: np.ndarray, eta: np.ndarray, flush: bool = False) -> None:
        """Each link sends what is worth it; ``lam``/``eta`` are the global map's flat arrays."""
        for link in self.links:
            link.take(lam, eta, flush)

    def start(self) -> None:
        """Start every link's sender (asks its shard for an epoch) and ack poller."""
        for link in self.links:
            link.sender.start()
            link.acks.start()

    def shutdown(self, ack_wait_s: float) -> None:
        """Stop polling, wait at most ``ack_wait_s`` s per link for every delta to be put and
        acked (not at all for a shard that never answered), then stop the senders."""
        for link in self.links:
            link.acks.stop()
        for link in self.links:
            link.sender.drain(ack_wait_s)
        for link in self.links:
            link.acks.await_all(ack_wait_s)
        for link in self.links:
            link.sender.stop()

    # -- figures -----------------------------------------------------------------------------
    @property
    def stats(self) -> OutboxStats:
        """The links' outbox figures summed (a new OutboxStats; the link's own when unsharded)."""
        if self.count == 1:
            return self.links[0].outbox.stats
        total = OutboxStats()
        for link in self.links:
            for field in vars(total):
                setattr(total, field, getattr(total, field) + getattr(link.outbox.stats, field))
        return total

    @property
    def acked(self) -> list[int]:
        """Per shard, its server's last contiguous acked seq of this run's deltas (0 before any)."""
        return [link.acks.acked for link in self.links]

    @property
    def held_bits(self) -> float:
        """What the utility filters hold back, summed over the shards (bits)."""
        return sum(link.outbox.held_bits for link in self.links)

    @property
    def unacked(self) -> int:
        """Deltas sent and not acked yet, over every shard."""
        return sum(len(link.outbox.unacked) for link in self.links)

    def own_epoch(self, shard: int) -> tuple[str, int | None]:
        """``(robot id, epoch)`` of this run on shard ``shard`` (epoch None until issued)."""
        return self.robot_id, self.links[shard].epoch

    def replica_feeds(self, snapshot_of: Callable[[int], Snapshot]) -> dict:
        """The team replica's per-shard ``own``, ``fetch`` (``snapshot_of(k)``: shard k's
        snapshot) and ``unshared`` (swarm.protocol.team_replica.TeamReplica, ``layout``)."""
        shards = range(self.count)
        return {
            "own": [functools.partial(self.own_epoch, k) for k in shards],
            "fetch": [functools.partial(snapshot_of, k) for k in shards],
            "unshared": [functools.partial(self.unshared, k) for k in shards],
        }

    def unshared(self, shard: int) -> Callable[[Snapshot], list[Delta]]:
        """What this agent holds that shard ``shard``'s server may not, in its local indices.

        Called before that shard's snapshot is asked for, it notes the deltas sent and not
        acked then (the snapshot holds every one acked before it was asked for); the function
        it returns gives, for the snapshot, the noted deltas it does not hold, oldest first,
        then the information not sent yet."""
        link = self.links[shard]
        held = link.outbox.to_resend()
        robot, epoch = self.robot_id, link.epoch

        def finish(snap: Snapshot) -> list[Delta]:
            covered = AppliedDeltas()
            covered.cover(snap.acks, snap.above)
            parts = [d for seq, d in held if (robot, epoch, seq) not in covered]
            return [*parts, link.outbox.pending()]

        return finish
