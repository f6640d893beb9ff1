"""How many whole-map queries the map server takes on at once (docs/protocol.md, "Queries").

A ``map/snapshot`` or ``map/region`` answer costs about 16 bytes per voxel while it is built
(the copy of ``lam``/``eta`` or of the region's values, then its encoding) and a share of the
map's lock. Zenoh hands a queryable's queries to one callback thread after the other, so a
flood of them would wait in line there, each to be answered in turn, and a team member's query
behind them all. :class:`QueryGate` takes at most ``per_requester`` queries of one requester
and ``total`` overall, answered by ``workers`` threads of its own; any other is answered at
once with a "busy" error reply. The requester is the Zenoh id a query states
(``source_info``), when it states one: a stranger need not, so only ``total`` binds it.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import zenoh

from map_server.replies import guarded
from swarm.log_limit import LogLimiter
from swarm.protocol.codec import short
from swarm.protocol.map_client import BUSY

log = logging.getLogger("swarm.server")
_peer_log = LogLimiter(log)

#: Whole-map queries taken on at once (being answered or waiting for a worker), all requesters.
MAX_QUERIES = 8
#: ... of one requester (one that states its Zenoh id in the query's source_info).
MAX_QUERIES_PER_REQUESTER = 2
#: Threads answering them: at most this many answers are being built at once.
QUERY_WORKERS = 2


def requester_of(query: zenoh.Query) -> str | None:
    """The Zenoh id the query states as its source (``source_info``), or None."""
    info = query.source_info
    return None if info is None else str(info.source_id.zid)


class QueryGate:
    """Admits at most ``total`` queries at once, ``per_requester`` of one requester; answers
    them on ``workers`` threads, and any other at once with ``<key>: busy: ...``. Thread-safe."""

    def __init__(
        self,
        total: int = MAX_QUERIES,
        per_requester: int = MAX_QUERIES_PER_REQUESTER,
        workers: int = QUERY_WORKERS,
    ) -> None:
        if total < 1 or per_requester < 1 or workers < 1:
            raise ValueError("a query gate takes at least one query, of each requester, on one worker")
        self.total, self.per_requester = total, per_requester
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="map-query")
        self._lock = threading.Lock()
        self._taken: Counter[str | None] = Counter()
        self._in_flight = 0
        self.high_water = 0
        #: queries answered "busy", by key part (``snapshot``, ``region``)
        self.busy: Counter[str] = Counter()

    def wrap(self, part: str, handler: Callable[[zenoh.Query], None]) -> Callable[[zenoh.Query], None]:
        """The queryable callback for ``map/<part>``: admit the query and answer it with
        ``handler`` on a worker, or answer "busy". Never raises into Zenoh."""
        answer = guarded(handler)

        def callback(query: zenoh.Query) -> None:
            try:
                requester = requester_of(query)
                why = self._enter(requester)
                if why is not None:
                    self._refuse(part, query, why)
                    return
                try:
                    self._pool.submit(self._answer, answer, query, requester)
                except RuntimeError:  # the pool is shut down: the server is stopping
                    self._leave(requester)
                    query.reply_err(f"{query.key_expr}: the map server is stopping".encode())
                    query.drop()
            except Exception:  # noqa: BLE001 (a callback must never raise into Zenoh)
                _peer_log.exception(f"{part}_callback", "map/%s callback failed", part)

        return callback

    def _enter(self, requester: str | None) -> str | None:
        with self._lock:
            if self._in_flight >= self.total:
                return f"{self.total} whole-map queries are being answered; ask again"
            if requester is not None and self._taken[requester] >= self.per_requester:
                return f"{self.per_requester} queries of {short(requester, 40)} are being answered; ask again"
            self._in_flight += 1
            self._taken[requester] += 1
            self.high_water = max(self.high_water, self._in_flight)
            return None

    def _leave(self, requester: str | None) -> None:
        with self._lock:
            self._in_flight -= 1
            self._taken[requester] -= 1
            if self._taken[requester] <= 0:
                del self._taken[requester]

    def _refuse(self, part: str, query: zenoh.Query, why: str) -> None:
        with self._lock:
            self.busy[part] += 1
        try:
            query.reply_err(f"{query.key_expr}{BUSY}{why}".encode())
        finally:
            query.drop()

    def _answer(
        self, answer: Callable[[zenoh.Query], None], query: zenoh.Query, requester: str | None
    ) -> None:
        try:
            answer(query)
        finally:
            query.drop()
            self._leave(requester)

    def stats(self) -> dict:
        """``map/stats`` ``queries``: taken on now, the high-water mark, the bounds, busy replies."""
        with self._lock:
            return {
                "in_flight": self._in_flight,
                "high_water": self.high_water,
                "max": self.total,
                "max_per_requester": self.per_requester,
                "busy": dict(sorted(self.busy.items())),
            }

    def close(self) -> None:
        """Answer the queries taken on, then stop the workers."""
        self._pool.shutdown(wait=True)
