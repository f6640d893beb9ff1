"""Trusted answers to a query: every reply is collected, and replies that disagree are refused.

Zenoh's default for a query keeps one reply per key (the first to arrive, for the default
consolidation), so any session that declares a matching queryable and answers quickly
could speak for the map server or the coordinator. Here a query goes to *all* matching
queryables (``QueryTarget.ALL``) with no consolidation (``ConsolidationMode.NONE``); when
the replies are not all the same bytes (or one is an error and another is not) the answer
is refused with :class:`ConflictingReplies`, which names the repliers. Who may answer at all
is the access-control rules' job (docs/security.md); this is the client's own check.
"""

from __future__ import annotations

from dataclasses import dataclass

import zenoh


class ConflictingReplies(RuntimeError):
    """More than one replier answered one query, and the answers differ."""


@dataclass(frozen=True)
class Answer:
    """The one answer to a query: ``ok`` payload bytes, or the ``error`` text."""

    ok: bytes | None
    error: str | None
    repliers: tuple[str, ...]


def _replier(reply: zenoh.Reply) -> str:
    zid = getattr(reply, "replier_id", None)
    return str(zid) if zid is not None else "unknown replier"


def ask(session: zenoh.Session, selector: str, timeout: float, payload: bytes | None = None) -> Answer | None:
    """Query ``selector`` and return the agreed answer, or None when nothing replied in time.

    Raises :class:`ConflictingReplies` when the repliers disagree, and ``zenoh.ZError``
    when the query cannot be sent.
    """
    kwargs = {"payload": payload} if payload is not None else {}
    answers: dict[tuple[bytes | None, str | None], list[str]] = {}
    replies = session.get(
        selector,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=timeout,
        **kwargs,
    )
    for reply in replies:
        if reply.ok is not None:
            content = (reply.ok.payload.to_bytes(), None)
        else:
            content = (None, reply.err.payload.to_bytes().decode("utf-8", errors="replace"))
        answers.setdefault(content, []).append(_replier(reply))
    if not answers:
        return None
    if len(answers) > 1:
        who = "; ".join(
            f"{', '.join(ids)} {'answered an error' if ok is None else f'answered {len(ok)} bytes'}"
            for (ok, _err), ids in answers.items()
        )
        raise ConflictingReplies(f"{selector}: {len(answers)} different answers, none taken ({who})")
    (ok, error), ids = next(iter(answers.items()))
    return Answer(ok, error, tuple(ids))
