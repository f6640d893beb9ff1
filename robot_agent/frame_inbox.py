"""The agent's inbox of camera frames: the newest one waiting, older ones dropped.

A driver that waits for the agent's answer before sending the next frame (the simulator,
``swarm replay`` in lockstep) never has more than one frame waiting. A real camera driver does
not wait: at 20 Hz against an agent that fuses 8 frames a second, a first-in first-out queue
would grow without end, and the agent would answer frames seconds old with commands for a
robot that has moved on. So the inbox holds one frame, the newest: a frame arriving while
another waits replaces it, and the replaced one is counted (``superseded``) and gets no answer.
This is the queue of depth one that ROS image pipelines use for the same reason; here a
:class:`swarm.protocol.mailbox.Mailbox` of one key.
"""

from __future__ import annotations

from swarm.protocol.mailbox import Mailbox

_FRAME = "frame"  # the one key: every frame replaces the one waiting


class FrameInbox:
    """One waiting frame, the newest: a payload (bytes), or a link's pending frame
    (``robot_agent.frame_link.PendingFrame``); thread-safe (the link's callback puts, the
    agent's loop takes)."""

    def __init__(self) -> None:
        self._box: Mailbox[str, object] = Mailbox(max_keys=1)

    @property
    def superseded(self) -> int:
        """Frames replaced by a newer one before the agent took them."""
        return self._box.replaced

    def put(self, payload: object) -> None:
        """Leave ``payload`` for the agent, replacing (and counting) a frame still waiting."""
        self._box.put(_FRAME, payload)

    def take(self, timeout: float) -> object | None:
        """The waiting frame, waiting up to ``timeout`` seconds for one; None if none came."""
        taken = self._box.take(timeout)
        return None if taken is None else taken[1]
