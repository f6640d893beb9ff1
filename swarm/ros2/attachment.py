"""The attachment rmw_zenoh_cpp puts on every sample (rmw_zenoh ``docs/design.md``, "Publishers").

33 bytes, little-endian: the publisher's sequence number (int64, from 1), the source timestamp
(int64 ns since the UNIX epoch), one byte with the GID's length (always 16), and the publisher's
16-byte GID. A sample without it is not a ROS 2 message to rmw_zenoh's subscriptions.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

GID_SIZE = 16
SIZE = 8 + 8 + 1 + GID_SIZE
_HEAD = struct.Struct("<qqB")


class AttachmentError(ValueError):
    """An attachment that is not rmw_zenoh's: the message says which part."""


@dataclass(frozen=True)
class Attachment:
    """(sequence number, source timestamp in ns, publisher GID of 16 bytes)."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        if len(self.gid) != GID_SIZE:
            raise AttachmentError(f"a GID has {GID_SIZE} bytes, got {len(self.gid)}")
        head = _HEAD.pack(int(self.sequence_number), int(self.source_timestamp_ns), GID_SIZE)
        return head + bytes(self.gid)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Attachment:
        """Parse the 33 bytes; AttachmentError for another length or GID length."""
        raw = bytes(data)
        if len(raw) != SIZE:
            raise AttachmentError(f"attachment of {len(raw)} bytes (rmw_zenoh's has {SIZE})")
        seq, stamp, gid_len = _HEAD.unpack_from(raw)
        if gid_len != GID_SIZE:
            raise AttachmentError(f"attachment GID length {gid_len} (rmw_zenoh's is {GID_SIZE})")
        return cls(seq, stamp, raw[_HEAD.size :])
