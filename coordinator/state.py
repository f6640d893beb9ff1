"""The coordinator's state without I/O: the replica, who holds what, and the planning of one answer.

Callable from tests; :class:`coordinator.role.Coordinator` drives it from Zenoh.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

from coordinator.assignment import (
    CoordinationParams,
    best_target,
    params_from_mission,
    teammates_share,
)
from coordinator.assignment_book import AssignmentBook
from coordinator.replica import CoordinatorReplica
from swarm.config import Mission
from swarm.map.coverage_map import CoverageMap
from swarm.navigation.exploration import (
    EntropyCandidate,
    ExplorationTarget,
    SearchContext,
    SearchOptions,
    rank_entropy_targets,
    wander_target,
)
from swarm.navigation.floor_cache import FloorCache, SweptFloor
from swarm.navigation.planner import cost_map, nearest_free_cell
from swarm.navigation.target_cache import SlabCache, TargetCache
from swarm.navigation.traversability import build_traversability, robot_band_top
from swarm.protocol.coord_messages import MAX_GOALS, MAX_VIEWS
from swarm.protocol.message_size import sources_of_deltas
from swarm.protocol.wire import (
    AssignReply,
    AssignRequest,
    Pose,
    Status,
    WireError,
    assign_request_on_key,
    status_on_key,
)

log = logging.getLogger("coordinator")

#: A released target is not handed back to the same robot while it is among its last few
#: releases and another candidate exists: standing points within this distance (m) are
#: skipped (choose_target's own exclusion radius).
RECENT_RADIUS = 1.0
#: Robot positions kept as swept (known empty) floor, and the spacing between them (m).
MAX_SWEPT = 50_000
SWEPT_STEP = 0.05


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
        # the team's reach (rigs' hit range) decides what is still in view, as on the robots
        sensor = replace(mission.sensor.model(), hit_range=mission.sensor_reach())
        # the ground of every source a map server may take deltas from is tracked, no more
        robots = sources_of_deltas(len(mission.robot_ids))
        self.team = CoordinatorReplica(
            mission.workspace.grid(), sensor, max_robots=robots, layout=mission.shard_layout()
        )
        self.targets = TargetCache(self.team.grid, self.team.changes)
        grid = self.team.grid
        self.floor = FloorCache(self.team.changes, mission.robot.radius)
        self._swept_floor = SweptFloor(grid.shape[:2], grid.lo[:2], grid.voxel, mission.robot.radius)
        self.book = AssignmentBook(self.params)
        self.counts: Counter[str] = Counter()
        self._book_lock = threading.Lock()
        self._answer_lock = threading.Lock()
        self._swept: list[tuple[float, float]] = []
        self._last_xy: dict[str, np.ndarray] = {}
        # the map columns each robot went to look at by itself (statuses' view), in order
        self._views: dict[str, list[tuple[float, float]]] = {}
        self._rng = np.random.default_rng(mission.sim.seed)

    # -- inputs ---------------------------------------------------------------------------
    def _moved(self, robot: str, xy) -> None:
        xy = np.asarray(xy, dtype=np.float64)[:2]
        last = self._last_xy.get(robot)
        if last is None or np.hypot(*(xy - last)) > SWEPT_STEP:
            self._last_xy[robot] = xy
            self._swept.append((float(xy[0]), float(xy[1])))
            self._swept_floor.add(self._swept[-1])
            if len(self._swept) > MAX_SWEPT:
                for old in self._swept[: len(self._swept) - MAX_SWEPT]:
                    self._swept_floor.drop(old)
                del self._swept[: len(self._swept) - MAX_SWEPT]

    def _viewed(self, robot: str, view) -> None:
        if view is None:
            return
        views = self._views.setdefault(robot, [])
        xy = (float(view[0]), float(view[1]))
        if not views or np.hypot(xy[0] - views[-1][0], xy[1] - views[-1][1]) > 1e-6:
            views.append(xy)
            del views[: max(0, len(views) - MAX_VIEWS)]

    def views_of_others(self, robot: str) -> tuple[tuple[float, float], ...]:
        """The columns (x, y) the robots other than ``robot`` went to look at by themselves,
        at most MAX_VIEWS, the most recent last (robots in name order)."""
        with self._book_lock:
            views = [xy for r in sorted(self._views) if r != robot for xy in self._views[r]]
        return tuple(views[-MAX_VIEWS:])

    def on_status(self, payload: bytes, now: float, key: str | None = None) -> list[tuple[str, str]]:
        """A ``robot/<rid>/status`` payload that came on ``key`` (None: trust its robot field);
        returns released (robot, reason). WireError if malformed or on another robot's key."""
        try:
            status = Status.decode(payload) if key is None else status_on_key(key, payload)
        except WireError:
            self.counts["status_rejected"] += 1
            raise
        with self._book_lock:
            self._moved(status.robot, status.pose.xyz)
            self._viewed(status.robot, status.view)
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
    def _rig(self, robot: str):
        return self.mission.rig_for(robot) if robot in self.mission.robot_ids else self.mission.rig

    def _floor(self, robot: str, pose: Pose):
        """(rig, traversability) of the team map from the per-tile cache (:class:`FloorCache`;
        call with the replica's lock held): :meth:`_reach_full`'s."""
        rig = self._rig(robot)
        self._check_pose(pose)
        with self._book_lock:
            swept = self._swept_floor.mask()
        return rig, self.floor.traversability(self.team.map, robot_band_top(rig.camera_height), swept)

    def _reach_full(self, robot: str, pose: Pose, cmap: CoverageMap):
        """(rig, traversability, planner cost map from the robot's cell) on ``cmap``, from scratch."""
        rig = self._rig(robot)
        self._check_pose(pose)
        with self._book_lock:
            swept = np.array(self._swept, dtype=np.float64).reshape(-1, 2)
        trav = build_traversability(
            cmap,
            robot_height=robot_band_top(rig.camera_height),
            robot_radius=self.mission.robot.radius,
            swept=swept,
        )
        return rig, trav, self._cost_map(trav, pose)

    def _cost_map(self, trav, pose: Pose) -> np.ndarray:
        """The planner's cost map (``GridPlanner.cost_map``'s values) from the robot's cell (the
        nearest free one when it is not free)."""
        cell = tuple(int(c) for c in trav.cell_of(np.array(pose.xyz[:2])))
        if not trav.is_free(np.array(cell)):
            cell = nearest_free_cell(trav, cell) or cell
        return cost_map(trav, cell)

    def candidates_for(self, robot: str, pose: Pose, cmap: CoverageMap, entropy: np.ndarray, reach=None):
        """Eq. 35 candidates of the team map with ``robot``'s path costs (whole map, spread out),
        computed from scratch on ``cmap`` and its per-voxel ``entropy``: the oracle of
        :meth:`cached_candidates`.

        ``reach``: what :meth:`_reach_full` gives for this robot and map, if already computed."""
        return self._ranked(pose, cmap, entropy, reach or self._reach_full(robot, pose, cmap), None)

    def cached_candidates(self, robot: str, pose: Pose, reach=None, slab: SlabCache | None = None):
        """:meth:`candidates_for` on the team map as it is, from the per-tile cache
        (:class:`swarm.navigation.target_cache.TargetCache`): the same list, without whole-map
        passes but for the planner's. Without ``slab`` and ``reach`` (:meth:`_slab`, and
        :meth:`_floor` with its cost map) it takes the replica's lock to bring the caches up to date."""
        if slab is None or reach is None:
            slab, fresh = self._cached_reach(robot, pose)
            reach = reach or fresh
        return self._ranked(pose, self.team.map, self.team.entropy.values, reach, slab)

    def _cached_reach(self, robot: str, pose: Pose):
        """(slab, (rig, traversability, cost map)) of ``robot`` from the caches, brought up to
        date under the replica's lock; the cost map is planned outside it."""
        with self.team.lock:  # the caches read the changed tiles' voxels
            slab = self._slab(self._rig(robot))
            rig, trav = self._floor(robot, pose)
        return slab, (rig, trav, self._cost_map(trav, pose))

    def _slab(self, rig) -> SlabCache:
        """The cached slab of the layer holding ``rig``'s camera (call with the replica's lock)."""
        grid = self.team.grid
        k0 = int(np.floor((float(rig.camera_height) - grid.lo[2]) / grid.voxel))
        return self.targets.slab(self.team.map, self.team.entropy.values, k0)

    def _ranked(self, pose: Pose, cmap: CoverageMap, entropy: np.ndarray, reach, slab: SlabCache | None):
        rig, trav, cost = reach
        grid = cmap.grid
        whole_map = float(np.linalg.norm(grid.hi[:2] - grid.lo[:2])) + grid.voxel
        c = self.mission.coordination
        ctx = SearchContext.build(
            cmap,
            entropy,
            (pose.xyz[0], pose.xyz[1], pose.ypr[0]),
            rig.camera_height,
            trav,
            cost,
            slab=None if slab is None else slab.beliefs,
        )
        options = SearchOptions(radius=whole_map)
        cached = {}
        if slab is not None and slab.k0 == ctx.k0:
            cached = {"slab": slab.fields, "stand": self.targets.standing(slab, ctx.reach, options.view)}
        return rank_entropy_targets(
            ctx,
            options,
            limit=c.max_candidates,
            min_separation=c.candidate_spacing,
            max_rejects=c.max_candidates,
            **cached,
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
            slab, reach = self._cached_reach(request.robot, request.pose)
            found = self.cached_candidates(request.robot, request.pose, reach, slab)
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
                # Wander only when eq. 35 targets exist but the others hold them: with none
                # at all on the team map, "nothing left" lets the agent fall back on its own
                # (eq. 35 on its map, then the 3-D frontier views the coordinator does not plan).
                if chosen is None and found:
                    wander = self._wander(request.pose, slab, reach, held, theirs)
                goal = chosen.xy if chosen is not None else None if wander is None else wander.xy
                if goal is not None:
                    self.book.hold(request.robot, goal, now)
                self.counts["released"] += len(released)
            for robot, reason in released:
                log.info("released the target of %s: %s", robot, reason)
        z = request.pose.xyz[2]
        if chosen is None and wander is None:
            self.counts["nothing_left"] += 1
            # the robot chooses by itself now: not the columns its teammates went to look at,
            # and away from where they are heading
            goals = tuple((float(x), float(y)) for x, y in held[:MAX_GOALS])
            reply = AssignReply(None, None, 0.0, views=self.views_of_others(request.robot), goals=goals)
            return Answer(request.robot, reply, None, len(found), len(held))
        self.counts["assigned" if chosen is not None else "wander"] += 1
        xy, yaw = (chosen.xy, chosen.gaze_yaw) if chosen is not None else (wander.xy, wander.gaze_yaw)
        # flush on demand: the robot gets back a target it had, so the team map may lack what
        # it saw there (still in its outbox, under the utility filter)
        flush = chosen is not None and _near(chosen.xy, recent, RECENT_RADIUS)
        self.counts["flush_asked"] += int(flush)
        reply = AssignReply(
            target=(float(xy[0]), float(xy[1]), float(z)),
            gaze=(math.cos(yaw), math.sin(yaw), 0.0),
            utility=float(chosen.utility) if chosen is not None else 0.0,
            flush=flush,
        )
        return Answer(request.robot, reply, chosen, len(found), len(held), wander)

    def _wander(
        self,
        pose: Pose,
        slab: SlabCache,
        reach,
        held: np.ndarray,
        theirs: np.ndarray | None,
    ):
        """When no eq. 35 target is left: the agent's wander (``wander_target``), kept off
        ``theirs`` (teammates' ground; None: anywhere) and away from the others'
        targets while it can be."""
        rig, trav, cost = reach
        ctx = SearchContext.build(
            self.team.map,  # its grid and sensor: the slab's beliefs come from the cache
            self.team.entropy.values,
            (pose.xyz[0], pose.xyz[1], pose.ypr[0]),
            rig.camera_height,
            trav,
            cost,
            exclude=list(held),
            exclude_radius=self.params.footprint_radius,
            slab=slab.beliefs,
        )
        return wander_target(ctx, 2.0 * self.mission.exploration.radius, self._rng, avoid=theirs)

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

    def decode_request(self, key: str, payload: bytes) -> AssignRequest:
        """The request of a ``coord/assign/<rid>`` query on ``key``, counted; WireError (counted
        in ``requests_rejected``) if it is malformed, or if its ``robot`` is not the key's
        ``<rid>`` (also counted in ``requests_robot_mismatch``): the key says who asks."""
        self.counts["requests"] += 1
        try:
            return assign_request_on_key(key, payload)
        except WireError as exc:
            self.counts["requests_rejected"] += 1
            if exc.kind == "robot_mismatch":
                self.counts["requests_robot_mismatch"] += 1
            raise

    def answer_request(self, request: AssignRequest, now: float) -> Answer:
        """:meth:`answer`, with a request it refuses (a pose outside the workspace) counted."""
        try:
            return self.answer(request, now)
        except WireError:
            self.counts["requests_rejected"] += 1
            raise


def _near(xy: np.ndarray, points: list[np.ndarray], radius: float) -> bool:
    return any(np.hypot(*(np.asarray(xy)[:2] - p[:2])) < radius for p in points)
