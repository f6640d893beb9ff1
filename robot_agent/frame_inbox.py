"""The agent's inbox of camera frames: the newest one waiting, older ones dropped.

A driver that waits for the agent's answer before sending the next frame (the simulator,
``swarm replay`` in lockstep) never has more than one frame waiting. A real camera driver does
not wait: at 20 Hz against an agent that fuses 8 frames a second, a first-in first-out queue
would grow without end, and the agent would answer frames seconds old with commands for a
robot that has moved on. So the inbox holds one frame, the newest: a frame arriving while
another waits replaces it, and the replaced one is counted (``superseded``) and gets no answer.
This is the queue of depth one that ROS image pipelines use for the same reason.
"""

from __future__ import annotations

import threading


class FrameInbox:
    """One waiting frame payload (bytes), the newest; thread-safe (Zenoh's callback puts, the
    agent's loop takes).

    ``superseded`` counts the frames replaced before the agent took them."""

    def __init__(self) -> None:
        self._ready = threading.Condition()
        self._payload: bytes | None = None
        self.superseded = 0

    def put(self, payload: bytes) -> None:
        """Leave ``payload`` for the agent, replacing (and counting) a frame still waiting."""
        with self._ready:
            if self._payload is not None:
                self.superseded += 1
            self._payload = payload
            self._ready.notify()

    def take(self, timeout: float) -> bytes | None:
        """The waiting frame, waiting up to ``timeout`` seconds for one; None if none came."""
        with self._ready:
            if self._payload is None:
                self._ready.wait_for(lambda: self._payload is not None, timeout=timeout)
            payload, self._payload = self._payload, None
            return payload
