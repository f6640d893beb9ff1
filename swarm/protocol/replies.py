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


def _replies(session: zenoh.Session, selector: str, timeout: float, payload: bytes | None = None):
    """Each reply to a query of every replier, unmerged: (reply, (ok bytes, None) or (None, error text))."""
    kwargs = {"payload": payload} if payload is not None else {}
    replies = session.get(
        selector,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=timeout,
        **kwargs,
    )
    for reply in replies:
        if reply.ok is not None:
            yield reply, (reply.ok.payload.to_bytes(), None)
        else:
            yield reply, (None, reply.err.payload.to_bytes().decode("utf-8", errors="replace"))


def ask(session: zenoh.Session, selector: str, timeout: float, payload: bytes | None = None) -> Answer | None:
    """Query ``selector`` and return the agreed answer, or None when nothing replied in time.

    Raises :class:`ConflictingReplies` when the repliers disagree, and ``zenoh.ZError``
    when the query cannot be sent.
    """
    answers: dict[tuple[bytes | None, str | None], list[str]] = {}
    for reply, content in _replies(session, selector, timeout, payload):
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


#: What Zenoh's own error reply says when a query's timeout ends before its last reply.
TIMEOUT = "Timeout"


@dataclass(frozen=True)
class Answers:
    """The replies to a query answered in several replies: the ``ok`` payloads in the order
    they came, the ``error`` text if one came, the repliers, and whether the timeout ended it."""

    ok: tuple[bytes, ...]
    error: str | None
    repliers: tuple[str, ...]
    timed_out: bool


def ask_all(session: zenoh.Session, selector: str, timeout: float) -> Answers | None:
    """Query ``selector`` and return every reply of the one replier, or None when nothing
    replied in time (Zenoh's own timeout reply aside). Raises :class:`ConflictingReplies`
    when several repliers answered differently, and ``zenoh.ZError`` when it cannot be sent."""
    by_replier: dict[str, list[tuple[bytes | None, str | None]]] = {}
    timed_out = False
    for reply, content in _replies(session, selector, timeout):
        if content == (None, TIMEOUT) and getattr(reply, "replier_id", None) is None:
            timed_out = True  # Zenoh's own reply: the timeout ended the query
            continue
        by_replier.setdefault(_replier(reply), []).append(content)
    if not by_replier:
        return None
    distinct = {tuple(contents) for contents in by_replier.values()}
    if len(distinct) > 1:
        who = "; ".join(f"{r} answered {len(c)} replies" for r, c in by_replier.items())
        raise ConflictingReplies(f"{selector}: {len(distinct)} different answers, none taken ({who})")
    contents = next(iter(distinct))
    errors = [err for ok, err in contents if ok is None]
    return Answers(
        tuple(ok for ok, _ in contents if ok is not None),
        errors[0] if errors else None,
        tuple(by_replier),
        timed_out,
    )
