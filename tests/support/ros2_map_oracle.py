"""Independent computations of what the team map's ROS 2 topics must carry, from a map file
(``swarm map export``'s map.npz) alone: the 2-D grid column by column in plain Python, and the
occupied voxels with their belief. Shared by tests/ros2_map/."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.map.sensor_model import SensorModel


def npz_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def oracle_grid(
    path: Path, band: tuple[float, float], threshold: float = 0.5, rule: str = "all"
) -> np.ndarray:
    """(nx, ny) int8: 100 where a band voxel has E[C] > threshold, else 0 where all (rule "all")
    or any (rule "any") band voxels carry information beyond the prior, else -1; a loop over
    columns and layers reading only the map file's arrays."""
    m = npz_arrays(path)
    ec, sigma = m["expected_coverage"], m["sigma"].astype(np.float64)
    origin, voxel = m["origin"], float(m["voxel_size"])
    sensor = SensorModel(*m["sensor"].tolist())
    prior_lam = 1.0 / sensor.prior_sigma() ** 2
    nx, ny, nz = ec.shape
    layers = [k for k in range(nz) if band[0] - 1e-9 <= origin[2] + (k + 0.5) * voxel <= band[1] + 1e-9]
    out = np.empty((nx, ny), np.int8)
    for i in range(nx):
        for j in range(ny):
            covs = [float(ec[i, j, k]) for k in layers]
            known = [1.0 / sigma[i, j, k] ** 2 > prior_lam * (1 + 1e-5) for k in layers]
            if any(c > threshold for c in covs):
                out[i, j] = 100
            elif all(known) if rule == "all" else any(known):
                out[i, j] = 0
            else:
                out[i, j] = -1
    return out


def oracle_cloud(path: Path, threshold: float = 0.5) -> np.ndarray:
    """(N, 6) float32 rows x, y, z (voxel centre), mu, sigma, entropy of the voxels with
    E[C] > threshold, sorted by x, y, z."""
    m = npz_arrays(path)
    ijk = np.argwhere(m["expected_coverage"] > threshold)
    centres = m["origin"] + (ijk + 0.5) * float(m["voxel_size"])
    at = tuple(ijk.T)
    rows = np.column_stack([centres, m["mu"][at], m["sigma"][at], m["entropy"][at]]).astype(np.float32)
    return sort_rows(rows)


def sort_rows(rows: np.ndarray) -> np.ndarray:
    return rows[np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0]))]


def apply_update(grid: np.ndarray, x: int, y: int, width: int, height: int, data) -> None:
    """Write an OccupancyGridUpdate's row-major cells into (nx, ny) ``grid``, as RViz does."""
    patch = np.asarray(data, np.int8).reshape(height, width).T
    grid[x : x + width, y : y + height] = patch
