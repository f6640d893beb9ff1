"""The seam between the agent and a robot that does not speak ``robot/<id>/frame`` and ``cmd``:
a link with a frame source and a command sink (``robot_agent.ros2_link.Ros2Link`` for ROS 2).

The source puts *pending frames* into the agent's ``FrameInbox`` (the newest one waits);
the agent turns the one it takes into a frame with ``pending.frame()`` (None: it could not be
made, and the source counted why), fuses it and hands its decision to the sink.
"""

from __future__ import annotations

from typing import Protocol

import zenoh

from robot_agent.decision import Decision
from robot_agent.frame_inbox import FrameInbox
from swarm.protocol import bus
from swarm.protocol.wire import Cmd, Frame


class PendingFrame(Protocol):
    def frame(self) -> Frame | None: ...


class FrameSource(Protocol):
    def start(self, inbox: FrameInbox) -> None: ...
    def notes(self) -> str: ...


class CommandSink(Protocol):
    def send(self, cmd: Cmd, decision: Decision, gaze_yaw: float | None = None) -> None: ...


class FrameLink(Protocol):
    frames: FrameSource
    commands: CommandSink

    def describe(self) -> str: ...
    def close(self) -> None: ...


class WireLink:
    """A robot that speaks our protocol: frames from ``robot/<rid>/frame`` (payloads, which the agent
    decodes), each command on ``robot/<rid>/cmd`` (docs/protocol.md)."""

    def __init__(self, session: zenoh.Session, mission: str, robot_id: str) -> None:
        self._session = session
        self.key = bus.key(mission, "robot", robot_id, "frame")
        self._cmd = bus.reliable_publisher(session, bus.key(mission, "robot", robot_id, "cmd"))
        self._sub: zenoh.Subscriber | None = None
        self.frames, self.commands = self, self

    def start(self, inbox: FrameInbox) -> None:
        self._sub = bus.subscribe(self._session, self.key, lambda _key, payload: inbox.put(payload))

    def notes(self) -> str:
        return ""  # the agent counts the frames it cannot decode

    def send(self, cmd: Cmd, decision: Decision, gaze_yaw: float | None = None) -> None:
        self._cmd.put(cmd.encode())

    def describe(self) -> str:
        return self.key

    def close(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
