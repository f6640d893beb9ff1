"""Who holds which target: the coordinator's book of the targets it gave, and the rules that
release them (the robot asks again, reports it is done, or goes silent; see
:class:`coordinator.assignment.CoordinationParams`). No I/O; times are the caller's clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from coordinator.assignment import CoordinationParams

__all__ = ["DONE_STATES", "AssignmentBook", "RobotRecord"]

#: Status states that end a robot's hold on its target (it finished, or gave the target up).
DONE_STATES = ("done", "gave_up", "failed")
#: How many of a robot's released targets are remembered (not given back to it at once).
RECENT_RELEASES = 4


@dataclass
class RobotRecord:
    """What the coordinator knows of one robot. Times are the caller's clock (seconds)."""

    robot: str
    last_seen: float
    xy: np.ndarray | None = None
    state: str | None = None
    target: np.ndarray | None = None  # x-y of the target it holds
    assigned_at: float | None = None  # when the coordinator gave that target
    silent: bool = False
    recent: list[np.ndarray] = field(default_factory=list)  # released targets, newest last


class AssignmentBook:
    """Targets held by robots, and the rules that release them (see CoordinationParams).

    A robot's target is released when the robot asks again (it reached or gave up its
    target), when its status reports a state of DONE_STATES, or no target (after the grace
    period of an assignment), and when it has been silent for ``robot_timeout_s``. A status
    that shows a target (after the grace period) makes that the held target: a robot that
    chose for itself still keeps the others away. Every method returns what it released as
    (robot, reason) pairs, for the caller to log.
    """

    def __init__(self, params: CoordinationParams = CoordinationParams()) -> None:
        self.params = params
        self.robots: dict[str, RobotRecord] = {}

    def _record(self, robot: str, now: float) -> RobotRecord:
        rec = self.robots.get(robot)
        if rec is None:
            rec = self.robots[robot] = RobotRecord(robot, now)
        rec.last_seen = max(rec.last_seen, now)
        rec.silent = False
        return rec

    def _release(self, rec: RobotRecord, reason: str) -> list[tuple[str, str]]:
        if rec.target is None:
            return []
        rec.recent = [*rec.recent, rec.target][-RECENT_RELEASES:]
        rec.target = None
        rec.assigned_at = None
        return [(rec.robot, reason)]

    def note_status(
        self, robot: str, now: float, xy=None, state: str | None = None, target=None
    ) -> list[tuple[str, str]]:
        """A status from ``robot``: liveness, pose, state and the target it reports (or None)."""
        rec = self._record(robot, now)
        if xy is not None:
            rec.xy = np.asarray(xy, dtype=np.float64)[:2]
        rec.state = state
        if state in DONE_STATES:
            return self._release(rec, f"status {state}")
        if rec.assigned_at is not None and now - rec.assigned_at < self.params.status_grace_s:
            return []  # may predate the assignment
        if target is None:
            return self._release(rec, f"status {state or '-'} without a target")
        rec.target = np.asarray(target, dtype=np.float64)[:2]
        return []

    def note_request(self, robot: str, now: float, xy=None) -> list[tuple[str, str]]:
        """``robot`` asks for a target: it no longer holds the one it had."""
        rec = self._record(robot, now)
        if xy is not None:
            rec.xy = np.asarray(xy, dtype=np.float64)[:2]
        return self._release(rec, "asked again")

    def hold(self, robot: str, target, now: float) -> None:
        """Record that the coordinator gave ``target`` (x-y) to ``robot`` at ``now``."""
        rec = self._record(robot, now)
        rec.target = np.asarray(target, dtype=np.float64)[:2]
        rec.assigned_at = now

    def release(self, robot: str, reason: str = "released") -> list[tuple[str, str]]:
        rec = self.robots.get(robot)
        return [] if rec is None else self._release(rec, reason)

    def expire(self, now: float) -> list[tuple[str, str]]:
        """Release the targets of robots silent for longer than ``robot_timeout_s``."""
        out: list[tuple[str, str]] = []
        for rec in self.robots.values():
            if not rec.silent and now - rec.last_seen > self.params.robot_timeout_s:
                rec.silent = True
                out += self._release(rec, f"silent for {now - rec.last_seen:.1f} s")
        return out

    def held_by_others(self, robot: str) -> np.ndarray:
        """(M, 2) targets held by live robots other than ``robot`` (call ``expire`` first)."""
        pts = [
            rec.target
            for rec in self.robots.values()
            if rec.robot != robot and rec.target is not None and not rec.silent
        ]
        return np.array(pts, dtype=np.float64).reshape(-1, 2)

    def holder(self, robot: str) -> np.ndarray | None:
        rec = self.robots.get(robot)
        return None if rec is None else rec.target

    def recent_releases(self, robot: str) -> list[np.ndarray]:
        """The last targets ``robot`` released, oldest first (not to be handed straight back)."""
        rec = self.robots.get(robot)
        return [] if rec is None else list(rec.recent)

    def live(self) -> list[str]:
        return [r for r, rec in self.robots.items() if not rec.silent]
