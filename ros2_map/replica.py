"""The team map as the ROS 2 topics see it: a replica (a snapshot + every merged delta once) and
the per-voxel arrays the messages are made of, E[C] and entropy, refreshed only where deltas
changed voxels.

A merged payload is checked as every replica of the project checks it (the coordinator's,
the view's): it must decode (``DeltaMessage.decode``: finite, non-negative information, indices
in the grid), be on the snapshot's grid, change something, and leave every voxel it touches in
range (``CoverageMap.apply_received``: whole or nothing). A refused one is counted by reason
and changes nothing.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table
from swarm.map.sensor_model import SensorModel
from swarm.protocol.applied_deltas import AppliedDeltas
from swarm.protocol.codec import short
from swarm.protocol.wire import DeltaMessage, Snapshot, WireError


def coverage_of(lam: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """E[C] of information-form beliefs as float32, exactly as ``map.npz`` stores it."""
    mu = (eta / lam).astype(np.float32, copy=False)
    sigma = (1.0 / np.sqrt(lam)).astype(np.float32, copy=False)
    return expected_coverage(mu, sigma).astype(np.float32)


class FollowedMap:
    """The team map from ``snapshot`` (with the server's ``sensor`` model, which sets the prior)
    plus the merged deltas given to :meth:`apply_payload`; ``coverage`` (E[C]) and ``entropy``
    (bits) per voxel, flat float32, as of the last :meth:`refresh`.

    Not thread-safe: one worker applies and refreshes. ``counts``: ``applied``, ``duplicate``
    and ``rejected`` plus one ``rejected_<reason>`` per reason.
    """

    def __init__(self, snapshot: Snapshot, sensor: SensorModel) -> None:
        self.grid = snapshot.grid
        self.map = CoverageMap(self.grid, sensor, snapshot.lam, snapshot.eta)
        self.applied = AppliedDeltas()
        self.applied.cover(snapshot.acks, snapshot.above)
        self.known_lam = float(self.map.known_threshold())
        self.coverage = coverage_of(self.map.lam, self.map.eta)
        self.entropy = EntropyCache.from_information(self.map.lam, self.map.eta, table=default_table())
        self.counts: Counter[str] = Counter()
        self._dirty: list[np.ndarray] = []

    def apply_payload(self, payload: bytes) -> str:
        """Apply one ``merged`` payload: "applied" or "duplicate"; WireError (counted) when refused."""
        try:
            msg = DeltaMessage.decode(payload)
            if not self.grid.matches(msg.grid):
                raise WireError(f"delta: grid {msg.grid} is not the team map's {self.grid}", "other_grid")
            if not msg.carries_information():  # the map server never sends one
                raise WireError(f"delta of {short(msg.robot, 40)} changes nothing", "no_information")
            if (msg.robot, msg.epoch, msg.seq) in self.applied:
                self.counts["duplicate"] += 1
                return "duplicate"
            try:  # whole or nothing: the map is as it was when a voxel would leave its range
                self.map.apply_received(Delta(msg.idx, msg.dlam, msg.deta))
            except ValueError as exc:
                raise WireError(f"delta of {short(msg.robot, 40)}: {exc}", "out_of_range") from exc
        except WireError as exc:
            self.counts["rejected"] += 1
            self.counts[f"rejected_{exc.kind}"] += 1
            raise
        self.applied.add(msg.robot, msg.epoch, msg.seq)
        self._dirty.append(msg.idx)
        self.counts["applied"] += 1
        return "applied"

    @property
    def pending(self) -> bool:
        """Whether deltas were applied since the last :meth:`refresh`."""
        return bool(self._dirty)

    def refresh(self) -> np.ndarray:
        """Recompute ``coverage`` and ``entropy`` of the voxels changed since the last refresh;
        returns those voxels (flat, sorted, unique int64; empty when none)."""
        if not self._dirty:
            return np.zeros(0, np.int64)
        voxels = np.unique(np.concatenate(self._dirty).astype(np.int64))
        self._dirty.clear()
        lam, eta = self.map.lam[voxels], self.map.eta[voxels]
        self.coverage[voxels] = coverage_of(lam, eta)
        self.entropy.update_information(voxels, lam, eta)
        return voxels
