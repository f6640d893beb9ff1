"""Messages of a robot's keys: ``robot/<rid>/frame``, ``cmd``, ``status``, and the simulator's
``sim/truth``.

Poses: ``xyz`` in metres in the world frame (z up); ``ypr`` = yaw, pitch, roll in radians
of the body frame (x forward, y left, z up, as ROS REP-103), R = Rz(yaw) Ry(pitch) Rx(roll),
so a positive pitch looks down. A camera's optical frame is x right, y down, z forward
(``Pose.optical_rotation``). Frame depth is the optical z (not the ray length).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm.map.rotation import rotation_zyx
from swarm.protocol.codec import (
    DEPTH_ENCODING,
    STEREO_ENCODINGS,
    WireError,
    integer,
    le,
    number,
    pack,
    raw,
    require,
    short,
    text,
    unpack,
    vec3,
)

#: Columns: the optical axes (right, down, forward) expressed in the body frame.
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


# -- shared parts ---------------------------------------------------------------------

_CAMERA_NUMBERS = ("fx", "fy", "cx", "cy", "baseline")


@dataclass(frozen=True)
class Pose:
    """Position ``xyz`` (m) and orientation ``ypr`` (rad) of a body in the world."""

    xyz: tuple[float, float, float]
    ypr: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def rotation(self) -> np.ndarray:
        """world_R_body = Rz(yaw) Ry(pitch) Rx(roll)."""
        return rotation_zyx(*self.ypr)

    def optical_rotation(self) -> np.ndarray:
        """world_R_optical: maps camera optical-frame vectors (x right, y down, z fwd) to world."""
        return self.rotation() @ BODY_FROM_OPTICAL

    def to_wire(self) -> dict:
        return {"xyz": [float(v) for v in self.xyz], "ypr": [float(v) for v in self.ypr]}

    @classmethod
    def from_wire(cls, value: Any, kind: str, name: str = "pose") -> Pose:
        if not isinstance(value, dict):
            raise WireError(f"{kind}: {name} must be a map with xyz and ypr")
        return cls(
            vec3(require(value, "xyz", kind), f"{name}.xyz", kind),
            vec3(require(value, "ypr", kind), f"{name}.ypr", kind),
        )


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics of a rectified pair (pixels) and its baseline (m)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float

    def to_wire(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_wire(cls, value: Any, kind: str) -> Camera:
        if not isinstance(value, dict):
            raise WireError(f"{kind}: camera must be a map")
        width = integer(require(value, "width", kind), "camera.width", kind, 1)
        height = integer(require(value, "height", kind), "camera.height", kind, 1)
        nums = {k: number(require(value, k, kind), f"camera.{k}", kind) for k in _CAMERA_NUMBERS}
        if nums["fx"] <= 0 or nums["fy"] <= 0 or nums["baseline"] < 0:
            raise WireError(f"{kind}: camera needs fx, fy > 0 and baseline >= 0")
        return cls(width, height, **nums)


# -- robot/<rid>/frame ------------------------------------------------------------------


@dataclass
class Frame:
    """A stereo pair (``left``, ``right``: uint8 H x W) or a ``depth`` image (float32 m, NaN none).

    ``encoding`` is ``raw8`` or ``png`` for pairs and ``f32`` for depth; ``pose`` is the
    (left) camera's body pose in the world.
    """

    robot: str
    seq: int
    t: float
    pose: Pose
    camera: Camera
    encoding: str = "raw8"
    left: np.ndarray | None = None
    right: np.ndarray | None = None
    depth: np.ndarray | None = None

    KIND = "frame"

    @property
    def is_depth(self) -> bool:
        return self.depth is not None

    def encode(self) -> bytes:
        shape = (self.camera.height, self.camera.width)
        fields = {
            "robot": self.robot,
            "seq": int(self.seq),
            "t": float(self.t),
            "pose": self.pose.to_wire(),
            "camera": self.camera.to_wire(),
        }
        if self.depth is not None:
            _check_shape(self.depth, shape, "depth")
            fields |= {"encoding": DEPTH_ENCODING, "depth": le(self.depth, "<f4")}
        elif self.encoding in STEREO_ENCODINGS and self.left is not None and self.right is not None:
            _check_shape(self.left, shape, "left")
            _check_shape(self.right, shape, "right")
            encode_image = _png if self.encoding == "png" else (lambda img: le(img, "u1"))
            fields |= {
                "encoding": self.encoding,
                "left": encode_image(self.left),
                "right": encode_image(self.right),
            }
        else:
            raise WireError("frame: needs depth, or left and right with encoding raw8/png")
        return pack(self.KIND, fields)

    @classmethod
    def decode(cls, payload: Any) -> Frame:
        kind = cls.KIND
        msg = unpack(payload, kind)
        camera = Camera.from_wire(require(msg, "camera", kind), kind)
        frame = cls(
            robot=text(require(msg, "robot", kind), "robot", kind),
            seq=integer(require(msg, "seq", kind), "seq", kind),
            t=number(require(msg, "t", kind), "t", kind),
            pose=Pose.from_wire(require(msg, "pose", kind), kind),
            camera=camera,
            encoding=require(msg, "encoding", kind),
        )
        shape = (camera.height, camera.width)
        count = shape[0] * shape[1]
        if frame.encoding == DEPTH_ENCODING:
            frame.depth = raw(require(msg, "depth", kind), "<f4", count, "depth", kind).reshape(shape)
        elif frame.encoding == "raw8":
            frame.left = raw(require(msg, "left", kind), "u1", count, "left", kind).reshape(shape)
            frame.right = raw(require(msg, "right", kind), "u1", count, "right", kind).reshape(shape)
        elif frame.encoding == "png":
            frame.left = _unpng(require(msg, "left", kind), shape, "left")
            frame.right = _unpng(require(msg, "right", kind), shape, "right")
        else:
            raise WireError(f"frame: unknown encoding {frame.encoding!r}")
        return frame


def _check_shape(image: np.ndarray, shape: tuple[int, int], name: str) -> None:
    if np.shape(image) != shape:
        raise WireError(f"frame: {name} has shape {np.shape(image)}, camera says {shape}")


def _png(image: np.ndarray) -> bytes:
    import cv2

    ok, data = cv2.imencode(".png", np.ascontiguousarray(image, dtype=np.uint8))
    if not ok:
        raise WireError("frame: PNG encoding failed")
    return data.tobytes()


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_size(value: bytes) -> tuple[int, int] | None:
    """(height, width) the PNG's IHDR chunk declares, or None when it does not start like a PNG."""
    if len(value) < 24 or value[:8] != _PNG_SIGNATURE or value[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", value[16:24])
    return height, width


def _unpng(value: Any, shape: tuple[int, int], name: str) -> np.ndarray:
    import cv2

    if not isinstance(value, bytes | bytearray):
        raise WireError(f"frame: {name} must be PNG bytes")
    # the declared size first: a few hundred KB of PNG may inflate to a gigapixel
    declared = _png_size(value)
    if declared != shape:
        got = "no PNG header" if declared is None else f"a header of shape {declared}"
        raise WireError(f"frame: {name} is not an 8-bit PNG of shape {shape} (got {got})")
    image = cv2.imdecode(np.frombuffer(value, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint8 or image.shape != shape:
        got = None if image is None else (image.shape, str(image.dtype))
        raise WireError(f"frame: {name} is not an 8-bit PNG of shape {shape} (got {got})")
    return image


# -- robot/<rid>/cmd --------------------------------------------------------------------


@dataclass(frozen=True)
class Cmd:
    """A velocity command answering frame ``seq``: forward speed ``v`` (m/s), turn ``omega`` (rad/s).

    On the wire the speed is the key ``speed``: ``v`` is the protocol version of every message.
    ``tilt`` (optional, rad) points a pan-tilt head: the camera's pitch relative to the rig's
    mounting pitch (positive looks down, as in ``Pose``); None leaves the head where it is.
    """

    robot: str
    seq: int
    t: float
    v: float
    omega: float
    tilt: float | None = None

    KIND = "cmd"

    def encode(self) -> bytes:
        fields = {
            "robot": self.robot,
            "seq": int(self.seq),
            "t": float(self.t),
            "speed": float(self.v),
            "omega": float(self.omega),
        }
        if self.tilt is not None:
            fields["tilt"] = float(self.tilt)
        return pack(self.KIND, fields)

    @classmethod
    def decode(cls, payload: Any) -> Cmd:
        kind = cls.KIND
        msg = unpack(payload, kind)
        tilt = msg.get("tilt")
        if tilt is not None:
            tilt = number(tilt, "tilt", kind)
            if abs(tilt) > math.pi / 2:
                raise WireError(f"{kind}: tilt must be within +-pi/2 rad, got {tilt}")
        return cls(
            robot=text(require(msg, "robot", kind), "robot", kind),
            seq=integer(require(msg, "seq", kind), "seq", kind),
            t=number(require(msg, "t", kind), "t", kind),
            v=number(require(msg, "speed", kind), "speed", kind),
            omega=number(require(msg, "omega", kind), "omega", kind),
            tilt=tilt,
        )


# -- robot/<rid>/status -----------------------------------------------------------------


@dataclass(frozen=True)
class Status:
    """An agent's state for monitors: pose, current target (or None), state name, bytes sent.

    ``view`` (an addition to protocol v1, optional on the wire, None when absent): when the
    robot's current target is a 3-D view it chose itself, the point it goes to look at (x, y
    of the map column, z of its first unknown voxel; m), so the coordinator can keep
    teammates from looking at the same column.
    """

    robot: str
    t: float
    pose: Pose
    target: tuple[float, float, float] | None
    state: str
    bytes_sent: int
    view: tuple[float, float, float] | None = None

    KIND = "status"

    def encode(self) -> bytes:
        return pack(
            self.KIND,
            {
                "robot": self.robot,
                "t": float(self.t),
                "pose": self.pose.to_wire(),
                "target": None if self.target is None else [float(v) for v in self.target],
                "state": self.state,
                "bytes_sent": int(self.bytes_sent),
                "view": None if self.view is None else [float(v) for v in self.view],
            },
        )

    @classmethod
    def decode(cls, payload: Any) -> Status:
        kind = cls.KIND
        msg = unpack(payload, kind)
        target = require(msg, "target", kind)
        view = msg.get("view")
        return cls(
            robot=text(require(msg, "robot", kind), "robot", kind),
            t=number(require(msg, "t", kind), "t", kind),
            pose=Pose.from_wire(require(msg, "pose", kind), kind),
            target=None if target is None else vec3(target, "target", kind),
            state=text(require(msg, "state", kind), "state", kind),
            bytes_sent=integer(require(msg, "bytes_sent", kind), "bytes_sent", kind),
            view=None if view is None else vec3(view, "view", kind),
        )


def status_on_key(key: str, payload: Any) -> Status:
    """The status a ``swarm/<mission>/robot/<rid>/status`` sample carries, checked against the
    ``<rid>`` of its key: a WireError when it is malformed or names another robot (on a secured
    bus each agent may put only its own key, so the key says who sent it; the field does not)."""
    status = Status.decode(payload)
    parts = str(key).split("/")
    rid = parts[-2] if len(parts) >= 2 and parts[-1] == "status" else None
    if status.robot != rid:
        raise WireError(
            f"{Status.KIND}: robot {short(status.robot, 40)} published on the key of {short(rid, 40)}",
            "robot_mismatch",
        )
    return status


# -- sim/truth ---------------------------------------------------------------------------


@dataclass
class TruthPoses:
    """The simulator's ground truth at sim time ``t``: robot -> (x, y, yaw); dead agents."""

    t: float
    poses: dict[str, tuple[float, float, float]]
    dead: list[str] = field(default_factory=list)

    KIND = "truth"

    def encode(self) -> bytes:
        return pack(
            self.KIND,
            {
                "t": float(self.t),
                "poses": {r: [float(v) for v in p] for r, p in self.poses.items()},
                "dead": list(self.dead),
            },
        )

    @classmethod
    def decode(cls, payload: Any) -> TruthPoses:
        kind = cls.KIND
        msg = unpack(payload, kind)
        poses = require(msg, "poses", kind)
        if not isinstance(poses, dict):
            raise WireError(f"{kind}: poses must be a map robot -> [x, y, yaw]")
        dead = require(msg, "dead", kind)
        if not isinstance(dead, list):
            raise WireError(f"{kind}: dead must be a list of robot ids")
        return cls(
            t=number(require(msg, "t", kind), "t", kind),
            poses={text(r, "robot", kind): vec3(p, f"poses.{r}", kind) for r, p in poses.items()},
            dead=[text(r, "dead[]", kind) for r in dead],
        )
