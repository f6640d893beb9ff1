"""The Gaussian range-sensor model (paper eq. 10-14, with the mean docs/design.md restores)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    """Parameters of eq. 14: sigma_s(d) = sigma_min + zeta * d, damping ``tau``; ``max_range`` in metres.

    Defaults are docs/design.md's: the paper prints sigma_min = -0.06 mm, which cannot be a
    standard deviation; we read it as 0.06 (coverage units) and zeta = 0.0375 per metre.

    How a batch is fused (``swarm.map.fusion``; docs/map-core.md): ``hit_precedence`` (a
    departure from the paper's text, as OctoMap does): a voxel holding a return of the batch
    gets no free-space update from the batch's other rays. ``discretize`` (OctoMap's
    option): one measurement per end voxel, the mean end point of the rays ending there.
    ``weighted`` (with ``discretize``): that measurement carries the information of all its
    rays (lam times their number), so a frame gives what its rays would, traversed once.
    ``hit_range`` (m; None: ``max_range``): a return farther than this is too uncertain to
    place a surface within a voxel (a stereo rig's depth error grows with the square of the
    range; ``swarm.config.RigConfig.hit_range_m``): its ray updates free space up to
    ``hit_range`` and gives no hit, as a ray beyond max range does (OctoMap's max range).
    These say how batches are fused, not what the map means: they take no part in
    equality (a map saved with one setting is the same mission's map under the other).
    """

    sigma_min: float = 0.06
    zeta: float = 0.0375
    tau: float = 2.0
    max_range: float = 5.0
    hit_precedence: bool = field(default=True, compare=False)
    discretize: bool = field(default=False, compare=False)
    weighted: bool = field(default=False, compare=False)
    hit_range: float | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        for name in ("sigma_min", "tau", "max_range"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"sensor model: {name} must be > 0, got {value!r}")
        if not (np.isfinite(self.zeta) and self.zeta >= 0):
            raise ValueError(f"sensor model: zeta must be >= 0, got {self.zeta!r}")
        if self.hit_range is not None and not (np.isfinite(self.hit_range) and self.hit_range > 0):
            raise ValueError(f"sensor model: hit_range must be > 0 or None, got {self.hit_range!r}")

    @property
    def reach(self) -> float:
        """The range (m) up to which a ray updates the map: ``min(max_range, hit_range)``.

        A ray longer than this is cut there: free space up to it, no hit (``swarm.map.fusion``).
        """
        if self.hit_range is None:
            return float(self.max_range)
        return float(min(self.max_range, self.hit_range))

    def sigma_s(self, d: np.ndarray) -> np.ndarray:
        """Sensor standard deviation at range d (eq. 14, sigma_s)."""
        return self.sigma_min + self.zeta * np.asarray(d)

    def prior_sigma(self) -> float:
        """Prior standard deviation: ten times the sensor's at max range (docs/design.md, Prior)."""
        return float(10.0 * self.sigma_s(self.max_range))

    def mean(self, d: np.ndarray, d_l: np.ndarray, voxel: float) -> np.ndarray:
        """Coverage mean mu(d, d_l) for a voxel at centre distance d_l from a hit at d (restored eq.)."""
        return np.clip(0.5 + (np.asarray(d_l) - np.asarray(d)) / voxel, 0.0, 1.0)

    def sigma(self, d: np.ndarray, d_l: np.ndarray, voxel: float) -> np.ndarray:
        """Coverage standard deviation sigma(d, d_l) (eq. 14)."""
        excess = np.maximum(np.abs(np.asarray(d_l) - np.asarray(d)) - voxel / 2, 0.0)
        return self.sigma_s(d) * np.exp(-excess / self.tau)
