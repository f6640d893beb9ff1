"""The agents' side of ``coord/assign``: ask the coordinator for a target (docs/protocol.md)."""

from __future__ import annotations

import logging

import zenoh

from swarm.protocol import bus
from swarm.protocol.wire import AssignReply, AssignRequest, Pose, WireError

log = logging.getLogger("swarm.coord_client")


def reply_text(payload) -> str:
    """A query error's payload as text, for the log."""
    data = payload.to_bytes() if hasattr(payload, "to_bytes") else bytes(payload)
    return data.decode("utf-8", errors="replace")


def ask_for_target(
    session: zenoh.Session, mission: str, robot: str, pose: Pose, timeout: float = 2.0
) -> AssignReply | None:
    """Ask the coordinator of ``mission`` for a target for ``robot`` at ``pose``.

    Returns the reply (its ``target`` is None when the coordinator has nothing left), or None
    when no coordinator answered within ``timeout`` seconds or it answered with an error
    (logged): the agent then chooses by itself. The reply's target is where to stand (x, y of
    a reachable cell; z of the request's pose), its gaze the unit direction to face there.
    """
    payload = AssignRequest(robot, pose).encode()
    try:
        for reply in session.get(bus.key(mission, "coord", "assign"), payload=payload, timeout=timeout):
            if reply.ok is None:
                log.warning("%s: coordinator error: %s", robot, reply_text(reply.err.payload))
                continue
            try:
                return AssignReply.decode(reply.ok.payload.to_bytes())
            except WireError as exc:
                log.warning("%s: malformed coordinator reply: %s", robot, exc)
    except zenoh.ZError as exc:
        log.warning("%s: coord/assign query failed: %s", robot, exc)
    return None
