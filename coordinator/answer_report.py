"""What the coordinator reports of its ``coord/assign`` answers (docs/protocol.md, ``coord/stats``).

:func:`answer_time_summary` is the ``answer_ms`` object of ``coord/stats``: the count, mean,
nearest-rank p50 and p95 and maximum of the most recent :data:`ANSWER_TIMES_KEPT` answer times
(milliseconds, from when the answering thread took a query to its reply); :func:`log_answer`
writes one line per answer: the eq. 35 target and its utility and path cost, a wander on the
robot's own ground, or "nothing left".
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable

from coordinator.state import Answer

log = logging.getLogger("coordinator")

#: The answer times ``coord/stats`` summarises: the most recent this many.
ANSWER_TIMES_KEPT = 10_000


def answer_time_summary(times_ms: Iterable[float]) -> dict:
    """``{count, mean, p50, p95, max}`` of answer times in milliseconds (zeros when none)."""
    times = sorted(float(t) for t in times_ms)
    if not times:
        return {"count": 0, "mean": 0.0, "p50": 0.0, "p95": 0.0, "max": 0.0}

    def rank(q: float) -> float:  # nearest-rank percentile
        return times[max(math.ceil(q * len(times)) - 1, 0)]

    return {
        "count": len(times),
        "mean": sum(times) / len(times),
        "p50": rank(0.50),
        "p95": rank(0.95),
        "max": times[-1],
    }


def log_answer(answer: Answer) -> None:
    """One log line for an answer: the target and why, a wander, or "nothing left"."""
    robot = answer.robot
    c = answer.candidate
    if c is None and answer.wander is not None:
        w = answer.wander
        log.info(
            "assign %s -> wander to (%.2f, %.2f) gaze %+.0f deg: no eq. 35 target left "
            "(%d candidates, %d held by others)",
            robot,
            w.xy[0],
            w.xy[1],
            math.degrees(w.gaze_yaw),
            answer.candidates,
            answer.held_by_others,
        )
        return
    if c is None:
        log.info(
            "assign %s -> nothing left (%d candidates, %d held by others)",
            robot,
            answer.candidates,
            answer.held_by_others,
        )
        return
    log.info(
        "assign %s -> stand (%.2f, %.2f) gaze %+.0f deg, looking at (%.2f, %.2f): eq. 35 %.1f bits/m, "
        "path %.2f m (%d candidates, %d held by others)",
        robot,
        c.xy[0],
        c.xy[1],
        math.degrees(c.gaze_yaw),
        c.point[0],
        c.point[1],
        c.utility,
        c.path_cost,
        answer.candidates,
        answer.held_by_others,
    )
