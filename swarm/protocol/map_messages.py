"""Messages of the map server: ``delta/<rid>`` (and ``merged``), ``map/snapshot``, ``map/region``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm.map.grid import Grid
from swarm.protocol import codec
from swarm.protocol.codec import WireError

# -- delta/<rid> and merged ---------------------------------------------------------------

#: The ``<rid>`` of the deltas that carry a mission's previous map (``prior_map:``), sent once by
#: the mission runner before the robots start (swarm.mission.prior_map uses the same id).
PRIOR_SOURCE = "prior"

#: What a v1 delta's refusal says: v2 epochs come from the server.
V1_DELTA_HINT = (
    "; protocol v2: ask swarm/<mission>/map/epoch/<rid> for an epoch and its key, and send each "
    "delta with its MAC as the attachment (docs/protocol.md)"
)

#: Voxels along one grid axis at most (the flat index is uint32).
MAX_AXIS = 1 << 20


def grid_field(value: Any, kind: str) -> Grid:
    """The ``grid`` field of a message of ``kind``; WireError when malformed or too large."""
    if not isinstance(value, dict):
        raise WireError(f"{kind}: grid must be a map with origin, voxel, shape")
    origin = codec.vec3(codec.require(value, "origin", kind), "grid.origin", kind)
    voxel = codec.number(codec.require(value, "voxel", kind), "grid.voxel", kind)
    shape = codec.require(value, "shape", kind)
    if not isinstance(shape, list | tuple) or len(shape) != 3:
        raise WireError(f"{kind}: grid.shape must be 3 integers, got {shape!r}")
    shape = tuple(codec.integer(n, f"grid.shape[{i}]", kind, 1) for i, n in enumerate(shape))
    if any(n > MAX_AXIS for n in shape):
        raise WireError(f"{kind}: grid.shape {list(shape)} has an axis over {MAX_AXIS} voxels")
    if voxel <= 0:
        raise WireError(f"{kind}: grid.voxel must be > 0, got {voxel}")
    try:
        grid = Grid(origin, voxel, shape)
    except (ValueError, TypeError, OverflowError) as exc:
        raise WireError(f"{kind}: bad grid ({exc})") from exc
    if grid.size > 1 << 32:
        raise WireError(f"{kind}: grid of {grid.size} voxels (a flat index is uint32)")
    return grid


def _information(dlam: np.ndarray, deta: np.ndarray, kind: str, names: tuple[str, str]) -> None:
    if not np.all(np.isfinite(dlam)) or not np.all(np.isfinite(deta)):
        raise WireError(f"{kind}: {names[0]}/{names[1]} must be finite", "non_finite")
    if np.any(dlam < 0):
        raise WireError(
            f"{kind}: {names[0]} must be >= 0 (information cannot be negative)", "negative_information"
        )


@dataclass
class DeltaMessage:
    """``delta/<rid>`` and ``merged``: information gathered by ``robot`` since its last delta,
    per flat voxel ``idx`` (dlam, deta); ``swarm.map.delta.Delta`` holds the same arrays.

    ``(robot, epoch, seq)`` identifies a delta once: epoch is issued by the map server
    (``map/epoch/<rid>``, swarm.protocol.epochs), seq counts 1, 2, 3 within it. Encoded as
    protocol v2; :meth:`decode` takes v2 only unless ``versions`` says otherwise (the map
    server's log replays the v1 deltas an older store holds).
    """

    robot: str
    epoch: int
    seq: int
    t: float
    grid: Grid
    idx: np.ndarray
    dlam: np.ndarray
    deta: np.ndarray

    KIND = "delta"

    def carries_information(self) -> bool:
        """Whether applying it would change any voxel: some ``dlam`` or ``deta`` is not zero. An
        empty delta, or one of zeros only, changes nothing; no agent sends one, and the map server
        refuses it (``no_information``) rather than log it and send it on to every replica."""
        return bool(np.any(self.dlam) or np.any(self.deta))

    def encode(self) -> bytes:
        n = len(self.idx)
        if len(self.dlam) != n or len(self.deta) != n:
            raise WireError("delta: idx, dlam and deta must have the same length")
        return codec.pack(
            self.KIND,
            {
                "robot": self.robot,
                "epoch": int(self.epoch),
                "seq": int(self.seq),
                "t": float(self.t),
                "grid": self.grid.to_dict(),
                "idx": codec.le(self.idx, "<u4"),
                "dlam": codec.le(self.dlam, "<f4"),
                "deta": codec.le(self.deta, "<f4"),
            },
            codec.DELTA_VERSION,
        )

    @classmethod
    def decode(cls, payload: Any, versions: tuple[int, ...] = (codec.DELTA_VERSION,)) -> DeltaMessage:
        kind = cls.KIND
        msg = codec.unpack(payload, kind, versions, V1_DELTA_HINT)
        grid = grid_field(codec.require(msg, "grid", kind), kind)
        idx = codec.indices(codec.require(msg, "idx", kind), kind, grid.size)
        n = len(idx)
        dlam = codec.raw(codec.require(msg, "dlam", kind), "<f4", n, "dlam", kind)
        deta = codec.raw(codec.require(msg, "deta", kind), "<f4", n, "deta", kind)
        _information(dlam, deta, kind, ("dlam", "deta"))
        return cls(
            robot=codec.text(codec.require(msg, "robot", kind), "robot", kind),
            epoch=codec.integer(codec.require(msg, "epoch", kind), "epoch", kind),
            seq=codec.integer(codec.require(msg, "seq", kind), "seq", kind, 1),
            t=codec.number(codec.require(msg, "t", kind), "t", kind),
            grid=grid,
            idx=idx,
            dlam=dlam,
            deta=deta,
        )


def ledger_fields(acks: dict[str, dict[int, int]], above: dict[str, dict[int, list[int]]]) -> dict:
    """A snapshot's ``acks`` and ``above`` as the wire carries them (epochs as decimal strings)."""
    return {
        "acks": {str(r): {str(int(e)): int(s) for e, s in by_epoch.items()} for r, by_epoch in acks.items()},
        "above": {
            str(r): {str(int(e)): sorted(int(s) for s in seqs) for e, seqs in by_epoch.items()}
            for r, by_epoch in above.items()
        },
    }


# -- map/snapshot reply -------------------------------------------------------------------


def check_beliefs(lam: np.ndarray, eta: np.ndarray, kind: str) -> None:
    """WireError unless every ``lam`` is finite and > 0 and every ``eta`` finite (a map's
    beliefs in information form, as a snapshot or its chunks carry them)."""
    if not np.all(np.isfinite(lam)) or not np.all(np.isfinite(eta)) or np.any(lam <= 0):
        raise WireError(f"{kind}: lam must be finite and > 0, eta finite")


@dataclass
class Snapshot:
    """The whole team map in information form (prior included) and the deltas it holds.

    ``acks`` is the contiguous prefix per (robot, epoch), as ``map/acks``; ``above`` lists
    the seqs applied beyond that prefix (optional on the wire, empty when absent), so that a
    replica started from the snapshot counts every delta in it as applied, not only the
    prefix, and never adds one twice.
    """

    grid: Grid
    lam: np.ndarray
    eta: np.ndarray
    acks: dict[str, dict[int, int]] = field(default_factory=dict)
    above: dict[str, dict[int, list[int]]] = field(default_factory=dict)

    KIND = "snapshot"

    def encode(self) -> bytes:
        fields = {
            "grid": self.grid.to_dict(),
            "lam": codec.le(np.ravel(self.lam), "<f4"),
            "eta": codec.le(np.ravel(self.eta), "<f4"),
        }
        return codec.pack(self.KIND, fields | self.ledger_fields())

    def ledger_fields(self) -> dict:
        """``acks`` and ``above`` as the wire carries them (epochs as decimal strings)."""
        return ledger_fields(self.acks, self.above)

    @classmethod
    def decode(cls, payload: Any) -> Snapshot:
        kind = cls.KIND
        msg = codec.unpack(payload, kind)
        grid = grid_field(codec.require(msg, "grid", kind), kind)
        lam = codec.raw(codec.require(msg, "lam", kind), "<f4", grid.size, "lam", kind)
        eta = codec.raw(codec.require(msg, "eta", kind), "<f4", grid.size, "eta", kind)
        check_beliefs(lam, eta, kind)
        return cls(grid, lam, eta, *cls.ledger_of(msg, kind))

    @staticmethod
    def ledger_of(msg: dict, kind: str) -> tuple[dict[str, dict[int, int]], dict[str, dict[int, list[int]]]]:
        """``(acks, above)`` of a decoded message of ``kind``; WireError when malformed."""
        acks = codec.require(msg, "acks", kind)
        if not isinstance(acks, dict) or not all(isinstance(v, dict) for v in acks.values()):
            raise WireError(f"{kind}: acks must be a map robot -> {{epoch: seq}}")
        acks = {
            codec.text(r, "acks robot", kind): {
                codec.decimal(e, "acks epoch", kind): codec.integer(s, "acks seq", kind)
                for e, s in by_epoch.items()
            }
            for r, by_epoch in acks.items()
        }
        above = msg.get("above", {})
        if not (
            isinstance(above, dict)
            and all(isinstance(v, dict) for v in above.values())
            and all(isinstance(seqs, list) for v in above.values() for seqs in v.values())
        ):
            raise WireError(f"{kind}: above must be a map robot -> {{epoch: [seq, ...]}}")
        above = {
            codec.text(r, "above robot", kind): {
                codec.decimal(e, "above epoch", kind): [codec.integer(s, "above seq", kind) for s in seqs]
                for e, seqs in by_epoch.items()
            }
            for r, by_epoch in above.items()
        }
        return acks, above


# -- map/region reply ---------------------------------------------------------------------


@dataclass
class Region:
    """The beliefs of the voxels of a box: flat ``idx`` (uint32, ascending) in ``grid`` and,
    per voxel, ``mu``, ``sigma`` (untruncated Gaussian), ``expected_coverage`` (E[C] of the
    belief truncated to [0, 1]) and ``entropy`` (bits), all float32.
    """

    grid: Grid
    idx: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    expected_coverage: np.ndarray
    entropy: np.ndarray

    KIND = "region"
    _VALUES = ("mu", "sigma", "expected_coverage", "entropy")

    def __len__(self) -> int:
        return len(self.idx)

    def centres(self) -> np.ndarray:
        """World centres (N, 3) of the voxels."""
        return self.grid.centre(self.grid.unflat(self.idx))

    def encode(self) -> bytes:
        n = len(self.idx)
        if any(len(getattr(self, name)) != n for name in self._VALUES):
            raise WireError("region: idx and every value array must have the same length")
        fields = {"grid": self.grid.to_dict(), "idx": codec.le(self.idx, "<u4")}
        fields |= {name: codec.le(getattr(self, name), "<f4") for name in self._VALUES}
        return codec.pack(self.KIND, fields)

    @classmethod
    def decode(cls, payload: Any) -> Region:
        kind = cls.KIND
        msg = codec.unpack(payload, kind)
        grid = grid_field(codec.require(msg, "grid", kind), kind)
        idx = codec.indices(codec.require(msg, "idx", kind), kind, grid.size)
        n = len(idx)
        values = {
            name: codec.raw(codec.require(msg, name, kind), "<f4", n, name, kind) for name in cls._VALUES
        }
        return cls(grid, idx, **values)
