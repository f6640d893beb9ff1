"""The wire's encoding rules: msgpack maps with ``"v": 1``, little-endian raw arrays, and the
field checks every message decoder uses; a malformed field raises :class:`WireError` naming it."""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

VERSION = 1
STEREO_ENCODINGS = ("raw8", "png")
DEPTH_ENCODING = "f32"


class WireError(ValueError):
    """A malformed message; the text says what is wrong."""


# -- decoding helpers ------------------------------------------------------------------


def as_bytes(payload: Any) -> bytes:
    if hasattr(payload, "to_bytes"):  # zenoh.ZBytes
        payload = payload.to_bytes()
    if isinstance(payload, bytes | bytearray | memoryview):
        return bytes(payload)
    raise WireError(f"payload must be bytes, got {type(payload).__name__}")


def unpack(payload: Any, kind: str) -> dict:
    try:
        msg = msgpack.unpackb(as_bytes(payload), raw=False, strict_map_key=False)
    except WireError:
        raise
    except Exception as e:  # msgpack raises several unrelated exception types
        raise WireError(f"{kind}: not a msgpack payload ({e})") from e
    if not isinstance(msg, dict):
        raise WireError(f"{kind}: payload must be a map, got {type(msg).__name__}")
    if msg.get("v") != VERSION:
        raise WireError(f"{kind}: unsupported version {msg.get('v')!r} (expected {VERSION})")
    return msg


def pack(kind: str, fields: dict) -> bytes:
    return msgpack.packb({"v": VERSION, **fields}, use_bin_type=True)


def require(msg: dict, name: str, kind: str) -> Any:
    if name not in msg:
        raise WireError(f"{kind}: missing field {name!r}")
    return msg[name]


def number(value: Any, name: str, kind: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise WireError(f"{kind}: {name} must be a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise WireError(f"{kind}: {name} must be finite, got {value!r}")
    return float(value)


def integer(value: Any, name: str, kind: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise WireError(f"{kind}: {name} must be an integer, got {value!r}")
    if value < minimum:
        raise WireError(f"{kind}: {name} must be >= {minimum}, got {value}")
    return value


def text(value: Any, name: str, kind: str) -> str:
    if not isinstance(value, str) or not value:
        raise WireError(f"{kind}: {name} must be a non-empty string, got {value!r}")
    return value


def vec3(value: Any, name: str, kind: str) -> tuple[float, float, float]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise WireError(f"{kind}: {name} must be 3 numbers, got {value!r}")
    return tuple(number(v, f"{name}[{i}]", kind) for i, v in enumerate(value))


def raw(value: Any, dtype: str, count: int, name: str, kind: str) -> np.ndarray:
    if not isinstance(value, bytes | bytearray):
        raise WireError(f"{kind}: {name} must be raw bytes, got {type(value).__name__}")
    itemsize = np.dtype(dtype).itemsize
    if len(value) != count * itemsize:
        raise WireError(
            f"{kind}: {name} has {len(value)} bytes, expected {count * itemsize} ({count} x {dtype})"
        )
    return np.frombuffer(value, dtype=dtype).copy()


def indices(value: Any, kind: str, grid_size: int) -> np.ndarray:
    """A raw little-endian uint32 array of any length: voxel indices, each below ``grid_size``."""
    if not isinstance(value, bytes | bytearray) or len(value) % 4:
        raise WireError(f"{kind}: idx must be raw uint32 bytes")
    idx = raw(value, "<u4", len(value) // 4, "idx", kind)
    if len(idx) and int(idx.max()) >= grid_size:
        raise WireError(f"{kind}: voxel index {int(idx.max())} outside grid of {grid_size}")
    return idx


def le(array: np.ndarray, dtype: str) -> bytes:
    return np.ascontiguousarray(array, dtype=dtype).tobytes()
