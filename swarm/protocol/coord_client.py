"""The agents' side of ``coord/assign/<rid>``: ask the coordinator for a target (docs/protocol.md)."""

from __future__ import annotations

import json
import logging

import zenoh

from swarm.protocol import bus
from swarm.protocol.replies import ConflictingReplies, ask
from swarm.protocol.wire import AssignReply, AssignRequest, Pose, WireError

log = logging.getLogger("swarm.coord_client")


def reply_text(payload) -> str:
    """A query error's payload as text, for the log."""
    data = payload.to_bytes() if hasattr(payload, "to_bytes") else bytes(payload)
    return data.decode("utf-8", errors="replace")


def assign_key(mission: str, robot: str) -> str:
    """The key robot ``robot`` asks its targets on: ``swarm/<mission>/coord/assign/<robot>``
    (its own, so that on a secured bus the access rules tell who asks)."""
    return bus.key(mission, "coord", "assign", robot)


def ask_for_target(
    session: zenoh.Session, mission: str, robot: str, pose: Pose, timeout: float = 2.0
) -> AssignReply | None:
    """Ask the coordinator of ``mission`` for a target for ``robot`` at ``pose``, on
    ``robot``'s own key (:func:`assign_key`).

    Returns the reply (its ``target`` is None when the coordinator has nothing left), or None
    when no coordinator answered within ``timeout`` seconds, it answered with an error, or
    several repliers answered differently (logged; ``swarm.protocol.replies``): the agent then
    chooses by itself. The reply's target is where to stand (x, y of
    a reachable cell; z of the request's pose), its gaze the unit direction to face there.
    """
    payload = AssignRequest(robot, pose).encode()
    try:
        answer = ask(session, assign_key(mission, robot), timeout=timeout, payload=payload)
    except ConflictingReplies as exc:
        log.warning("%s: refused the coordinator's answer: %s", robot, exc)
        return None
    except zenoh.ZError as exc:
        log.warning("%s: coord/assign query failed: %s", robot, exc)
        return None
    if answer is None:
        return None
    if answer.ok is None:
        log.warning("%s: coordinator error: %s", robot, answer.error)
        return None
    try:
        return AssignReply.decode(answer.ok)
    except WireError as exc:
        log.warning("%s: malformed coordinator reply: %s", robot, exc)
    return None


def coordinator_stats(session: zenoh.Session, mission: str, timeout: float = 2.0) -> dict | None:
    """The ``coord/stats`` JSON object of ``mission``'s coordinator, or None without a usable answer.

    It holds ``answer_ms`` (``count``, ``mean``, ``p50``, ``p95``, ``max`` of the time from a
    ``coord/assign`` query's arrival to its reply, over the coordinator's most recent answers)
    and ``counts`` (requests, assignments, merged deltas and statuses); docs/protocol.md.
    """
    try:
        answer = ask(session, bus.key(mission, "coord", "stats"), timeout=timeout)
    except (ConflictingReplies, zenoh.ZError) as exc:
        log.warning("coord/stats query failed: %s", exc)
        return None
    if answer is None or answer.ok is None:
        return None
    try:
        stats = json.loads(answer.ok)
    except ValueError as exc:
        log.warning("coord/stats: the reply is not JSON: %s", exc)
        return None
    return stats if isinstance(stats, dict) else None
