"""The map server's streamed answers to ``map/snapshot`` and ``map/region`` (docs/protocol.md,
"Streamed answers"; the chunks are ``swarm.protocol.map_chunks``).

The first query of an answer (no ``stream`` parameter) makes the server take one copy of it:
the whole map (8 bytes per voxel, under the map's lock, with the ledger's acks and seqs: one
consistent point however many deltas arrive while it streams), or a region's beliefs. The copy
is held under a fresh stream id in a :class:`StreamCache` and cut into chunks of
``map_chunks.CHUNK_BYTES``; each query is answered with the chunks ``cursor`` up to
``cursor + count`` (one reply each). A client asks on with ``stream=<id>;cursor=<n>`` until it
holds every chunk, and asks again from the cursor of a chunk it lost. A snapshot asked while
the map has not changed since the last one is served from that one's copy.

The cache holds at most ``max_streams`` streams of ``max_bytes`` in all, at most
``per_requester`` started by one requester (the Zenoh id in the query's ``source_info``;
as in ``map_server.query_gate``, only the overall bounds hold for those that state none),
and drops a stream no one asked for ``idle_s`` seconds; the least recently asked goes first.
A query for a stream no longer held, or never held, is answered ``<key>: expired: ...`` and
the client starts again. Bad parameters are answered ``<key>: bad query: ...``. Nothing
here raises into Zenoh (``map_server.replies``).
"""

from __future__ import annotations

import os
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from map_server.query_gate import requester_of
from swarm.protocol.codec import short
from swarm.protocol.map_chunks import (
    EXPIRED,
    MAX_WINDOW,
    REGION_KIND,
    SNAPSHOT_KIND,
    WINDOW,
    chunk_count,
    is_stream_id,
    region_chunk,
    snapshot_chunk,
    voxels_per_chunk,
)
from swarm.protocol.wire import Region, Snapshot

#: Streams held at once, of one requester, and seconds a stream is kept since last asked for.
MAX_STREAMS = 8
MAX_STREAMS_PER_REQUESTER = 2
IDLE_S = 30.0
#: A cursor or count is at most this many decimal digits (a cursor past the last chunk is refused).
_DIGITS = re.compile(r"[0-9]{1,9}", re.ASCII)


@dataclass
class HeldStream:
    """One answer held for streaming: ``kind`` (``snapshot_chunk``/``region_chunk``), its
    ``chunks``, the function that encodes chunk ``i``, the bytes held, and for a snapshot the
    map ``version`` it copies (None for a region)."""

    stream: str
    kind: str
    chunks: int
    encode: Callable[[int], bytes]
    nbytes: int
    version: int | None = None
    requester: str | None = None
    last_used: float = 0.0


def new_stream_id() -> str:
    """16 random lower-case hex digits (not guessable: a stream is only read by who started it
    or learnt its id)."""
    return os.urandom(8).hex()


def held_snapshot(snap: Snapshot, deltas: int, version: int, chunk_bytes: int) -> HeldStream:
    """A stream of the snapshot ``snap`` (its own arrays, copied by the caller), ``deltas``
    applied in it, taken at map ``version``."""
    per = voxels_per_chunk(SNAPSHOT_KIND, chunk_bytes)
    stream = new_stream_id()
    n = snap.grid.size
    return HeldStream(
        stream,
        SNAPSHOT_KIND,
        chunk_count(n, per),
        lambda i: snapshot_chunk(stream, snap, i, per, deltas).encode(),
        snap.lam.nbytes + snap.eta.nbytes,
        version,
    )


def held_region(region: Region, chunk_bytes: int) -> HeldStream:
    """A stream of ``region`` (its own arrays)."""
    per = voxels_per_chunk(REGION_KIND, chunk_bytes)
    stream = new_stream_id()
    nbytes = sum(getattr(region, n).nbytes for n in ("idx", "mu", "sigma", "expected_coverage", "entropy"))
    return HeldStream(
        stream,
        REGION_KIND,
        chunk_count(len(region), per),
        lambda i: region_chunk(stream, region, i, per).encode(),
        nbytes,
    )


class StreamCache:
    """The streams held (see the module doc); thread-safe. ``clock``: seconds, monotonic."""

    def __init__(
        self,
        max_streams: int = MAX_STREAMS,
        per_requester: int = MAX_STREAMS_PER_REQUESTER,
        max_bytes: int = 1 << 30,
        idle_s: float = IDLE_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if max_streams < 1 or per_requester < 1 or max_bytes < 1 or idle_s <= 0:
            raise ValueError("a stream cache holds at least one stream, of one byte, for some time")
        self.max_streams, self.per_requester = max_streams, per_requester
        self.max_bytes, self.idle_s, self.clock = max_bytes, idle_s, clock
        self._held: OrderedDict[str, HeldStream] = OrderedDict()  # least recently asked first
        self._lock = threading.Lock()
        self.started = 0
        self.shared = 0
        self.expired = 0
        self.evicted = 0

    def _expire(self, now: float) -> None:
        for stream in [s for s, h in self._held.items() if now - h.last_used > self.idle_s]:
            del self._held[stream]
            self.expired += 1

    def find(self, stream: str) -> HeldStream | None:
        """The stream ``stream`` (now the most recently asked), or None when not held."""
        with self._lock:
            now = self.clock()
            self._expire(now)
            held = self._held.get(stream)
            if held is not None:
                held.last_used = now
                self._held.move_to_end(stream)
            return held

    def current_snapshot(self, version: int) -> HeldStream | None:
        """A held snapshot stream of map ``version`` (to serve again without a new copy)."""
        with self._lock:
            now = self.clock()
            self._expire(now)
            for held in reversed(self._held.values()):
                if held.kind == SNAPSHOT_KIND and held.version == version:
                    held.last_used = now
                    self._held.move_to_end(held.stream)
                    self.shared += 1
                    return held
            return None

    def hold(self, held: HeldStream, requester: str | None) -> HeldStream:
        """Hold a new stream of ``requester`` (None: one that states no id), dropping the least
        recently asked ones (a stated requester's own first) to stay within the bounds; returns it."""
        with self._lock:
            now = self.clock()
            self._expire(now)
            if held.stream in self._held:  # a snapshot of the same map version, served again
                held.last_used = now
                self._held.move_to_end(held.stream)
                return held
            held.requester, held.last_used = requester, now
            own = [h for h in self._held.values() if requester is not None and h.requester == requester]
            while len(own) >= self.per_requester:
                del self._held[own.pop(0).stream]
                self.evicted += 1
            while self._held and (
                len(self._held) >= self.max_streams
                or sum(h.nbytes for h in self._held.values()) + held.nbytes > self.max_bytes
            ):
                self._held.popitem(last=False)
                self.evicted += 1
            self._held[held.stream] = held
            self.started += 1
            return held

    def stats(self) -> dict:
        """``map/stats`` ``streams``: held now, their bytes, and counts since start."""
        with self._lock:
            self._expire(self.clock())
            return {
                "held": len(self._held),
                "held_bytes": sum(h.nbytes for h in self._held.values()),
                "started": self.started,
                "shared": self.shared,
                "expired": self.expired,
                "evicted": self.evicted,
                "max": self.max_streams,
                "max_per_requester": self.per_requester,
                "idle_s": self.idle_s,
            }


@dataclass(frozen=True)
class StreamAsk:
    """A query's stream parameters: ``stream`` id (None: start an answer), first ``cursor``,
    ``count`` of chunks to answer."""

    stream: str | None
    cursor: int
    count: int


def parse_stream_parameters(params) -> StreamAsk:
    """``stream``, ``cursor`` and ``count`` of a selector's parameters (a mapping with
    ``get``); ValueError naming the parameter, echoing at most 40 characters of it."""

    def shown(text: str) -> str:
        return short(text, 40)

    stream = params.get("stream")
    if stream is not None and not is_stream_id(stream):
        raise ValueError(f"stream={shown(stream)}: expected 16 lower-case hex digits")
    cursor_text, count_text = params.get("cursor"), params.get("count")
    cursor = 0
    if cursor_text is not None:
        if not _DIGITS.fullmatch(cursor_text):
            raise ValueError(f"cursor={shown(cursor_text)}: expected a chunk number (decimal digits)")
        cursor = int(cursor_text)
        if stream is None and cursor != 0:
            raise ValueError(f"cursor={cursor} without stream=: a stream starts at cursor 0")
    count = WINDOW
    if count_text is not None:
        if not _DIGITS.fullmatch(count_text) or not 1 <= int(count_text) <= MAX_WINDOW:
            raise ValueError(f"count={shown(count_text)}: expected 1 to {MAX_WINDOW} chunks")
        count = int(count_text)
    return StreamAsk(stream, cursor, count)


class MapStreams:
    """Answers the streamed queries of one map server: ``answer(query, start)``, where
    ``start(query)`` returns the new stream of a query without ``stream`` (raising
    ValueError for bad parameters of its own, such as a region's box)."""

    def __init__(self, cache: StreamCache, chunk_bytes: int) -> None:
        self.cache, self.chunk_bytes = cache, chunk_bytes

    def answer(self, query: zenoh.Query, start: Callable[[zenoh.Query], HeldStream]) -> None:
        """Reply the chunks the query asks for, or one error reply; the caller's ``guarded``
        turns anything unexpected into an error reply."""
        key = query.key_expr
        try:
            ask = parse_stream_parameters(query.parameters)
            if ask.stream is None:
                held = self.cache.hold(start(query), requester_of(query))
            else:
                held = self.cache.find(ask.stream)
                if held is None:
                    query.reply_err(
                        f"{key}{EXPIRED}stream {ask.stream} is not held (unknown, or not asked for in "
                        f"{self.cache.idle_s:g} s); ask again without stream=".encode()
                    )
                    return
            if ask.cursor >= held.chunks:
                raise ValueError(
                    f"cursor={ask.cursor}: stream {held.stream} has chunks 0 to {held.chunks - 1}"
                )
        except ValueError as exc:
            query.reply_err(f"{key}: bad query: {short(exc, 200)}".encode())
            return
        for i in range(ask.cursor, min(held.chunks, ask.cursor + ask.count)):
            query.reply(key, held.encode(i))
