"""The agent process: a thin Zenoh loop around the Explorer (``swarm agent``).

Takes ``robot/<rid>/frame``, answers every frame with ``robot/<rid>/cmd`` (the simulator's
lockstep clock waits for it), publishes ``robot/<rid>/status``, and shares voxel deltas
on ``delta/<rid>`` through the utility-filtered outbox, keeping them until the map
server's ``map/acks`` says they are durable (robot_agent.ack_poller); robot_agent.delta_sender
publishes them from its own thread under the epoch the server issued.

The team map reaches the agent as the server's ``merged`` stream: every delta of another
robot (or of an earlier run of this one) is added to the local map once, so the robot
plans on what the team has seen; its own deltas of this run are already in it and are
skipped. An agent that starts while a map server runs begins from its ``map/snapshot``,
and one that misses merged samples starts again from a fresh snapshot plus what it holds
that the server does not (:meth:`Agent.unshared`). The team map is a
:class:`swarm.protocol.team_replica.TeamReplica` whose map and entropy the explorer fuses into.
With coordination on, the agent asks ``coord/assign`` before each decision that chooses a new
target (``Explorer.wants_target``; robot_agent.assignment_requests) and passes the answer in
(``TeamAdvice``); the explorer chooses by itself (eq. 35) when no coordinator answered in
time, and the agent asks again a little later.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter

import zenoh

from robot_agent.assignment_requests import AssignmentRequests
from robot_agent.explorer import Explorer
from robot_agent.frame_inbox import FrameInbox
from robot_agent.frame_link import FrameLink, PendingFrame, WireLink
from robot_agent.shard_sharing import ShardedSharing
from robot_agent.teammate_statuses import TeammateStatuses
from swarm.config import Mission
from swarm.log_limit import LogLimiter
from swarm.protocol import bus
from swarm.protocol.codec import short
from swarm.protocol.map_client import (
    MapClient,
    MapQueryError,
    MapServerUnavailable,
    MissionMismatch,
    missions_answering,
)
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import Cmd, Frame, Pose, Status, WireError

log = logging.getLogger("swarm.agent")

STATUS_EVERY = 1  # frames: every frame, so that teammates avoid this robot where it is now
PROGRESS_EVERY_S = 10.0  # seconds between progress lines (and "still waiting" lines)
SHUTDOWN_ACK_WAIT_S = 5.0  # at shutdown, wait this long at most for the server to ack every delta


class Agent:
    """One robot's agent on a Zenoh session."""

    def __init__(
        self,
        mission: Mission,
        robot_id: str,
        session: zenoh.Session,
        strategy: str = "entropy",
        seed: int = 0,
        coordination: bool = True,
        link: FrameLink | None = None,
    ) -> None:
        if robot_id not in mission.robot_ids:
            raise ValueError(f"robot {robot_id!r} is not in the mission (robots: {mission.robot_ids})")
        self.mission = mission
        self.robot_id = robot_id
        self.session = session
        self.explorer = Explorer(mission, robot_id, strategy, seed)
        name = mission.mission
        #: per map server shard: outbox, sender, ack poller, epoch (one link when unsharded)
        self.sharing = ShardedSharing(
            session, mission, robot_id, mission.shard_layout(), self.explorer.table, lambda: self.last_t
        )
        #: where frames come from and commands go: robot/<rid>/frame and cmd, or a robot's ROS 2 topics
        self.link = link or WireLink(session, name, robot_id)
        self._status_pub = session.declare_publisher(bus.key(name, "robot", robot_id, "status"))
        self._frames = FrameInbox()  # the newest frame: older waiting ones are dropped, counted
        self.link.frames.start(self._frames)
        #: what a remote peer makes the agent log: one line per reason per 10 s, with counts
        self._peer_log = LogLimiter(log)
        #: the team map: the explorer fuses into the replica's map and entropy, merged deltas of
        #: the others are applied at each frame, a missed one makes it start again from a snapshot
        self.team = TeamReplica(
            self.explorer.grid,
            self.explorer.sensor,
            **self._replica_feeds(),
            layout=self.sharing.layout,
            table=self.explorer.table,
            cmap=self.explorer.map,
            entropy=self.explorer.entropy,
            peer_log=self._peer_log,
            name=robot_id,
            entropy_per_delta=False,  # one entropy pass per frame over the teammates' deltas
        )
        self._merged_subs = self.team.follow(session, name)  # every shard's merged
        #: the teammates' statuses: where they are, for keeping out of their way
        self.statuses = TeammateStatuses(session, name, robot_id, self._peer_log)
        self.coordination = coordination and strategy == "entropy"
        #: coord/assign before each new target (robot_agent.assignment_requests)
        self.assignments = AssignmentRequests(session, name, robot_id, lambda: self._share(flush=True))
        self._told_target: tuple[float, float] | None = None  # the target of the last status
        self._pose: Pose | None = None
        self.rejected_frames = 0
        self.frames_fused = 0
        self.last_t = 0.0
        self.progress_every_s = PROGRESS_EVERY_S
        self._frame_key = self.link.describe()
        self._stop = threading.Event()

    # -- the loop ------------------------------------------------------------------------
    def run(self, max_frames: int | None = None, idle_timeout: float | None = None) -> None:
        """Handle frames until stopped (or ``max_frames``, or ``idle_timeout`` s without a frame)."""
        self.catch_up()
        self.sharing.start()
        handled = 0
        last_frame = time.monotonic()
        log.info("%s: waiting for frames on %s", self.robot_id, self._frame_key)
        report = (last_frame, 0)  # (time, frames handled) of the last progress line
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if now - report[0] >= self.progress_every_s:
                    self._log_progress(handled - report[1], now - report[0])
                    report = (now, handled)
                payload = self._frames.take(timeout=0.2)
                if payload is None:
                    if idle_timeout is not None and time.monotonic() - last_frame > idle_timeout:
                        break
                    continue
                last_frame = time.monotonic()
                self.handle(payload)
                handled += 1
                if max_frames is not None and handled >= max_frames:
                    break
        finally:
            self.shutdown()

    def _log_progress(self, frames: int, seconds: float) -> None:
        """One progress line: frames fused and their rate, deltas sent and acked, map entropy."""
        if self.frames_fused == 0:
            log.info(
                "%s: no frame yet on %s (is 'swarm sim world' or the robot's driver publishing?)",
                self.robot_id,
                self._frame_key,
            )
            return
        stats = self.sharing.stats
        log.info(
            "%s: %d frames fused (%.1f/s)%s, %d deltas sent, %s acked by the map server, %d resent, "
            "%s bits held back; map entropy %s bits; merged from the team %d; coordinator %s",
            self.robot_id,
            self.frames_fused,
            frames / max(seconds, 1e-9),
            self._dropped_frames_note(),
            stats.deltas_sent,
            self._acked_note(),
            stats.resent,
            f"{self.sharing.held_bits:,.0f}",
            f"{self.explorer.map_entropy:,.0f}",
            self.merged_counts["applied"],
            dict(self.coordinator_counts) or "not asked yet",
        )

    @property
    def coordinator_counts(self) -> Counter[str]:
        """The coordinator's answers: ``silent``, ``nothing_left``, ``assigned``, ``flushed``."""
        return self.assignments.counts

    def _acked_note(self) -> str:
        """The acked seqs: one number unsharded, one per shard (``0/3/2``) when sharded."""
        return "/".join(str(a) for a in self.sharing.acked)

    # -- the unsharded agent's sharing parts (link 0); ValueError when the service is sharded --
    def _link0(self):
        if self.sharing.count != 1:
            raise ValueError(f"the map service has {self.sharing.count} shards: use agent.sharing.links")
        return self.sharing.links[0]

    @property
    def outbox(self):
        """The delta outbox (unsharded map service only)."""
        return self._link0().outbox

    @property
    def sender(self):
        """The delta sender (unsharded map service only)."""
        return self._link0().sender

    @property
    def acks(self):
        """The map/acks poller (unsharded map service only)."""
        return self._link0().acks

    @property
    def epoch(self) -> int | None:
        """The epoch the map server issued (map/epoch/<rid>); None until it has. A sharded
        service issues one per shard (``sharing.links[k].epoch``): None here, so that the team
        replica's ``own()`` on the mission's own keys never takes a stray delta for this run's."""
        return self.sharing.links[0].epoch if self.sharing.count == 1 else None

    @property
    def acked(self) -> int:
        """The map server's last contiguous acked seq of this run's deltas (0 before any);
        summed over the shards when the service is sharded."""
        return sum(self.sharing.acked)

    @property
    def superseded_frames(self) -> int:
        """Frames dropped unanswered because a newer one came before the agent took them."""
        return self._frames.superseded

    def _dropped_frames_note(self) -> str:
        """The frames dropped unanswered so far, if any: superseded, and refused (logged each)."""
        notes = []
        if self._frames.superseded:
            faster = "the driver sends faster than the agent fuses"
            notes.append(f"{self._frames.superseded:,} older frames dropped: {faster}")
        if self.rejected_frames:
            notes.append(f"{self.rejected_frames:,} frames refused (see the warnings above)")
        if refused := self.link.frames.notes():
            notes.append(refused)
        return f" ({'; '.join(notes)})" if notes else ""

    def handle(self, payload: bytes | PendingFrame) -> Cmd | None:
        """Fuse one frame, answer with a command, then share what is worth it.

        The command goes out as soon as the decision is made: the simulator (or a robot's
        driver) waits for it, so the work the decision does not need, sharing this frame's
        delta and applying the team's merged deltas that arrived meanwhile, comes after it
        and overlaps the next physics step instead of delaying it.
        """
        # a link's pending frame makes itself (None: it could not, and the link counted why)
        frame = payload.frame() if hasattr(payload, "frame") else self._decode(payload)
        if frame is None:
            return None
        self.last_t = frame.t
        self._pose = frame.pose
        self.apply_merged()
        self.statuses.apply(self.explorer.teammates, frame.t)
        delta = self.explorer.fuse(frame)
        self.frames_fused += 1
        self.sharing.add(delta)
        x, y = frame.pose.xyz[0], frame.pose.xyz[1]
        advice = (
            self.assignments.advice(self._pose) if self.coordination and self.explorer.wants_target else None
        )
        decision = self.explorer.decide(x, y, frame.pose.ypr[0], frame.t, advice)
        cmd = Cmd(self.robot_id, frame.seq, frame.t, decision.v, decision.omega, decision.tilt)
        target = self.explorer.target
        self.link.commands.send(cmd, decision, None if target is None else target.gaze_yaw)
        self._share(flush=decision.state == "done")
        self.apply_merged()
        # every STATUS_EVERY frames, and at once when the robot takes up a new target
        if frame.seq % STATUS_EVERY == 0 or decision.state == "done" or decision.target != self._told_target:
            self._told_target = decision.target
            target = None if decision.target is None else (*decision.target, 0.0)
            status = Status(
                self.robot_id,
                frame.t,
                frame.pose,
                target,
                decision.state,
                self.sharing.stats.bytes_sent,
                self.explorer.view_point(),
            )
            self._status_pub.put(status.encode())
        return cmd

    def _decode(self, payload: bytes) -> Frame | None:
        """A robot/<rid>/frame payload's frame; None when refused (counted, logged)."""
        try:
            frame = Frame.decode(payload)
        except WireError as exc:
            self.rejected_frames += 1
            self._peer_log.warning("frame", "%s: rejected frame: %s", self.robot_id, exc)
            return None
        if frame.robot != self.robot_id:
            self.rejected_frames += 1
            self._peer_log.warning(
                "frame_robot", "%s: rejected frame addressed to %s", self.robot_id, short(frame.robot, 40)
            )
            return None
        return frame

    def _share(self, flush: bool = False) -> None:
        """Each shard's link sends what is worth it (never blocks: sender threads put them)."""
        self.sharing.share(self.explorer.map.lam, self.explorer.map.eta, flush=flush)

    # -- the team map --------------------------------------------------------------------
    def _server(self, shard: int) -> str:
        """Map server shard ``shard``'s key prefix (the mission's name when unsharded)."""
        return bus.shard_mission(self.mission.mission, shard, self.sharing.count)

    def _replica_feeds(self) -> dict:
        """The team replica's ``own``, ``fetch`` and ``unshared``: about the one server, or
        one each per shard of a sharded map service (docs/sharding.md)."""
        if self.sharing.count == 1:
            return {
                "own": lambda: (self.robot_id, self.epoch),
                "fetch": lambda: MapClient(self.session, self.mission.mission, 2.0).snapshot(),
                "unshared": self.unshared,
            }
        return self.sharing.replica_feeds(lambda k: MapClient(self.session, self._server(k), 2.0).snapshot())

    def catch_up(self, timeout: float = 2.0) -> bool:
        """Start from the map server's snapshot, if one answers within ``timeout`` seconds;
        sharded, each shard's slab from that shard's snapshot (True when any was loaded)."""
        if self.sharing.count > 1:
            loaded = [self._catch_up_shard(k, timeout) for k in range(self.sharing.count)]
            entropy = self.explorer.map_entropy
            log.info(
                "%s: started from %d of %d map server shards' snapshots (entropy %.0f bits)",
                self.robot_id,
                sum(loaded),
                len(loaded),
                entropy,
            )
            return any(loaded)
        name = self.mission.mission
        try:
            snap = MapClient(self.session, name, timeout).snapshot()
        except (MapServerUnavailable, MapQueryError, zenoh.ZError) as exc:
            others = [m for m in missions_answering(self.session, 0.5) if m != name]
            if others:
                raise MissionMismatch(
                    f"the mission config names mission {name!r}, but the map server on this network "
                    f"serves mission {', '.join(repr(m) for m in others)}"
                ) from exc
            log.info("%s: no team map to start from (%s)", self.robot_id, exc)
            return False
        try:
            self.team.load_snapshot(snap)
        except ValueError as exc:
            log.warning("%s: ignored the server's snapshot: %s", self.robot_id, exc)
            return False
        entropy = self.explorer.map_entropy
        log.info("%s: started from the team map (entropy %.0f bits)", self.robot_id, entropy)
        return True

    def _catch_up_shard(self, shard: int, timeout: float) -> bool:
        try:
            snap = MapClient(self.session, self._server(shard), timeout).snapshot()
            self.team.load_snapshot(snap, shard=shard)
        except (MapServerUnavailable, MapQueryError, zenoh.ZError, ValueError) as exc:
            log.info("%s: no snapshot of map server shard %d to start from (%s)", self.robot_id, shard, exc)
            return False
        return True

    @property
    def merged_counts(self) -> Counter[str]:
        """The team map's counts: ``applied``, ``duplicate``, ``own``, ``rejected``, ``dropped``,
        ``resyncs`` (``TeamReplica``)."""
        return self.team.counts

    def apply_merged(self) -> int:
        """Add the merged deltas received since the last frame (after a catch-up from a fresh
        snapshot when one was missed); returns how many were applied."""
        return self.team.drain()

    def unshared(self):
        """What this agent's map holds that the (unsharded) server's may not: see
        :meth:`ShardedSharing.unshared`; the team replica's resync calls it."""
        self._link0()
        return self.sharing.unshared(0)

    # -- shutdown ------------------------------------------------------------------------
    def stop(self) -> None:
        self._stop.set()

    def shutdown(self, ack_wait_s: float = SHUTDOWN_ACK_WAIT_S) -> None:
        """Flush every pending voxel, wait until the map server holds every delta sent (at most
        ``ack_wait_s`` s; not at all when no server answers), then stop polling.

        The wait makes "the agent has exited" mean "its deltas are in the team map" whenever a map
        server is there: a runner that then reads the server's map gets all of them.
        """
        stats = self.sharing.stats
        before = (stats.deltas_sent, stats.voxels_sent)
        self._share(flush=True)
        stats = self.sharing.stats
        sent, voxels = stats.deltas_sent - before[0], stats.voxels_sent - before[1]
        self._stop.set()
        self.sharing.shutdown(ack_wait_s)
        log.info(
            "%s: shutdown flush: %s; %d deltas not yet acked by the map server%s",
            self.robot_id,
            f"sent {sent} last delta(s), {voxels} voxels" if sent else "nothing pending",
            self.sharing.unacked,
            self._dropped_frames_note(),
        )
        self.link.close()
        for sub in self._merged_subs:
            sub.undeclare()
        self.statuses.undeclare()
