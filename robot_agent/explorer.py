"""One robot's mind, without I/O: fuse each frame (its :class:`LocalMap`), pick targets, plan,
and drive.

The loop is the paper's (section III): fuse the batch of the current view into the local
coverage map, choose a viewpoint by the entropy gradient (eq. 27-35, or a baseline), drive
there through known free space, look along the gradient on arrival, and stop when the map
entropy is below H_th (eq. 36) or nothing reachable is informative. The robot starts by
turning once on the spot, since a forward camera sees nothing of its sides. Its states are
:class:`robot_agent.decision.ExplorerState`.

A robot whose camera sits on a tilt head (``rig.tilt_range_deg`` > 0) also looks up for one
frame after each gaze, and makes its last turn before giving up with the head raised: a level
camera low on a robot sees the upper part of a room only from afar. The entropy strategy
drives through unknown floor only towards a probe (a room behind a door whose floor it has not
seen; ``swarm.navigation.probing``), planned on the optimistic grid.

A new target comes from the fallback ladder (:mod:`robot_agent.choosers`), the coordinator's
target first: the agent asks for it when :attr:`Explorer.wants_target` and passes it in
(:class:`robot_agent.decision.TeamAdvice`). The explorer owns its parts: the
:class:`LocalMap`, the :class:`GivingWay` to teammates, the :class:`TargetMemory`, the ladder.
"""

from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np

from robot_agent.choosers import VIEW_KINDS, AssignedTarget, Situation, TargetMemory, TargetSearch, ladder
from robot_agent.decision import Decision, ExplorerState, TeamAdvice
from robot_agent.ground import Ground
from robot_agent.kernels import load_kernels
from robot_agent.local_map import LocalMap
from robot_agent.stereo import matcher_for_rig
from robot_agent.teammate_avoidance import GivingWay, Way, reachable_without_teammates
from swarm.config import Mission
from swarm.map.coverage_map import CoverageMap, prior_entropy_bits
from swarm.map.delta import Delta
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import EntropyTable, default_table
from swarm.map.grid import Grid
from swarm.navigation.exploration import ExplorationTarget, SearchOptions
from swarm.navigation.floor_cache import FloorCache
from swarm.navigation.path_follower import DriveWatch, FollowerLimits, PathFollower, needs_replan, wrap_angle
from swarm.navigation.planner import GridPlanner, large_free_areas, nearest_free_cell
from swarm.navigation.strategies import check_strategy
from swarm.navigation.teammates import Teammates, block_teammates, blocking_teammate
from swarm.navigation.view_targets import CameraReach
from swarm.protocol.wire import Frame

log = logging.getLogger("swarm.agent")

GAZE_TOLERANCE = math.radians(12)
REPLAN_EVERY = 4  # frames between traversability refreshes while driving
FAILED_MEMORY = 12  # how many given-up targets to avoid
MAX_FAILURES = 6  # unreachable targets in a row before the robot looks around again
MAX_LOOKS_IN_PLACE = 2  # targets in a row at the robot's own cell before it is avoided
BOXED_IN_CELLS = 30  # fewer reachable cells than this: step blind to free floor beyond
# entropy strategy, where it would stop: voxels with more than this share of the prior's
# entropy left that a reachable cell can see are looked at first, each column once
LAST_LOOK_SHARE = 0.5


class Explorer:
    """The local map of one robot and the decisions it drives by."""

    def __init__(self, mission: Mission, robot_id: str, strategy: str = "entropy", seed: int = 0) -> None:
        self.mission = mission
        self.robot_id = robot_id
        self.strategy = check_strategy(strategy)
        self.rig = mission.rig_for(robot_id)
        # Returns beyond the rig's hit range are free space up to it, no hit (SensorModel.reach).
        self.sensor = mission.sensor_model_for(robot_id)
        load_kernels(log.info, robot_id)  # before the first frame
        matcher = matcher_for_rig(self.rig) if self.rig.mode == "stereo" else None
        self.local = LocalMap(mission.workspace.grid(), self.sensor, default_table(), matcher)
        self.threshold = mission.threshold_bits()
        body = mission.robot
        self.follower = PathFollower(
            FollowerLimits(max_speed=body.max_speed, max_turn_rate=body.max_turn_rate)
        )
        self._state = ExplorerState.LOOK_AROUND
        self.turned = 0.0
        self.last_yaw: float | None = None
        self.target: ExplorationTarget | None = None
        self.ground = Ground(
            self.rig.camera_height,
            body.radius,
            probes=self.strategy == "entropy",
            floor=FloorCache(self.local.changes, body.radius),
        )
        self.progress = DriveWatch()
        self.frames = 0
        self.failures_in_a_row = 0
        self.looked_before_done = False  # made the last turn before concluding
        self.looks_in_place = 0  # targets in a row at the robot's own cell
        # where the camera can look (the head only ever looks up), for 3-D frontier views
        self.camera = CameraReach.of_rig(self.rig, self.sensor.reach, looks_up=self.rig.tilt_range_deg > 0)
        self.memory = TargetMemory()
        grid = self.local.grid
        self.search = TargetSearch(
            local=self.local,
            strategy=self.strategy,
            camera_height=self.rig.camera_height,
            options=SearchOptions(radius=mission.exploration.radius, camera=self.camera),
            rng=np.random.default_rng([seed, sum(robot_id.encode())]),
            memory=self.memory,
            last_look_bits=LAST_LOOK_SHARE * prior_entropy_bits(grid, self.sensor) / grid.size,
        )
        self.choosers = ladder(self.search)
        self.give_ups: Counter[str] = Counter()  # drives given up, by reason (printed at exit)
        self.has_head = self.rig.tilt_range_deg > 0
        self.look_up_tilt = -math.radians(self.rig.tilt_range_deg)
        self.head = 0.0  # the tilt this robot asks for now
        mates = Teammates(robot_id, body.radius, body.max_speed, lead_s=mission.sim.frame_period_s)
        self.giving_way = GivingWay(mission.robot_ids, robot_id, mates)
        self._advice: TeamAdvice | None = None  # this decision's, from the agent

    # -- the parts, as the agent reads them --------------------------------------------------
    @property
    def state(self) -> ExplorerState:
        return self._state

    @state.setter
    def state(self, value: ExplorerState | str) -> None:
        self._state = ExplorerState(value)

    @property
    def map(self) -> CoverageMap:
        return self.local.map

    @property
    def grid(self) -> Grid:
        return self.local.grid

    @property
    def table(self) -> EntropyTable:
        return self.local.table

    @property
    def entropy(self) -> EntropyCache:
        return self.local.entropy

    @property
    def map_entropy(self) -> float:
        return self.local.entropy_bits

    @property
    def teammates(self) -> Teammates:
        """Where the teammates were last seen (the agent feeds their statuses in)."""
        return self.giving_way.teammates

    @property
    def target_kinds(self) -> Counter[str]:
        """Targets chosen, by kind (printed at exit)."""
        return self.memory.target_kinds

    @property
    def declined_assignments(self) -> int:
        """Coordinator targets declined, near a spot given up (printed at exit)."""
        return sum(c.declined for c in self.choosers if isinstance(c, AssignedTarget))

    def fuse(self, frame: Frame) -> Delta:  # the local map's (see LocalMap)
        return self.local.fuse(frame)

    # -- decisions -----------------------------------------------------------------------
    @property
    def wants_target(self) -> bool:
        """Whether the next decision chooses a new target: the agent then asks the coordinator
        first and passes its answer to :meth:`decide`."""
        return (
            self._state is ExplorerState.CHOOSE
            and self.map_entropy > self.threshold
            and self.failures_in_a_row < MAX_FAILURES
        )

    def decide(
        self, x: float, y: float, yaw: float, t: float | None = None, advice: TeamAdvice | None = None
    ) -> Decision:
        """The command for this frame, given the robot's pose (from the frame), the frame's
        time ``t`` (s, the mission's clock; None: teammates are not avoided) and what the
        coordinator said (None: coordination off, or not asked this frame)."""
        self.giving_way.now = t
        self._advice = advice
        decision = self._decide(x, y, yaw)
        self._advice = None
        decision.tilt = self.head if self.has_head else None
        return decision

    def _decide(self, x: float, y: float, yaw: float) -> Decision:
        self.frames += 1
        here = np.array([x, y])
        self.ground.note_position(x, y)
        if self.map_entropy <= self.threshold:
            self._state = ExplorerState.DONE
        state = self._state
        if state is ExplorerState.DONE:
            return Decision(0.0, 0.0, "done")
        if state is ExplorerState.LOOK_AROUND:
            return self._look_around(yaw)
        if state is ExplorerState.GAZE:
            return self._gaze(yaw)
        if state is ExplorerState.LOOK_UP:  # this frame was seen with the head raised
            self.head = 0.0
            self._state = ExplorerState.CHOOSE
            return Decision(0.0, 0.0, "gaze", self._target_xy())
        if state is ExplorerState.DRIVE:
            return self._drive(here, yaw)
        return self._choose(here, yaw)

    def _look_around(self, yaw: float) -> Decision:
        if self.last_yaw is not None:
            self.turned += abs(wrap_angle(yaw - self.last_yaw))
        self.last_yaw = yaw
        if self.turned >= 2 * math.pi - 0.2:
            self.head = 0.0
            self._state = ExplorerState.CHOOSE
            return Decision(0.0, 0.0, "choose")
        return Decision(0.0, self.mission.robot.max_turn_rate * 0.8, "look_around")

    def _gaze(self, yaw: float) -> Decision:
        error = wrap_angle(self.target.gaze_yaw - yaw) if self.target else 0.0
        if abs(error) <= GAZE_TOLERANCE:
            if self.has_head:  # raise the head for the next frame, then choose
                self.head = self.look_up_tilt
                self._state = ExplorerState.LOOK_UP
            else:
                self._state = ExplorerState.CHOOSE
            return Decision(0.0, 0.0, "gaze", self._target_xy())
        limit = self.mission.robot.max_turn_rate
        return Decision(0.0, float(np.clip(2.0 * error, -limit, limit)), "gaze", self._target_xy())

    def _choose(self, here: np.ndarray, yaw: float) -> Decision:
        discs = self.giving_way.discs(here)
        trav = block_teammates(self.ground.refresh(self.map), discs)
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
        if self._advice is not None:
            self.memory.take_advice(self._advice)
        exclude = self.memory.failed[-FAILED_MEMORY:] + self.giving_way.set_aside_points()
        situation = Situation(
            here, yaw, trav, cost, exclude, self.ground.optimistic, self.looked_before_done, self._advice
        )
        target = next((t for c in self.choosers if (t := c.choose(situation)) is not None), None)
        if target is None:
            if not self.looked_before_done:
                # Nothing reachable looks informative: turn once more (head raised, if it
                # can be) before concluding.
                self.looked_before_done = True
                self.head = self.look_up_tilt
                return self._wander_blind(yaw)
            self._state = ExplorerState.DONE
            return Decision(0.0, 0.0, "done")
        self.memory.note_chosen(target, self.grid)
        self.looked_before_done = False
        return self._set_out(target, here, start, yaw, planner, discs)

    def _set_out(
        self,
        target: ExplorationTarget,
        here: np.ndarray,
        start: np.ndarray,
        yaw: float,
        planner: GridPlanner,
        discs: list,
    ) -> Decision:
        """Look from here, or plan from ``start`` to the chosen ``target`` and drive."""
        if np.hypot(*(target.xy - here)) < 0.15:
            # Already there: just look. Looking from here again and again has not settled
            # it, though, after MAX_LOOKS_IN_PLACE in a row: try elsewhere.
            self.looks_in_place += 1
            if self.looks_in_place <= MAX_LOOKS_IN_PLACE:
                self.target = target
                self._state = ExplorerState.GAZE
                return self._gaze(yaw)
            self.looks_in_place = 0
            self.memory.failed.append(np.asarray(target.xy))
            return Decision(0.0, 0.0, "choose")
        if target.kind == "probe":
            planner = GridPlanner(block_teammates(self.ground.optimistic, discs))
        path = planner.plan(start, target.xy)
        if start is not here and path is not None and len(path) < 2:
            path = np.vstack([here, start])  # the target is where the robot leaves from
        if path is None or len(path) < 2:
            if discs and reachable_without_teammates(
                self.ground.grid_for(target, self.map), start, target.xy
            ):
                self.giving_way.set_aside(target)  # teammates in the way: later again
                return Decision(0.0, 0.0, "choose")
            self.memory.failed.append(np.asarray(target.xy))
            self.failures_in_a_row += 1
            return Decision(0.0, 0.0, "choose")
        if start is not here and not np.array_equal(path[0], here):
            path = np.vstack([here, path])
        self.failures_in_a_row = 0
        self.looks_in_place = 0
        self.target = target
        self.follower.set_path(path)
        self._state = ExplorerState.DRIVE
        self.progress = DriveWatch(here)
        return self._drive(here, yaw)

    def _drive(self, here: np.ndarray, yaw: float) -> Decision:
        reason = self.progress.update(here, self.follower.way_left(here[0], here[1]))
        if reason is not None:
            self.give_ups[reason] += 1
            return self._give_up()
        if self.frames % REPLAN_EVERY == 0:
            self.ground.refresh(self.map)
            trav = self.ground.grid_for(self.target, self.map)
            if needs_replan(self.follower.remaining_path(), trav):
                path = GridPlanner(trav).plan(here, self.target.xy)
                if path is None or len(path) < 2:
                    return self._give_up()
                self.follower.set_path(path)
        # the path as it is now (after a replan too): full discs, never nearer than one
        discs = self.giving_way.discs()
        mate = blocking_teammate(self.follower.remaining_path()[1:], here, discs) if discs else None
        if mate is not None:
            return self._make_way(here, yaw, discs, mate)
        self.giving_way.waited = 0
        command = self.follower.command(here[0], here[1], yaw)
        if command.arrived:
            self._state = ExplorerState.GAZE
            return self._gaze(yaw)
        if discs and command.v > 0:
            # the arc to the path may head nearer a teammate than the path does: turn on the spot
            step = command.v * self.mission.sim.frame_period_s * np.array([math.cos(yaw), math.sin(yaw)])
            if blocking_teammate((here + step)[None], here, discs) is not None:
                return Decision(0.0, command.omega, "drive", self._target_xy())
        return Decision(command.v, command.omega, "drive", self._target_xy())

    def _make_way(self, here: np.ndarray, yaw: float, discs: list, mate: str) -> Decision:
        """A teammate in the way: what :meth:`GivingWay.make_way` says, done."""
        self.progress = DriveWatch(here)  # waiting is not being stuck
        target = self.target
        way, path = self.giving_way.make_way(
            here, discs, mate, target, lambda: self.ground.grid_for(target, self.map)
        )
        if way is Way.AROUND:
            self.follower.set_path(path)
            command = self.follower.command(here[0], here[1], yaw)
            return Decision(command.v, command.omega, "drive", self._target_xy())
        if way is Way.GIVE_UP:
            self.give_ups["teammate"] += 1
            self.target = None
            self._state = ExplorerState.CHOOSE
            return Decision(0.0, 0.0, "choose")
        return Decision(0.0, 0.0, "wait", self._target_xy())

    def _give_up(self) -> Decision:
        self.failures_in_a_row += 1
        if self.target is not None:
            self.memory.failed.append(np.asarray(self.target.xy))
        self.target = None
        self._state = ExplorerState.CHOOSE
        return Decision(0.0, 0.0, "choose")

    def _wander_blind(self, yaw: float) -> Decision:
        """No free cell known around the robot: turn on the spot to see more."""
        self._state = ExplorerState.LOOK_AROUND
        self.turned = 0.0
        self.last_yaw = yaw
        return Decision(0.0, self.mission.robot.max_turn_rate * 0.8, "look_around")

    def view_point(self) -> tuple[float, float, float] | None:
        """The point (x, y, z; m) the current target goes to look at, when it is a 3-D view the
        robot chose itself (the centre of the column's first frontier voxel); else None."""
        t = self.target
        if t is None or t.voxel is None or t.kind not in VIEW_KINDS or self._state is ExplorerState.DONE:
            return None
        ijk = np.array(np.unravel_index(t.voxel, self.grid.shape), dtype=np.float64)
        x, y, z = self.grid.lo + (ijk + 0.5) * self.grid.voxel
        return float(x), float(y), float(z)

    def _target_xy(self) -> tuple[float, float] | None:
        return None if self.target is None else (float(self.target.xy[0]), float(self.target.xy[1]))
