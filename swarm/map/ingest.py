"""Ingest a point cloud seen from one sensor position into a coverage map (``swarm ingest``)."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from swarm.map.coverage_map import CoverageMap, prior_entropy_bits
from swarm.map.entropy_table import default_table
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

CHUNK_RAYS = 20_000


@dataclass
class IngestReport:
    """What ``swarm ingest`` did, printed with ``--json``."""

    points: int
    rays: int
    voxel_updates: int
    voxels: int
    shape: list[int]
    voxel_size: float
    fusion_seconds: float
    initial_entropy_bits: float
    final_entropy_bits: float
    truncated_at_max_range: int
    clipped_at_box: int
    skipped_nonfinite: int
    skipped_outside: int
    skipped_degenerate: int

    def to_dict(self) -> dict:
        return asdict(self)


def default_bounds(
    points: np.ndarray, origin: np.ndarray, max_range: float, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """A box that fits the origin and every finite ray (cut at max range), one voxel of margin."""
    points = points[np.all(np.isfinite(points), axis=1)]
    vec = points - origin
    dist = np.linalg.norm(vec, axis=1)
    scale = np.where(dist > max_range, max_range / np.maximum(dist, 1e-12), 1.0)
    ends = np.vstack([origin[None, :], origin + vec * scale[:, None]])
    return ends.min(axis=0) - voxel, ends.max(axis=0) + 2 * voxel


def ingest_cloud(
    points: np.ndarray,
    origin: np.ndarray,
    sensor: SensorModel,
    voxel: float = 0.1,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    chunk_rays: int = CHUNK_RAYS,
) -> tuple[CoverageMap, IngestReport]:
    """Fuse ``points`` (N, 3) seen from ``origin`` into a new map over ``bounds`` (default: fitted)."""
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = bounds if bounds is not None else default_bounds(points, origin, sensor.max_range, voxel)
    grid = Grid.from_bounds(lo, hi, voxel)
    cmap = CoverageMap(grid, sensor)
    table = default_table()
    initial = prior_entropy_bits(grid, sensor)

    totals = dict(rays=0, voxel_updates=0, truncated=0, clipped=0, nonfinite=0, outside=0, degenerate=0)
    seconds = 0.0
    for first in range(0, len(points), chunk_rays):
        t0 = time.perf_counter()
        r = cmap.integrate(origin, points[first : first + chunk_rays])
        seconds += time.perf_counter() - t0
        totals["rays"] += r.rays
        totals["voxel_updates"] += r.voxel_updates
        totals["truncated"] += r.truncated
        totals["clipped"] += r.clipped
        totals["nonfinite"] += r.skipped_nonfinite
        totals["outside"] += r.skipped_outside
        totals["degenerate"] += r.skipped_degenerate

    final = float(np.sum(table(cmap.mean(), cmap.sigma()), dtype=np.float64))
    report = IngestReport(
        points=len(points),
        rays=totals["rays"],
        voxel_updates=totals["voxel_updates"],
        voxels=grid.size,
        shape=list(grid.shape),
        voxel_size=grid.voxel,
        fusion_seconds=round(seconds, 4),
        initial_entropy_bits=round(initial, 1),
        final_entropy_bits=round(final, 1),
        truncated_at_max_range=totals["truncated"],
        clipped_at_box=totals["clipped"],
        skipped_nonfinite=totals["nonfinite"],
        skipped_outside=totals["outside"],
        skipped_degenerate=totals["degenerate"],
    )
    return cmap, report
