"""The coverage map: a Gaussian belief per voxel, kept in information form (docs/design.md section 3).

lam = 1/sigma^2 and eta = mu/sigma^2, two float32 arrays (the paper's "two values per
voxel"). The Gaussian product of eq. 24-25 becomes a sum, so the map is
prior + the sum of all deltas, in any order.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from swarm.map.delta import Delta
from swarm.map.entropy_table import default_table
from swarm.map.fusion import BatchResult, batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

PRIOR_MU = 0.5
#: No voxel may hold more information than this (float32 tops at 3.4e38; the mean eta / lam and
#: sigma 1 / sqrt(lam) stay finite well below it).
LAM_MAX = 1e30
#: Relative float32 rounding allowed around a voxel's mean range 0 <= eta <= lam.
MEAN_SLACK = 1e-5


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
        """Add a delta's information (eq. 24-25 in information form). Rejects bad deltas whole.

        Raises ValueError when an index is outside the grid or an increment is NaN or inf;
        the map is then unchanged. Indices listed twice add twice.
        """
        self._add(delta, check_range=False)

    def apply_received(self, delta: Delta) -> None:
        """:meth:`apply` a delta that came over the bus (the team's merged stream): also refused
        (ValueError, map unchanged) when a voxel it touches would end with information outside
        (0, LAM_MAX] or a mean eta / lam outside [0, 1] (within MEAN_SLACK), as the map server
        refuses it; no honest delta does that, a forged one would make the map's entropy NaN.
        """
        self._add(delta, check_range=True)

    def check_received(self, delta: Delta) -> None:
        """Whether :meth:`apply_received` would take ``delta``, without changing the map: raises
        what it would raise (ValueError; :class:`OutOfRange` for a voxel it would leave out of
        range). The same kernel, run on copies of the touched voxels."""
        idx = delta.idx.astype(np.int64)
        self.grid.check_flat(idx)
        lam, eta = self.lam[idx], self.eta[idx]  # copies
        at = np.arange(len(idx), dtype=np.int64)
        status = add_information(lam, eta, at, delta.dlam, delta.deta, True, LAM_MAX, MEAN_SLACK)
        if status == NONFINITE:
            raise ValueError("delta holds NaN or inf information")
        if status == OUT_OF_RANGE:
            raise OutOfRange.of(self.lam[idx] + delta.dlam)

    def invalid_voxels(self) -> np.ndarray:
        """Mask of the voxels no delta :meth:`apply_received` takes could have made: information
        not in (0, LAM_MAX] (NaN included) or a mean outside [0, 1] (within MEAN_SLACK)."""
        lam, eta = self.lam, self.eta
        with np.errstate(invalid="ignore"):
            good = np.isfinite(lam) & np.isfinite(eta) & (lam > 0) & (lam <= LAM_MAX)
            good &= (eta >= -MEAN_SLACK * lam) & (eta <= (1 + MEAN_SLACK) * lam)
        return ~good

    def _add(self, delta: Delta, check_range: bool) -> None:
        idx = delta.idx if delta.idx.dtype in (np.uint32, np.int64) else delta.idx.astype(np.int64)
        status = add_information(
            self.lam, self.eta, idx, delta.dlam, delta.deta, check_range, LAM_MAX, MEAN_SLACK
        )
        if status == OUTSIDE:
            self.grid.check_flat(delta.idx)  # raises, naming the range
        if status == NONFINITE:
            raise ValueError("delta holds NaN or inf information")
        if status == OUT_OF_RANGE:
            raise OutOfRange.of(self.lam[idx] + delta.dlam)  # the map is as it was

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
        """Voxels with any information beyond the prior: lam above ``known_threshold()``."""
        return self.lam > self.known_threshold()

    def known_threshold(self) -> np.float32:
        """The float32 lam above which a voxel counts as known (the prior's, plus a relative 1e-5)."""
        lam0, _ = prior_information(self.sensor)
        return np.float32(lam0) * np.float32(1.0 + 1e-5)


OUTSIDE, NONFINITE, OUT_OF_RANGE = 1, 2, 3


class OutOfRange(ValueError):
    """A delta would leave a voxel out of range; ``information``: True when some voxel's
    information would pass LAM_MAX (or stop being finite), False when only a mean would leave
    [0, 1]."""

    def __init__(self, reason: str, information: bool) -> None:
        super().__init__(reason)
        self.information = information

    @classmethod
    def of(cls, new_lam: np.ndarray) -> OutOfRange:
        """The error for a delta whose touched voxels would end with information ``new_lam``."""
        with np.errstate(invalid="ignore"):
            over = not bool(np.all(new_lam <= LAM_MAX))  # NaN fails too
        if over:
            return cls(f"delta would leave a voxel's information outside (0, {LAM_MAX:g}]", True)
        return cls("delta would leave a voxel's mean outside [0, 1] (or its information <= 0)", False)


@njit(cache=True, nogil=True)
def add_information(lam, eta, idx, dlam, deta, check_range, lam_max, slack):
    """lam[idx] += dlam and eta[idx] += deta in order (repeats add again), or nothing at all
    (the update of ``CoverageMap.apply`` and of the block-sparse map's flat block arrays):
    returns 0 when applied, OUTSIDE for an index outside the map, NONFINITE for NaN/inf,
    and with ``check_range`` OUT_OF_RANGE when a touched voxel would end outside
    0 < lam <= lam_max or -slack lam <= eta <= (1 + slack) lam (its old values put back)."""
    n = idx.shape[0]
    for k in range(n):
        if idx[k] < 0 or idx[k] >= lam.shape[0]:
            return OUTSIDE
    for k in range(n):
        if not (np.isfinite(dlam[k]) and np.isfinite(deta[k])):
            return NONFINITE
    if not check_range:
        for k in range(n):
            lam[idx[k]] += dlam[k]
            eta[idx[k]] += deta[k]
        return 0
    old_lam = np.empty(n, lam.dtype)
    old_eta = np.empty(n, eta.dtype)
    for k in range(n):
        old_lam[k] = lam[idx[k]]
        old_eta[k] = eta[idx[k]]
        lam[idx[k]] += dlam[k]
        eta[idx[k]] += deta[k]
    for k in range(n):
        v, e = lam[idx[k]], eta[idx[k]]
        if not (v > 0 and v <= lam_max and e >= -slack * v and e <= (1 + slack) * v):  # NaN fails
            for j in range(n - 1, -1, -1):  # backwards: a repeated index ends at its first old value
                lam[idx[j]] = old_lam[j]
                eta[idx[j]] = old_eta[j]
            return OUT_OF_RANGE
    return 0


def _flat(values: np.ndarray, grid: Grid) -> np.ndarray:
    values = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
    if values.size != grid.size:
        raise ValueError(f"map array has {values.size} values, grid has {grid.size} voxels")
    return values
