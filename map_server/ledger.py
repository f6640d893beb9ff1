"""Which deltas the map server has applied, and which payloads it refuses (pure, no I/O).

A delta is identified by ``(robot, epoch, seq)`` (docs/design.md section 5). The :class:`Ledger`
keeps, per ``(robot, epoch)``, the contiguous prefix ``1..n`` of applied seqs plus the
applied seqs above it, so each delta is applied exactly once whatever the order and
however often it arrives; the acks are the contiguous prefixes.

:func:`validate_delta` decodes a ``delta/<rid>`` payload and checks it against the
server's grid; a refused payload raises :class:`Rejected` with one of :data:`REJECT_KINDS`.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from swarm.map.grid import Grid
from swarm.protocol.codec import DELTA_VERSION, short
from swarm.protocol.wire import DeltaMessage, WireError

#: Why a delta payload is refused, as counted in ``map/stats`` ``rejected`` (docs/protocol.md).
REJECT_KINDS = (
    "malformed",  # not msgpack, missing or mistyped field, arrays of different lengths
    "unsupported_version",  # "v" is not the integer 2 (a v1 delta: ask map/epoch)
    "wrong_grid",  # grid differs from the mission's
    "robot_mismatch",  # the robot field differs from the <rid> of the key it came on
    "out_of_grid",  # a voxel index >= the number of voxels
    "non_finite",  # NaN or inf in dlam/deta or t
    "negative_information",  # dlam < 0
    "duplicate_idx",  # a voxel listed twice in one delta
    "mean_outside_unit",  # deta < 0 or deta > dlam: a coverage mean outside [0, 1]
    "too_large",  # payload over the maximum size (refused before decoding)
    "unknown_robot",  # <rid> is not one of the mission's robots (refused before decoding)
    "unknown_epoch",  # an epoch the server did not issue to this robot (map_server.epochs)
    "stale_epoch",  # an epoch of the robot the server has fenced
    "bad_mac",  # the attachment is not the MAC of the payload under the epoch's key
    "seq_gap",  # seq beyond the next one the epoch expects (contiguous ack + 1)
    "too_much_information",  # over the robot's information budget (limits.py)
    "map_overflow",  # would lift a voxel's information over LAM_MAX
    "quarantined",  # the robot is quarantined (swarm server --quarantine, at run time, or breaches)
    "no_information",  # empty, or every dlam and deta zero: it would change nothing (not logged, not sent on)
    "internal_error",  # any other exception while validating or applying this one delta
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


def validate_delta(
    payload: bytes,
    grid: Grid,
    robot: str | None = None,
    increments: bool = True,
    versions: tuple[int, ...] = (DELTA_VERSION,),
) -> DeltaMessage:
    """Decode a delta (once) and check it against ``grid`` (and the key's ``robot``); raise Rejected.

    Checks: wire decoding (version, fields, array lengths, index range, finite values,
    dlam >= 0), the grid equals ``grid``, the robot field equals ``robot``, indices unique,
    0 <= deta <= dlam (unless ``increments`` is False: a previous map's delta moves a belief
    from the prior to another Gaussian, and its mean is checked on the resulting voxel by
    MergedMap instead). Any exception at all becomes a Rejected (``malformed``, or
    ``internal_error`` for one that is not a WireError), so one payload can only ever be refused.
    ``versions``: the protocol versions taken (the log's replay takes v1 deltas of older stores).
    """
    try:
        return _validate(payload, grid, robot, increments, versions)
    except Rejected:
        raise
    except WireError as exc:
        kind = exc.kind if exc.kind in REJECT_KINDS else "malformed"
        raise Rejected(kind, str(exc)) from exc
    except Exception as exc:  # noqa: BLE001 (whatever a hostile payload triggers, refuse it alone)
        raise Rejected("internal_error", f"delta: {type(exc).__name__}: {short(exc)}") from exc


def _validate(
    payload: bytes, grid: Grid, robot: str | None, increments: bool, versions: tuple[int, ...]
) -> DeltaMessage:
    msg = DeltaMessage.decode(payload, versions)
    if not grid.matches(msg.grid):
        raise Rejected(
            "wrong_grid", f"delta: grid {describe_grid(msg.grid)} is not the mission's {describe_grid(grid)}"
        )
    if robot is not None and msg.robot != robot:
        raise Rejected(
            "robot_mismatch", f"delta: robot {short(msg.robot)} published on the key of {short(robot)}"
        )
    idx = msg.idx
    if len(idx) > 1 and not np.all(idx[1:] > idx[:-1]) and len(np.unique(idx)) != len(idx):
        raise Rejected("duplicate_idx", "delta: a voxel index appears more than once")
    if increments and (np.any(msg.deta < 0) or np.any(msg.deta > msg.dlam * np.float32(1 + ETA_TOLERANCE))):
        raise Rejected("mean_outside_unit", "delta: deta must lie in [0, dlam] (a coverage mean in [0, 1])")
    return msg


#: Relative float32 rounding allowed in deta <= dlam (sums of mu * lam and of lam in float32).
ETA_TOLERANCE = 1e-5


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
    """Applied delta ids per (robot, epoch); acks are the contiguous prefixes.

    Which epochs it holds is the server's to say (map_server.epochs): :meth:`drop` forgets a
    fenced epoch's ids (its robot's ``compacted`` count keeps how many it had). The seqs above
    a gap come only from stores written before deltas had to arrive in order.
    """

    def __init__(self) -> None:
        self._seqs: dict[tuple[str, int], _Seqs] = {}
        #: per robot, the newest epoch compacted away by an older server (kept for its stores)
        self.floors: dict[str, int] = {}
        #: per robot, deltas applied in its fenced (compacted) epochs
        self.compacted: Counter[str] = Counter()

    def __contains__(self, delta_id: DeltaId) -> bool:
        robot, epoch, seq = delta_id
        seqs = self._seqs.get((robot, epoch))
        return seqs is not None and seq in seqs

    def next_seq(self, robot: str, epoch: int) -> int:
        """The seq the (robot, epoch) expects next: its contiguous ack + 1."""
        seqs = self._seqs.get((robot, epoch))
        return 1 if seqs is None else seqs.contiguous + 1

    def used(self) -> list[tuple[str, int]]:
        """The (robot, epoch) pairs it holds ids of."""
        return list(self._seqs)

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

    def drop(self, robot: str, epoch: int) -> None:
        """Forget a fenced epoch's ids (its deltas stay in the map and in the counts)."""
        seqs = self._seqs.pop((robot, epoch), None)
        if seqs is not None:
            self.compacted[robot] += seqs.count

    def __len__(self) -> int:
        """Number of applied deltas (compacted epochs included)."""
        return sum(s.count for s in self._seqs.values()) + sum(self.compacted.values())

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
            entry = out.setdefault(robot, {"deltas": self.compacted.get(robot, 0)})
            entry["deltas"] += seqs.count
            entry |= {"epoch": epoch, "last_seq": seqs.last, "acked_seq": seqs.contiguous}
        return out

    # -- persistence form ------------------------------------------------------------------
    def compaction_json(self) -> dict:
        """``{"floors": {robot: epoch}, "compacted": {robot: deltas}}``, kept in the snapshot's counters."""
        return {"floors": dict(self.floors), "compacted": dict(self.compacted)}

    def restore_compaction(self, data: dict) -> None:
        """Take back what :meth:`compaction_json` saved (absent in older stores)."""
        self.floors.update({str(r): int(e) for r, e in data.get("floors", {}).items()})
        self.compacted.update({str(r): int(n) for r, n in data.get("compacted", {}).items()})

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
