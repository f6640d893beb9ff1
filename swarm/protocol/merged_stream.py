"""The numbering of the map server's ``merged`` stream (docs/protocol.md, "The merged stream").

The server publishes ``merged`` with congestion control DROP, so a subscriber that does not
drain (a stalled link, a blocked callback) loses samples instead of holding the merge worker
back. Each sample carries a 16-byte Zenoh attachment: the server run's id and the sample's
number in that run, both unsigned 64-bit little-endian (``struct`` format ``<QQ``). The run
id is random, drawn when the server starts; the number starts at 1 and grows by one per
sample. A subscriber that sees a number jump, or a new run id, has missed samples and
catches up from ``map/snapshot``. (No I/O here: encoding, and the receiver's bookkeeping.)
"""

from __future__ import annotations

import os
import struct
import threading

ATTACHMENT = struct.Struct("<QQ")


def new_run_id() -> int:
    """A random non-zero 64-bit server run id."""
    while True:
        run = int.from_bytes(os.urandom(8), "little")
        if run:
            return run


def encode_position(run: int, number: int) -> bytes:
    """The 16-byte attachment of sample ``number`` of server run ``run``."""
    return ATTACHMENT.pack(run, number)


def decode_position(attachment: bytes | None) -> tuple[int, int] | None:
    """(run, number) of an attachment; None when absent or not 16 bytes (not the server's)."""
    if attachment is None or len(attachment) != ATTACHMENT.size:
        return None
    return ATTACHMENT.unpack(attachment)


class MergedNumbering:
    """The numbers a server gives its ``merged`` samples: :meth:`next` per sample (thread-safe)."""

    def __init__(self, run: int | None = None) -> None:
        self.run = run or new_run_id()
        self.number = 0
        self._lock = threading.Lock()

    def next(self) -> bytes:
        """The attachment of the next sample."""
        with self._lock:
            self.number += 1
            return encode_position(self.run, self.number)


class StreamPosition:
    """Where a subscriber is in the ``merged`` stream; :meth:`observe` tells a gap (thread-safe).

    The first numbered sample sets the position (a replica starts from a snapshot taken after
    it subscribed). ``missed``: samples known lost (the sum of the jumps); ``new_runs``: server
    restarts seen; ``unnumbered``: samples without a valid attachment (not the server's:
    applied as any other, but they cannot be counted in the stream).
    """

    def __init__(self) -> None:
        self.run: int | None = None
        self.number = 0
        self.missed = 0
        self.new_runs = 0
        self.unnumbered = 0
        self._lock = threading.Lock()

    def observe(self, attachment: bytes | None) -> str | None:
        """Record a sample's attachment; returns "gap" (a number skipped), "new_run" (another
        server run than the last one seen), else None (in order, the first one, a repeat of an
        older number, or unnumbered)."""
        position = decode_position(attachment)
        with self._lock:
            if position is None:
                self.unnumbered += 1
                return None
            run, number = position
            if self.run is None:
                self.run, self.number = run, number
                return None
            if run != self.run:
                self.run, self.number = run, number
                self.new_runs += 1
                return "new_run"
            if number <= self.number:
                return None
            jump = number - self.number - 1
            self.number = number
            if jump:
                self.missed += jump
                return "gap"
            return None
