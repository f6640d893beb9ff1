"""Compiled preparation of a batch's rays (Numba): where each ray ends in the grid, and OctoMap's discretize.

- ``prepare_rays``: per point, the ray's end in the grid (cut at max range or at the grid's
  boundary), the range the sensor model uses and whether it ends in a return;
- ``discretize_rays``: optionally, one measurement per end voxel (the mean end point of
  the rays ending there), as OctoMap's ``discretize``, with the number of rays it stands for;
- ``order_by_direction``: the measurements grouped by direction, so that consecutive rays
  traverse nearby voxels (on the real scan's whole beam, 10 % off the fusion time).

``discretize_rays`` finds an end voxel's group through a grid-sized slot map (int32, -1 =
untouched) laid out in 8 x 8 x 8 bricks (``slot_map_size``, ``brick_index``);
``swarm.map.fusion_kernel`` keeps its sums in blocks of the same bricks (``BRICK_BITS``).
Compiled with ``cache=True``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

BRICK_BITS = 3  # bricks of 8 x 8 x 8 voxels in the slot map


def brick_count(shape: tuple[int, int, int]) -> int:
    """8 x 8 x 8 bricks of a grid of ``shape`` (padded to whole bricks)."""
    b = 1 << BRICK_BITS
    bricks = 1
    for n in shape:
        bricks *= -(-int(n) // b)
    return bricks


def slot_map_size(shape: tuple[int, int, int]) -> int:
    """Entries of the brick-ordered slot map of a grid of ``shape`` (padded to whole bricks)."""
    return brick_count(shape) << (3 * BRICK_BITS)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def brick_index(i, j, k, nbj, nbk):
    """Slot-map position of voxel (i, j, k): its brick, then its place within the brick."""
    b = BRICK_BITS
    m = (1 << b) - 1
    brick = ((i >> b) * nbj + (j >> b)) * nbk + (k >> b)
    return (brick << (3 * b)) | ((i & m) << (2 * b)) | ((j & m) << b) | (k & m)


# The counts prepare_rays returns, by position.
NONFINITE, DEGENERATE, OUTSIDE, TRUNCATED, CLIPPED = 0, 1, 2, 3, 4


@njit(cache=True, nogil=True, error_model="numpy")
def prepare_rays(origin, points, lo, hi, voxel, max_range, margin_fraction, margin_voxels, frame):
    """The rays of a batch that fusion traverses (see ``swarm.map.fusion.batch_information``).

    ``lo``, ``hi`` (3,): the box rays are cut at (world metres; +-inf for none); ``frame`` (3,):
    the point voxel units are measured from (a grid's ``lo``, or a lattice's origin).
    Returns ``ends`` (M, 3) in voxel units from ``frame``, ``d`` (M,) the sensor model's range
    (metres; min(true range, max range)), ``returned`` (M,) bool, packed in input order, and
    ``counts`` (5,): points skipped as NaN/inf, as zero-length, as outside (sensor outside
    the grid, or end just beyond it), then fused rays truncated at max range and clipped at
    the grid's boundary.
    """
    n = points.shape[0]
    ends = np.empty((n, 3))
    d = np.empty(n)
    returned = np.empty(n, np.bool_)
    counts = np.zeros(5, np.int64)
    origin_inside = True
    for a in range(3):
        if not (origin[a] >= lo[a] and origin[a] < hi[a]):
            origin_inside = False
    m = 0
    for r in range(n):
        vx = points[r, 0] - origin[0]
        vy = points[r, 1] - origin[1]
        vz = points[r, 2] - origin[2]
        if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(vz)):
            counts[NONFINITE] += 1
            continue
        scale = max(abs(vx), abs(vy), abs(vz))  # a norm that cannot overflow
        dist = 0.0
        if scale > 0.0:
            dist = scale * math.sqrt((vx / scale) ** 2 + (vy / scale) ** 2 + (vz / scale) ** 2)
        if not dist > 1e-9:
            counts[DEGENERATE] += 1
            continue
        if not origin_inside:
            counts[OUTSIDE] += 1
            continue
        hit = dist <= max_range
        reach = 1.0 if hit else max_range / dist
        exit_at = np.inf
        for a, va in ((0, vx), (1, vy), (2, vz)):
            if va > 0:
                exit_at = min(exit_at, (hi[a] - origin[a]) / va)
            elif va < 0:
                exit_at = min(exit_at, (lo[a] - origin[a]) / va)
        margin = max(margin_fraction * dist, margin_voxels * voxel)
        cut = reach >= exit_at and (1.0 - exit_at) * dist > margin
        if cut:
            reach = exit_at - 1e-6 * voxel / dist
            hit = False
        ex = origin[0] + vx * reach
        ey = origin[1] + vy * reach
        ez = origin[2] + vz * reach
        inside = reach * dist > 1e-9
        for a, ea in ((0, ex), (1, ey), (2, ez)):
            if not (ea >= lo[a] and ea < hi[a]):
                inside = False
        if not inside:
            counts[OUTSIDE] += 1
            continue
        ends[m, 0] = (ex - frame[0]) / voxel
        ends[m, 1] = (ey - frame[1]) / voxel
        ends[m, 2] = (ez - frame[2]) / voxel
        d[m] = min(dist, max_range)
        returned[m] = hit
        counts[TRUNCATED] += dist > max_range
        counts[CLIPPED] += cut
        m += 1
    return ends[:m], d[:m], returned[:m], counts


@njit(cache=True, nogil=True, error_model="numpy")
def discretize_rays(start, voxel, ends, d, returned, box, slots):
    """One measurement per (end voxel, returned) pair: the mean end point of its rays.

    ``start`` (3,) and ``ends`` (M, 3) in voxel units; a returned measurement's range is the
    distance to its mean end point, a free one's the mean of its rays' ranges. Returns
    ``ends``, ``d``, ``returned`` and ``rays`` (float64: how many rays each measurement
    stands for) of the measurements, in first-seen order. ``box`` (2, 3) int64: the voxel
    indices lo (inclusive) and hi (exclusive) that hold every end (a grid's: 0 and its
    shape); ``slots`` is the int32 map of at least ``slot_map_size(hi - lo)`` entries (all -1),
    restored before returning.
    """
    m = ends.shape[0]
    nbj = (box[1, 1] - box[0, 1] + 7) >> BRICK_BITS
    nbk = (box[1, 2] - box[0, 2] + 7) >> BRICK_BITS
    sums = np.zeros((2 * m, 4))  # x, y, z, range; rows 2 * group + returned
    counts = np.zeros(2 * m, np.int64)
    voxels = np.empty(m, np.int64)
    groups = 0
    for r in range(m):
        v = brick_index(
            int(math.floor(ends[r, 0])) - box[0, 0],
            int(math.floor(ends[r, 1])) - box[0, 1],
            int(math.floor(ends[r, 2])) - box[0, 2],
            nbj,
            nbk,
        )
        g = slots[v]
        if g < 0:
            g = groups
            slots[v] = g
            voxels[g] = v
            groups += 1
        row = 2 * g + (1 if returned[r] else 0)
        sums[row, 0] += ends[r, 0]
        sums[row, 1] += ends[r, 1]
        sums[row, 2] += ends[r, 2]
        sums[row, 3] += d[r]
        counts[row] += 1
    for g in range(groups):
        slots[voxels[g]] = -1
    out_ends = np.empty((2 * groups, 3))
    out_d = np.empty(2 * groups)
    out_returned = np.empty(2 * groups, np.bool_)
    out_rays = np.empty(2 * groups)
    k = 0
    for row in range(2 * groups):
        c = counts[row]
        if c == 0:
            continue
        for a in range(3):
            out_ends[k, a] = sums[row, a] / c
        if row % 2 == 1:
            dx = out_ends[k, 0] - start[0]
            dy = out_ends[k, 1] - start[1]
            dz = out_ends[k, 2] - start[2]
            out_d[k] = voxel * math.sqrt(dx * dx + dy * dy + dz * dz)
            out_returned[k] = True
        else:
            out_d[k] = sums[row, 3] / c
            out_returned[k] = False
        out_rays[k] = c
        k += 1
    return out_ends[:k], out_d[:k], out_returned[:k], out_rays[:k]


#: Direction cells per axis of ``order_by_direction``'s octahedral map (2 x 32 x 32 cells).
DIRECTION_BINS = 32


@njit(cache=True, nogil=True, error_model="numpy")
def direction_cell(dx, dy, dz, bins):
    """The cell of direction (dx, dy, dz) on the octahedron |x| + |y| + |z| = 1: (x, y) binned
    ``bins`` x ``bins``, and the sign of z. No trigonometry; neighbouring cells hold
    neighbouring directions."""
    n = abs(dx) + abs(dy) + abs(dz)
    if not n > 0.0:
        return 0
    a = min(int((dx / n + 1.0) * 0.5 * bins), bins - 1)
    b = min(int((dy / n + 1.0) * 0.5 * bins), bins - 1)
    return ((1 if dz > 0 else 0) * bins + a) * bins + b


@njit(cache=True, nogil=True, error_model="numpy")
def order_by_direction(start, ends, d, returned, weight, bins):
    """``ends``, ``d``, ``returned``, ``weight`` (M rays from ``start``, voxel units), by direction cell.

    A stable counting sort on ``direction_cell``: rays in one cell keep their order. Fusion's
    sums do not depend on the order but for float rounding; its memory traffic does, as
    consecutive rays then touch the same voxels while they are in cache.
    """
    m = ends.shape[0]
    cells = 2 * bins * bins
    key = np.empty(m, np.int64)
    first = np.zeros(cells + 1, np.int64)
    for r in range(m):
        c = direction_cell(ends[r, 0] - start[0], ends[r, 1] - start[1], ends[r, 2] - start[2], bins)
        key[r] = c
        first[c + 1] += 1
    for c in range(cells):
        first[c + 1] += first[c]
    out_ends = np.empty_like(ends)
    out_d = np.empty_like(d)
    out_returned = np.empty_like(returned)
    out_weight = np.empty_like(weight)
    for r in range(m):
        k = first[key[r]]
        first[key[r]] += 1
        out_ends[k, 0] = ends[r, 0]
        out_ends[k, 1] = ends[r, 1]
        out_ends[k, 2] = ends[r, 2]
        out_d[k] = d[r]
        out_returned[k] = returned[r]
        out_weight[k] = weight[r]
    return out_ends, out_d, out_returned, out_weight
