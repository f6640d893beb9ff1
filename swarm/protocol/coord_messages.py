"""Messages of the coordinator: the ``coord/assign/<rid>`` request and reply."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from swarm.protocol.codec import (
    WireError,
    number,
    pack,
    require,
    short,
    text,
    unpack,
    vec3,
)
from swarm.protocol.robot_messages import Pose

# -- coord/assign/<rid> ---------------------------------------------------------------


@dataclass(frozen=True)
class AssignRequest:
    """A robot asks the coordinator for a target."""

    robot: str
    pose: Pose

    KIND = "assign request"

    def encode(self) -> bytes:
        return pack(self.KIND, {"robot": self.robot, "pose": self.pose.to_wire()})

    @classmethod
    def decode(cls, payload: Any) -> AssignRequest:
        msg = unpack(payload, cls.KIND)
        return cls(
            robot=text(require(msg, "robot", cls.KIND), "robot", cls.KIND),
            pose=Pose.from_wire(require(msg, "pose", cls.KIND), cls.KIND),
        )


def assign_request_on_key(key: str, payload: Any) -> AssignRequest:
    """The request a ``swarm/<mission>/coord/assign/<rid>`` query carries, checked against the
    ``<rid>`` of its key: a WireError when it is malformed or asks for another robot (kind
    ``robot_mismatch``; on a secured bus each agent may query only its own key, so the key
    says who asks; the field does not)."""
    request = AssignRequest.decode(payload)
    parts = str(key).split("/")
    rid = parts[-1] if len(parts) >= 2 and parts[-2] == "assign" else None
    if request.robot != rid:
        raise WireError(
            f"{AssignRequest.KIND}: robot {short(request.robot, 40)} asked on the key of {short(rid, 40)}",
            "robot_mismatch",
        )
    return request


@dataclass(frozen=True)
class AssignReply:
    """The coordinator's answer: a target point and gaze direction (None: no target).

    ``flush`` (an addition to protocol v1, optional on the wire, False when absent): the
    target is one this robot was given before, so what it saw there may still sit in its
    outbox; the robot should share all its pending deltas now ("flush on demand").

    ``views`` (also an addition, optional, empty when absent; sent with "nothing left"):
    the x-y points (m) of the map columns the other robots have gone to look at by
    themselves (their statuses' ``view``), at most MAX_VIEWS, most recent last; the robot
    does not choose a 3-D view of those columns itself.

    ``goals`` (also an addition, optional, empty when absent; sent with "nothing left"):
    the x-y points (m) the other live robots are heading to now (the targets the
    coordinator holds for them, their own choices included), at most MAX_GOALS; the robot
    choosing alone keeps its own target away from them while it finds one that is.
    """

    target: tuple[float, float, float] | None
    gaze: tuple[float, float, float] | None
    utility: float
    flush: bool = False
    views: tuple[tuple[float, float], ...] = ()
    goals: tuple[tuple[float, float], ...] = ()

    KIND = "assign reply"

    def encode(self) -> bytes:
        def vec(v):
            return None if v is None else [float(x) for x in v]

        return pack(
            self.KIND,
            {
                "target": vec(self.target),
                "gaze": vec(self.gaze),
                "utility": float(self.utility),
                "flush": bool(self.flush),
                "views": [[float(x), float(y)] for x, y in self.views],
                "goals": [[float(x), float(y)] for x, y in self.goals],
            },
        )

    @classmethod
    def decode(cls, payload: Any) -> AssignReply:
        kind = cls.KIND
        msg = unpack(payload, kind)
        target, gaze = require(msg, "target", kind), require(msg, "gaze", kind)
        flush = msg.get("flush", False)
        if not isinstance(flush, bool):
            raise WireError(f"{kind}: field 'flush' must be a boolean, got {type(flush).__name__}")
        return cls(
            target=None if target is None else vec3(target, "target", kind),
            gaze=None if gaze is None else vec3(gaze, "gaze", kind),
            utility=number(require(msg, "utility", kind), "utility", kind),
            flush=flush,
            views=_points(msg.get("views", []), "views", MAX_VIEWS, kind),
            goals=_points(msg.get("goals", []), "goals", MAX_GOALS, kind),
        )


#: The most column points a reply's ``views`` may hold.
MAX_VIEWS = 4096
#: The most points a reply's ``goals`` may hold (one per other robot).
MAX_GOALS = 256


def _points(value: Any, field: str, limit: int, kind: str) -> tuple[tuple[float, float], ...]:
    """A list field of at most ``limit`` finite [x, y] pairs (``views``, ``goals``)."""
    if not isinstance(value, list):
        raise WireError(f"{kind}: field '{field}' must be a list of [x, y], got {type(value).__name__}")
    if len(value) > limit:
        raise WireError(f"{kind}: field '{field}' holds {len(value)} points, at most {limit}")
    out = []
    for n, point in enumerate(value):
        name = f"{field}[{n}]"
        if not (isinstance(point, list) and len(point) == 2):
            raise WireError(f"{kind}: {name} must be [x, y], got {short(point)}")
        out.append((number(point[0], name, kind), number(point[1], name, kind)))
    return tuple(out)
