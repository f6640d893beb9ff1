"""The coverage map: a Gaussian belief per voxel, kept in information form (docs/design.md section 3).

lam = 1/sigma^2 and eta = mu/sigma^2, two float32 arrays (the paper's "two values per
voxel"). The Gaussian product of eq. 24-25 becomes a sum, so the map is
prior + the sum of all deltas, in any order.
"""

from __future__ import annotations

import numpy as np

from swarm.map.delta import Delta
from swarm.map.entropy_table import default_table
from swarm.map.fusion import BatchResult, batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

PRIOR_MU = 0.5


def prior_entropy_bits(grid: Grid, sensor: SensorModel) -> float:
    """Map entropy of the prior alone: every voxel at N(0.5, sigma0) (eq. 31 at k = 0)."""
    lam0, eta0 = prior_information(sensor)
    h0 = default_table()(np.float32(eta0 / lam0), np.float32(1.0 / np.sqrt(lam0)))
    return float(h0) * grid.size


def prior_information(sensor: SensorModel) -> tuple[float, float]:
    """(lam0, eta0) of the prior N(0.5, 10 * sigma_s(max range))."""
    lam0 = 1.0 / sensor.prior_sigma() ** 2
    return lam0, PRIOR_MU * lam0


class CoverageMap:
    """Beliefs of every voxel of ``grid``; flat C-order float32 arrays ``lam`` and ``eta``."""

    def __init__(
        self,
        grid: Grid,
        sensor: SensorModel | None = None,
        lam: np.ndarray | None = None,
        eta: np.ndarray | None = None,
    ) -> None:
        self.grid = grid
        self.sensor = sensor or SensorModel()
        lam0, eta0 = prior_information(self.sensor)
        self.lam = np.full(grid.size, lam0, np.float32) if lam is None else _flat(lam, grid)
        self.eta = np.full(grid.size, eta0, np.float32) if eta is None else _flat(eta, grid)

    def copy(self) -> CoverageMap:
        return CoverageMap(self.grid, self.sensor, self.lam.copy(), self.eta.copy())

    # -- updates -----------------------------------------------------------------------
    def apply(self, delta: Delta) -> None:
        """Add a delta's information (eq. 24-25 in information form). Rejects bad deltas whole."""
        self.grid.check_flat(delta.idx)
        if not delta.is_finite():
            raise ValueError("delta holds NaN or inf information")
        idx = delta.idx.astype(np.int64)
        # Deltas are sorted and unique by construction; only others need the slow path.
        if len(idx) > 1 and not np.all(idx[1:] > idx[:-1]):
            np.add.at(self.lam, idx, delta.dlam)
            np.add.at(self.eta, idx, delta.deta)
        else:
            self.lam[idx] += delta.dlam
            self.eta[idx] += delta.deta

    def integrate(self, origin: np.ndarray, points: np.ndarray) -> BatchResult:
        """Fuse one batch of hit points seen from ``origin``; returns the batch and its delta."""
        result = batch_information(self.grid, self.sensor, origin, points)
        self.apply(result.delta)
        return result

    def delta_from_prior(self) -> Delta:
        """Everything this map knows beyond the prior, as one delta."""
        lam0, eta0 = prior_information(self.sensor)
        dlam = self.lam.astype(np.float64) - lam0
        deta = self.eta.astype(np.float64) - eta0
        idx = np.flatnonzero((dlam != 0) | (deta != 0))
        return Delta(idx.astype(np.uint32), dlam[idx].astype(np.float32), deta[idx].astype(np.float32))

    # -- beliefs -----------------------------------------------------------------------
    def mean(self, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        """mu = eta / lam (untruncated)."""
        return self.eta[idx] / self.lam[idx]

    def sigma(self, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        """sigma = 1 / sqrt(lam)."""
        return 1.0 / np.sqrt(self.lam[idx])

    def known_mask(self) -> np.ndarray:
        """Voxels with any information beyond the prior."""
        lam0, _ = prior_information(self.sensor)
        return self.lam > np.float32(lam0) * np.float32(1.0 + 1e-5)


def _flat(values: np.ndarray, grid: Grid) -> np.ndarray:
    values = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
    if values.size != grid.size:
        raise ValueError(f"map array has {values.size} values, grid has {grid.size} voxels")
    return values
