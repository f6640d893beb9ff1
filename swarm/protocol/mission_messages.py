"""``mission/done``: the map server's word that the mission is over (docs/protocol.md, "The end
of a mission").

The map server puts it on ``swarm/<mission>/mission/done`` once the team map's entropy is at
or below the mission's threshold H_th (eq. 36, reason ``threshold``), or once every robot that
is still heard from says it has nothing left to explore (its status's ``state`` is ``done``;
reason ``nothing left``), and again every few seconds while it runs, so that a process that
joins later hears it too. The agents and the simulated world stop on it; the services (the
map server, the coordinator) say so and go on answering queries until they are stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from swarm.protocol.codec import WireError, integer, number, pack, require, text, unpack

#: The reasons a mission ends.
REASONS = ("threshold", "nothing left")


@dataclass
class MissionDone:
    """The end of a mission as the map server saw it: why, when (``t``, seconds since the Unix
    epoch), the team map's entropy then and the threshold (bits), its known fraction, the
    deltas it had applied, and the robots whose last status said ``done``."""

    reason: str
    t: float
    entropy_bits: float
    threshold_bits: float | None  # None: a mission without one (it ended with "nothing left")
    known_fraction: float
    deltas: int
    robots_done: list[str] = field(default_factory=list)

    KIND = "mission_done"

    def encode(self) -> bytes:
        return pack(
            self.KIND,
            {
                "reason": self.reason,
                "t": float(self.t),
                "entropy_bits": float(self.entropy_bits),
                "threshold_bits": None if self.threshold_bits is None else float(self.threshold_bits),
                "known_fraction": float(self.known_fraction),
                "deltas": int(self.deltas),
                "robots_done": list(self.robots_done),
            },
        )

    @classmethod
    def decode(cls, payload: Any) -> MissionDone:
        kind = cls.KIND
        msg = unpack(payload, kind)
        reason = text(require(msg, "reason", kind), "reason", kind)
        if reason not in REASONS:
            raise WireError(f"{kind}: reason must be one of {', '.join(REASONS)}, got {reason[:40]!r}")
        threshold = require(msg, "threshold_bits", kind)
        robots = require(msg, "robots_done", kind)
        if not isinstance(robots, list):
            raise WireError(f"{kind}: robots_done must be a list of robot ids")
        return cls(
            reason=reason,
            t=number(require(msg, "t", kind), "t", kind),
            entropy_bits=number(require(msg, "entropy_bits", kind), "entropy_bits", kind),
            threshold_bits=None if threshold is None else number(threshold, "threshold_bits", kind),
            known_fraction=number(require(msg, "known_fraction", kind), "known_fraction", kind),
            deltas=integer(require(msg, "deltas", kind), "deltas", kind),
            robots_done=[text(r, "robots_done[]", kind) for r in robots],
        )

    def describe(self) -> str:
        """One line: ``threshold: H = 612,000 bits <= H_th 620,000 bits, known 89.1%, 1,523 deltas``."""
        if self.threshold_bits is None:
            versus = "(no H_th)"
        else:
            below = "<=" if self.entropy_bits <= self.threshold_bits else ">"
            versus = f"{below} H_th {self.threshold_bits:,.0f} bits"
        line = f"{self.reason}: H = {self.entropy_bits:,.0f} bits {versus}, known {self.known_fraction:.1%}, "
        line += f"{self.deltas:,} deltas"
        if self.reason == "nothing left":
            line += f" (robots done: {', '.join(self.robots_done) or 'none'})"
        return line
