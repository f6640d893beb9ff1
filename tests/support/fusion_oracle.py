"""The numpy fusion of one batch: the oracle the compiled kernel (``swarm.map.fusion``) is tested against.

This was the project's fusion before the Numba kernel: every (ray, voxel) pair of a batch
as numpy arrays (``swarm.map.traversal.traverse``, itself checked against a rational
brute force), the sensor model per pair, and one ``bincount`` per voxel. It implements the
same model as the kernel (cut rays at max range or the hit range, the information bound, hit precedence,
discretize) with independent code, and is slow and memory-hungry on purpose.
"""

from __future__ import annotations

import numpy as np

from swarm.map.delta import Delta
from swarm.map.fusion import BOUNDARY_MARGIN_FRACTION, BOUNDARY_MARGIN_VOXELS, BatchResult
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.map.traversal import traverse
from swarm.map.voxel_information import LAM_MAX


def reference_batch_information(
    grid: Grid,
    sensor: SensorModel,
    origin: np.ndarray,
    points: np.ndarray,
    hit_precedence: bool | None = None,
    discretize: bool | None = None,
    weighted: bool | None = None,
) -> BatchResult:
    """``swarm.map.fusion.batch_information`` in numpy (options default to the sensor's)."""
    hit_precedence = sensor.hit_precedence if hit_precedence is None else hit_precedence
    discretize = sensor.discretize if discretize is None else discretize
    weighted = sensor.weighted if weighted is None else weighted
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)

    finite = np.all(np.isfinite(points), axis=1)
    vec = points[finite] - origin
    scale = np.abs(vec).max(axis=1, initial=0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = vec / scale[:, None]
    dist = np.where(scale > 0, scale * np.sqrt(np.einsum("ij,ij->i", unit, unit)), 0.0)
    nondegenerate = dist > 1e-9
    vec, dist = vec[nondegenerate], dist[nondegenerate]
    # A ray is cut at max range, or at the hit range when that is shorter: no hit beyond.
    cut_at = sensor.max_range if sensor.hit_range is None else min(sensor.max_range, sensor.hit_range)
    returned = dist <= cut_at
    truncated = ~returned
    reach = np.where(returned, 1.0, cut_at / dist)
    if grid.contains_point(origin):
        exit_at = _grid_exit(grid, origin, vec)
        margin = np.maximum(BOUNDARY_MARGIN_FRACTION * dist, BOUNDARY_MARGIN_VOXELS * grid.voxel)
        clipped = (reach >= exit_at) & ((1.0 - exit_at) * dist > margin)
        reach = np.where(clipped, exit_at - 1e-6 * grid.voxel / dist, reach)
        returned &= ~clipped
        end = origin + vec * reach[:, None]
        inside = (reach * dist > 1e-9) & grid.contains_point(end)
    else:
        clipped = np.zeros(len(vec), dtype=bool)
        end = origin + vec
        inside = np.zeros(len(vec), dtype=bool)
    end, dist, returned, truncated = end[inside], dist[inside], returned[inside], truncated[inside]
    d_model = np.minimum(dist, cut_at)
    rays = len(end)
    weight = np.ones(len(end))
    if discretize:
        end, d_model, returned, counts = _discretize(grid, origin, end, d_model, returned)
        weight = counts.astype(np.float64) if weighted else np.ones(len(end))

    voxels = traverse(grid, origin, end, hit=returned)
    i, j, k, ray, behind = voxels.i, voxels.j, voxels.k, voxels.ray, voxels.behind
    keep = grid.contains_index(np.column_stack([i, j, k]))  # only a behind voxel can be outside
    flat = np.where(keep, grid.flat_of(i, j, k), -1)
    if hit_precedence and returned.any():
        hit_flat = grid.flat(grid.index_of(end[returned]))
        own_hit = returned[ray] & (flat == grid.flat(grid.index_of(end))[ray]) & ~behind
        keep &= ~np.isin(flat, hit_flat) | own_hit | behind
    flat, ray = flat[keep], ray[keep]
    i, j, k = grid.unflat(flat).T

    d_l = np.linalg.norm(grid.centre(np.column_stack([i, j, k])) - origin, axis=1)
    d = d_model[ray]
    diff = d_l - d
    mu = np.where(returned[ray], np.clip(0.5 + diff / grid.voxel, 0.0, 1.0), 0.0)
    excess = np.maximum(np.abs(diff) - grid.voxel / 2, 0.0)
    sigma_s = sensor.sigma_min + sensor.zeta * d
    with np.errstate(over="ignore"):
        lam = np.minimum(weight[ray] * np.exp(2.0 * excess / sensor.tau) / sigma_s**2, LAM_MAX)
    return BatchResult(
        delta=Delta.accumulate(flat, lam, mu * lam, grid.size),
        rays=rays,
        measurements=len(end),
        voxel_updates=len(ray),
        truncated=int(truncated.sum()),
        skipped_nonfinite=int((~finite).sum()),
        skipped_outside=int((~inside).sum()),
        skipped_degenerate=int((~nondegenerate).sum()),
        clipped=int((clipped & inside).sum()),
    )


def _discretize(grid, origin, end, d_model, returned):
    """One measurement per (end voxel, returned): mean end point; range to it, or mean range; ray count."""
    key = grid.flat(grid.index_of(end)) * 2 + returned
    groups, inverse = np.unique(key, return_inverse=True)
    counts = np.bincount(inverse)
    mean_end = np.column_stack([np.bincount(inverse, weights=end[:, a]) / counts for a in range(3)])
    mean_d = np.bincount(inverse, weights=d_model) / counts
    is_returned = (groups % 2) == 1
    d = np.where(is_returned, np.linalg.norm(mean_end - origin, axis=1), mean_d)
    return mean_end, d, is_returned, counts


def _grid_exit(grid: Grid, origin: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Where rays from ``origin`` (inside the grid) leave it, as t in units of each ray's ``vec``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = (grid.hi - origin) / vec
        t_lo = (grid.lo - origin) / vec
    t_axis = np.where(vec > 0, t_hi, np.where(vec < 0, t_lo, np.inf))
    return t_axis.min(axis=1)
