"""How the map server's queryables answer: strict JSON, and an error reply instead of a crash."""

from __future__ import annotations

import json
import logging

import zenoh

from swarm.log_limit import LogLimiter
from swarm.protocol.codec import short

log = logging.getLogger("swarm.server")
#: a query's failure, which a stranger may repeat: one line per 10 s, with counts
_peer_log = LogLimiter(log)


def guarded(handler):
    """A queryable callback that answers an error instead of raising into Zenoh."""

    def callback(query: zenoh.Query) -> None:
        try:
            handler(query)
        except Exception as exc:  # noqa: BLE001 (one bad query must not take the server down)
            _peer_log.exception("query_failed", "query %s failed", short(str(query.selector), 200))
            try:
                query.reply_err(f"{query.key_expr}: server error: {short(exc, 200)}".encode())
            except zenoh.ZError:
                pass

    return callback


def reply_json(query: zenoh.Query, obj: dict, key: str | None = None) -> None:
    """Reply strict JSON: a NaN or inf raises (and the query gets an error reply), never ``NaN``.
    ``key``: the reply's key (default the query's own key expression)."""
    text = json.dumps(obj, allow_nan=False)
    query.reply(key or query.key_expr, text.encode(), encoding=zenoh.Encoding.APPLICATION_JSON)
