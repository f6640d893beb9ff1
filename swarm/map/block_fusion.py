"""Fusion of one batch straight into blocks of an unbounded lattice (paper eq. 6-14, 24-25).

The same kernels as ``swarm.map.fusion.batch_information`` (``swarm.map.ray_batch``,
``swarm.map.fusion_kernel``), run over the box of lattice voxels that the batch's rays reach
(their end points and sensor, one voxel wider for the voxel behind each hit), then the
box's voxels grouped by block (``BlockDelta.from_box``). Rays, voxel centres and distances
are computed in the lattice's own voxel units, from its origin, whatever the box: so a
lattice whose origin is a grid's origin gives, voxel for voxel, bit for bit, the delta the
dense map gets on that grid (when no ray leaves the grid; with ``bounds`` the grid, always).

With no ``bounds`` there is no box to leave: a ray ends at its point or at the sensor's
reach, never at a boundary. With ``bounds`` (a grid aligned with the lattice: a mission's
workspace) rays are cut and skipped at its boundary exactly as the dense map does.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from swarm.map import block_kernels, ray_batch
from swarm.map import fusion_kernel as kernel
from swarm.map.block_delta import BlockDelta
from swarm.map.fusion import (
    BOUNDARY_MARGIN_FRACTION,
    BOUNDARY_MARGIN_VOXELS,
    BatchResult,
    kept_index,
    kept_pool,
)
from swarm.map.grid import Grid
from swarm.map.lattice import Lattice, check_box
from swarm.map.sensor_model import SensorModel

#: A batch's box may hold at most this many voxels (its flat indices are uint32, and the
#: kernel's brick table and discretize's slot map grow with it: 4 bytes per 512 voxels, and
#: 4 bytes per voxel). A 5 m sensor at 0.1 m reaches a box of about 1e6 voxels.
MAX_BOX_VOXELS = 1 << 31
#: A sensor whose reach fits a cube of at most this many voxels around it gets that cube as its
#: batch's box, with no pass over the rays (a 5 m reach at 0.1 m: 1.1e6 voxels).
REACH_BOX_VOXELS = 1 << 23


@dataclass(frozen=True)
class BlockBatchResult(BatchResult):
    """The block delta of one batch and what happened to its rays (as ``BatchResult``)."""

    delta: BlockDelta


@functools.lru_cache(maxsize=64)
def _bounds_box(lattice: Lattice, bounds: Grid) -> np.ndarray:
    """The lattice voxel box of ``bounds`` (read-only; lattices and grids are frozen, so kept)."""
    box = lattice.box_of_grid(bounds)
    box.flags.writeable = False
    return box


def reach_box(
    start: np.ndarray, ends: np.ndarray, bounds: np.ndarray | None = None, reach: float | None = None
) -> np.ndarray:
    """Lattice voxel box (2, 3) int64 (lo inclusive, hi exclusive) holding the voxels of rays from
    ``start`` (3,) to ``ends`` (M, 3) (voxel units) and the voxels behind their ends, within the
    voxel box ``bounds`` when given. ``reach``: no ray is longer (voxel units); when the cube of
    that half-width around the sensor is small (``REACH_BOX_VOXELS``) it is the box. Which box
    holds the rays changes nothing in the delta."""
    s = start.tolist()
    if reach is not None and (2 * reach + 6) ** 3 <= REACH_BOX_VOXELS and max(map(abs, s)) < 2.0**52:
        r = math.ceil(reach) + 2  # + the voxel behind a hit, + rounding of the ends
        lo = [math.floor(v) - r for v in s]
        hi = [math.floor(v) + r + 1 for v in s]
    else:
        lo, hi = block_kernels.ray_box(start, ends, float(1 << 62)).tolist()  # clamped beyond any key
    if bounds is not None:
        (blo, bhi) = bounds.tolist()
        lo = [max(a, b) for a, b in zip(lo, blo, strict=True)]
        hi = [min(a, b) for a, b in zip(hi, bhi, strict=True)]
    return np.array([lo, hi], dtype=np.int64)


def block_batch_information(
    lattice: Lattice,
    sensor: SensorModel,
    origin: np.ndarray,
    points: np.ndarray,
    bounds: Grid | None = None,
    hit_precedence: bool | None = None,
    discretize: bool | None = None,
    weighted: bool | None = None,
) -> BlockBatchResult:
    """Information increments of one batch in blocks: sensor at ``origin`` (3,), points (N, 3), metres.

    The options and counts are those of ``swarm.map.fusion.batch_information``; ``bounds``
    (an aligned Grid, or None for the unbounded lattice) plays the grid's part. Raises
    ValueError for a non-finite origin, a ``bounds`` grid off the lattice, or a batch whose
    box exceeds ``MAX_BOX_VOXELS`` or the lattice's block keys.
    """
    hit_precedence = sensor.hit_precedence if hit_precedence is None else hit_precedence
    discretize = sensor.discretize if discretize is None else discretize
    weighted = sensor.weighted if weighted is None else weighted
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(origin)):
        raise ValueError(f"sensor origin must be finite, got {origin.tolist()}")
    frame, e = lattice.lo, lattice.voxel
    if bounds is None:
        bounds_box, lo, hi = None, np.full(3, -np.inf), np.full(3, np.inf)
    else:
        bounds_box, lo, hi = _bounds_box(lattice, bounds), bounds.lo, bounds.hi
    ends, d, returned, counts = ray_batch.prepare_rays(
        origin, points, lo, hi, e, sensor.reach, BOUNDARY_MARGIN_FRACTION, BOUNDARY_MARGIN_VOXELS, frame
    )
    start = (origin - frame) / e
    rays = len(ends)
    if rays:
        box = reach_box(start, ends, bounds_box, sensor.reach / e)
        check_box(box, lattice.block_bits)
        span = (box[1] - box[0]).tolist()
        size = span[0] * span[1] * span[2]
        if size > MAX_BOX_VOXELS:
            raise ValueError(
                f"the batch's rays span {size:,} voxels (at most {MAX_BOX_VOXELS:,}): lower the sensor's "
                "max range or fuse its rays in smaller batches"
            )
        if discretize:
            slots = kept_index("slots", ray_batch.slot_map_size(span))
            ends, d, returned, n_rays = ray_batch.discretize_rays(start, e, ends, d, returned, box, slots)
            weight = n_rays if weighted else np.ones(len(ends))
        else:
            weight = np.ones(rays)
        ends, d, returned, weight = ray_batch.order_by_direction(
            start, ends, d, returned, weight, ray_batch.DIRECTION_BINS
        )
        buffers = (
            kept_index("table", kernel.block_table_size(box)),
            *kept_pool(int(kernel.blocks_bound(start, ends, box))),
        )
        model = (float(sensor.sigma_min), float(sensor.zeta), float(sensor.tau), bool(hit_precedence))
        rays_at = (start, ends, d, returned, weight, box, e, frame - origin + 0.5 * e)
        if lattice.block_bits >= ray_batch.BRICK_BITS:  # read out block by block
            n_blocks, updates = kernel.traverse_rays(*rays_at, *model, buffers)
            keys, per_block, offsets, lam, eta = block_kernels.collect_blocks(
                *buffers, n_blocks, box, e, rays_at[-1], 2.0 / sensor.tau, lattice.block_bits
            )
            delta = BlockDelta(
                lattice.block_bits, keys.astype(np.int32), per_block.astype(np.uint32), offsets, lam, eta
            )
        else:  # blocks smaller than the kernel's bricks: in C order, then sorted into blocks
            idx, lam, eta, updates = kernel.fuse_rays(*rays_at, *model, buffers)
            delta = BlockDelta.from_box(idx, lam, eta, box, lattice.block_bits)
    else:
        delta, updates = BlockDelta.empty(lattice.block_bits), 0
    return BlockBatchResult(
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
