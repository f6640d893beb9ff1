"""Which deltas the map server has applied, and which payloads it refuses (pure, no I/O).

A delta is identified by ``(robot, epoch, seq)`` (DESIGN.md section 5). The :class:`Ledger`
keeps, per ``(robot, epoch)``, the contiguous prefix ``1..n`` of applied seqs plus the
applied seqs above it, so each delta is applied exactly once whatever the order and
however often it arrives; the acks are the contiguous prefixes.

:func:`validate_delta` decodes a ``delta/<rid>`` payload and checks it against the
server's grid; a refused payload raises :class:`Rejected` with one of :data:`REJECT_KINDS`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

from swarm.map.grid import Grid
from swarm.protocol.wire import VERSION, DeltaMessage, WireError

#: Why a delta payload is refused, as counted in ``map/stats`` ``rejected``.
REJECT_KINDS = (
    "malformed",  # not msgpack, missing or mistyped field, arrays of different lengths
    "unsupported_version",  # "v" is not 1
    "wrong_grid",  # grid differs from the mission's
    "robot_mismatch",  # the robot field differs from the <rid> of the key it came on
    "out_of_grid",  # a voxel index >= the number of voxels
    "non_finite",  # NaN or inf in dlam/deta
    "negative_information",  # dlam < 0
    "duplicate_idx",  # a voxel listed twice in one delta
)

DeltaId = tuple[str, int, int]


class Rejected(ValueError):
    """A delta payload the server refuses: ``kind`` is one of REJECT_KINDS, the text says why."""

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(reason)
        self.kind = kind


# -- validation ----------------------------------------------------------------------------


def describe_grid(grid: Grid) -> str:
    return f"shape {list(grid.shape)} voxel {grid.voxel:g} origin {[round(v, 6) for v in grid.origin]}"


def validate_delta(payload: bytes, grid: Grid, robot: str | None = None) -> DeltaMessage:
    """Decode a delta and check it against ``grid`` (and the key's ``robot``); raise Rejected.

    Checks: wire decoding (version, fields, array lengths, index range, finite values,
    dlam >= 0), the grid equals ``grid``, the robot field equals ``robot``, indices unique.
    """
    try:
        msg = DeltaMessage.decode(payload)
    except WireError as exc:
        raise Rejected(_classify(payload, grid), str(exc)) from exc
    if not grid.matches(msg.grid):
        raise Rejected(
            "wrong_grid", f"delta: grid {describe_grid(msg.grid)} is not the mission's {describe_grid(grid)}"
        )
    if robot is not None and msg.robot != robot:
        raise Rejected("robot_mismatch", f"delta: robot {msg.robot!r} published on the key of {robot!r}")
    idx = msg.idx
    if len(idx) > 1 and not np.all(idx[1:] > idx[:-1]) and len(np.unique(idx)) != len(idx):
        raise Rejected("duplicate_idx", "delta: a voxel index appears more than once")
    return msg


def _classify(payload: Any, grid: Grid) -> str:
    """The REJECT_KINDS entry of a payload that DeltaMessage.decode refused."""
    try:
        data = payload.to_bytes() if hasattr(payload, "to_bytes") else bytes(payload)
        msg = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception:  # noqa: BLE001 (any failure to unpack means the same thing)
        return "malformed"
    if not isinstance(msg, dict):
        return "malformed"
    if msg.get("v") != VERSION:
        return "unsupported_version"
    try:
        sent = Grid.from_dict(msg["grid"])
    except (KeyError, TypeError, ValueError):
        return "malformed"
    if not grid.matches(sent):
        return "wrong_grid"
    arrays = [msg.get(name) for name in ("idx", "dlam", "deta")]
    if not all(isinstance(a, bytes) for a in arrays) or len(arrays[0]) % 4:
        return "malformed"
    if not len(arrays[0]) == len(arrays[1]) == len(arrays[2]):
        return "malformed"
    idx, dlam, deta = (np.frombuffer(a, dtype=t) for a, t in zip(arrays, ("<u4", "<f4", "<f4"), strict=True))
    if len(idx) and int(idx.max()) >= grid.size:
        return "out_of_grid"
    if not (np.all(np.isfinite(dlam)) and np.all(np.isfinite(deta))):
        return "non_finite"
    if np.any(dlam < 0):
        return "negative_information"
    return "malformed"


# -- the ledger ----------------------------------------------------------------------------


@dataclass
class _Seqs:
    """Applied seqs of one (robot, epoch): 1..contiguous, and the set above it."""

    contiguous: int = 0
    above: set[int] = field(default_factory=set)

    def __contains__(self, seq: int) -> bool:
        return seq <= self.contiguous or seq in self.above

    def add(self, seq: int) -> None:
        if seq == self.contiguous + 1:
            self.contiguous = seq
            while self.contiguous + 1 in self.above:
                self.contiguous += 1
                self.above.discard(self.contiguous)
        else:
            self.above.add(seq)

    @property
    def count(self) -> int:
        return self.contiguous + len(self.above)

    @property
    def last(self) -> int:
        return max(self.above, default=self.contiguous)


class Ledger:
    """Applied delta ids per (robot, epoch); acks are the contiguous prefixes."""

    def __init__(self) -> None:
        self._seqs: dict[tuple[str, int], _Seqs] = {}

    def __contains__(self, delta_id: DeltaId) -> bool:
        robot, epoch, seq = delta_id
        seqs = self._seqs.get((robot, epoch))
        return seqs is not None and seq in seqs

    def add(self, delta_id: DeltaId) -> bool:
        """Record an applied delta; False (and nothing changes) when it was already there."""
        robot, epoch, seq = delta_id
        if seq < 1:
            raise ValueError(f"seq must be >= 1, got {seq}")
        seqs = self._seqs.setdefault((robot, epoch), _Seqs())
        if seq in seqs:
            return False
        seqs.add(seq)
        return True

    def __len__(self) -> int:
        """Number of applied deltas."""
        return sum(s.count for s in self._seqs.values())

    def acks(self) -> dict[str, dict[int, int]]:
        """``{robot: {epoch: last contiguous seq}}`` (0 when seq 1 is still missing)."""
        out: dict[str, dict[int, int]] = {}
        for (robot, epoch), seqs in self._seqs.items():
            out.setdefault(robot, {})[epoch] = seqs.contiguous
        return out

    def above(self) -> dict[str, dict[int, list[int]]]:
        """``{robot: {epoch: [seqs applied beyond the contiguous prefix]}}``, only where there are some."""
        out: dict[str, dict[int, list[int]]] = {}
        for (robot, epoch), seqs in self._seqs.items():
            if seqs.above:
                out.setdefault(robot, {})[epoch] = sorted(seqs.above)
        return out

    def robots(self) -> dict[str, dict[str, int]]:
        """Per robot: ``deltas`` applied (all epochs), and ``epoch``, ``last_seq`` (highest
        applied) and ``acked_seq`` (contiguous) of its latest epoch."""
        out: dict[str, dict[str, int]] = {}
        for (robot, epoch), seqs in sorted(self._seqs.items()):
            entry = out.setdefault(robot, {"deltas": 0})
            entry["deltas"] += seqs.count
            entry |= {"epoch": epoch, "last_seq": seqs.last, "acked_seq": seqs.contiguous}
        return out

    # -- persistence form ------------------------------------------------------------------
    def to_json(self) -> str:
        """``[[robot, epoch, contiguous, [seqs above]], ...]`` as JSON."""
        rows = [[r, e, s.contiguous, sorted(s.above)] for (r, e), s in sorted(self._seqs.items())]
        return json.dumps(rows, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> Ledger:
        ledger = cls()
        rows = json.loads(text)
        if not isinstance(rows, list):
            raise ValueError("ledger must be a JSON list of [robot, epoch, contiguous, [seqs]]")
        for row in rows:
            robot, epoch, contiguous, above = row
            if not (isinstance(robot, str) and isinstance(epoch, int) and isinstance(contiguous, int)):
                raise ValueError(f"bad ledger row {row!r}")
            ledger._seqs[(robot, epoch)] = _Seqs(contiguous, {int(s) for s in above})
        return ledger
