"""The explorer's fallback ladder: an ordered list of target choosers, each with one job.

When the robot needs a new target, :class:`robot_agent.explorer.Explorer` asks each chooser of
its ladder in turn (:func:`ladder`) and takes the first target offered:

1. :class:`AssignedTarget`: the coordinator's target (passed in by the agent), unless it stands
   near a spot this robot gave up (the coordinator does not know those);
2. :class:`SpreadFromTeam`: choosing alone in a team, the robot's own target away from where
   its teammates head (TEAM_SPREAD_RADIUS);
3. :class:`OwnTarget`: the robot's own target by its strategy (eq. 35, frontier, random);
4. :class:`LookAgain` (frontier strategy, once the robot would conclude): 3-D frontier columns
   one look left unknown, from another cell, then without the spots it gave up;
5. :class:`LastLook` (entropy strategy, once the robot would conclude): voxels still holding
   over LAST_LOOK_SHARE of the prior's entropy, in view of a reachable cell.

When none offers a target the explorer turns once more on the spot, then stops. The choosers
read one :class:`Situation` (this decision) and a :class:`TargetSearch` (the robot's map,
strategy, options and :class:`TargetMemory`); no I/O.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from robot_agent.decision import TeamAdvice
from robot_agent.local_map import LocalMap
from swarm.map.grid import Grid
from swarm.navigation.exploration import (
    ExplorationTarget,
    SearchContext,
    SearchOptions,
    choose_target,
    last_look_target,
)
from swarm.navigation.target_cache import SlabCache
from swarm.navigation.traversability import TraversabilityGrid

FAILED_RADIUS = 1.0  # m: a target standing this near a given-up one is avoided too
FRONTIER_LOOKS = 3  # frontier strategy: looks at a 3-D frontier column, each from another cell
TEAM_SPREAD_RADIUS = 2.0  # m: a robot choosing alone first keeps this far from teammates' goals
VIEW_KINDS = ("view", "frontier3d", "last look")  # targets that look at a map column chosen here


@dataclass
class TargetMemory:
    """What a robot remembers between decisions about targets (x-y points, m)."""

    failed: list[np.ndarray] = field(default_factory=list)  # targets given up, newest last
    tried_views: list[np.ndarray] = field(default_factory=list)  # columns a view target was chosen for
    view_stands: list[np.ndarray] = field(default_factory=list)  # the standing point of each of tried_views
    #: columns teammates went to look at (from the coordinator; entropy strategy)
    team_views: list[np.ndarray] = field(default_factory=list)
    #: where the teammates are heading (from the coordinator's "nothing left")
    team_goals: list[np.ndarray] = field(default_factory=list)
    target_kinds: Counter[str] = field(default_factory=Counter)  # targets chosen, by kind

    def take_advice(self, advice: TeamAdvice) -> None:
        """Note what the coordinator said about the teammates (views kept until told again)."""
        self.team_goals = list(advice.goals)
        if advice.views is not None:
            self.team_views = list(advice.views)

    def note_chosen(self, target: ExplorationTarget, grid: Grid) -> None:
        """Count ``target`` by kind; for a view of a map column, remember the column and stand."""
        self.target_kinds[target.kind] += 1
        if target.kind in VIEW_KINDS and target.voxel is not None:
            i, j, _k = np.unravel_index(target.voxel, grid.shape)
            self.tried_views.append(grid.lo[:2] + (np.array([i, j]) + 0.5) * grid.voxel)
            self.view_stands.append(np.asarray(target.xy, dtype=np.float64))


@dataclass
class Situation:
    """One decision's inputs: the robot's x-y ``here`` (m) and ``yaw`` (rad), its traversability
    grid (teammates blocked) and path costs from its cell, the points to keep away from
    (``exclude``: recently given up, set aside for teammates), the probes' grid (entropy
    strategy, else None), whether the robot has made its last turn (``concluding``), and what
    the coordinator said (None: coordination off)."""

    here: np.ndarray
    yaw: float
    trav: TraversabilityGrid
    cost: np.ndarray
    exclude: list[np.ndarray]
    optimistic: TraversabilityGrid | None
    concluding: bool
    advice: TeamAdvice | None


@dataclass
class TargetSearch:
    """A robot's target searches: its map, strategy, options, random stream and memory."""

    local: LocalMap
    strategy: str
    camera_height: float  # m, the sensor's world z
    options: SearchOptions
    rng: np.random.Generator
    memory: TargetMemory
    last_look_bits: float  # bits per voxel: a last look's threshold
    #: read the slab's eq. 32-35 fields from the local map's per-tile cache (False: a pass over
    #: the whole slab at every decision, the oracle the tests compare the cache with)
    cached: bool = True

    def context(
        self, s: Situation, exclude: Sequence[np.ndarray], keep_away: Sequence[np.ndarray] = ()
    ) -> SearchContext:
        """The search context of this decision on the robot's map, with these points excluded;
        the slab's beliefs come from the local map's per-tile cache."""
        slab = self.slab()
        return SearchContext.build(
            self.local.map,
            self.local.entropy.values,
            (s.here[0], s.here[1], s.yaw),
            self.camera_height,
            s.trav,
            s.cost,
            exclude=exclude,
            exclude_radius=FAILED_RADIUS,
            keep_away=keep_away,
            keep_away_radius=TEAM_SPREAD_RADIUS,
            slab=None if slab is None else slab.beliefs,
        )

    def slab(self) -> SlabCache | None:
        """The eq. 32-35 fields of the sensor's layer, redone where the map changed since the
        last decision (swarm.navigation.target_cache); None when the sensor is outside the map
        or the search is not ``cached``."""
        grid = self.local.grid
        k0 = int(np.floor((self.camera_height - grid.lo[2]) / grid.voxel))
        if not self.cached or not 0 <= k0 < grid.shape[2]:
            return None
        return self.local.targets.slab(self.local.map, self.local.entropy.values, k0)

    def own(
        self,
        s: Situation,
        exclude: Sequence[np.ndarray],
        *,
        max_looks: int = 1,
        optimistic: TraversabilityGrid | None = None,
        keep_away: Sequence[np.ndarray] = (),
    ) -> ExplorationTarget | None:
        """This robot's own choice by its strategy (``choose_target``)."""
        memory = self.memory
        tried = memory.tried_views + memory.team_views if self.strategy == "entropy" else memory.tried_views
        options = (
            self.options
            if max_looks == self.options.max_looks
            else replace(self.options, max_looks=max_looks)
        )
        ctx = self.context(s, exclude, keep_away)
        slab = self.slab()
        cached = {}
        if slab is not None and slab.k0 == ctx.k0:
            cached = {
                "slab": slab.fields,
                "stand": self.local.targets.standing(slab, ctx.reach, options.view),
            }
        return choose_target(
            self.strategy,
            ctx,
            options,
            self.rng,
            tried=tried,
            stands=memory.view_stands,
            optimistic=optimistic,
            **cached,
        )


class Chooser(Protocol):
    """One rung of the ladder: a target for this decision, or None to let the next one try."""

    def choose(self, s: Situation) -> ExplorationTarget | None: ...


@dataclass
class AssignedTarget:
    """The coordinator's target, declined (counted) when near a spot the robot gave up: the
    coordinator offers the same spot again while it holds the best candidate on the team map,
    and the robot would look from there (or drive there and stick) for ever."""

    declined: int = 0

    def choose(self, s: Situation) -> ExplorationTarget | None:
        target = None if s.advice is None else s.advice.target
        if target is not None and _near_any(target.xy, s.exclude, FAILED_RADIUS):
            self.declined += 1
            return None
        return target


@dataclass
class SpreadFromTeam:
    """Choosing alone in a team: first the robot's own target away from the teammates' goals."""

    search: TargetSearch

    def choose(self, s: Situation) -> ExplorationTarget | None:
        goals = self.search.memory.team_goals
        if not goals:
            return None
        return self.search.own(s, s.exclude, optimistic=s.optimistic, keep_away=goals)


@dataclass
class OwnTarget:
    """The robot's own target by its strategy (eq. 35 for the entropy strategy)."""

    search: TargetSearch

    def choose(self, s: Situation) -> ExplorationTarget | None:
        return self.search.own(s, s.exclude, optimistic=s.optimistic)


@dataclass
class WhenConcluding:
    """A rung that joins in only where the robot would conclude (after its last turn), and
    stays in once it has: ``active``."""

    search: TargetSearch
    active: bool = False

    def joins(self, s: Situation) -> bool:
        """Whether this rung offers a target for ``s`` (and from now on)."""
        self.active = self.active or s.concluding
        return self.active


@dataclass
class LookAgain(WhenConcluding):
    """Frontier strategy, where the robot would conclude (after its last turn): look again at
    3-D frontier columns one look left unknown, each from another cell, then forget the spots
    it gave up: 1 m around each, they can cover all the reachable floor of a small room while
    frontiers are in view of it (the lab: 4 spots, 185 viewable frontier columns left). Finite,
    as every 3-D view uses up one of a column's FRONTIER_LOOKS. Once started, it goes on without
    a turn before each (new frontier still comes first)."""

    def choose(self, s: Situation) -> ExplorationTarget | None:
        if not self.joins(s):
            return None
        target = self.search.own(s, s.exclude, max_looks=FRONTIER_LOOKS)
        if target is None and s.exclude:
            self.search.memory.failed.clear()
            target = self.search.own(s, [], max_looks=FRONTIER_LOOKS)
        return target


@dataclass
class LastLook(WhenConcluding):
    """Entropy strategy, where the robot would conclude (after its last turn): a view of what
    is still uncertain in view of a reachable cell (known voxels too), each column once."""

    def choose(self, s: Situation) -> ExplorationTarget | None:
        if not self.joins(s):
            return None
        search, memory = self.search, self.search.memory
        camera = search.options.camera
        if camera is None:
            return None
        ctx = search.context(s, s.exclude)
        return last_look_target(
            ctx, camera, search.last_look_bits, tried=memory.tried_views + memory.team_views
        )


def ladder(search: TargetSearch) -> list[Chooser]:
    """The choosers of ``search.strategy``, in the order they are asked (see the module doc)."""
    rungs: list[Chooser] = [AssignedTarget(), SpreadFromTeam(search), OwnTarget(search)]
    if search.strategy == "frontier":
        rungs.append(LookAgain(search))
    if search.strategy == "entropy":
        rungs.append(LastLook(search))
    return rungs


def _near_any(xy: np.ndarray, points: list[np.ndarray], radius: float) -> bool:
    """Whether the x-y point ``xy`` lies within ``radius`` (m) of any of ``points``."""
    return any(np.hypot(*(np.asarray(xy)[:2] - np.asarray(p)[:2])) < radius for p in points)
