"""Pure-pursuit path following for a differential-drive robot.

The follower keeps its progress along a polyline of world waypoints, picks the point one
``lookahead`` distance ahead on the path, and steers towards it on a circular arc
(curvature 2 sin(alpha) / distance, alpha = heading error to that point). When the heading
error exceeds ``turn_in_place`` it stops and turns on the spot. Speed is capped by
``max_speed``, by ``max_turn_rate`` / curvature, and near the goal by ``slow_gain`` times
the remaining distance; the turn rate is capped by ``max_turn_rate``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm.navigation.traversability import TraversabilityGrid


@dataclass(frozen=True)
class FollowerLimits:
    """Limits and gains: speeds in m/s and rad/s, distances in metres, angles in radians."""

    max_speed: float = 0.5
    max_turn_rate: float = 1.5
    lookahead: float = 0.35
    goal_tolerance: float = 0.08
    turn_in_place: float = math.radians(60)
    turn_gain: float = 2.0
    slow_gain: float = 1.5
    min_speed: float = 0.05

    def __post_init__(self) -> None:
        for name in ("max_speed", "max_turn_rate", "lookahead", "goal_tolerance", "turn_gain", "slow_gain"):
            if not getattr(self, name) > 0:
                raise ValueError(f"follower: {name} must be > 0, got {getattr(self, name)!r}")
        if not 0 < self.turn_in_place <= math.pi:
            raise ValueError(f"follower: turn_in_place must be in (0, pi], got {self.turn_in_place!r}")


@dataclass(frozen=True)
class Command:
    """A velocity command ``v`` (m/s, forward) and ``omega`` (rad/s, counter-clockwise)."""

    v: float
    omega: float
    arrived: bool = False


def wrap_angle(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


class PathFollower:
    """Follows one path at a time: ``set_path(waypoints)``, then ``command(x, y, yaw)`` every tick."""

    def __init__(self, limits: FollowerLimits | None = None) -> None:
        self.limits = limits or FollowerLimits()
        self.path = np.zeros((0, 2))
        self.segment = 0  # index of the path segment the robot is on

    def set_path(self, waypoints: np.ndarray) -> None:
        """Start following a new polyline (K, 2) of world waypoints."""
        pts = np.asarray(waypoints, dtype=np.float64).reshape(-1, 2)
        if len(pts) == 0:
            raise ValueError("path needs at least one waypoint")
        self.path = pts
        self.segment = 0

    @property
    def goal(self) -> np.ndarray | None:
        return self.path[-1] if len(self.path) else None

    def remaining_path(self) -> np.ndarray:
        """The waypoints still ahead (from the start of the current segment)."""
        return self.path[self.segment :]

    def way_left(self, x: float, y: float) -> float:
        """Length (m) of the way from (x, y) to the goal: to the current segment's end, then
        along the waypoints after it (0.0 without a path)."""
        ahead = self.path[self.segment + 1 :] if len(self.path) > self.segment + 1 else self.path[-1:]
        if len(ahead) == 0:
            return 0.0
        legs = np.diff(ahead, axis=0)
        return float(np.hypot(ahead[0][0] - x, ahead[0][1] - y) + np.hypot(legs[:, 0], legs[:, 1]).sum())

    def command(self, x: float, y: float, yaw: float) -> Command:
        """The next (v, omega) for a robot at (x, y) heading ``yaw``; arrived=True (and zeros) at the goal."""
        lim = self.limits
        if len(self.path) == 0:
            return Command(0.0, 0.0, True)
        pos = np.array([x, y], dtype=np.float64)
        to_goal = float(np.linalg.norm(self.path[-1] - pos))
        if to_goal <= lim.goal_tolerance:
            return Command(0.0, 0.0, True)
        self._advance(pos)
        target = self._lookahead_point(pos)
        dx, dy = target - pos
        dist = math.hypot(dx, dy)
        alpha = wrap_angle(math.atan2(dy, dx) - yaw)
        if abs(alpha) > lim.turn_in_place:
            omega = _clip(lim.turn_gain * alpha, lim.max_turn_rate)
            return Command(0.0, omega, False)
        curvature = 2.0 * math.sin(alpha) / max(dist, 1e-9)
        v = min(lim.max_speed, max(lim.slow_gain * to_goal, lim.min_speed))
        if abs(curvature) * v > lim.max_turn_rate:
            v = lim.max_turn_rate / abs(curvature)
        omega = _clip(v * curvature, lim.max_turn_rate)
        return Command(float(v), float(omega), False)

    def _advance(self, pos: np.ndarray) -> None:
        """Step to the next segment while it is at least as close as the current one (no jumps)."""
        last = len(self.path) - 2
        while self.segment < last:
            here = _point_segment_distance(pos, self.path[self.segment], self.path[self.segment + 1])
            ahead = _point_segment_distance(pos, self.path[self.segment + 1], self.path[self.segment + 2])
            if ahead > here:
                break
            self.segment += 1

    def _lookahead_point(self, pos: np.ndarray) -> np.ndarray:
        """Where the path leaves the lookahead circle beyond the current segment.

        The goal when it lies inside the circle; the nearest point of the current segment
        when the robot has strayed farther than the lookahead from the path.
        """
        la = self.limits.lookahead
        if np.linalg.norm(self.path[-1] - pos) <= la or len(self.path) == 1:
            return self.path[-1]
        for k in range(self.segment, len(self.path) - 1):
            hit = _circle_exit(pos, la, self.path[k], self.path[k + 1])
            if hit is not None:
                return hit
        a, b = self.path[self.segment], self.path[self.segment + 1]
        return _nearest_on_segment(pos, a, b)


#: Frames without 5 cm of motion before a drive is given up.
STUCK_FRAMES = 16
#: Frames without coming 5 cm nearer the goal along the path before a drive is given up: a
#: robot that rocks to and fro (pushing against a teammate in a narrow corridor) moves, but
#: never arrives.
NO_PROGRESS_FRAMES = 48


class DriveWatch:
    """Whether a drive still gets anywhere, one ``update`` per frame: the robot must move
    5 cm within STUCK_FRAMES frames, and come 5 cm nearer its goal (the way left along its
    path, ``PathFollower.way_left``) within NO_PROGRESS_FRAMES frames."""

    def __init__(self, position: np.ndarray | None = None) -> None:
        self.position = np.zeros(2) if position is None else np.array(position, dtype=np.float64)[:2]
        self.frames = 0  # frames since the robot was last 5 cm from ``position``
        self.best = math.inf  # the least way left so far (m)
        self.since_best = 0  # frames since ``best`` last shrank by 5 cm

    def update(self, here: np.ndarray, way_left: float) -> str | None:
        """Count one frame at ``here`` (x, y; m) with ``way_left`` (m) to go: the reason to
        give the drive up ("stuck" or "no progress"), or None while it gets somewhere."""
        self.frames += 1
        self.since_best += 1
        if np.hypot(*(np.asarray(here)[:2] - self.position)) > 0.05:
            self.position, self.frames = np.array(here, dtype=np.float64)[:2], 0
        if way_left < self.best - 0.05:
            self.best, self.since_best = way_left, 0
        if self.frames > STUCK_FRAMES:
            return "stuck"
        return "no progress" if self.since_best > NO_PROGRESS_FRAMES else None


def needs_replan(path: np.ndarray, traversability: TraversabilityGrid) -> bool:
    """True when any segment of the (remaining) world path crosses a cell that is no longer navigable."""
    return not traversability.path_is_free(path)


def _clip(value: float, limit: float) -> float:
    return float(min(max(value, -limit), limit))


def _nearest_on_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    denom = float(ab @ ab)
    t = 0.0 if denom == 0 else min(max(float((p - a) @ ab) / denom, 0.0), 1.0)
    return a + t * ab


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(_nearest_on_segment(p, a, b) - p))


def _circle_exit(c: np.ndarray, r: float, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The farthest-along point of segment a-b on the circle (c, r) if the segment leaves it; else None."""
    d = b - a
    f = a - c
    qa = float(d @ d)
    if qa == 0:
        return None
    qb = 2 * float(f @ d)
    qc = float(f @ f) - r * r
    disc = qb * qb - 4 * qa * qc
    if disc < 0:
        return None
    t = (-qb + math.sqrt(disc)) / (2 * qa)
    if 0.0 <= t <= 1.0:
        return a + t * d
    return None
