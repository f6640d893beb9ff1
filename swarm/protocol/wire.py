"""Wire protocol v1 (docs/design.md section 5): msgpack messages as dataclasses; import them from here.

Every message is a msgpack map with ``"v": 1``; arrays travel as little-endian raw bytes.
``Message.encode()`` gives the payload, ``Message.decode(payload)`` validates one and
raises ``WireError`` (a ``ValueError``) with the reason when it is malformed. No transport
here: the Zenoh side lives in ``swarm.protocol.bus``.

Poses: ``xyz`` in metres in the world frame (z up); ``ypr`` = yaw, pitch, roll in radians
of the body frame (x forward, y left, z up, as ROS REP-103), R = Rz(yaw) Ry(pitch) Rx(roll),
so a positive pitch looks down. A camera's optical frame is x right, y down, z forward
(``Pose.optical_rotation``). Frame depth is the optical z (not the ray length).
"""

from __future__ import annotations

from swarm.protocol.codec import DEPTH_ENCODING, STEREO_ENCODINGS, VERSION, WireError
from swarm.protocol.coord_messages import AssignReply, AssignRequest, assign_request_on_key
from swarm.protocol.map_messages import DeltaMessage, Region, Snapshot
from swarm.protocol.robot_messages import (
    BODY_FROM_OPTICAL,
    Camera,
    Cmd,
    Frame,
    Pose,
    Status,
    TruthPoses,
    status_on_key,
)

__all__ = [
    "AssignReply",
    "AssignRequest",
    "BODY_FROM_OPTICAL",
    "Camera",
    "Cmd",
    "DEPTH_ENCODING",
    "DeltaMessage",
    "Frame",
    "Pose",
    "Region",
    "STEREO_ENCODINGS",
    "Snapshot",
    "Status",
    "TruthPoses",
    "VERSION",
    "assign_request_on_key",
    "status_on_key",
    "WireError",
]
