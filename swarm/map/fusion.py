"""Fusion of one batch of range measurements into information increments (paper eq. 6-14, 24-25).

A batch M_k = (x_k, V_k) is a sensor position and the points where obstacles were
detected. Each ray updates the voxels it traverses and the voxel behind its hit with
the Gaussian sensor model; in information form the update of a voxel is the sum of
lam = 1/sigma^2 and eta = mu/sigma^2 over the rays that influence it. The work is done
by the compiled kernels of ``swarm.map.ray_batch`` and ``swarm.map.fusion_kernel``;
``tests/support/fusion_oracle.py`` is the numpy implementation they are tested against.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from swarm.map import fusion_kernel as kernel
from swarm.map import ray_batch
from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

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
    voxel_updates: int  # (measurement, voxel) updates applied
    truncated: int  # rays longer than the sensor's reach: free space up to it, no hit
    skipped_nonfinite: int  # NaN/inf points
    skipped_outside: int  # sensor outside the grid, or point just beyond its boundary
    skipped_degenerate: int  # zero-length rays
    clipped: int = 0  # rays that leave the grid: free space up to its boundary, no hit
    measurements: int | None = None  # traversed measurements (fewer than rays with discretize)


_local = threading.local()


def reserve(grid: Grid) -> None:
    """Allocate this thread's brick table for ``grid`` now (kept between batches on one grid).
    The discretize slot map spans each batch's end voxels only (:func:`ends_box`), so it is
    small and allocated by the first batch."""
    _table(grid)


def kept_pool(blocks: int) -> tuple[np.ndarray, np.ndarray]:
    """This thread's per-voxel sums for ``fuse_rays`` (room for ``blocks`` blocks), kept and grown.

    Zero between batches (the kernel restores them). Kept, their memory is faulted in once,
    and numpy backs arrays of 4 MB and more with huge pages (madvise) where the kernel
    allows; pages never written stay unallocated, so a large bound costs address space,
    not memory.
    """
    entries = blocks * kernel.BLOCK
    pool = getattr(_local, "pool", None)
    if pool is None or len(pool[0]) < entries:
        size = max(entries, 2 * len(pool[0]) if pool is not None else 0, kernel.BLOCK)
        pool = (np.zeros(size), np.zeros((size, 2)))
        _local.pool = pool
    return pool


def kept_index(name: str, size: int) -> np.ndarray:
    """The first ``size`` entries of this thread's int32 index array ``name``, all -1 between
    batches (its users restore them); kept, and grown when a batch needs more."""
    index = getattr(_local, name, None)
    if index is None or len(index) < size:
        index = np.full(size, -1, dtype=np.int32)
        setattr(_local, name, index)
    return index[:size]


def _table(grid: Grid) -> np.ndarray:
    """This thread's brick table for ``grid`` (int32, all -1), kept between batches."""
    return kept_index("table", kernel.block_table_size(kernel.grid_box(grid.shape)))


def ends_box(ends: np.ndarray) -> np.ndarray:
    """The box (2, 3) int64 of the voxels holding ``ends`` (M >= 1, 3; voxel units): the floors'
    least and largest plus one. ``discretize_rays`` numbers the end voxels within it, so its
    slot map spans the batch's reach (a 5 m sensor at 0.1 m: about 1 MB) instead of the grid
    (the campus floor's 8.4e6 voxels: 37 MB, all of it written)."""
    cells = np.floor(ends).astype(np.int64)
    return np.array([cells.min(axis=0), cells.max(axis=0) + 1], dtype=np.int64)


def _slots(box: np.ndarray) -> np.ndarray:
    """This thread's slot map for the voxels of ``box`` (int32, all -1) for ``discretize_rays``,
    kept between batches (grown when a batch's box needs more)."""
    return kept_index("slots", ray_batch.slot_map_size(tuple((box[1] - box[0]).tolist())))


def batch_information(
    grid: Grid,
    sensor: SensorModel,
    origin: np.ndarray,
    points: np.ndarray,
    hit_precedence: bool | None = None,
    discretize: bool | None = None,
    weighted: bool | None = None,
) -> BatchResult:
    """Information increments of one batch: sensor at ``origin`` (3,), hit points (N, 3), world metres.

    Points that are NaN/inf, zero-length rays and all rays of a sensor outside the grid
    are skipped and counted. Rays longer than ``sensor.reach`` (max range, or the hit range
    when shorter) update free space up to that range (mean 0) with the information of a ray
    of that length, and give no hit (as OctoMap's max range). Rays that leave the grid are
    treated alike at the grid's boundary (mean 0, the sensor model at their true range);
    but a point within the boundary margin (``BOUNDARY_MARGIN_FRACTION``) beyond the
    boundary is skipped. One measurement's lam is at most ``voxel_information.LAM_MAX``, so no
    finite input gives non-finite information.

    ``hit_precedence`` (default ``sensor.hit_precedence``): a voxel holding a return of this
    batch gets no free-space update from its other rays. ``discretize`` (default
    ``sensor.discretize``): one measurement per end voxel, the mean end point of its rays.
    ``weighted`` (default ``sensor.weighted``; only with ``discretize``): that measurement
    carries the information of all its rays (eq. 14's lam times their number), as the rays
    themselves would, but traversed once. Raises ValueError for a non-finite origin.
    """
    hit_precedence = sensor.hit_precedence if hit_precedence is None else hit_precedence
    discretize = sensor.discretize if discretize is None else discretize
    weighted = sensor.weighted if weighted is None else weighted
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(origin)):
        raise ValueError(f"sensor origin must be finite, got {origin.tolist()}")

    lo, hi, e = grid.lo, grid.hi, grid.voxel
    ends, d, returned, counts = ray_batch.prepare_rays(
        origin, points, lo, hi, e, sensor.reach, BOUNDARY_MARGIN_FRACTION, BOUNDARY_MARGIN_VOXELS, lo
    )
    with np.errstate(over="ignore"):  # an origin past 1e307 m: no ray reaches the grid, start unused
        start = (origin - lo) / e
    box = kernel.grid_box(grid.shape)
    rays = len(ends)
    if discretize and rays:
        near = ends_box(ends)
        ends, d, returned, n_rays = ray_batch.discretize_rays(start, e, ends, d, returned, near, _slots(near))
        weight = n_rays if weighted else np.ones(len(ends))
    else:
        weight = np.ones(rays)
    if len(ends):
        ends, d, returned, weight = ray_batch.order_by_direction(
            start, ends, d, returned, weight, ray_batch.DIRECTION_BINS
        )
        idx, lam, eta, updates = kernel.fuse_rays(
            start,
            ends,
            d,
            returned,
            weight,
            box,
            e,
            lo - origin + 0.5 * e,
            float(sensor.sigma_min),
            float(sensor.zeta),
            float(sensor.tau),
            bool(hit_precedence),
            (_table(grid), *kept_pool(int(kernel.blocks_bound(start, ends, box)))),
        )
        delta = Delta(idx, lam, eta)
    else:
        delta, updates = Delta.empty(), 0
    return BatchResult(
        delta=delta,
        rays=rays,
        measurements=len(ends),
        voxel_updates=int(updates),
        truncated=int(counts[ray_batch.TRUNCATED]),
        skipped_nonfinite=int(counts[ray_batch.NONFINITE]),
        skipped_outside=int(counts[ray_batch.OUTSIDE]),
        skipped_degenerate=int(counts[ray_batch.DEGENERATE]),
        clipped=int(counts[ray_batch.CLIPPED]),
    )


def warm_up_kernels() -> tuple:
    """The compiled kernels :func:`warm_up` loads (a first run: compiles), for its progress lines."""
    return (
        kernel.fuse_rays,
        kernel.blocks_bound,
        ray_batch.prepare_rays,
        ray_batch.order_by_direction,
        ray_batch.discretize_rays,
    )


def warm_up() -> None:
    """Load (or, on a first run, compile and cache) every fusion kernel now, not on the first frame.

    Numba compiles on first call; with ``cache=True`` later processes load the machine code
    from the cache in well under a second, but a fresh install compiles for tens of seconds.
    A role calls this before it announces itself, so that its first frame is not late.
    """
    grid = Grid((0.0, 0.0, 0.0), 1.0, (2, 2, 2))
    for discretize, weighted in ((False, False), (True, False), (True, True)):
        sensor = SensorModel(discretize=discretize, weighted=weighted)
        batch_information(grid, sensor, np.full(3, 0.5), np.full((1, 3), 1.5))
