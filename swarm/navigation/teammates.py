"""Teammate avoidance: where the other robots of the mission were last seen, and what that
keeps this robot out of. Pure logic, no I/O: the agent feeds it the teammates' statuses
(``robot/<rid>/status``: robot, t, pose) and the explorer asks it every frame.

A teammate is a disc of the robot's own size. Seen ``age`` seconds ago (the mission's clock:
its status's ``t`` against this frame's ``t``), it may have driven ``max_speed * age`` since,
and may drive ``max_speed * lead_s`` more before this robot decides again (``lead_s``: one
frame period), so this robot's centre keeps out of

    keep_out = 2 * robot_radius + margin + max_speed * (age + lead_s)        (m)

around the teammate's last position. A sighting older than ``max_age_s`` is stale and
ignored (a stopped or dead agent does not block the floor for ever).

Two uses (``robot_agent.explorer``):

* planning: the keep-out discs are blocked in the traversability grid the planner plans on
  (``block_teammates``), so paths go around teammates (a disc the robot stands in, as at a
  start 0.5 m apart, shrinks so that its own cell stays free to plan from);
* following: each frame, a teammate whose keep-out disc the next ``look_ahead`` metres of
  the path enter (coming nearer to it; moving away is always allowed) stops the robot
  (``blocking_teammate``): it replans around, or waits.

Priority and deadlock rule: a robot meeting a teammate that comes before it in the mission's
robot list waits for it (it does not drive around it: two robots each driving around the
other pick the same side); after a few frames it gives its target up and chooses another,
which frees the way. A robot meeting a teammate that comes after it drives around it when a
path does, else waits longer, then gives its target up too. A target given up because of a
teammate is set aside for a while, not for ever.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from swarm.navigation.traversability import TraversabilityGrid

#: Seconds (mission clock) after which a teammate's last status no longer blocks anything.
MAX_AGE_S = 3.0
#: Robots whose last sighting is held at most (a team's own robots are far fewer; statuses of
#: further robot ids, which anyone on an open bus can invent, are ignored).
MAX_TEAMMATES = 128
#: Extra clearance (m) between two robots' discs.
MARGIN = 0.1
#: How far (m) along its path a robot looks for teammates each frame.
LOOK_AHEAD_M = 0.8
#: A keep-out disc this robot already stands in shrinks to this much (m) inside its distance
#: from the teammate, so that its own cell stays free to plan from.
STAND_SLACK = 0.15

#: A keep-out disc: centre (2,) world x-y in m, radius in m, and the teammate's robot id.
Disc = tuple[np.ndarray, float, str]


@dataclass(frozen=True)
class Sighting:
    """A teammate's last known position ``xy`` (m, world x-y) at mission time ``t`` (s)."""

    robot: str
    xy: tuple[float, float]
    t: float


class Teammates:
    """The latest position of each teammate of robot ``own`` (its own statuses are ignored)."""

    def __init__(
        self,
        own: str,
        robot_radius: float,
        max_speed: float,
        lead_s: float = 0.0,
        margin: float = MARGIN,
        max_age_s: float = MAX_AGE_S,
    ) -> None:
        if min(robot_radius, max_speed, lead_s, margin) < 0 or max_age_s <= 0:
            raise ValueError(
                "teammates: robot_radius, max_speed, lead_s and margin must be >= 0 and max_age_s > 0, "
                f"got {robot_radius!r}, {max_speed!r}, {lead_s!r}, {margin!r}, {max_age_s!r}"
            )
        self.own = own
        self.robot_radius = robot_radius
        self.max_speed = max_speed
        self.lead_s = lead_s
        self.margin = margin
        self.max_age_s = max_age_s
        self.latest: dict[str, Sighting] = {}

    def update(self, robot: str, t: float, x: float, y: float, now: float | None = None) -> bool:
        """Record teammate ``robot`` at (x, y) (m) at mission time ``t`` (s); returns whether it
        was kept. Ignored: a status of this robot itself, one not finite, one older than the
        one held, one more than ``max_age_s`` ahead of ``now`` (this frame's time, when given:
        a status from the future would hold its disc, and shut out the robot's true statuses,
        for ever), and a robot beyond the first MAX_TEAMMATES."""
        if robot == self.own or not all(math.isfinite(v) for v in (t, x, y)):
            return False
        if now is not None and t > now + self.max_age_s:
            return False
        held = self.latest.get(robot)
        if held is None and len(self.latest) >= MAX_TEAMMATES:
            return False
        if held is not None and held.t > t:
            return False
        self.latest[robot] = Sighting(robot, (float(x), float(y)), float(t))
        return True

    def fresh(self, now: float) -> list[Sighting]:
        """The sightings at most ``max_age_s`` old, or ahead, at mission time ``now`` (s)."""
        return [s for s in self.latest.values() if abs(now - s.t) <= self.max_age_s]

    def keep_out(self, sighting: Sighting, now: float) -> float:
        """Radius (m) around the sighting this robot's centre keeps out of at time ``now``."""
        age = max(0.0, now - sighting.t)
        return 2.0 * self.robot_radius + self.margin + self.max_speed * (age + self.lead_s)

    def discs(self, now: float, here: np.ndarray | None = None) -> list[Disc]:
        """The fresh keep-out discs ``(centre (2,), radius m, robot)`` at time ``now``. With
        ``here`` (x, y; m), a disc this robot already stands in shrinks to STAND_SLACK inside
        its distance from the teammate, for planning: its own cell stays free to plan from.
        Check paths against the full discs (``blocking_teammate``): inside one, the robot may
        stay or move away, not come nearer."""
        out = []
        for s in self.fresh(now):
            centre = np.asarray(s.xy, dtype=np.float64)
            radius = self.keep_out(s, now)
            if here is not None:
                radius = min(radius, float(np.hypot(*(np.asarray(here)[:2] - centre))) - STAND_SLACK)
            if radius > 0:
                out.append((centre, radius, s.robot))
        return out


def block_teammates(trav: TraversabilityGrid, discs: list[Disc]) -> TraversabilityGrid:
    """``trav`` with every cell whose centre lies inside a keep-out disc made not free (a new
    grid; ``occupied``/``unknown`` are kept: teammates are not part of the map)."""
    if not discs:
        return trav
    nx, ny = trav.shape
    xs = trav.origin[0] + (np.arange(nx) + 0.5) * trav.resolution
    ys = trav.origin[1] + (np.arange(ny) + 0.5) * trav.resolution
    free = trav.free.copy()
    for centre, radius, _robot in discs:
        inside = (xs[:, None] - centre[0]) ** 2 + (ys[None, :] - centre[1]) ** 2 < radius**2
        free &= ~inside
    return replace(trav, free=free)


def blocking_teammate(
    path: np.ndarray,
    here: np.ndarray,
    discs: list[Disc],
    look_ahead: float = LOOK_AHEAD_M,
    step: float = 0.05,
) -> str | None:
    """The teammate whose keep-out disc the way from ``here`` through the waypoints ``path``
    (K, 2; world m, those still ahead) enters within its first ``look_ahead`` metres while
    coming nearer to it, or None when the way is clear."""
    ahead = _first_metres(np.vstack([np.asarray(here)[:2], np.asarray(path)[:, :2]]), look_ahead, step)
    for centre, radius, robot in discs:
        now_dist = float(np.hypot(*(np.asarray(here)[:2] - centre)))
        dist = np.hypot(ahead[:, 0] - centre[0], ahead[:, 1] - centre[1])
        if np.any((dist < radius) & (dist < now_dist - 1e-3)):
            return robot
    return None


def _first_metres(points: np.ndarray, length: float, step: float) -> np.ndarray:
    """Points every ``step`` m along the polyline (K, 2) for its first ``length`` m."""
    out = [points[0]]
    left = length
    for a, b in zip(points[:-1], points[1:], strict=True):
        leg = float(np.hypot(*(b - a)))
        if leg == 0:
            continue
        take = min(leg, left)
        n = max(1, math.ceil(take / step))
        out.extend(a + (b - a) * (take / leg) * (np.arange(1, n + 1) / n)[:, None])
        left -= take
        if left <= 0:
            break
    return np.asarray(out)
