"""Grid geometry of docs/design.md section 3: axis-aligned voxels of edge e over a box.

Index (i, j, k) = floor((p - origin) / e); the flat index is C order over
``shape = (nx, ny, nz)``. Voxel centres are w(l) = origin + (index + 0.5) * e.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Grid:
    """A regular voxel grid: ``origin`` (the min corner, metres), ``voxel`` edge, ``shape``."""

    origin: tuple[float, float, float]
    voxel: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        origin = tuple(float(v) for v in self.origin)
        shape = tuple(int(n) for n in self.shape)
        if len(origin) != 3 or not all(np.isfinite(origin)):
            raise ValueError(f"grid origin must be 3 finite numbers, got {self.origin!r}")
        if not (np.isfinite(self.voxel) and self.voxel > 0):
            raise ValueError(f"voxel size must be a positive number, got {self.voxel!r}")
        if len(shape) != 3 or min(shape) < 1:
            raise ValueError(f"grid shape must be 3 positive integers, got {self.shape!r}")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "voxel", float(self.voxel))
        object.__setattr__(self, "shape", shape)

    @classmethod
    def from_bounds(cls, lo: np.ndarray, hi: np.ndarray, voxel: float) -> Grid:
        """The smallest grid with corner ``lo`` whose voxels cover the box [lo, hi]."""
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,):
            raise ValueError("bounds must be two points of 3 coordinates")
        if not np.all(hi > lo):
            raise ValueError(f"bounds are empty: lo={lo.tolist()} hi={hi.tolist()}")
        shape = np.maximum(np.ceil((hi - lo) / voxel - 1e-9), 1).astype(int)
        return cls(tuple(lo), voxel, tuple(shape))

    # -- sizes and boxes -------------------------------------------------------------
    @property
    def size(self) -> int:
        """Number of voxels."""
        nx, ny, nz = self.shape
        return nx * ny * nz

    @property
    def lo(self) -> np.ndarray:
        return np.asarray(self.origin, dtype=np.float64)

    @property
    def hi(self) -> np.ndarray:
        return self.lo + np.asarray(self.shape, dtype=np.float64) * self.voxel

    @property
    def volume(self) -> float:
        return self.size * self.voxel**3

    # -- conversions -----------------------------------------------------------------
    def index_of(self, points: np.ndarray) -> np.ndarray:
        """Voxel index (…, 3) int64 of world points (…, 3); points outside give out-of-range indices."""
        points = np.asarray(points, dtype=np.float64)
        return np.floor((points - self.lo) / self.voxel).astype(np.int64)

    def contains_index(self, ijk: np.ndarray) -> np.ndarray:
        """Boolean mask of indices (…, 3) inside the grid."""
        ijk = np.asarray(ijk)
        return np.all((ijk >= 0) & (ijk < np.asarray(self.shape)), axis=-1)

    def contains_point(self, points: np.ndarray) -> np.ndarray:
        """Boolean mask of world points (…, 3) inside the half-open box [lo, hi)."""
        points = np.asarray(points, dtype=np.float64)
        return np.all((points >= self.lo) & (points < self.hi), axis=-1) & np.all(
            np.isfinite(points), axis=-1
        )

    def flat(self, ijk: np.ndarray) -> np.ndarray:
        """Flat C-order index of in-grid voxel indices (…, 3)."""
        ijk = np.asarray(ijk, dtype=np.int64)
        _, ny, nz = self.shape
        return (ijk[..., 0] * ny + ijk[..., 1]) * nz + ijk[..., 2]

    def flat_of(self, i: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Flat C-order index of in-grid voxel index columns i, j, k."""
        _, ny, nz = self.shape
        return (i * ny + j) * nz + k

    def unflat(self, flat: np.ndarray) -> np.ndarray:
        """Voxel indices (…, 3) of flat indices."""
        return np.stack(np.unravel_index(np.asarray(flat, dtype=np.int64), self.shape), axis=-1)

    def centre(self, ijk: np.ndarray) -> np.ndarray:
        """Voxel centres w(l) of indices (…, 3)."""
        return self.lo + (np.asarray(ijk, dtype=np.float64) + 0.5) * self.voxel

    def centres(self) -> np.ndarray:
        """Centres of all voxels, shape (nx, ny, nz, 3)."""
        axes = [self.lo[a] + (np.arange(n) + 0.5) * self.voxel for a, n in enumerate(self.shape)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def check_flat(self, flat: np.ndarray) -> None:
        """Raise ValueError when any flat index is outside the grid."""
        flat = np.asarray(flat)
        if flat.size and (flat.min() < 0 or flat.max() >= self.size):
            raise ValueError(
                f"voxel index out of grid: range [{flat.min()}, {flat.max()}] for {self.size} voxels"
            )

    def matches(self, other: Grid) -> bool:
        """The same voxels: equal shapes, origins and voxel sizes equal to a millionth of a voxel.

        The one grid test of every role (server, coordinator, agents): a grid that went
        through YAML, msgpack or a file compares equal to the mission's despite rounding.
        """
        tol = 1e-6 * min(self.voxel, other.voxel)
        return (
            tuple(self.shape) == tuple(other.shape)
            and abs(self.voxel - other.voxel) <= tol
            and all(abs(a - b) <= tol for a, b in zip(self.origin, other.origin, strict=True))
        )

    def to_dict(self) -> dict:
        """Wire/file form: ``{origin, voxel, shape}``."""
        return {"origin": list(self.origin), "voxel": self.voxel, "shape": list(self.shape)}

    @classmethod
    def from_dict(cls, d: dict) -> Grid:
        return cls(tuple(d["origin"]), float(d["voxel"]), tuple(d["shape"]))
