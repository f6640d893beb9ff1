"""Fusion of one batch of range measurements into information increments (paper eq. 6-14, 24-25).

A batch M_k = (x_k, V_k) is a sensor position and the points where obstacles were
detected. Each ray updates the voxels it traverses and the voxel behind its hit with
the Gaussian sensor model; in information form the update of a voxel is the sum of
lam = 1/sigma^2 and eta = mu/sigma^2 over the rays that influence it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.map.traversal import traverse

#: A ray whose point lies beyond the grid's boundary by at most this share of its range (or
#: BOUNDARY_MARGIN_VOXELS voxels, whichever is more) is skipped, not cut at the boundary: the
#: point may be a surface on the boundary seen with a range error (a wall forming the
#: workspace's outer layer, stereo depth overestimated by 0.1-0.5 m at 3-5 m), and the
#: free-space update of the cut ray would clear that surface without the hit that balances it.
BOUNDARY_MARGIN_FRACTION = 0.1
BOUNDARY_MARGIN_VOXELS = 2.0


@dataclass(frozen=True)
class BatchResult:
    """The delta of one batch and what happened to its rays."""

    delta: Delta
    rays: int  # rays fused
    voxel_updates: int  # (ray, voxel) updates
    truncated: int  # rays longer than max range: free space up to max range, no hit
    skipped_nonfinite: int  # NaN/inf points
    skipped_outside: int  # sensor outside the grid, or point just beyond its boundary
    skipped_degenerate: int  # zero-length rays
    clipped: int = 0  # rays that leave the grid: free space up to its boundary, no hit


def batch_information(grid: Grid, sensor: SensorModel, origin: np.ndarray, points: np.ndarray) -> BatchResult:
    """Information increments of one batch: sensor at ``origin`` (3,), hit points (N, 3), world metres.

    Points that are NaN/inf, zero-length rays and all rays of a sensor outside the grid
    are skipped and counted. Rays longer than ``sensor.max_range`` update free space up to
    max range with the sensor model at their true range d, and give no hit (as OctoMap's
    max range). Rays that leave the grid are treated alike at the grid's boundary: the
    voxels they cross inside it are free space, whatever lies beyond; but a point within
    the boundary margin (``BOUNDARY_MARGIN_FRACTION``) beyond the boundary is skipped.
    """
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(origin)):
        raise ValueError(f"sensor origin must be finite, got {origin.tolist()}")

    finite = np.all(np.isfinite(points), axis=1)
    vec = points[finite] - origin
    dist = np.sqrt(np.einsum("ij,ij->i", vec, vec))
    nondegenerate = dist > 1e-9
    vec, dist = vec[nondegenerate], dist[nondegenerate]
    returned = dist <= sensor.max_range
    truncated = ~returned
    reach = np.where(returned, 1.0, sensor.max_range / dist)
    if grid.contains_point(origin):
        exit_at = _grid_exit(grid, origin, vec)
        margin = np.maximum(BOUNDARY_MARGIN_FRACTION * dist, BOUNDARY_MARGIN_VOXELS * grid.voxel)
        clipped = (reach >= exit_at) & ((1.0 - exit_at) * dist > margin)
        # Stop a hair (1e-6 voxel) inside the boundary, which is the first point outside.
        reach = np.where(clipped, exit_at - 1e-6 * grid.voxel / dist, reach)
        returned &= ~clipped
        end = origin + vec * reach[:, None]
        inside = (reach * dist > 1e-9) & grid.contains_point(end)
    else:
        clipped = np.zeros(len(vec), dtype=bool)
        end = origin + vec
        inside = np.zeros(len(vec), dtype=bool)
    end, dist, returned, truncated = end[inside], dist[inside], returned[inside], truncated[inside]

    voxels = traverse(grid, origin, end, hit=returned)
    i, j, k, ray = voxels.i, voxels.j, voxels.k, voxels.ray
    behind = np.flatnonzero(voxels.behind)
    if len(behind):  # only a voxel behind a hit can fall outside the grid
        out = behind[~grid.contains_index(np.column_stack([i[behind], j[behind], k[behind]]))]
        if len(out):
            keep = np.ones(len(ray), dtype=bool)
            keep[out] = False
            i, j, k, ray = i[keep], j[keep], k[keep], ray[keep]

    # Distance from the sensor to each influenced voxel's centre, d_l.
    e = grid.voxel
    offset = (grid.lo - origin + 0.5 * e).astype(np.float32)
    e32 = np.float32(e)
    dx = i.astype(np.float32) * e32 + offset[0]
    dy = j.astype(np.float32) * e32 + offset[1]
    dz = k.astype(np.float32) * e32 + offset[2]
    d_l = np.sqrt(dx * dx + dy * dy + dz * dz)
    d = dist.astype(np.float32)[ray]
    lam, eta = _information(sensor, d, d_l, e)

    return BatchResult(
        delta=Delta.accumulate(grid.flat_of(i, j, k), lam, eta, grid.size),
        rays=len(end),
        voxel_updates=len(ray),
        truncated=int(truncated.sum()),
        skipped_nonfinite=int((~finite).sum()),
        skipped_outside=int((~inside).sum()),
        skipped_degenerate=int((~nondegenerate).sum()),
        clipped=int((clipped & inside).sum()),
    )


def _grid_exit(grid: Grid, origin: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Where rays from ``origin`` (inside the grid) leave it, as t in units of each ray's ``vec``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = (grid.hi - origin) / vec
        t_lo = (grid.lo - origin) / vec
    t_axis = np.where(vec > 0, t_hi, np.where(vec < 0, t_lo, np.inf))
    return t_axis.min(axis=1)


def _information(
    sensor: SensorModel, d: np.ndarray, d_l: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """lam = 1/sigma^2 and eta = mu/sigma^2 of the sensor model (restored mean, eq. 14).

    The same model as ``SensorModel.mean``/``sigma``, fused for the hot path (one exp, no
    square of a small sigma); tests check it against them.
    """
    diff = d_l - d
    mu = np.clip(0.5 + diff / np.float32(voxel), 0.0, 1.0)
    excess = np.maximum(np.abs(diff) - np.float32(voxel / 2), 0.0)
    sigma_s = np.float32(sensor.sigma_min) + np.float32(sensor.zeta) * d
    # 1/sigma^2 = exp(2 * excess / tau) / sigma_s^2
    lam = np.exp(excess * np.float32(2.0 / sensor.tau)) / (sigma_s * sigma_s)
    return lam, mu * lam
