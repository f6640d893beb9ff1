"""The team map as the ROS 2 topics see it: a :class:`swarm.protocol.team_replica.TeamReplica`
(a snapshot + every merged delta once, checked as every replica of the project checks it) and
E[C] per voxel, the array the messages are made of, refreshed only where deltas changed voxels.
"""

from __future__ import annotations

import numpy as np

from swarm.map.entropy import expected_coverage
from swarm.map.sensor_model import SensorModel
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import DeltaMessage, Snapshot


def coverage_of(lam: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """E[C] of information-form beliefs as float32, exactly as ``map.npz`` stores it."""
    mu = (eta / lam).astype(np.float32, copy=False)
    sigma = (1.0 / np.sqrt(lam)).astype(np.float32, copy=False)
    return expected_coverage(mu, sigma).astype(np.float32)


class FollowedMap(TeamReplica):
    """The team map from ``snapshot`` (with the server's ``sensor`` model, which sets the prior)
    plus the merged deltas given to :meth:`apply_payload`; ``coverage`` (E[C], flat float32) as
    of the last :meth:`refresh`, ``entropy`` (bits per voxel) kept by the replica.

    Not thread-safe: one worker applies and refreshes. ``counts``: as ``TeamReplica`` counts
    (``applied``, ``duplicate``, ``rejected`` plus one ``rejected_<reason>`` per reason).
    """

    def __init__(self, snapshot: Snapshot, sensor: SensorModel, **replica) -> None:
        super().__init__(snapshot.grid, sensor, name="ros2-map", **replica)
        self._dirty: list[np.ndarray] = []
        self.known_lam = float(self.map.known_threshold())
        self.load_snapshot(snapshot)

    def loaded_hook(self, snap: Snapshot) -> None:
        self.coverage = coverage_of(self.map.lam, self.map.eta)
        self._dirty.clear()

    def applied_hook(self, msg: DeltaMessage, idx: np.ndarray, size: int) -> None:
        self._dirty.append(idx)

    @property
    def pending(self) -> bool:
        """Whether deltas were applied since the last :meth:`refresh`."""
        return bool(self._dirty)

    def refresh(self) -> np.ndarray:
        """Recompute ``coverage`` of the voxels changed since the last refresh; returns those
        voxels (flat, sorted, unique int64; empty when none)."""
        if not self._dirty:
            return np.zeros(0, np.int64)
        voxels = np.unique(np.concatenate(self._dirty).astype(np.int64))
        self._dirty.clear()
        self.coverage[voxels] = coverage_of(self.map.lam[voxels], self.map.eta[voxels])
        return voxels
