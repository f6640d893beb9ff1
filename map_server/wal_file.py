"""The write-ahead log's file format (docs/protocol.md, "Store layout"): an 8-byte magic
``SWARMWAL``, a uint32 format version, then one record per accepted delta: uint32 length,
uint32 CRC-32 (zlib) of the payload, the raw payload; little-endian.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from pathlib import Path

from map_server.store_files import OS_FILES, StoreFiles

FORMAT = 1
WAL_MAGIC = b"SWARMWAL"
WAL_HEADER = WAL_MAGIC + struct.pack("<I", FORMAT)
RECORD_HEADER = struct.Struct("<II")  # length, crc32
#: A record longer than this is taken as corruption, not as a delta.
MAX_RECORD_BYTES = 1 << 30


class StoreError(RuntimeError):
    """A store that cannot be used; the text names the folder and the problem."""


def read_wal(path: Path, truncate: bool = True, files: StoreFiles = OS_FILES) -> tuple[list[bytes], int]:
    """The intact records of a WAL file and the number of bytes after them (torn or corrupt),
    which are cut off the file when ``truncate``. Raises StoreError for a file that is not a WAL."""
    data = path.read_bytes()
    if data[: len(WAL_HEADER)] != WAL_HEADER and WAL_HEADER.startswith(data.rstrip(b"\0")):
        # a header cut short, or zeros where it was never synced (a power cut): the log was new
        # and held no record, since its header is synced before the first record is written
        good = 0
        payloads: list[bytes] = []
    else:
        if data[: len(WAL_MAGIC)] != WAL_MAGIC:
            raise StoreError(f"{path}: not a swarm write-ahead log (bad magic)")
        (version,) = struct.unpack_from("<I", data, len(WAL_MAGIC))
        if version != FORMAT:
            raise StoreError(f"{path}: write-ahead log format {version}, this server reads {FORMAT}")
        payloads, good = _records(data)
    torn = len(data) - good
    if torn and truncate:
        files.truncate_path(path, good)
    return payloads, torn


def _records(data: bytes) -> tuple[list[bytes], int]:
    """Records of a WAL image after its header; the offset where the intact ones end."""
    payloads = []
    pos = len(WAL_HEADER)
    while pos + RECORD_HEADER.size <= len(data):
        length, crc = RECORD_HEADER.unpack_from(data, pos)
        start = pos + RECORD_HEADER.size
        if not 0 < length <= MAX_RECORD_BYTES or start + length > len(data):  # 0: a zeroed tail
            break
        payload = data[start : start + length]
        if zlib.crc32(payload) != crc:
            break
        payloads.append(payload)
        pos = start + length
    return payloads, pos


def encode_records(payloads: Sequence[bytes]) -> bytes:
    """WAL records (length, CRC32, payload) of ``payloads``."""
    parts = []
    for p in payloads:
        parts.append(RECORD_HEADER.pack(len(p), zlib.crc32(p)))
        parts.append(p)
    return b"".join(parts)
