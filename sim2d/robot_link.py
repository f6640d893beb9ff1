"""How the simulated robots meet their agents: frames out, one command per frame back.

``WireRobots`` speaks our protocol (``robot/<rid>/frame`` and ``robot/<rid>/cmd``,
docs/protocol.md); ``sim2d.ros2_robots.Ros2Robots`` speaks ROS 2 (docs/ros2.md). The simulator's
lockstep loop (``sim2d.simulator``) uses either through the same four calls: ``missing`` (robots
whose agent is not listening yet), ``publish`` (one tick's frames), ``take`` (the next command, a
``Cmd`` naming its robot and the frame seq it answers) and ``close``; ``rejected`` counts the
commands refused.
"""

from __future__ import annotations

import logging
import queue
from typing import Protocol

import zenoh

from swarm.config import Mission
from swarm.protocol import bus
from swarm.protocol.wire import Cmd, Frame, WireError

log = logging.getLogger("sim2d.simulator")


class RobotLink(Protocol):
    rejected: int
    where: str  # what the agents subscribe to, for the log

    def missing(self) -> list[str]: ...
    def publish(self, frames: dict[str, Frame], t: float) -> None: ...
    def take(self, timeout: float) -> Cmd | None: ...
    def close(self) -> None: ...


class WireRobots:
    """The robots' frames on ``robot/<rid>/frame``, their commands from ``robot/<rid>/cmd``."""

    def __init__(self, session: zenoh.Session, mission: Mission) -> None:
        name = mission.mission
        self.robot_ids = mission.robot_ids
        self.rejected = 0
        self._frame_pubs = {
            rid: bus.reliable_publisher(session, bus.key(name, "robot", rid, "frame"))
            for rid in self.robot_ids
        }
        self._cmd_sub, self._inbox = bus.subscribe_queue(session, bus.key_pattern(name, "robot", "*", "cmd"))
        self._cmd_prefix = bus.key(name, "robot") + "/"
        self.where = bus.key(name, "robot", "<id>", "frame")
        self._seq = 0

    def missing(self) -> list[str]:
        """Robots whose frame key no subscriber (agent) matches yet."""
        return [rid for rid, pub in self._frame_pubs.items() if not bus.has_subscribers(pub)]

    def publish(self, frames: dict[str, Frame], t: float) -> None:
        """One tick's frames (all of seq ``frame.seq``, at simulated time ``t``)."""
        for rid, frame in frames.items():
            self._seq = frame.seq
            self._frame_pubs[rid].put(frame.encode())

    def take(self, timeout: float) -> Cmd | None:
        """The next command (None when none came within ``timeout`` s); refused ones are counted."""
        try:
            key_expr, payload = self._inbox.get(timeout=timeout)
        except queue.Empty:
            return None
        try:
            cmd = Cmd.decode(payload)
        except WireError as e:
            return self._reject(f"{key_expr}: {e}")
        rid = key_expr.removeprefix(self._cmd_prefix).removesuffix("/cmd")
        if rid != cmd.robot or rid not in self._frame_pubs:
            return self._reject(f"{key_expr}: command for robot {cmd.robot!r} on this key")
        if cmd.seq > self._seq:
            return self._reject(f"{key_expr}: seq {cmd.seq} is ahead of frame {self._seq}")
        return cmd

    def _reject(self, reason: str) -> None:
        self.rejected += 1
        log.warning("rejected command: %s", reason)

    def close(self) -> None:
        self._cmd_sub.undeclare()
        for pub in self._frame_pubs.values():
            pub.undeclare()
