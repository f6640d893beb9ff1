"""The client's side of a streamed ``map/snapshot`` or ``map/region`` answer (docs/protocol.md,
"Streamed answers"): ask window after window of chunks, resume from the first chunk missing,
start again when the server no longer holds the stream. Used by
``swarm.protocol.map_client.MapClient``; the chunks are ``swarm.protocol.map_chunks``.
"""

from __future__ import annotations

from collections.abc import Callable

from swarm.protocol.codec import WireError
from swarm.protocol.map_chunks import EXPIRED, WINDOW, Chunk, ChunkAssembler
from swarm.protocol.replies import Answers

#: Times an answer is started again after an ``expired`` reply before the client gives up.
MAX_RESTARTS = 3
#: Windows in a row that bring no new chunk before the client gives up.
MAX_STALLS = 3

#: ``ask(parameters)``: the replies to one query of the stream's key with those parameters
#: (raising when no server answers, or on an error the caller cannot resume from).
Ask = Callable[[str], Answers]
#: ``progress(received, chunks)``: called after each new chunk.
Progress = Callable[[int, int], None]


class StreamFailed(RuntimeError):
    """The stream could not be assembled: an error reply, unreadable chunks, or no progress."""


def fetch_stream(
    ask: Ask,
    kind: str,
    first: str = "",
    window: int = WINDOW,
    progress: Progress | None = None,
) -> ChunkAssembler:
    """Every chunk of one stream of ``kind`` (``snapshot_chunk``/``region_chunk``), assembled.

    ``first``: the parameters of the answer's first query (a region's ``lo=...;hi=...``), to
    which ``count=<window>`` is added; the next queries ask ``stream=<id>;cursor=<n>;count=
    <window>`` from the first chunk missing, so a chunk lost or cut off by a timeout is asked
    again. An ``expired`` reply starts the answer again (at most MAX_RESTARTS times: a fresh
    copy, of a later state). Raises :class:`StreamFailed` for an error reply, an unreadable
    chunk, a chunk of another stream, or MAX_STALLS windows without a new chunk; what ``ask``
    raises passes through.
    """
    assembler = ChunkAssembler(kind)
    restarts = stalls = 0
    while True:
        if assembler.head is None:
            parameters = ";".join(p for p in (first, f"count={window}") if p)
        else:
            parameters = f"stream={assembler.stream};cursor={assembler.next_missing()};count={window}"
        answer = ask(parameters)
        new = 0
        for payload in answer.ok:
            try:
                chunk = Chunk.decode(payload, kind)
                new += assembler.add(chunk)
            except WireError as exc:
                raise StreamFailed(f"unreadable chunk: {exc}") from exc
            if progress is not None:
                progress(assembler.received, assembler.chunks)
        if assembler.complete:
            return assembler
        if answer.error is not None:
            if EXPIRED in answer.error and restarts < MAX_RESTARTS:
                restarts += 1
                assembler = ChunkAssembler(kind)
                continue
            raise StreamFailed(answer.error)
        stalls = 0 if new else stalls + 1
        if stalls >= MAX_STALLS:
            raise StreamFailed(
                f"{kind}: {MAX_STALLS} queries in a row brought no new chunk "
                f"({assembler.received} of {assembler.chunks} held)"
            )
