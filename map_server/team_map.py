"""The map server's merged team map and what it answers (pure, no I/O, not thread-safe).

:class:`MergedMap` holds the coverage map (information form, float32, prior counted once),
its per-voxel entropy cache, the :class:`~map_server.ledger.Ledger` of applied deltas and
the counters of ``map/stats``. A delta is checked against the map by
``CoverageMap.check_received`` and added by ``CoverageMap.apply_received`` (one check of
range and mean for every holder of a map). The server calls :meth:`MergedMap.admit` on a validated
delta (new, or a duplicate that is only counted), makes it durable, then
:meth:`MergedMap.apply` adds it to the map and the ledger. Queries: :meth:`stats`,
:meth:`snapshot`, :meth:`region`.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterable

import numpy as np

from map_server.contributions import Contributions
from map_server.ledger import REJECT_KINDS, DeltaId, Ledger, Rejected
from swarm.map.coverage_map import (
    CoverageMap,
    OutOfRange,
    add_information,
    prior_entropy_bits,
    prior_information,
)
from swarm.map.delta import Delta
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol.wire import DeltaMessage, Region, Snapshot

#: A region query may ask for this many voxels at most.
MAX_REGION_VOXELS = 2_000_000


def delta_id(msg: DeltaMessage) -> DeltaId:
    return (msg.robot, msg.epoch, msg.seq)


class MergedMap:
    """The merged map of every robot's deltas, each applied exactly once."""

    def __init__(
        self,
        grid: Grid,
        sensor: SensorModel,
        lam: np.ndarray | None = None,
        eta: np.ndarray | None = None,
        ledger: Ledger | None = None,
        updates: dict[str, int] | None = None,
        contributions: Contributions | None = None,
        quarantined: Iterable[str] = (),
    ) -> None:
        self.grid = grid
        self.sensor = sensor
        self.cmap = CoverageMap(grid, sensor, lam, eta)
        self.repaired = self._repair()
        #: base + per-robot sums, to take a quarantined robot's deltas out (contributions.py)
        self.contributions = contributions or Contributions(self.cmap.lam, self.cmap.eta)
        self.quarantined: set[str] = set(quarantined)
        self.ledger = ledger or Ledger()
        self.entropy = EntropyCache.from_information(self.cmap.lam, self.cmap.eta, table=default_table())
        self.initial_entropy_bits = prior_entropy_bits(grid, sensor)
        self.known = int(np.count_nonzero(self.cmap.known_mask()))
        #: voxel updates merged per robot (persisted with the snapshot)
        self.updates: Counter[str] = Counter(updates or {})
        self.rejected: Counter[str] = Counter()
        self.duplicates = 0
        self._pending: dict[DeltaId, float] = {}  # admitted, not yet applied: their information
        #: counts every change of the map (an applied delta, a quarantine): two snapshots of one
        #: version are the same map (map_server.snapshot_stream serves one copy to both)
        self.version = 0

    def _repair(self) -> int:
        """Reset to the prior every voxel a store written by an older server may hold with
        non-finite, non-positive or over-LAM_MAX information (or eta outside [0, lam]); returns
        how many. A map this server writes never holds one."""
        lam, eta = self.cmap.lam, self.cmap.eta
        bad = self.cmap.invalid_voxels()
        n = int(np.count_nonzero(bad))
        if n:
            lam0, eta0 = prior_information(self.sensor)
            lam[bad], eta[bad] = lam0, eta0
        return n

    # -- merging -------------------------------------------------------------------------
    def is_known(self, ident: DeltaId) -> bool:
        """Whether the delta ``ident`` is applied already or pending."""
        return ident in self.ledger or ident in self._pending

    def next_seq(self, robot: str, epoch: int) -> int:
        """The seq (robot, epoch) takes next: its contiguous ack + 1, past the pending ones."""
        seq = self.ledger.next_seq(robot, epoch)
        while (robot, epoch, seq) in self._pending:
            seq += 1
        return seq

    def admit(self, msg: DeltaMessage) -> bool:
        """True when ``msg`` is new (it is then pending until :meth:`apply` or :meth:`release`);
        False for a delta already applied or pending, which is counted as a duplicate.

        Raises Rejected for a quarantined robot's delta, or one that would lift a voxel over
        LAM_MAX (``map_overflow``) or move a mean out of [0, 1]. Which epochs and seqs are
        taken is map_server.admission's to check before.
        """
        ident = delta_id(msg)
        if msg.robot in self.quarantined:
            raise Rejected("quarantined", f"{msg.robot} is quarantined")
        if self.is_known(ident):
            self.duplicates += 1
            return False
        self._check_range(msg)
        self._pending[ident] = float(np.sum(msg.dlam, dtype=np.float64))
        return True

    def _check_range(self, msg: DeltaMessage) -> None:
        """Rejected when adding ``msg`` would lift a voxel over LAM_MAX (``map_overflow``) or
        leave a mean outside [0, 1] (``mean_outside_unit``): ``CoverageMap.check_received``."""
        try:
            self.cmap.check_received(Delta(msg.idx, msg.dlam, msg.deta))
        except OutOfRange as exc:
            kind = "map_overflow" if exc.information else "mean_outside_unit"
            raise Rejected(kind, f"delta of {msg.robot}: {exc}") from exc
        except ValueError as exc:
            raise Rejected("malformed", f"delta of {msg.robot}: {exc}") from exc

    def release(self, msg: DeltaMessage) -> float:
        """Forget an admitted delta that could not be made durable or applied (its sender will
        resend it); returns its information (0 when it was not pending), for the budget."""
        return self._pending.pop(delta_id(msg), 0.0)

    def apply(self, msg: DeltaMessage) -> None:
        """Add a validated, admitted delta to the map, the entropy and the ledger.

        Indices are unique (validate_delta checks it), so a fancy-indexed sum is exact. Raises
        Rejected (``map_overflow``) and changes nothing when a voxel would pass LAM_MAX.
        """
        if msg.robot in self.quarantined:  # quarantined between admit and apply
            raise Rejected("quarantined", f"{msg.robot} is quarantined")
        idx = msg.idx.astype(np.int64)
        known = self.cmap.known_threshold()
        known_before = int(np.count_nonzero(self.cmap.lam[idx] > known))
        try:  # whole or nothing: the map is as it was when a voxel would leave its range
            self.cmap.apply_received(Delta(msg.idx, msg.dlam, msg.deta))
        except OutOfRange as exc:
            kind = "map_overflow" if exc.information else "mean_outside_unit"
            raise Rejected(kind, f"delta of {msg.robot}: {exc}") from exc
        lam, eta = self.cmap.lam[idx], self.cmap.eta[idx]
        self.entropy.update_information(idx, lam, eta)
        self.known += int(np.count_nonzero(lam > known)) - known_before
        self.contributions.add(msg.robot, idx, msg.dlam, msg.deta)
        ident = delta_id(msg)
        self._pending.pop(ident, None)
        self.ledger.add(ident)
        self.updates[msg.robot] += len(idx)
        self.version += 1

    def quarantine(self, robot: str) -> bool:
        """Refuse ``robot``'s further deltas and take its applied ones out of the map: the map is
        rebuilt from the base and the other robots' contributions, the entropy cache and known
        count with it. Its ids stay in the ledger (a resend is a duplicate, never re-applied).
        Returns True when the map changed."""
        self.quarantined.add(robot)
        if not self.contributions.drop(robot):
            return False
        lam, eta = self.contributions.total()
        self.cmap.lam[:] = lam
        self.cmap.eta[:] = eta
        self.entropy = EntropyCache.from_information(self.cmap.lam, self.cmap.eta, table=default_table())
        self.known = int(np.count_nonzero(self.cmap.known_mask()))
        self.version += 1
        return True

    def count_rejected(self, kind: str) -> int:
        """Count one refused payload of ``kind``; returns the count of that kind so far."""
        self.rejected[kind] += 1
        return self.rejected[kind]

    # -- queries -------------------------------------------------------------------------
    def acks(self) -> dict[str, dict[int, int]]:
        return self.ledger.acks()

    def stats(self) -> dict:
        """The ``map/stats`` JSON object (see docs/protocol.md)."""
        robots = self.ledger.robots()
        for robot, entry in robots.items():
            entry["voxel_updates"] = int(self.updates.get(robot, 0))
            if robot in self.quarantined:
                entry["quarantined"] = True
        s = self.sensor
        return {
            "voxels": self.grid.size,
            "shape": list(self.grid.shape),
            "voxel_size": self.grid.voxel,
            "origin": list(self.grid.origin),
            "sensor": {"sigma_min": s.sigma_min, "zeta": s.zeta, "tau": s.tau, "max_range": s.max_range},
            "entropy_bits": round(float(self.entropy.total), 3),
            "initial_entropy_bits": round(self.initial_entropy_bits, 3),
            "known_fraction": self.known / self.grid.size,
            "deltas_applied": len(self.ledger),
            "updates_merged": int(sum(self.updates.values())),
            "duplicates": self.duplicates,
            "rejected": {kind: self.rejected.get(kind, 0) for kind in REJECT_KINDS},
            "robots": robots,
            "quarantined": sorted(self.quarantined),
        }

    def snapshot(self) -> Snapshot:
        """A copy of the whole map (prior included), the acks and the seqs applied beyond them."""
        return Snapshot(
            self.grid, self.cmap.lam.copy(), self.cmap.eta.copy(), self.acks(), self.ledger.above()
        )

    def region(self, lo: np.ndarray, hi: np.ndarray) -> Region:
        """Beliefs of the voxels whose cells overlap the box [lo, hi] (empty when it misses the grid).

        Touching a cell's face does not count, so [0, 0.2] at 0.1 m is two voxels per axis; on an
        axis where lo = hi the voxel holding that coordinate counts, so lo = hi gives the voxel
        holding a point. Raises ValueError for lo > hi or a box of more than MAX_REGION_VOXELS.
        The server calls the three steps apart, holding its lock for :meth:`gather` only.
        """
        idx = self.region_indices(lo, hi)
        return region_of(self.grid, idx, *self.gather(idx))

    def region_indices(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The flat indices (uint32, ascending) of :meth:`region`'s voxels; reads no map value."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("lo and hi must be 3 finite numbers each")
        if np.any(hi < lo):
            raise ValueError(f"hi {hi.tolist()} must be >= lo {lo.tolist()} on every axis")
        shape = np.asarray(self.grid.shape)
        # voxel coordinates, clipped to one voxel beyond the grid before they become integers: a
        # box 1e19 m away is past int64, whose cast wraps (it gave the whole grid, not nothing)
        lo_v = np.clip((lo - self.grid.lo) / self.grid.voxel, -1.0, shape + 1.0)
        hi_v = np.clip((hi - self.grid.lo) / self.grid.voxel, -1.0, shape + 1.0)
        first = np.floor(lo_v).astype(np.int64)
        upper = np.ceil(hi_v - 1e-9).astype(np.int64) - 1
        last = np.minimum(np.maximum(upper, first), shape - 1)
        first = np.maximum(first, 0)
        counts = np.maximum(last - first + 1, 0)
        n = int(np.prod(counts))
        if n > MAX_REGION_VOXELS:
            raise ValueError(
                f"the box holds {n:,} voxels; a region query returns at most {MAX_REGION_VOXELS:,}"
            )
        i, j, k = (np.arange(first[a], first[a] + counts[a], dtype=np.int64) for a in range(3))
        _, ny, nz = self.grid.shape
        return ((i[:, None, None] * ny + j[None, :, None]) * nz + k[None, None, :]).ravel().astype(np.uint32)

    def gather(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of ``lam``, ``eta`` (float32) and the entropy (bits) of the voxels ``idx``."""
        at = idx.astype(np.int64)
        return self.cmap.lam[at], self.cmap.eta[at], self.entropy.values[at]


def region_of(grid: Grid, idx: np.ndarray, lam: np.ndarray, eta: np.ndarray, entropy: np.ndarray) -> Region:
    """The ``map/region`` reply of voxels ``idx`` from their gathered ``lam``, ``eta`` (float32)
    and entropy: mean, sigma and E[C] of each belief (no map state: callable without a lock)."""
    mu = eta / lam
    sigma = 1.0 / np.sqrt(lam)
    return Region(
        grid,
        idx,
        mu.astype(np.float32),
        sigma.astype(np.float32),
        expected_coverage(mu, sigma).astype(np.float32),
        entropy.astype(np.float32, copy=False),
    )


#: A selector number: ASCII digits, optional sign, fraction and exponent (no "_", no "inf").
_NUMBER = re.compile(r"[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]{1,3})?", re.ASCII)
#: Longest selector value a region query reads (3 numbers in any honest notation fit).
MAX_PARAMETER_CHARS = 120


def parse_vector(text: str | None, name: str) -> np.ndarray:
    """``"x,y,z"`` as 3 finite floats written in ASCII decimal notation; ValueError naming
    ``name`` otherwise, whose text echoes at most the first 40 characters of what was sent."""
    if text is None or text == "":
        raise ValueError(f"missing parameter {name} (expected {name}=x,y,z)")
    shown = repr(text) if len(text) <= 40 else repr(text[:37] + "...")
    if len(text) > MAX_PARAMETER_CHARS:
        raise ValueError(f"{name}={shown}: longer than {MAX_PARAMETER_CHARS} characters")
    parts = text.split(",")
    if len(parts) != 3 or not all(_NUMBER.fullmatch(p) for p in parts):
        raise ValueError(f"{name}={shown}: expected 3 comma-separated decimal numbers")
    values = [float(p) for p in parts]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name}={shown}: expected 3 finite numbers")
    return np.array(values)


def merge_kernels() -> tuple:
    """The compiled kernels a merge runs (for ``swarm.compile_progress``)."""
    return (add_information,)


def warm_up_merge(sensor: SensorModel) -> None:
    """Run one delta through the merge's checks and its addition on a scratch 2 x 2 x 2 map, so
    that Numba has loaded (or, on a first run, compiled) the kernels before the first robot's
    delta arrives: loading them took about half a second, which the first deltas waited."""
    scratch = MergedMap(Grid((0.0, 0.0, 0.0), 0.1, (2, 2, 2)), sensor)
    idx = np.array([0, 7], dtype=np.uint32)
    dlam = np.array([1.0, 2.0], dtype=np.float32)
    msg = DeltaMessage("warm-up", 1, 1, 0.0, scratch.grid, idx, dlam, 0.5 * dlam)
    if scratch.admit(msg):
        scratch.apply(msg)
