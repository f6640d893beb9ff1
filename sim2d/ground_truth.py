"""Ground-truth coverage of a voxel grid: the fraction of each voxel inside obstacles.

Obstacles stand on the floor, so a point (x, y, z) is covered when z lies below the top
H(x, y) of the tallest obstacle over (x, y). Each voxel column is supersampled on an
s x s lattice in x, y; along z the covered fraction of [z0, z0 + e] below H is exact.
Below the floor (z < 0) the ground counts as solid unless ``ground_is_solid`` is False.
"""

from __future__ import annotations

import numpy as np

from swarm.formats.floor_plan import FloorPlan
from swarm.map.grid import Grid


def coverage(plan: FloorPlan, grid: Grid, samples: int = 4, ground_is_solid: bool = True) -> np.ndarray:
    """True coverage in [0, 1] of every voxel, float32 of shape ``grid.shape``."""
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    nx, ny, nz = grid.shape
    e = grid.voxel
    offsets = (np.arange(samples) + 0.5) / samples * e
    xs = (grid.lo[0] + np.arange(nx)[:, None] * e + offsets).ravel()
    ys = (grid.lo[1] + np.arange(ny)[:, None] * e + offsets).ravel()
    top = plan.height_field(xs, ys)  # (nx * s, ny * s)
    out = np.empty(grid.shape, dtype=np.float32)
    for k in range(nz):
        z0 = grid.lo[2] + k * e
        if ground_is_solid:
            covered = np.clip((top - z0) / e, 0.0, 1.0)
        else:
            covered = np.clip((np.minimum(top, z0 + e) - max(z0, 0.0)) / e, 0.0, 1.0)
        out[:, :, k] = covered.reshape(nx, samples, ny, samples).mean(axis=(1, 3))
    return out
