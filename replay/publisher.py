"""Publish recorded frames on ``robot/<id>/frame`` as a robot driver would.

Lockstep (default): each frame waits for the agent's ``robot/<id>/cmd`` answering its seq,
so no frame is lost whatever the agent's speed. ``realtime``: frames leave at the recorded
rate and the agent drops what it cannot keep up with (as on a robot).
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import zenoh

from swarm.protocol import bus
from swarm.protocol.wire import Cmd, Frame, WireError


@dataclass
class PublishLog:
    """Per frame: seq, recording time (s), round trip to the agent's answer (s; None: none)."""

    rows: list[tuple[int, float, float | None]] = field(default_factory=list)
    unanswered: int = 0


class FramePublisher:
    """Sends frames of one robot and waits for the agent's answers."""

    def __init__(self, session: zenoh.Session, mission: str, robot: str) -> None:
        self.robot = robot
        self._pub = bus.reliable_publisher(session, bus.key(mission, "robot", robot, "frame"))
        self._cmds: queue.Queue = queue.Queue()
        self._sub = bus.subscribe(
            session, bus.key(mission, "robot", robot, "cmd"), lambda _k, p: self._cmds.put(p)
        )

    def wait_for_agent(self, timeout: float) -> bool:
        """True once an agent subscribes to this robot's frames."""
        return bus.wait_for_subscribers([self._pub], timeout)

    def send(self, frame: Frame, timeout: float | None) -> float | None:
        """Publish a frame; with a timeout, wait for its cmd and return the round trip (s)."""
        start = time.perf_counter()
        self._pub.put(frame.encode())
        if timeout is None:
            return None
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                payload = self._cmds.get(timeout=left)
            except queue.Empty:
                break
            try:
                cmd = Cmd.decode(payload)
            except WireError:
                continue
            if cmd.seq == frame.seq:
                return time.perf_counter() - start
        return None

    def run(
        self,
        frames: Iterable[Frame],
        realtime: bool = False,
        timeout: float = 60.0,
        after_each: Callable[[Frame, float | None], None] | None = None,
    ) -> PublishLog:
        """Send every frame (lockstep, or paced by the recorded times with ``realtime``)."""
        log = PublishLog()
        t0_rec = t0_wall = None
        for frame in frames:
            if realtime:
                if t0_rec is None:
                    t0_rec, t0_wall = frame.t, time.monotonic()
                time.sleep(max(0.0, (frame.t - t0_rec) - (time.monotonic() - t0_wall)))
            rtt = self.send(frame, None if realtime else timeout)
            if rtt is None and not realtime:
                log.unanswered += 1
            log.rows.append((frame.seq, frame.t, rtt))
            if after_each is not None:
                after_each(frame, rtt)
        return log

    def close(self) -> None:
        self._sub.undeclare()
        self._pub.undeclare()
