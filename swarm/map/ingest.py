"""Ingest a point cloud seen from one sensor position into a coverage map (``swarm ingest``)."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from swarm.map import fusion
from swarm.map.coverage_map import CoverageMap, prior_entropy_bits
from swarm.map.entropy_table import default_table
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel


@dataclass
class IngestReport:
    """What ``swarm ingest`` did, printed with ``--json``."""

    points: int
    rays: int
    voxel_updates: int
    measurements: int
    voxels: int
    shape: list[int]
    voxel_size: float
    fusion_seconds: float
    first_fusion_seconds: float
    fusion_repeats: int
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
    """A box that fits the origin and every finite ray (cut at max range), one voxel of margin,
    its corners on the lattice of multiples of ``voxel`` (m) from the world origin, as OctoMap's
    voxels are: the map then exports to ``.bt`` voxel for voxel (``swarm map export``)."""
    points = points[np.all(np.isfinite(points), axis=1)]
    vec = points - origin
    dist = np.linalg.norm(vec, axis=1)
    scale = np.where(dist > max_range, max_range / np.maximum(dist, 1e-12), 1.0)
    ends = np.vstack([origin[None, :], origin + vec * scale[:, None]])
    lo = np.floor((ends.min(axis=0) - voxel) / voxel) * voxel
    hi = np.ceil((ends.max(axis=0) + 2 * voxel) / voxel) * voxel
    return lo, hi


def ingest_cloud(
    points: np.ndarray,
    origin: np.ndarray,
    sensor: SensorModel,
    voxel: float = 0.1,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    repeat: int = 1,
) -> tuple[CoverageMap, IngestReport]:
    """Fuse ``points`` (N, 3) seen from ``origin`` into a new map over ``bounds`` (default: fitted).

    The cloud is one batch (``sensor.hit_precedence`` and ``sensor.discretize`` apply to all
    of it). ``fusion_seconds`` times its fusion and the application of its delta to the map.
    With ``repeat`` > 1 the cloud is fused that many times, each into a fresh map, and
    ``fusion_seconds`` is the best time, as ``swarm bench fusion`` takes it; the first
    fusion in a process also faults in the kernel's scratch memory, which a running agent
    or server pays once (``first_fusion_seconds``). The map returned is one fusion's (fusion
    is deterministic, so every repeat gives the same map). Raises ValueError for a
    non-finite origin or a ``repeat`` below 1.
    """
    if repeat < 1:
        raise ValueError(f"repeat must be at least 1, got {repeat}")
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = bounds if bounds is not None else default_bounds(points, origin, sensor.max_range, voxel)
    grid = Grid.from_bounds(lo, hi, voxel)
    initial = prior_entropy_bits(grid, sensor)

    # Set-up, not fusion (as in ``swarm bench fusion``): load the compiled kernels and
    # allocate the grid's brick table and each fresh map before its clock starts.
    fusion.warm_up()
    fusion.reserve(grid)
    times = []
    for _ in range(repeat):
        cmap = None  # the previous repeat's map is freed before the next one is allocated
        cmap = CoverageMap(grid, sensor)
        t0 = time.perf_counter()
        r = cmap.integrate(origin, points)
        times.append(time.perf_counter() - t0)

    final = float(np.sum(default_table()(cmap.mean(), cmap.sigma()), dtype=np.float64))
    report = IngestReport(
        points=len(points),
        rays=r.rays,
        measurements=r.measurements if r.measurements is not None else r.rays,
        voxel_updates=r.voxel_updates,
        voxels=grid.size,
        shape=list(grid.shape),
        voxel_size=grid.voxel,
        fusion_seconds=round(min(times), 4),
        first_fusion_seconds=round(times[0], 4),
        fusion_repeats=repeat,
        initial_entropy_bits=round(initial, 1),
        final_entropy_bits=round(final, 1),
        truncated_at_max_range=r.truncated,
        clipped_at_box=r.clipped,
        skipped_nonfinite=r.skipped_nonfinite,
        skipped_outside=r.skipped_outside,
        skipped_degenerate=r.skipped_degenerate,
    )
    return cmap, report
