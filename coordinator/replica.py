"""The coordinator's replica of the team map: prior + every merged delta, each (robot, epoch, seq) once."""

from __future__ import annotations

import threading
from collections import Counter

import numpy as np

from coordinator.assignment import (
    ObservedColumns,
)
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol.applied_deltas import AppliedDeltas
from swarm.protocol.codec import short
from swarm.protocol.wire import DeltaMessage, Snapshot, WireError


class TeamMap:
    """A replica of the team map: prior + every merged delta, each (robot, epoch, seq) once.

    Thread-safe: ``apply_payload``, ``load_snapshot`` and ``copy`` take ``lock``. Rejected
    and duplicate messages are counted in ``counts`` (``applied``, ``duplicate``,
    ``rejected``).
    """

    def __init__(self, grid: Grid, sensor: SensorModel, max_robots: int | None = None) -> None:
        """``max_robots``: how many robots' ground is tracked (ObservedColumns), None: all."""
        self.grid = grid
        self.map = CoverageMap(grid, sensor)
        self.table = default_table()
        self.entropy = EntropyCache.from_information(self.map.lam, self.map.eta, table=self.table)
        self.lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self._seen = AppliedDeltas()
        self.columns = ObservedColumns(grid.shape, max_robots)

    def load_snapshot(self, snap: Snapshot) -> None:
        """Start from a map server's snapshot; the deltas its acks cover count as applied."""
        if not self.grid.matches(snap.grid):
            raise ValueError(f"snapshot grid {snap.grid} is not the mission's {self.grid}")
        with self.lock:
            self.map = CoverageMap(self.grid, self.map.sensor, snap.lam, snap.eta)
            self.entropy = EntropyCache.from_information(self.map.lam, self.map.eta, table=self.table)
            self._seen.cover(snap.acks, snap.above)
            # a snapshot does not say which robot saw what: only later deltas are attributed

    def apply_payload(self, payload: bytes) -> str:
        """Apply one ``merged`` payload: returns "applied" or "duplicate"; raises WireError
        (counted as rejected) for a malformed message, one on another grid, or one that changes
        nothing (empty or zeros: the map server refuses those, so it is forged). A delta of a
        robot beyond the ``max_robots`` tracked is applied, counted ``unattributed``."""
        try:
            msg = DeltaMessage.decode(payload)
            if not self.grid.matches(msg.grid):
                raise WireError(f"delta: grid {msg.grid} is not the mission's {self.grid}")
            if not msg.carries_information():  # the map server never sends one
                raise WireError(f"delta of {short(msg.robot, 40)} changes nothing (empty, or zeros)")
        except WireError:
            self.counts["rejected"] += 1
            raise
        with self.lock:
            if (msg.robot, msg.epoch, msg.seq) in self._seen:
                self.counts["duplicate"] += 1
                return "duplicate"
            try:  # whole or nothing: a delta no server would have applied leaves the map as it was
                self.map.apply_received(Delta(msg.idx, msg.dlam, msg.deta))
            except ValueError as exc:
                self.counts["rejected"] += 1
                raise WireError(f"delta of {msg.robot}: {exc}") from exc
            self._seen.add(msg.robot, msg.epoch, msg.seq)
            idx = msg.idx.astype(np.int64)
            self.entropy.update_information(idx, self.map.lam[idx], self.map.eta[idx])
            if not self.columns.add(msg.robot, idx, msg.dlam):
                self.counts["unattributed"] += 1  # applied, but the robot's ground is not tracked
        self.counts["applied"] += 1
        return "applied"

    def copy(self) -> tuple[CoverageMap, np.ndarray]:
        """A consistent copy of the map and its per-voxel entropy (to plan without the lock)."""
        with self.lock:
            return self.map.copy(), self.entropy.values.copy()

    def teammates_ground(self, robot: str) -> np.ndarray:
        """(nx, ny): x-y cells to which other robots brought more information than ``robot``."""
        with self.lock:
            return self.columns.teammates_ground(robot)

    @property
    def entropy_bits(self) -> float:
        return float(self.entropy.total)
