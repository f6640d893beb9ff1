"""One robot's mind, without I/O: fuse each frame (its local map, ``robot_agent.local_map``),
pick targets, plan, and drive.

The loop is the paper's (section III): fuse the batch of the current view into the local
coverage map, choose a viewpoint by the entropy gradient (eq. 27-35, or a baseline), drive
there through known free space, look along the gradient on arrival, and stop when the map
entropy is below H_th (eq. 36) or nothing reachable is informative. The robot starts by
turning once on the spot, since a forward camera sees nothing of its sides.

A robot whose camera sits on a tilt head (``rig.tilt_range_deg`` > 0) also looks up on
arrival, one frame with the head raised to its limit after the gaze, and makes its last
turn before giving up with the head raised: a level camera low on a robot sees the upper
part of a room only from afar, and eq. 30 chooses targets in the sensor's slab alone.

The entropy strategy drives through unknown or ambiguous floor only towards a probe (a room
whose floor it has not seen, behind a door; ``swarm.navigation.probing``), planning and
replanning it on the optimistic grid; every other target is reached on known free floor.

Before it stops for want of targets, an entropy robot takes its last looks: at voxels that
still hold over half the prior's entropy and that a reachable cell sees (docs/design.md
section 3). In a team, a robot the coordinator leaves to itself first keeps away from where
its teammates head (the reply's ``goals``).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable

import numpy as np

from robot_agent.decision import Decision
from robot_agent.kernels import load_kernels
from robot_agent.local_map import LocalMapping
from robot_agent.stereo import matcher_for_rig
from robot_agent.teammate_avoidance import TeammateAvoidance, robot_rank
from swarm.config import Mission
from swarm.map.coverage_map import CoverageMap, prior_entropy_bits
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table
from swarm.navigation.exploration import ExplorationTarget, choose_target, last_look_target
from swarm.navigation.path_follower import DriveWatch, FollowerLimits, PathFollower, needs_replan, wrap_angle
from swarm.navigation.planner import GridPlanner, large_free_areas, nearest_free_cell
from swarm.navigation.probing import open_swept, optimistic_traversability
from swarm.navigation.teammates import Teammates, block_teammates, blocking_teammate
from swarm.navigation.traversability import TraversabilityGrid, build_traversability, robot_band_top
from swarm.navigation.view_targets import CameraReach

log = logging.getLogger("swarm.agent")

STRATEGIES = ("entropy", "frontier", "random")
GAZE_TOLERANCE = math.radians(12)
REPLAN_EVERY = 4  # frames between traversability refreshes while driving
FAILED_MEMORY = 12  # how many given-up targets to avoid
FAILED_RADIUS = 1.0  # m: a target standing this near a given-up one is avoided too
MAX_FAILURES = 6  # unreachable targets in a row before the robot looks around again
MAX_LOOKS_IN_PLACE = 2  # targets in a row at the robot's own cell before it is avoided
BOXED_IN_CELLS = 30  # fewer reachable cells than this: step blind to free floor beyond
FRONTIER_LOOKS = 3  # frontier strategy: looks at a 3-D frontier column, each from another cell
TEAM_SPREAD_RADIUS = 2.0  # m: a robot choosing alone first keeps this far from teammates' goals
# entropy strategy, where it would stop: voxels with more than this share of the prior's
# entropy left that a reachable cell can see are looked at first, each column once
LAST_LOOK_SHARE = 0.5
VIEW_KINDS = ("view", "frontier3d", "last look")  # targets that look at a map column chosen here


class Explorer(TeammateAvoidance, LocalMapping):
    """The local map of one robot and the decisions it drives by."""

    def __init__(self, mission: Mission, robot_id: str, strategy: str = "entropy", seed: int = 0) -> None:
        if strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {STRATEGIES}, got {strategy!r}")
        self.mission = mission
        self.robot_id = robot_id
        self.strategy = strategy
        self.rng = np.random.default_rng([seed, sum(robot_id.encode())])
        self.grid = mission.workspace.grid()
        self.rig = mission.rig_for(robot_id)
        # Returns beyond the rig's hit range are free space up to it, no hit (SensorModel.reach).
        self.sensor = mission.sensor_model_for(robot_id)
        self.map = CoverageMap(self.grid, self.sensor)
        load_kernels(log.info, robot_id)  # before the first frame
        self.table = default_table()
        self.entropy = EntropyCache.from_information(self.map.lam, self.map.eta, table=self.table)
        self.threshold = mission.threshold_bits()
        self.matcher = matcher_for_rig(self.rig) if self.rig.mode == "stereo" else None
        body = mission.robot
        self.follower = PathFollower(
            FollowerLimits(max_speed=body.max_speed, max_turn_rate=body.max_turn_rate)
        )
        self.robot_height = robot_band_top(self.rig.camera_height)
        self.state = "look_around"
        self.turned = 0.0
        self.last_yaw: float | None = None
        self.target: ExplorationTarget | None = None
        self.failed: list[np.ndarray] = []
        self.swept: list[tuple[float, float]] = []
        self.progress = DriveWatch()
        self.frames = 0
        self.trav: TraversabilityGrid | None = None
        self.optimistic: TraversabilityGrid | None = None  # probes' grid (entropy strategy)
        self.failures_in_a_row = 0
        self.looked_before_done = False
        self.looks_in_place = 0  # targets in a row at the robot's own cell
        # where the camera can look (the head only ever looks up), for 3-D frontier views
        self.camera = CameraReach.of_rig(self.rig, self.sensor.reach, looks_up=self.rig.tilt_range_deg > 0)
        self.tried_views: list[np.ndarray] = []  # x-y of the columns a view target was chosen for
        self.view_stands: list[np.ndarray] = []  # x-y of the standing point of each of tried_views
        #: x-y of the columns teammates went to look at (from the coordinator; entropy strategy)
        self.team_views: list[np.ndarray] = []
        #: x-y of where the teammates are heading (from the coordinator's "nothing left")
        self.team_goals: list[np.ndarray] = []
        self.looking_again = False  # frontier strategy: looking at columns a second/third time
        self.looking_last = False  # entropy strategy: last looks at uncertain voxels before stopping
        self.last_look_bits = LAST_LOOK_SHARE * prior_entropy_bits(self.grid, self.sensor) / self.grid.size
        self.target_kinds: Counter[str] = Counter()  # targets chosen, by kind (printed at exit)
        self.give_ups: Counter[str] = Counter()  # drives given up, by reason (printed at exit)
        self.declined_assignments = 0  # coordinator targets near a given-up one (printed at exit)
        self.has_head = self.rig.tilt_range_deg > 0
        self.look_up_tilt = -math.radians(self.rig.tilt_range_deg)
        self.head = 0.0  # the tilt this robot asks for now
        #: Asked first for each new target (the coordinator); None: choose alone.
        self.assigner: Callable[[], ExplorationTarget | None] | None = None
        #: where the teammates were last seen (the agent feeds their statuses in)
        self.teammates = Teammates(robot_id, body.radius, body.max_speed, lead_s=mission.sim.frame_period_s)
        self.priority = robot_rank(mission.robot_ids, robot_id)  # lowest first: the others yield to it
        self.now: float | None = None  # the frame's mission time (s); None: teammates ignored
        self.deferred: list[tuple[np.ndarray, float]] = []  # (target x-y, set aside until t)
        self.waited = 0  # frames waited in a row for a teammate in the way

    # -- decisions -----------------------------------------------------------------------
    def decide(self, x: float, y: float, yaw: float, t: float | None = None) -> Decision:
        """The command for this frame, given the robot's pose (from the frame) and the frame's
        time ``t`` (s, the mission's clock; None: teammates are not avoided)."""
        self.now = t
        decision = self._decide(x, y, yaw)
        decision.tilt = self.head if self.has_head else None
        return decision

    def _decide(self, x: float, y: float, yaw: float) -> Decision:
        self.frames += 1
        here = np.array([x, y])
        if not self.swept or np.hypot(*(here - self.swept[-1])) > 0.05:
            self.swept.append((x, y))
        if self.map_entropy <= self.threshold:
            self.state = "done"
        if self.state == "done":
            return Decision(0.0, 0.0, "done")
        if self.state == "look_around":
            return self._look_around(yaw)
        if self.state == "gaze":
            return self._gaze(yaw)
        if self.state == "look_up":  # this frame was seen with the head raised
            self.head = 0.0
            self.state = "choose"
            return Decision(0.0, 0.0, "gaze", self._target_xy())
        if self.state == "drive":
            return self._drive(here, yaw)
        return self._choose(here, yaw)

    def _look_around(self, yaw: float) -> Decision:
        if self.last_yaw is not None:
            self.turned += abs(wrap_angle(yaw - self.last_yaw))
        self.last_yaw = yaw
        if self.turned >= 2 * math.pi - 0.2:
            self.head = 0.0
            self.state = "choose"
            return Decision(0.0, 0.0, "choose")
        return Decision(0.0, self.mission.robot.max_turn_rate * 0.8, "look_around")

    def _gaze(self, yaw: float) -> Decision:
        error = wrap_angle(self.target.gaze_yaw - yaw) if self.target else 0.0
        if abs(error) <= GAZE_TOLERANCE:
            if self.has_head:  # raise the head for the next frame, then choose
                self.head = self.look_up_tilt
                self.state = "look_up"
            else:
                self.state = "choose"
            return Decision(0.0, 0.0, "gaze", self._target_xy())
        omega = float(
            np.clip(2.0 * error, -self.mission.robot.max_turn_rate, self.mission.robot.max_turn_rate)
        )
        return Decision(0.0, omega, "gaze", self._target_xy())

    def _refresh_traversability(self) -> TraversabilityGrid:
        swept = np.asarray(self.swept)
        trav = build_traversability(
            self.map, robot_height=self.robot_height, robot_radius=self.mission.robot.radius, swept=swept
        )
        if self.strategy == "entropy":  # probes, and the way back through their doors
            self.optimistic = optimistic_traversability(self.map, trav, self.robot_height)
            trav = open_swept(trav, self.optimistic, swept)
        self.trav = trav
        return self.trav

    def _choose(self, here: np.ndarray, yaw: float) -> Decision:
        discs = self._teammate_discs(here)
        trav = block_teammates(self._refresh_traversability(), discs)
        planner = GridPlanner(trav)
        cell = tuple(int(c) for c in trav.cell_of(here))
        start = here
        if not trav.is_free(np.array(cell)):
            # The robot's own cell looks blocked (inflation, noise): leave from the nearest free one.
            cell = nearest_free_cell(trav, cell)
            if cell is None:
                return self._wander_blind(yaw)
            start = trav.centre(np.array(cell))
        if self.failures_in_a_row >= MAX_FAILURES:
            self.failures_in_a_row = 0
            return self._wander_blind(yaw)
        cost = planner.cost_map(cell)
        if np.isfinite(cost).sum() < BOXED_IN_CELLS:
            # Boxed in by floor the camera cannot see (a level camera misses the floor near
            # the robot): step blind to the nearest free cell beyond, as a robot with bumpers
            # or sonars would (the paper's Scout had sonars); the physics stops it on contact.
            roomy = large_free_areas(trav.free, BOXED_IN_CELLS)
            beyond = nearest_free_cell(roomy & ~np.isfinite(cost), cell)
            if beyond is not None:
                cell, start = beyond, trav.centre(np.array(beyond))
                cost = planner.cost_map(cell)
        exclude = self.failed[-FAILED_MEMORY:] + self._set_aside()
        target = self.assigner() if self.assigner is not None else None
        if target is not None and _near_any(target.xy, exclude, FAILED_RADIUS):
            # The coordinator does not know what this robot gave up: it offers the same spot
            # again while it holds the best candidate on the team map, and the robot would
            # look from there (or drive there and stick) for ever. Choose alone instead.
            self.declined_assignments += 1
            target = None
        if target is None and self.team_goals:
            # choosing alone in a team: first away from where the teammates are heading
            target = self._own_target(here, yaw, trav, cost, exclude, optimistic=self.optimistic, team=True)
        target = target or self._own_target(here, yaw, trav, cost, exclude, optimistic=self.optimistic)
        if target is None and (self.looked_before_done or self.looking_again) and self.strategy == "frontier":
            # Where the robot would conclude (after its last turn), the frontier strategy
            # first looks again at 3-D frontier columns one look left unknown, each from
            # another cell, then forgets the spots it gave up: 1 m around each, they can
            # cover all the reachable floor of a small room while frontiers are in view of
            # it (the lab: 4 spots, 185 viewable frontier columns left). Finite, as every
            # 3-D view uses up one of a column's FRONTIER_LOOKS. (After the first time, without
            # a turn before each: new frontier still comes first.)
            self.looking_again = True
            target = self._own_target(here, yaw, trav, cost, exclude, FRONTIER_LOOKS)
            if target is None and exclude:
                self.failed.clear()
                target = self._own_target(here, yaw, trav, cost, [], FRONTIER_LOOKS)
        if target is None and (self.looked_before_done or self.looking_last) and self.strategy == "entropy":
            # Where the robot would conclude (after its last turn): first look at what is
            # still uncertain in view of a reachable cell (known voxels too), each column once.
            self.looking_last = True
            target = self._last_look(here, yaw, trav, cost, exclude)
        if target is not None:
            self.target_kinds[target.kind] += 1
        if target is not None and target.kind in VIEW_KINDS and target.voxel is not None:
            i, j, _k = np.unravel_index(target.voxel, self.grid.shape)
            self.tried_views.append(self.grid.lo[:2] + (np.array([i, j]) + 0.5) * self.grid.voxel)
            self.view_stands.append(np.asarray(target.xy, dtype=np.float64))
        if target is None:
            if not self.looked_before_done:
                # Nothing reachable looks informative: turn once more (head raised, if it
                # can be) before concluding.
                self.looked_before_done = True
                self.head = self.look_up_tilt
                return self._wander_blind(yaw)
            self.state = "done"
            return Decision(0.0, 0.0, "done")
        self.looked_before_done = False
        if np.hypot(*(target.xy - here)) < 0.15:
            # Already there: just look. Looking from here again and again has not settled
            # it, though, after MAX_LOOKS_IN_PLACE in a row: try elsewhere.
            self.looks_in_place += 1
            if self.looks_in_place <= MAX_LOOKS_IN_PLACE:
                self.target = target
                self.state = "gaze"
                return self._gaze(yaw)
            self.looks_in_place = 0
            self.failed.append(np.asarray(target.xy))
            return Decision(0.0, 0.0, "choose")
        if target.kind == "probe":
            planner = GridPlanner(block_teammates(self.optimistic, discs))
        path = planner.plan(start, target.xy)
        if start is not here and path is not None and len(path) < 2:
            path = np.vstack([here, start])  # the target is where the robot leaves from
        if path is None or len(path) < 2:
            if discs and self._reachable_without_teammates(start, target):
                self._set_aside_target(target)  # teammates in the way: later again
                return Decision(0.0, 0.0, "choose")
            self.failed.append(np.asarray(target.xy))
            self.failures_in_a_row += 1
            return Decision(0.0, 0.0, "choose")
        if start is not here and not np.array_equal(path[0], here):
            path = np.vstack([here, path])
        self.failures_in_a_row = 0
        self.looks_in_place = 0
        self.target = target
        self.follower.set_path(path)
        self.state = "drive"
        self.progress = DriveWatch(here)
        return self._drive(here, yaw)

    def _own_target(
        self,
        here: np.ndarray,
        yaw: float,
        trav: TraversabilityGrid,
        cost: np.ndarray,
        exclude: list,
        max_looks: int = 1,
        optimistic: TraversabilityGrid | None = None,
        team: bool = False,
    ) -> ExplorationTarget | None:
        """This robot's own choice of target by its strategy (``choose_target``); ``max_looks``:
        looks per 3-D frontier column for the frontier strategy (see view_targets);
        ``optimistic``: the grid probes into unknown floor are planned on (entropy strategy);
        ``team``: stay TEAM_SPREAD_RADIUS from where the teammates are heading."""
        return choose_target(
            self.strategy,
            *self._search_from(here, yaw, trav, cost),
            self.mission.exploration.radius,
            self.rng,
            exclude=exclude,
            camera=self.camera,
            tried=self.tried_views + self.team_views if self.strategy == "entropy" else self.tried_views,
            stands=self.view_stands,
            max_looks=max_looks,
            exclude_radius=FAILED_RADIUS,
            optimistic=optimistic,
            keep_away=self.team_goals if team else (),
            keep_away_radius=TEAM_SPREAD_RADIUS,
        )

    def _search_from(self, here: np.ndarray, yaw: float, trav: TraversabilityGrid, cost: np.ndarray) -> tuple:
        """The arguments every target search starts with: map, per-voxel entropy, pose (x, y,
        yaw), camera height, traversability and path costs from the robot's cell."""
        return self.map, self.entropy.values, (here[0], here[1], yaw), self.rig.camera_height, trav, cost

    def _last_look(
        self, here: np.ndarray, yaw: float, trav: TraversabilityGrid, cost: np.ndarray, exclude: list
    ) -> ExplorationTarget | None:
        """A view of a voxel with ``last_look_bits`` or more left (``last_look_target``), or None."""
        return last_look_target(
            *self._search_from(here, yaw, trav, cost),
            self.camera,
            self.last_look_bits,
            tried=self.tried_views + self.team_views,
            exclude=exclude,
            exclude_radius=FAILED_RADIUS,
        )

    def _drive(self, here: np.ndarray, yaw: float) -> Decision:
        reason = self.progress.update(here, self.follower.way_left(here[0], here[1]))
        if reason is not None:
            self.give_ups[reason] += 1
            return self._give_up()
        if self.frames % REPLAN_EVERY == 0:
            trav = self._refresh_traversability()
            if self.target.kind == "probe":
                trav = self.optimistic
            if needs_replan(self.follower.remaining_path(), trav):
                path = GridPlanner(trav).plan(here, self.target.xy)
                if path is None or len(path) < 2:
                    return self._give_up()
                self.follower.set_path(path)
        # the path as it is now (after a replan too): full discs, never nearer than one
        discs = self._teammate_discs()
        mate = blocking_teammate(self.follower.remaining_path()[1:], here, discs) if discs else None
        if mate is not None:
            return self._make_way(here, yaw, discs, mate)
        self.waited = 0
        command = self.follower.command(here[0], here[1], yaw)
        if command.arrived:
            self.state = "gaze"
            return self._gaze(yaw)
        if discs and command.v > 0:
            # the arc to the path may head nearer a teammate than the path does: turn on the spot
            step = command.v * self.mission.sim.frame_period_s * np.array([math.cos(yaw), math.sin(yaw)])
            if blocking_teammate((here + step)[None], here, discs) is not None:
                return Decision(0.0, command.omega, "drive", self._target_xy())
        return Decision(command.v, command.omega, "drive", self._target_xy())

    def _give_up(self) -> Decision:
        self.failures_in_a_row += 1
        if self.target is not None:
            self.failed.append(np.asarray(self.target.xy))
        self.target = None
        self.state = "choose"
        return Decision(0.0, 0.0, "choose")

    def _wander_blind(self, yaw: float) -> Decision:
        """No free cell known around the robot: turn on the spot to see more."""
        self.state = "look_around"
        self.turned = 0.0
        self.last_yaw = yaw
        return Decision(0.0, self.mission.robot.max_turn_rate * 0.8, "look_around")

    def view_point(self) -> tuple[float, float, float] | None:
        """The point (x, y, z; m) the current target goes to look at, when it is a 3-D view the
        robot chose itself (the centre of the column's first frontier voxel); else None."""
        t = self.target
        if t is None or t.voxel is None or t.kind not in VIEW_KINDS or self.state == "done":
            return None
        ijk = np.array(np.unravel_index(t.voxel, self.grid.shape), dtype=np.float64)
        x, y, z = self.grid.lo + (ijk + 0.5) * self.grid.voxel
        return float(x), float(y), float(z)

    def _target_xy(self) -> tuple[float, float] | None:
        return None if self.target is None else (float(self.target.xy[0]), float(self.target.xy[1]))


def _near_any(xy: np.ndarray, points: list[np.ndarray], radius: float) -> bool:
    """Whether the x-y point ``xy`` lies within ``radius`` (m) of any of ``points``."""
    return any(np.hypot(*(np.asarray(xy)[:2] - np.asarray(p)[:2])) < radius for p in points)
