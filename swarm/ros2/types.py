"""ROS 2 message types of one distribution: CDR (de)serialisation and RIHS01 type hashes.

Both come from ``rosbags`` (its type store of the distribution's message definitions, its CDR
serde with the 4-byte encapsulation header, its REP-2016 RIHS01 hashes); nothing here writes CDR
by hand. Humble predates type hashes: rmw_zenoh on Humble writes ``TypeHashNotSupported`` in their
place, and so do we.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from rosbags.typesys import Stores, get_typestore

#: the ROS 2 distributions rmw_zenoh runs on, and their rosbags type stores
DISTROS: dict[str, Stores] = {
    "humble": Stores.ROS2_HUMBLE,
    "jazzy": Stores.ROS2_JAZZY,
    "kilted": Stores.ROS2_KILTED,
    "lyrical": Stores.ROS2_LYRICAL,
    "rolling": Stores.LATEST,
}
DEFAULT_DISTRO = "jazzy"
NO_TYPE_HASH = "TypeHashNotSupported"


class MessageError(ValueError):
    """A payload that is not a message of the expected type (the text says why)."""


class Ros2Types:
    """The message types of ``distro``: ``new``, ``serialize``, ``deserialize``, ``type_hash``.

    Raises ValueError for an unknown distro (naming the known ones).
    """

    def __init__(self, distro: str = DEFAULT_DISTRO) -> None:
        if distro not in DISTROS:
            raise ValueError(f"ROS 2 distro {distro!r} is not one of {', '.join(DISTROS)}")
        self.distro = distro
        self.store = _store(distro)

    def _type(self, type_name: str) -> Any:
        try:
            return self.store.types[type_name]
        except KeyError:
            known = f"ROS 2 {self.distro}'s definitions"
            raise ValueError(f"message type {type_name!r} is not in {known}") from None

    def new(self, type_name: str, **fields: Any) -> Any:
        """A message object of ``type_name`` (e.g. ``sensor_msgs/msg/Image``) from its fields."""
        return self._type(type_name)(**fields)

    def type_hash(self, type_name: str) -> str:
        """The RIHS01 hash of ``type_name`` (``TypeHashNotSupported`` on Humble)."""
        self._type(type_name)
        return NO_TYPE_HASH if self.distro == "humble" else self.store.hash_rihs01(type_name)

    def serialize(self, message: Any, type_name: str) -> bytes:
        """CDR little-endian with its encapsulation header, as rmw_zenoh puts it on the wire."""
        return bytes(self.store.serialize_cdr(message, type_name))

    def deserialize(self, payload: bytes | bytearray | memoryview, type_name: str) -> Any:
        """The message in ``payload``; MessageError for a truncated or malformed one."""
        data = bytes(payload)
        if len(data) < 4:
            raise MessageError(f"{type_name}: {len(data)} bytes, shorter than the CDR header")
        if data[0] != 0 or data[1] not in (0, 1):
            raise MessageError(f"{type_name}: CDR header {data[:4].hex()} is not plain CDR (00 00 or 00 01)")
        try:
            return self.store.deserialize_cdr(data, type_name)
        except Exception as exc:  # rosbags raises SerdeError, struct.error, IndexError, ValueError
            raise MessageError(f"{type_name}: does not deserialize ({exc})") from None


@cache
def _store(distro: str):
    return get_typestore(DISTROS[distro])


def stamp_of(header: Any) -> float:
    """A ``std_msgs/Header``'s stamp in seconds."""
    return int(header.stamp.sec) + int(header.stamp.nanosec) * 1e-9


def time_fields(t: float) -> dict[str, int]:
    """``builtin_interfaces/Time`` fields (sec, nanosec) of ``t`` seconds (t >= 0)."""
    if not t >= 0:
        raise ValueError(f"a ROS time is >= 0 s, got {t}")
    ns = int(round(float(t) * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def header(types: Ros2Types, t: float, frame_id: str) -> Any:
    """A ``std_msgs/Header`` stamped ``t`` seconds in ``frame_id``."""
    stamp = types.new("builtin_interfaces/msg/Time", **time_fields(t))
    return types.new("std_msgs/msg/Header", stamp=stamp, frame_id=str(frame_id))
