"""Wire protocol v1 (DESIGN.md section 5): msgpack messages as plain dataclasses.

Every message is a msgpack map with ``"v": 1``; arrays travel as little-endian raw bytes.
``Message.encode()`` gives the payload, ``Message.decode(payload)`` validates one and
raises ``WireError`` (a ``ValueError``) with the reason when it is malformed. No transport
here: the Zenoh side lives in ``swarm.bus``.

Poses: ``xyz`` in metres in the world frame (z up); ``ypr`` = yaw, pitch, roll in radians
of the body frame (x forward, y left, z up, as ROS REP-103), R = Rz(yaw) Ry(pitch) Rx(roll),
so a positive pitch looks down. A camera's optical frame is x right, y down, z forward
(``Pose.optical_rotation``). Frame depth is the optical z (not the ray length).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

from swarm.map.grid import Grid
from swarm.rotation import rotation_zyx

VERSION = 1
STEREO_ENCODINGS = ("raw8", "png")
DEPTH_ENCODING = "f32"

#: Columns: the optical axes (right, down, forward) expressed in the body frame.
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class WireError(ValueError):
    """A malformed message; the text says what is wrong."""


# -- decoding helpers ------------------------------------------------------------------


def _as_bytes(payload: Any) -> bytes:
    if hasattr(payload, "to_bytes"):  # zenoh.ZBytes
        payload = payload.to_bytes()
    if isinstance(payload, bytes | bytearray | memoryview):
        return bytes(payload)
    raise WireError(f"payload must be bytes, got {type(payload).__name__}")


def _unpack(payload: Any, kind: str) -> dict:
    try:
        msg = msgpack.unpackb(_as_bytes(payload), raw=False, strict_map_key=False)
    except WireError:
        raise
    except Exception as e:  # msgpack raises several unrelated exception types
        raise WireError(f"{kind}: not a msgpack payload ({e})") from e
    if not isinstance(msg, dict):
        raise WireError(f"{kind}: payload must be a map, got {type(msg).__name__}")
    if msg.get("v") != VERSION:
        raise WireError(f"{kind}: unsupported version {msg.get('v')!r} (expected {VERSION})")
    return msg


def _pack(kind: str, fields: dict) -> bytes:
    return msgpack.packb({"v": VERSION, **fields}, use_bin_type=True)


def _field(msg: dict, name: str, kind: str) -> Any:
    if name not in msg:
        raise WireError(f"{kind}: missing field {name!r}")
    return msg[name]


def _number(value: Any, name: str, kind: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise WireError(f"{kind}: {name} must be a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise WireError(f"{kind}: {name} must be finite, got {value!r}")
    return float(value)


def _integer(value: Any, name: str, kind: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise WireError(f"{kind}: {name} must be an integer, got {value!r}")
    if value < minimum:
        raise WireError(f"{kind}: {name} must be >= {minimum}, got {value}")
    return value


def _text(value: Any, name: str, kind: str) -> str:
    if not isinstance(value, str) or not value:
        raise WireError(f"{kind}: {name} must be a non-empty string, got {value!r}")
    return value


def _vec3(value: Any, name: str, kind: str) -> tuple[float, float, float]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise WireError(f"{kind}: {name} must be 3 numbers, got {value!r}")
    return tuple(_number(v, f"{name}[{i}]", kind) for i, v in enumerate(value))


def _raw(value: Any, dtype: str, count: int, name: str, kind: str) -> np.ndarray:
    if not isinstance(value, bytes | bytearray):
        raise WireError(f"{kind}: {name} must be raw bytes, got {type(value).__name__}")
    itemsize = np.dtype(dtype).itemsize
    if len(value) != count * itemsize:
        raise WireError(
            f"{kind}: {name} has {len(value)} bytes, expected {count * itemsize} ({count} x {dtype})"
        )
    return np.frombuffer(value, dtype=dtype).copy()


def _indices(value: Any, kind: str, grid_size: int) -> np.ndarray:
    """A raw little-endian uint32 array of any length: voxel indices, each below ``grid_size``."""
    if not isinstance(value, bytes | bytearray) or len(value) % 4:
        raise WireError(f"{kind}: idx must be raw uint32 bytes")
    idx = _raw(value, "<u4", len(value) // 4, "idx", kind)
    if len(idx) and int(idx.max()) >= grid_size:
        raise WireError(f"{kind}: voxel index {int(idx.max())} outside grid of {grid_size}")
    return idx


def _le(array: np.ndarray, dtype: str) -> bytes:
    return np.ascontiguousarray(array, dtype=dtype).tobytes()


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
            _vec3(_field(value, "xyz", kind), f"{name}.xyz", kind),
            _vec3(_field(value, "ypr", kind), f"{name}.ypr", kind),
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
        width = _integer(_field(value, "width", kind), "camera.width", kind, 1)
        height = _integer(_field(value, "height", kind), "camera.height", kind, 1)
        nums = {k: _number(_field(value, k, kind), f"camera.{k}", kind) for k in _CAMERA_NUMBERS}
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
            fields |= {"encoding": DEPTH_ENCODING, "depth": _le(self.depth, "<f4")}
        elif self.encoding in STEREO_ENCODINGS and self.left is not None and self.right is not None:
            _check_shape(self.left, shape, "left")
            _check_shape(self.right, shape, "right")
            pack = _png if self.encoding == "png" else (lambda img: _le(img, "u1"))
            fields |= {"encoding": self.encoding, "left": pack(self.left), "right": pack(self.right)}
        else:
            raise WireError("frame: needs depth, or left and right with encoding raw8/png")
        return _pack(self.KIND, fields)

    @classmethod
    def decode(cls, payload: Any) -> Frame:
        kind = cls.KIND
        msg = _unpack(payload, kind)
        camera = Camera.from_wire(_field(msg, "camera", kind), kind)
        frame = cls(
            robot=_text(_field(msg, "robot", kind), "robot", kind),
            seq=_integer(_field(msg, "seq", kind), "seq", kind),
            t=_number(_field(msg, "t", kind), "t", kind),
            pose=Pose.from_wire(_field(msg, "pose", kind), kind),
            camera=camera,
            encoding=_field(msg, "encoding", kind),
        )
        shape = (camera.height, camera.width)
        count = shape[0] * shape[1]
        if frame.encoding == DEPTH_ENCODING:
            frame.depth = _raw(_field(msg, "depth", kind), "<f4", count, "depth", kind).reshape(shape)
        elif frame.encoding == "raw8":
            frame.left = _raw(_field(msg, "left", kind), "u1", count, "left", kind).reshape(shape)
            frame.right = _raw(_field(msg, "right", kind), "u1", count, "right", kind).reshape(shape)
        elif frame.encoding == "png":
            frame.left = _unpng(_field(msg, "left", kind), shape, "left")
            frame.right = _unpng(_field(msg, "right", kind), shape, "right")
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


def _unpng(value: Any, shape: tuple[int, int], name: str) -> np.ndarray:
    import cv2

    if not isinstance(value, bytes | bytearray):
        raise WireError(f"frame: {name} must be PNG bytes")
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
        return _pack(self.KIND, fields)

    @classmethod
    def decode(cls, payload: Any) -> Cmd:
        kind = cls.KIND
        msg = _unpack(payload, kind)
        tilt = msg.get("tilt")
        if tilt is not None:
            tilt = _number(tilt, "tilt", kind)
            if abs(tilt) > math.pi / 2:
                raise WireError(f"{kind}: tilt must be within +-pi/2 rad, got {tilt}")
        return cls(
            robot=_text(_field(msg, "robot", kind), "robot", kind),
            seq=_integer(_field(msg, "seq", kind), "seq", kind),
            t=_number(_field(msg, "t", kind), "t", kind),
            v=_number(_field(msg, "speed", kind), "speed", kind),
            omega=_number(_field(msg, "omega", kind), "omega", kind),
            tilt=tilt,
        )


# -- robot/<rid>/status -----------------------------------------------------------------


@dataclass(frozen=True)
class Status:
    """An agent's state for monitors: pose, current target (or None), state name, bytes sent."""

    robot: str
    t: float
    pose: Pose
    target: tuple[float, float, float] | None
    state: str
    bytes_sent: int

    KIND = "status"

    def encode(self) -> bytes:
        return _pack(
            self.KIND,
            {
                "robot": self.robot,
                "t": float(self.t),
                "pose": self.pose.to_wire(),
                "target": None if self.target is None else [float(v) for v in self.target],
                "state": self.state,
                "bytes_sent": int(self.bytes_sent),
            },
        )

    @classmethod
    def decode(cls, payload: Any) -> Status:
        kind = cls.KIND
        msg = _unpack(payload, kind)
        target = _field(msg, "target", kind)
        return cls(
            robot=_text(_field(msg, "robot", kind), "robot", kind),
            t=_number(_field(msg, "t", kind), "t", kind),
            pose=Pose.from_wire(_field(msg, "pose", kind), kind),
            target=None if target is None else _vec3(target, "target", kind),
            state=_text(_field(msg, "state", kind), "state", kind),
            bytes_sent=_integer(_field(msg, "bytes_sent", kind), "bytes_sent", kind),
        )


# -- delta/<rid> and merged ---------------------------------------------------------------


def _grid(value: Any, kind: str) -> Grid:
    if not isinstance(value, dict):
        raise WireError(f"{kind}: grid must be a map with origin, voxel, shape")
    origin = _vec3(_field(value, "origin", kind), "grid.origin", kind)
    voxel = _number(_field(value, "voxel", kind), "grid.voxel", kind)
    shape = _field(value, "shape", kind)
    if not isinstance(shape, list | tuple) or len(shape) != 3:
        raise WireError(f"{kind}: grid.shape must be 3 integers, got {shape!r}")
    shape = tuple(_integer(n, f"grid.shape[{i}]", kind, 1) for i, n in enumerate(shape))
    if voxel <= 0:
        raise WireError(f"{kind}: grid.voxel must be > 0, got {voxel}")
    return Grid(origin, voxel, shape)


def _information(dlam: np.ndarray, deta: np.ndarray, kind: str, names: tuple[str, str]) -> None:
    if not np.all(np.isfinite(dlam)) or not np.all(np.isfinite(deta)):
        raise WireError(f"{kind}: {names[0]}/{names[1]} must be finite")
    if np.any(dlam < 0):
        raise WireError(f"{kind}: {names[0]} must be >= 0 (information cannot be negative)")


@dataclass
class DeltaMessage:
    """``delta/<rid>`` and ``merged``: information gathered by ``robot`` since its last delta,
    per flat voxel ``idx`` (dlam, deta); ``swarm.map.delta.Delta`` holds the same arrays.

    ``(robot, epoch, seq)`` identifies a delta once: epoch is the agent process's start time
    in ns, seq counts 1, 2, 3 within it.
    """

    robot: str
    epoch: int
    seq: int
    t: float
    grid: Grid
    idx: np.ndarray
    dlam: np.ndarray
    deta: np.ndarray

    KIND = "delta"

    def encode(self) -> bytes:
        n = len(self.idx)
        if len(self.dlam) != n or len(self.deta) != n:
            raise WireError("delta: idx, dlam and deta must have the same length")
        return _pack(
            self.KIND,
            {
                "robot": self.robot,
                "epoch": int(self.epoch),
                "seq": int(self.seq),
                "t": float(self.t),
                "grid": self.grid.to_dict(),
                "idx": _le(self.idx, "<u4"),
                "dlam": _le(self.dlam, "<f4"),
                "deta": _le(self.deta, "<f4"),
            },
        )

    @classmethod
    def decode(cls, payload: Any) -> DeltaMessage:
        kind = cls.KIND
        msg = _unpack(payload, kind)
        grid = _grid(_field(msg, "grid", kind), kind)
        idx = _indices(_field(msg, "idx", kind), kind, grid.size)
        n = len(idx)
        dlam = _raw(_field(msg, "dlam", kind), "<f4", n, "dlam", kind)
        deta = _raw(_field(msg, "deta", kind), "<f4", n, "deta", kind)
        _information(dlam, deta, kind, ("dlam", "deta"))
        return cls(
            robot=_text(_field(msg, "robot", kind), "robot", kind),
            epoch=_integer(_field(msg, "epoch", kind), "epoch", kind),
            seq=_integer(_field(msg, "seq", kind), "seq", kind, 1),
            t=_number(_field(msg, "t", kind), "t", kind),
            grid=grid,
            idx=idx,
            dlam=dlam,
            deta=deta,
        )


# -- map/snapshot reply -------------------------------------------------------------------


@dataclass
class Snapshot:
    """The whole team map in information form (prior included) and the deltas it holds.

    ``acks`` is the contiguous prefix per (robot, epoch), as ``map/acks``; ``above`` lists
    the seqs applied beyond that prefix (optional on the wire, empty when absent), so that a
    replica started from the snapshot counts every delta in it as applied, not only the
    prefix, and never adds one twice.
    """

    grid: Grid
    lam: np.ndarray
    eta: np.ndarray
    acks: dict[str, dict[int, int]] = field(default_factory=dict)
    above: dict[str, dict[int, list[int]]] = field(default_factory=dict)

    KIND = "snapshot"

    def encode(self) -> bytes:
        return _pack(
            self.KIND,
            {
                "grid": self.grid.to_dict(),
                "lam": _le(np.ravel(self.lam), "<f4"),
                "eta": _le(np.ravel(self.eta), "<f4"),
                "acks": {
                    str(r): {int(e): int(s) for e, s in by_epoch.items()} for r, by_epoch in self.acks.items()
                },
                "above": {
                    str(r): {int(e): sorted(int(s) for s in seqs) for e, seqs in by_epoch.items()}
                    for r, by_epoch in self.above.items()
                },
            },
        )

    @classmethod
    def decode(cls, payload: Any) -> Snapshot:
        kind = cls.KIND
        msg = _unpack(payload, kind)
        grid = _grid(_field(msg, "grid", kind), kind)
        lam = _raw(_field(msg, "lam", kind), "<f4", grid.size, "lam", kind)
        eta = _raw(_field(msg, "eta", kind), "<f4", grid.size, "eta", kind)
        if not np.all(np.isfinite(lam)) or not np.all(np.isfinite(eta)) or np.any(lam <= 0):
            raise WireError(f"{kind}: lam must be finite and > 0, eta finite")
        acks = _field(msg, "acks", kind)
        if not isinstance(acks, dict) or not all(isinstance(v, dict) for v in acks.values()):
            raise WireError(f"{kind}: acks must be a map robot -> {{epoch: seq}}")
        acks = {
            str(r): {int(e): _integer(s, f"acks.{r}", kind) for e, s in by_epoch.items()}
            for r, by_epoch in acks.items()
        }
        above = msg.get("above", {})
        if not (
            isinstance(above, dict)
            and all(isinstance(v, dict) for v in above.values())
            and all(isinstance(seqs, list) for v in above.values() for seqs in v.values())
        ):
            raise WireError(f"{kind}: above must be a map robot -> {{epoch: [seq, ...]}}")
        above = {
            str(r): {int(e): [_integer(s, f"above.{r}", kind) for s in seqs] for e, seqs in by_epoch.items()}
            for r, by_epoch in above.items()
        }
        return cls(grid, lam, eta, acks, above)


# -- map/region reply ---------------------------------------------------------------------


@dataclass
class Region:
    """The beliefs of the voxels of a box: flat ``idx`` (uint32, ascending) in ``grid`` and,
    per voxel, ``mu``, ``sigma`` (untruncated Gaussian), ``expected_coverage`` (E[C] of the
    belief truncated to [0, 1]) and ``entropy`` (bits), all float32.
    """

    grid: Grid
    idx: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    expected_coverage: np.ndarray
    entropy: np.ndarray

    KIND = "region"
    _VALUES = ("mu", "sigma", "expected_coverage", "entropy")

    def __len__(self) -> int:
        return len(self.idx)

    def centres(self) -> np.ndarray:
        """World centres (N, 3) of the voxels."""
        return self.grid.centre(self.grid.unflat(self.idx))

    def encode(self) -> bytes:
        n = len(self.idx)
        if any(len(getattr(self, name)) != n for name in self._VALUES):
            raise WireError("region: idx and every value array must have the same length")
        fields = {"grid": self.grid.to_dict(), "idx": _le(self.idx, "<u4")}
        fields |= {name: _le(getattr(self, name), "<f4") for name in self._VALUES}
        return _pack(self.KIND, fields)

    @classmethod
    def decode(cls, payload: Any) -> Region:
        kind = cls.KIND
        msg = _unpack(payload, kind)
        grid = _grid(_field(msg, "grid", kind), kind)
        idx = _indices(_field(msg, "idx", kind), kind, grid.size)
        n = len(idx)
        values = {name: _raw(_field(msg, name, kind), "<f4", n, name, kind) for name in cls._VALUES}
        return cls(grid, idx, **values)


# -- coord/assign -----------------------------------------------------------------------


@dataclass(frozen=True)
class AssignRequest:
    """A robot asks the coordinator for a target."""

    robot: str
    pose: Pose

    KIND = "assign request"

    def encode(self) -> bytes:
        return _pack(self.KIND, {"robot": self.robot, "pose": self.pose.to_wire()})

    @classmethod
    def decode(cls, payload: Any) -> AssignRequest:
        msg = _unpack(payload, cls.KIND)
        return cls(
            robot=_text(_field(msg, "robot", cls.KIND), "robot", cls.KIND),
            pose=Pose.from_wire(_field(msg, "pose", cls.KIND), cls.KIND),
        )


@dataclass(frozen=True)
class AssignReply:
    """The coordinator's answer: a target point and gaze direction (None: no target)."""

    target: tuple[float, float, float] | None
    gaze: tuple[float, float, float] | None
    utility: float

    KIND = "assign reply"

    def encode(self) -> bytes:
        def vec(v):
            return None if v is None else [float(x) for x in v]

        return _pack(
            self.KIND,
            {"target": vec(self.target), "gaze": vec(self.gaze), "utility": float(self.utility)},
        )

    @classmethod
    def decode(cls, payload: Any) -> AssignReply:
        kind = cls.KIND
        msg = _unpack(payload, kind)
        target, gaze = _field(msg, "target", kind), _field(msg, "gaze", kind)
        return cls(
            target=None if target is None else _vec3(target, "target", kind),
            gaze=None if gaze is None else _vec3(gaze, "gaze", kind),
            utility=_number(_field(msg, "utility", kind), "utility", kind),
        )


# -- sim/truth ---------------------------------------------------------------------------


@dataclass
class TruthPoses:
    """The simulator's ground truth at sim time ``t``: robot -> (x, y, yaw); dead agents."""

    t: float
    poses: dict[str, tuple[float, float, float]]
    dead: list[str] = field(default_factory=list)

    KIND = "truth"

    def encode(self) -> bytes:
        return _pack(
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
        msg = _unpack(payload, kind)
        poses = _field(msg, "poses", kind)
        if not isinstance(poses, dict):
            raise WireError(f"{kind}: poses must be a map robot -> [x, y, yaw]")
        dead = _field(msg, "dead", kind)
        if not isinstance(dead, list):
            raise WireError(f"{kind}: dead must be a list of robot ids")
        return cls(
            t=_number(_field(msg, "t", kind), "t", kind),
            poses={_text(r, "robot", kind): _vec3(p, f"poses.{r}", kind) for r, p in poses.items()},
            dead=[_text(r, "dead[]", kind) for r in dead],
        )
