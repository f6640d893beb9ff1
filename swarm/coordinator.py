"""The coordinator role (``swarm coordinator``): entropy targets for the team, spread out.

It keeps a replica of the team map from the map server's ``merged`` stream (starting from
``map/snapshot`` when a server answers), follows every robot's ``robot/<rid>/status``, and
answers ``coord/assign``: the requesting robot gets the eq. 35 target of the team map that
maximises utility minus path cost, with the targets other robots hold discounted and kept
one sensor footprint away, and its teammates' ground lowered (Burgard et al.
2005 and our addition; the rule is in ``swarm.coordination`` and docs/coordinator.md).
When no eq. 35 target is left it wanders the robot on its own ground, as long as anything
unknown is in view.

Layers: :class:`TeamMap` (the replica: idempotent merged deltas), :class:`CoordinatorState`
(the replica, who holds what, and the planning of one answer; no I/O, callable from tests)
and :class:`Coordinator` (the Zenoh side: one worker thread applies merged deltas and
statuses in arrival order, one thread answers queries one at a time). An agent asks with
:func:`ask_for_target`.
"""

from __future__ import annotations

import argparse
import logging
import math
import queue
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

from swarm import bus
from swarm.applied_deltas import AppliedDeltas
from swarm.config import Mission
from swarm.coordination import (
    AssignmentBook,
    CoordinationParams,
    ObservedColumns,
    best_target,
    teammates_share,
)
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy import EntropyCache, default_table
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.navigation.exploration import (
    EntropyCandidate,
    ExplorationTarget,
    rank_entropy_targets,
    wander_target,
)
from swarm.navigation.planner import GridPlanner, nearest_free_cell
from swarm.navigation.traversability import build_traversability
from swarm.wire import AssignReply, AssignRequest, DeltaMessage, Pose, Snapshot, Status, WireError

__all__ = [
    "Coordinator",
    "CoordinatorState",
    "TeamMap",
    "add_arguments",
    "ask_for_target",
    "params_from_mission",
    "run",
]

log = logging.getLogger("swarm.coordinator")

#: Seconds to wait for a map server's snapshot at start.
SNAPSHOT_TIMEOUT_S = 3.0
#: A released target is not handed back to the same robot while it is among its last few
#: releases and another candidate exists: standing points within this distance (m) are
#: skipped (choose_target's own exclusion radius).
RECENT_RADIUS = 1.0
#: Robot positions kept as swept (known empty) floor, and the spacing between them (m).
MAX_SWEPT = 50_000
SWEPT_STEP = 0.05


def params_from_mission(mission: Mission) -> CoordinationParams:
    """The assignment parameters of a mission's ``coordination`` section.

    The footprint radius defaults to min(2 xi, sensor max range): two robots whose targets
    are at least 2 xi apart choose their next targets (within xi of where they stand, eq. 30)
    from disjoint neighbourhoods, and nothing beyond the sensor's range is seen from a target.
    """
    c = mission.coordination
    footprint = c.footprint_radius
    if footprint is None:
        footprint = min(2.0 * mission.exploration.radius, mission.sensor.max_range)
    return CoordinationParams(
        beta=c.beta,
        footprint_radius=footprint,
        overlap_weight=c.overlap_weight,
        robot_timeout_s=c.robot_timeout_s,
    )


# ---------------------------------------------------------------------------------------
# The replica
# ---------------------------------------------------------------------------------------
class TeamMap:
    """A replica of the team map: prior + every merged delta, each (robot, epoch, seq) once.

    Thread-safe: ``apply_payload``, ``load_snapshot`` and ``copy`` take ``lock``. Rejected
    and duplicate messages are counted in ``counts`` (``applied``, ``duplicate``,
    ``rejected``).
    """

    def __init__(self, grid: Grid, sensor: SensorModel) -> None:
        self.grid = grid
        self.map = CoverageMap(grid, sensor)
        self.table = default_table()
        self.entropy = EntropyCache.from_information(self.map.lam, self.map.eta, table=self.table)
        self.lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self._seen = AppliedDeltas()
        self.columns = ObservedColumns(grid.shape)

    def load_snapshot(self, snap: Snapshot) -> None:
        """Start from a map server's snapshot; the deltas its acks cover count as applied."""
        if not self.grid.matches(snap.grid):
            raise ValueError(f"snapshot grid {snap.grid} is not the mission's {self.grid}")
        with self.lock:
            self.map = CoverageMap(self.grid, self.map.sensor, snap.lam, snap.eta)
            self.entropy = EntropyCache.from_information(self.map.lam, self.map.eta, table=self.table)
            self._seen.cover(snap.acks, snap.above)
            # a snapshot does not say which robot saw what: only later deltas are attributed

    def apply_payload(self, payload: bytes) -> str:
        """Apply one ``merged`` payload: returns "applied" or "duplicate"; raises WireError
        (counted as rejected) for a malformed message or one on another grid."""
        try:
            msg = DeltaMessage.decode(payload)
            if not self.grid.matches(msg.grid):
                raise WireError(f"delta: grid {msg.grid} is not the mission's {self.grid}")
        except WireError:
            self.counts["rejected"] += 1
            raise
        with self.lock:
            if not self._seen.add(msg.robot, msg.epoch, msg.seq):
                self.counts["duplicate"] += 1
                return "duplicate"
            delta = Delta(msg.idx, msg.dlam, msg.deta)
            self.map.apply(delta)
            idx = msg.idx.astype(np.int64)
            self.entropy.update_information(idx, self.map.lam[idx], self.map.eta[idx])
            self.columns.add(msg.robot, idx, msg.dlam)
        self.counts["applied"] += 1
        return "applied"

    def copy(self) -> tuple[CoverageMap, np.ndarray]:
        """A consistent copy of the map and its per-voxel entropy (to plan without the lock)."""
        with self.lock:
            return self.map.copy(), self.entropy.values.copy()

    def teammates_ground(self, robot: str) -> np.ndarray:
        """(nx, ny): x-y cells to which other robots brought more information than ``robot``."""
        with self.lock:
            return self.columns.teammates_ground(robot)

    @property
    def entropy_bits(self) -> float:
        return float(self.entropy.total)


# ---------------------------------------------------------------------------------------
# Answers, without I/O
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Answer:
    """One request's outcome: the reply, the chosen candidate (None: nothing left) and the
    figures of the log line."""

    robot: str
    reply: AssignReply
    candidate: EntropyCandidate | None
    candidates: int
    held_by_others: int
    wander: ExplorationTarget | None = None  # the wander target, when no eq. 35 one was left


class CoordinatorState:
    """The replica, who holds what, and the planning of one answer (no I/O, no threads).

    ``now`` arguments are the caller's clock in seconds (monotonic). Safe to call from
    several threads: answers are computed one at a time; statuses and merged deltas may
    arrive meanwhile.
    """

    def __init__(self, mission: Mission, params: CoordinationParams | None = None) -> None:
        self.mission = mission
        self.params = params or params_from_mission(mission)
        self.team = TeamMap(mission.workspace.grid(), mission.sensor.model())
        self.book = AssignmentBook(self.params)
        self.counts: Counter[str] = Counter()
        self._book_lock = threading.Lock()
        self._answer_lock = threading.Lock()
        self._swept: list[tuple[float, float]] = []
        self._last_xy: dict[str, np.ndarray] = {}
        self._rng = np.random.default_rng(mission.sim.seed)

    # -- inputs ---------------------------------------------------------------------------
    def _moved(self, robot: str, xy) -> None:
        xy = np.asarray(xy, dtype=np.float64)[:2]
        last = self._last_xy.get(robot)
        if last is None or np.hypot(*(xy - last)) > SWEPT_STEP:
            self._last_xy[robot] = xy
            self._swept.append((float(xy[0]), float(xy[1])))
            if len(self._swept) > MAX_SWEPT:
                del self._swept[: len(self._swept) - MAX_SWEPT]

    def on_status(self, payload: bytes, now: float) -> list[tuple[str, str]]:
        """A ``robot/<rid>/status`` payload; returns released (robot, reason). WireError if malformed."""
        try:
            status = Status.decode(payload)
        except WireError:
            self.counts["status_rejected"] += 1
            raise
        with self._book_lock:
            self._moved(status.robot, status.pose.xyz)
            released = self.book.note_status(
                status.robot, now, status.pose.xyz, status.state, status.target
            ) + self.book.expire(now)
            self.counts["released"] += len(released)
        return released

    def expire(self, now: float) -> list[tuple[str, str]]:
        """Release the targets of silent robots (also done on every status and request)."""
        with self._book_lock:
            released = self.book.expire(now)
            self.counts["released"] += len(released)
        return released

    # -- answers ----------------------------------------------------------------------------
    def _reach(self, robot: str, pose: Pose, cmap: CoverageMap):
        """(rig, traversability, planner cost map from the robot's cell) on ``cmap``."""
        rig = self.mission.rig_for(robot) if robot in self.mission.robot_ids else self.mission.rig
        self._check_pose(pose)
        with self._book_lock:
            swept = np.array(self._swept, dtype=np.float64).reshape(-1, 2)
        trav = build_traversability(
            cmap,
            robot_height=max(rig.camera_height + 0.1, 0.3),
            robot_radius=self.mission.robot.radius,
            swept=swept,
        )
        cell = tuple(int(c) for c in trav.cell_of(np.array(pose.xyz[:2])))
        if not trav.is_free(np.array(cell)):
            cell = nearest_free_cell(trav, cell) or cell
        return rig, trav, GridPlanner(trav).cost_map(cell)

    def candidates_for(self, robot: str, pose: Pose, cmap: CoverageMap, entropy: np.ndarray, reach=None):
        """Eq. 35 candidates of the team map with ``robot``'s path costs (whole map, spread out).

        ``reach``: what :meth:`_reach` gives for this robot and map, if already computed."""
        rig, trav, cost = reach or self._reach(robot, pose, cmap)
        grid = cmap.grid
        whole_map = float(np.linalg.norm(grid.hi[:2] - grid.lo[:2])) + grid.voxel
        c = self.mission.coordination
        return rank_entropy_targets(
            cmap,
            entropy,
            (pose.xyz[0], pose.xyz[1], pose.ypr[0]),
            rig.camera_height,
            trav,
            cost,
            whole_map,
            limit=c.max_candidates,
            min_separation=c.candidate_spacing,
            max_rejects=c.max_candidates,
        )

    def _check_pose(self, pose: Pose) -> None:
        grid = self.team.grid
        x, y = pose.xyz[0], pose.xyz[1]
        if not (grid.lo[0] <= x < grid.hi[0] and grid.lo[1] <= y < grid.hi[1]):
            raise WireError(
                f"assign request: pose ({x:g}, {y:g}) is outside the workspace x [{grid.lo[0]:g}, "
                f"{grid.hi[0]:g}), y [{grid.lo[1]:g}, {grid.hi[1]:g})"
            )

    def answer(self, request: AssignRequest, now: float) -> Answer:
        """The reply to one request (see the module doc); the robot then holds its target.

        WireError (nothing changed) when the pose is outside the workspace."""
        self._check_pose(request.pose)
        with self._answer_lock:
            with self._book_lock:
                self._moved(request.robot, request.pose.xyz)
                released = self.book.note_request(request.robot, now, request.pose.xyz)
                released += self.book.expire(now)
                recent = self.book.recent_releases(request.robot)
                self.counts["released"] += len(released)
            for robot, reason in released:
                log.info("released the target of %s: %s", robot, reason)
            cmap, entropy = self.team.copy()
            reach = self._reach(request.robot, request.pose, cmap)
            found = self.candidates_for(request.robot, request.pose, cmap, entropy, reach)
            pool = [c for c in found if not _near(c.xy, recent, RECENT_RADIUS)] or found
            # teammates' ground: one mask for the scores and the wander
            theirs = self.team.teammates_ground(request.robot) if self.params.overlap_weight > 0 else None
            shares = self._teammates_shares(pool, theirs)
            with self._book_lock:
                released = self.book.expire(now)
                held = self.book.held_by_others(request.robot)
                best = None
                if pool:
                    best = best_target(
                        [c.utility for c in pool],
                        np.array([c.xy for c in pool]),
                        [c.path_cost for c in pool],
                        held,
                        self.params,
                        shares,
                    )
                chosen = None if best is None else pool[best]
                wander = None
                if chosen is None:
                    wander = self._wander(request.pose, cmap, reach, held, theirs)
                goal = chosen.xy if chosen is not None else None if wander is None else wander.xy
                if goal is not None:
                    self.book.hold(request.robot, goal, now)
                self.counts["released"] += len(released)
            for robot, reason in released:
                log.info("released the target of %s: %s", robot, reason)
        z = request.pose.xyz[2]
        if chosen is None and wander is None:
            self.counts["nothing_left"] += 1
            return Answer(request.robot, AssignReply(None, None, 0.0), None, len(found), len(held))
        self.counts["assigned" if chosen is not None else "wander"] += 1
        xy, yaw = (chosen.xy, chosen.gaze_yaw) if chosen is not None else (wander.xy, wander.gaze_yaw)
        reply = AssignReply(
            target=(float(xy[0]), float(xy[1]), float(z)),
            gaze=(math.cos(yaw), math.sin(yaw), 0.0),
            utility=float(chosen.utility) if chosen is not None else 0.0,
        )
        return Answer(request.robot, reply, chosen, len(found), len(held), wander)

    def _wander(self, pose: Pose, cmap: CoverageMap, reach, held: np.ndarray, theirs: np.ndarray | None):
        """When no eq. 35 target is left: the agent's wander (``wander_target``), kept off
        ``theirs`` (teammates' ground; None: anywhere) and away from the others'
        targets while it can be."""
        rig, trav, cost = reach
        return wander_target(
            cmap,
            (pose.xyz[0], pose.xyz[1], pose.ypr[0]),
            rig.camera_height,
            trav,
            cost,
            2.0 * self.mission.exploration.radius,
            self._rng,
            avoid=theirs,
            exclude=list(held),
            exclude_radius=self.params.footprint_radius,
        )

    def _teammates_shares(self, pool: list[EntropyCandidate], theirs: np.ndarray | None) -> np.ndarray | None:
        """f_r(t) of each candidate's standing point over ``theirs`` (None when it is None)."""
        if not pool or theirs is None:
            return None
        grid = self.team.grid
        return teammates_share(
            np.array([c.xy for c in pool]),
            theirs,
            grid.lo[:2],
            grid.voxel,
            self.params.footprint_radius,
        )

    def handle_request(self, payload: bytes, now: float) -> Answer:
        """Decode and answer a ``coord/assign`` payload; WireError (counted) if it is malformed."""
        self.counts["requests"] += 1
        try:
            request = AssignRequest.decode(payload)
        except WireError:
            self.counts["requests_rejected"] += 1
            raise
        try:
            return self.answer(request, now)
        except WireError:
            self.counts["requests_rejected"] += 1
            raise


def _near(xy: np.ndarray, points: list[np.ndarray], radius: float) -> bool:
    return any(np.hypot(*(np.asarray(xy)[:2] - p[:2])) < radius for p in points)


# ---------------------------------------------------------------------------------------
# The Zenoh role
# ---------------------------------------------------------------------------------------
class Coordinator:
    """The coordinator on a Zenoh session: ``start()``, then ``stop()`` (or ``wait()``).

    ``mission_name`` overrides the mission's name in the keys (``swarm/<mission>/...``);
    ``clock`` gives seconds (monotonic) for liveness.
    """

    def __init__(
        self,
        mission: Mission,
        session: zenoh.Session,
        params: CoordinationParams | None = None,
        *,
        mission_name: str | None = None,
        snapshot_timeout: float = SNAPSHOT_TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.state = CoordinatorState(mission, params)
        self.session = session
        self.name = mission_name or mission.mission
        self.snapshot_timeout = snapshot_timeout
        self.clock = clock
        self.started_from_snapshot = False
        self._inbox: queue.Queue = queue.Queue()
        self._queries: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._declared: list = []

    @property
    def counts(self) -> Counter[str]:
        """Every counter: requests, merged deltas (``merged_*``), statuses, releases."""
        out = Counter(self.state.counts)
        out.update({f"merged_{k}": v for k, v in self.state.team.counts.items()})
        return out

    def start(self) -> None:
        """Subscribe, load a snapshot if a map server answers, and start answering."""
        name, s = self.name, self.session
        # subscribe before the snapshot so no merged delta falls between the two
        self._declared.append(bus.subscribe(s, bus.key(name, "merged"), self._on_merged))
        self._declared.append(
            bus.subscribe(s, bus.key_pattern(name, "robot", "*", "status"), self._on_status)
        )
        self._load_snapshot()
        self._threads = [
            threading.Thread(target=self._work, name="coordinator-map", daemon=True),
            threading.Thread(target=self._answer_queries, name="coordinator-assign", daemon=True),
        ]
        for t in self._threads:
            t.start()
        self._declared.append(s.declare_queryable(bus.key(name, "coord", "assign"), self._queries.put))
        p = self.state.params
        log.info(
            "coordinator for mission %s: footprint %.2f m, beta %.3f/m, robot timeout %.1f s, map %s",
            name,
            p.footprint_radius,
            p.beta,
            p.robot_timeout_s,
            "from a snapshot" if self.started_from_snapshot else "from the prior",
        )

    def _load_snapshot(self) -> None:
        try:
            replies = self.session.get(bus.key(self.name, "map", "snapshot"), timeout=self.snapshot_timeout)
            for reply in replies:
                if reply.ok is None:
                    log.warning("map/snapshot answered an error: %s", _text(reply.err.payload))
                    continue
                self.state.team.load_snapshot(Snapshot.decode(reply.ok.payload.to_bytes()))
                self.started_from_snapshot = True
                return
        except (zenoh.ZError, ValueError) as exc:  # WireError is a ValueError
            log.warning("no usable map snapshot (%s); starting from the prior", exc)

    def _on_merged(self, _key: str, payload: bytes) -> None:
        self._inbox.put(("merged", payload))

    def _on_status(self, _key: str, payload: bytes) -> None:
        self._inbox.put(("status", payload))

    def _work(self) -> None:
        """The one thread that changes the replica and the book from the streams, in order."""
        last_expiry = self.clock()
        while not self._stop.is_set():
            try:
                kind, payload = self._inbox.get(timeout=0.2)
            except queue.Empty:
                kind = None
            now = self.clock()
            try:
                if kind == "merged":
                    self.state.team.apply_payload(payload)
                elif kind == "status":
                    for robot, reason in self.state.on_status(payload, now):
                        log.info("released the target of %s: %s", robot, reason)
                if now - last_expiry >= 0.5:
                    last_expiry = now
                    for robot, reason in self.state.expire(now):
                        log.info("released the target of %s: %s", robot, reason)
            except WireError as exc:
                log.warning("rejected %s message: %s", kind, exc)
            except Exception:  # never die of one message
                self.state.counts["worker_errors"] += 1
                log.exception("error handling a %s message", kind)

    def _answer_queries(self) -> None:
        while not self._stop.is_set():
            try:
                query = self._queries.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                self._answer(query)
            finally:
                query.drop()

    def _answer(self, query: zenoh.Query) -> None:
        payload = b"" if query.payload is None else query.payload.to_bytes()
        try:
            answer = self.state.handle_request(payload, self.clock())
        except WireError as exc:
            log.warning("rejected assign request: %s", exc)
            query.reply_err(f"coord/assign: {exc}".encode())
            return
        except Exception as exc:  # never die of one request
            self.state.counts["requests_failed"] += 1
            log.exception("assign request failed")
            query.reply_err(f"coord/assign: internal error: {exc}".encode())
            return
        query.reply(query.key_expr, answer.reply.encode())
        _log_answer(answer)

    def stop(self) -> None:
        """Stop answering and join the threads (the session stays open: the caller owns it)."""
        self._stop.set()
        for declared in self._declared:
            try:
                declared.undeclare()
            except zenoh.ZError:
                pass
        self._declared = []
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads = []

    def request_stop(self) -> None:
        """Make ``wait()`` return (safe from a signal handler); ``stop()`` then cleans up."""
        self._stop.set()

    def wait(self) -> None:
        """Block until ``stop()`` or ``request_stop()`` is called."""
        while not self._stop.wait(0.5):
            pass


def _log_answer(answer: Answer) -> None:
    robot = answer.robot
    c = answer.candidate
    if c is None and answer.wander is not None:
        w = answer.wander
        log.info(
            "assign %s -> wander to (%.2f, %.2f) gaze %+.0f deg: no eq. 35 target left (%d held by others)",
            robot,
            w.xy[0],
            w.xy[1],
            math.degrees(w.gaze_yaw),
            answer.held_by_others,
        )
        return
    if c is None:
        log.info(
            "assign %s -> nothing left (%d candidates, %d held by others)",
            robot,
            answer.candidates,
            answer.held_by_others,
        )
        return
    log.info(
        "assign %s -> stand (%.2f, %.2f) gaze %+.0f deg, looking at (%.2f, %.2f): eq. 35 %.1f bits/m, "
        "path %.2f m (%d candidates, %d held by others)",
        robot,
        c.xy[0],
        c.xy[1],
        math.degrees(c.gaze_yaw),
        c.point[0],
        c.point[1],
        c.utility,
        c.path_cost,
        answer.candidates,
        answer.held_by_others,
    )


def _text(payload) -> str:
    data = payload.to_bytes() if hasattr(payload, "to_bytes") else bytes(payload)
    return data.decode("utf-8", errors="replace")


# ---------------------------------------------------------------------------------------
# The client side
# ---------------------------------------------------------------------------------------
def ask_for_target(
    session: zenoh.Session, mission: str, robot: str, pose: Pose, timeout: float = 2.0
) -> AssignReply | None:
    """Ask the coordinator of ``mission`` for a target for ``robot`` at ``pose``.

    Returns the reply (its ``target`` is None when the coordinator has nothing left), or None
    when no coordinator answered within ``timeout`` seconds or it answered with an error
    (logged): the agent then chooses by itself. The reply's target is where to stand (x, y of
    a reachable cell; z of the request's pose), its gaze the unit direction to face there.
    """
    payload = AssignRequest(robot, pose).encode()
    try:
        for reply in session.get(bus.key(mission, "coord", "assign"), payload=payload, timeout=timeout):
            if reply.ok is None:
                log.warning("%s: coordinator error: %s", robot, _text(reply.err.payload))
                continue
            try:
                return AssignReply.decode(reply.ok.payload.to_bytes())
            except WireError as exc:
                log.warning("%s: malformed coordinator reply: %s", robot, exc)
    except zenoh.ZError as exc:
        log.warning("%s: coord/assign query failed: %s", robot, exc)
    return None


# ---------------------------------------------------------------------------------------
# swarm coordinator
# ---------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm coordinator``."""
    parser.description = (
        "Run the coordinator: keep a replica of the team map from swarm/<mission>/merged (starting "
        "from map/snapshot when a map server answers), follow robot/*/status, and answer "
        "coord/assign with entropy-gradient targets spread out over the team (Burgard et al. 2005). "
        "Stops on SIGINT/SIGTERM."
    )
    parser.add_argument("--config", required=True, type=Path, help="mission YAML file")
    parser.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (default tcp/127.0.0.1:7447); repeatable",
    )
    parser.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on as well; repeatable",
    )
    parser.add_argument(
        "--mission", metavar="NAME", help="mission name in the keys (default: the config's `mission`)"
    )
    parser.add_argument(
        "--snapshot-timeout",
        type=float,
        default=SNAPSHOT_TIMEOUT_S,
        metavar="S",
        help=f"seconds to wait for a map server's snapshot at start (default {SNAPSHOT_TIMEOUT_S:g})",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log at debug level")


def run(args: argparse.Namespace) -> int:
    """``swarm coordinator``: run until SIGINT/SIGTERM; 0 on a clean stop, 2 on bad arguments."""
    import sys

    from swarm.config import ConfigError, load_mission

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s: %(message)s"
    )
    try:
        mission = load_mission(args.config)
        if args.mission is not None:
            bus.key(args.mission)  # a valid key part
        session = bus.open_session(args.listen, args.connect)
    except (ConfigError, ValueError, ConnectionError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 2
    coordinator = Coordinator(
        mission, session, mission_name=args.mission, snapshot_timeout=args.snapshot_timeout
    )
    signal.signal(signal.SIGTERM, lambda *_: coordinator.request_stop())
    signal.signal(signal.SIGINT, lambda *_: coordinator.request_stop())
    try:
        coordinator.start()
        coordinator.wait()
    finally:
        coordinator.stop()
        counts = coordinator.counts
        print(
            "coordinator: "
            + ", ".join(f"{k} {counts[k]}" for k in sorted(counts))
            + f"; team map {coordinator.state.team.entropy_bits:,.0f} bits",
            flush=True,
        )
        session.close()
    return 0
