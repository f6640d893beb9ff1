"""The wire's encoding rules: msgpack maps with ``"v": 1``, little-endian raw arrays, and the
field checks every message decoder uses; a malformed field raises :class:`WireError` naming it.

Strict (docs/protocol.md, revision 2): ``v`` is the integer 1 (not ``true``, not ``1.0``), map
keys are strings, integers are integers and booleans are not numbers. :func:`unpack` caps the
length msgpack may declare for an array, a map or a string, so a small payload cannot make
the decoder build a huge object.
"""

from __future__ import annotations

import math
import re
from typing import Any

import msgpack
import numpy as np

VERSION = 1
#: The version of ``delta/<rid>`` payloads (and so of ``merged``) and of the ``map/epoch`` reply:
#: server-issued epochs and a MAC per delta (docs/protocol.md, "Versions").
DELTA_VERSION = 2
STEREO_ENCODINGS = ("raw8", "png")
DEPTH_ENCODING = "f32"


#: The longest array, map and string a message may declare (bin arrays are bounded by the payload).
MAX_CONTAINER_LEN = 1 << 16
MAX_STR_LEN = 4096


class WireError(ValueError):
    """A malformed message; the text says what is wrong and ``kind`` names the way it is wrong
    (``malformed``, ``unsupported_version``, ``out_of_grid``, ``non_finite``, ...)."""

    def __init__(self, reason: str, kind: str = "malformed") -> None:
        super().__init__(reason)
        self.kind = kind


# -- decoding helpers ------------------------------------------------------------------


def as_bytes(payload: Any) -> bytes:
    if hasattr(payload, "to_bytes"):  # zenoh.ZBytes
        payload = payload.to_bytes()
    if isinstance(payload, bytes | bytearray | memoryview):
        return bytes(payload)
    raise WireError(f"payload must be bytes, got {type(payload).__name__}")


def unpack(payload: Any, kind: str, versions: tuple[int, ...] = (VERSION,), hint: str = "") -> dict:
    """The msgpack map of a payload, decoded once; WireError unless it is a map of string keys
    whose ``v`` is one of the integers ``versions`` (kind ``unsupported_version`` for another
    ``v``, whose text ends with ``hint``)."""
    try:
        msg = msgpack.unpackb(
            as_bytes(payload),
            raw=False,
            strict_map_key=True,
            max_array_len=MAX_CONTAINER_LEN,
            max_map_len=MAX_CONTAINER_LEN,
            max_str_len=MAX_STR_LEN,
            max_ext_len=0,
        )
    except WireError:
        raise
    except Exception as e:  # msgpack raises several unrelated exception types
        raise WireError(f"{kind}: not a msgpack payload ({short(e)})") from e
    if not isinstance(msg, dict):
        raise WireError(f"{kind}: payload must be a map, got {type(msg).__name__}")
    if not all(isinstance(k, str) for k in msg):
        raise WireError(f"{kind}: map keys must be strings")
    version = msg.get("v")
    if type(version) is not int or version not in versions:  # True == 1 and 1.0 == 1 in Python
        expected = " or ".join(str(v) for v in versions)
        raise WireError(
            f"{kind}: unsupported version {short(version)} (expected the integer {expected}){hint}",
            "unsupported_version",
        )
    return msg


def short(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for error texts that echo what was sent."""
    text = repr(value) if not isinstance(value, BaseException) else str(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def pack(kind: str, fields: dict, version: int = VERSION) -> bytes:
    return msgpack.packb({"v": version, **fields}, use_bin_type=True)


def require(msg: dict, name: str, kind: str) -> Any:
    if name not in msg:
        raise WireError(f"{kind}: missing field {name!r}")
    return msg[name]


def number(value: Any, name: str, kind: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise WireError(f"{kind}: {name} must be a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise WireError(f"{kind}: {name} must be finite, got {value!r}", "non_finite")
    return float(value)


def integer(value: Any, name: str, kind: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise WireError(f"{kind}: {name} must be an integer, got {short(value)}")
    if value < minimum:
        raise WireError(f"{kind}: {name} must be >= {minimum}, got {value}")
    return value


_DECIMAL = re.compile(r"(0|[1-9][0-9]{0,19})", re.ASCII)


def decimal(value: Any, name: str, kind: str) -> int:
    """A map key that is a non-negative integer written as ASCII decimal digits (epochs)."""
    if not isinstance(value, str) or not _DECIMAL.fullmatch(value):
        raise WireError(f"{kind}: {name} must be a decimal string, got {short(value)}")
    return int(value)


def text(value: Any, name: str, kind: str) -> str:
    if not isinstance(value, str) or not value:
        raise WireError(f"{kind}: {name} must be a non-empty string, got {short(value)}")
    return value


def vec3(value: Any, name: str, kind: str) -> tuple[float, float, float]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise WireError(f"{kind}: {name} must be 3 numbers, got {short(value)}")
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
        raise WireError(f"{kind}: voxel index {int(idx.max())} outside grid of {grid_size}", "out_of_grid")
    return idx


def le(array: np.ndarray, dtype: str) -> bytes:
    return np.ascontiguousarray(array, dtype=dtype).tobytes()
