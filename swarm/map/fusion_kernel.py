"""Compiled fusion of one batch (Numba): one ray at a time, straight into per-voxel sums.

``fuse_rays`` (``traverse_rays``, then the sums read out) is the kernel behind
``swarm.map.fusion.batch_information`` (after ``swarm.map.ray_batch`` has prepared the rays),
and ``traverse_rays`` that of the block map: exact Amanatides-Woo traversal of each ray
(the semantics of ``swarm.map.traversal``, whose numpy implementation the tests use as the
oracle), the sensor model of eq. 14 per voxel, and the sums of lam and eta per voxel, with
hit precedence.

- The voxels are a box of a lattice, indices ``box[0]`` to ``box[1]`` (exclusive): a grid's 0
  to its shape (``grid_box``), or the part of a block-sparse map's lattice a batch reaches.
  Rays and centres are computed from the lattice's indices: any box holding the rays gives
  the same numbers.
- Per-voxel sums live in a pool of blocks, one of 8 x 8 x 8 voxels per lattice brick
  (indices >> 3) the batch touches, found through a table of the bricks meeting the box
  (``block_table_size`` int32 entries, -1 = none). A ray looks a block up once per brick it
  enters. The read-out restores table (-1) and pool (zeros), so the same scratch space
  serves every batch. Nothing allocates per (ray, voxel).
- In front of a ray's end eq. 14's lam is the ray's gain exp(2 (d - e/2) / tau) / sigma_s^2
  times the voxel's damping exp(-2 r / tau), r the distance from the sensor to the voxel's
  centre. The voxels surely in front (every point nearer than d - e/2 minus the voxel's
  half diagonal) add only the ray's gain to an 8-byte sum; the damping multiplies that sum
  once per voxel at the end. The few voxels near the end and the one behind it get eq. 14
  in full into two other sums. An update in front costs no square root, no exp and no
  distance.
- A voxel holding a return of the batch (hit precedence) is marked by a negative gain sum.
- ``fuse_rays`` reads out in C order, walking the table's blocks row by row (the pool is read
  once, in order); ``block_kernels.collect_blocks`` reads out block by block.
- Only the axis that steps gets its next plane parameter (one division per step).
- Eq. 14 of one voxel (its lam and mean, the damping of a gain sum) is
  ``swarm.map.voxel_information``'s, inlined into these loops.

Compiled with ``cache=True``: a second process loads the machine code from Numba's cache.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarm.map.ray_batch import BRICK_BITS
from swarm.map.voxel_information import (
    EXP_LIMIT,
    LAM_MAX,
    centre_distance,
    voxel_information,
    voxel_lam,
    voxel_mean,
)

BLOCK = 1 << (3 * BRICK_BITS)  # voxels per block (one brick)
HALF_DIAGONAL = 0.5 * math.sqrt(3.0)  # of a voxel, in edges


def grid_box(shape: tuple[int, int, int]) -> np.ndarray:
    """The box (2, 3) int64 of a grid of ``shape``: indices 0 to ``shape``."""
    return np.array([(0, 0, 0), tuple(int(n) for n in shape)], dtype=np.int64)


def block_table_size(box: np.ndarray) -> int:
    """Entries of the brick table of ``box`` (2, 3): one per 8 x 8 x 8 lattice brick meeting it."""
    (i0, j0, k0), (i1, j1, k1) = box.tolist()
    b = BRICK_BITS
    return (
        (((i1 - 1) >> b) - (i0 >> b) + 1)
        * (((j1 - 1) >> b) - (j0 >> b) + 1)
        * (((k1 - 1) >> b) - (k0 >> b) + 1)
    )


@njit(cache=True, nogil=True, error_model="numpy")
def blocks_bound(start, ends, box):
    """At most how many blocks ``fuse_rays`` allocates: per ray the bricks its voxels cross (its
    L1 length in brick steps, plus one) and the brick behind its end, and never more than
    the bricks meeting ``box``."""
    b = BRICK_BITS
    i0 = int(math.floor(start[0])) >> b
    j0 = int(math.floor(start[1])) >> b
    k0 = int(math.floor(start[2])) >> b
    bound = 0
    for r in range(ends.shape[0]):
        bound += 2
        bound += abs((int(math.floor(ends[r, 0])) >> b) - i0)
        bound += abs((int(math.floor(ends[r, 1])) >> b) - j0)
        bound += abs((int(math.floor(ends[r, 2])) >> b) - k0)
    bricks = 1
    for a in range(3):
        bricks *= ((box[1, a] - 1) >> b) - (box[0, a] >> b) + 1
    return min(bound, bricks)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _block(brick, table, n_blocks):
    """The pool block of ``brick``: its table entry, or the next free block if it has none yet.
    Returns (block, new block count)."""
    block = table[brick]
    if block < 0:
        block = n_blocks
        table[brick] = block
        n_blocks += 1
    return block, n_blocks


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _entry(i, j, k, nbj, nbk, first, table, n_blocks):
    """Pool entry of voxel (i, j, k): its brick's block's start plus the voxel's place in the
    brick (``first``: the table position the lattice formula gives the box's first brick).
    Returns (entry, new block count)."""
    b = BRICK_BITS
    m = (1 << b) - 1
    block, n_blocks = _block(((i >> b) * nbj + (j >> b)) * nbk + (k >> b) - first, table, n_blocks)
    return (block << (3 * b)) | ((i & m) << (2 * b)) | ((j & m) << b) | (k & m), n_blocks


@njit(cache=True, nogil=True, error_model="numpy")
def fuse_rays(
    start, ends, d, returned, weight, box, voxel, centre_offset, sigma_min, zeta, tau, precedence, buffers
):
    """Sum eq. 14's information over every ray's voxels: (idx sorted uint32, lam, eta float32, updates).

    ``traverse_rays`` (the arguments) then the sums read out in C order of ``box``: ``idx`` the
    voxels' flat indices within ``box``.
    """
    n_blocks, updates = traverse_rays(
        start, ends, d, returned, weight, box, voxel, centre_offset, sigma_min, zeta, tau, precedence, buffers
    )
    table, gains, sums = buffers
    return _collect(table, gains, sums, n_blocks, box, voxel, centre_offset, 2.0 / tau) + (updates,)


@njit(cache=True, nogil=True, error_model="numpy")
def traverse_rays(
    start,
    ends,
    d,
    returned,
    weight,
    box,
    voxel,
    centre_offset,
    sigma_min,
    zeta,
    tau,
    precedence,
    buffers,
):
    """Sum eq. 14's information over every ray's voxels into the scratch ``buffers``: (blocks used,
    updates). ``fuse_rays`` or ``block_kernels.collect_blocks`` read the sums out.

    ``start`` (3,) and ``ends`` (M, 3) in voxel units of the lattice (inside ``box``, (2, 3)
    int64: voxel indices lo inclusive, hi exclusive; a grid's ``grid_box``), ``d`` (M,) the model's
    range in metres, ``returned`` (M,) bool: a ray with a return updates its hit voxel and
    the voxel behind it (eq. 8); one without updates free space (mean 0). ``weight`` (M,):
    a ray's information is eq. 14's lam times its weight (1 for one measurement; the number
    of rays a weighted discretize measurement stands for), bounded by ``LAM_MAX``. ``centre_offset``
    (3,) = lattice origin - sensor + voxel / 2 (metres). With ``precedence`` a voxel holding a
    return of the batch gets no update from the batch's other rays except as their
    behind voxel, which is dropped outside ``box``. ``buffers`` = (table int32
    (``block_table_size``, all -1), gains float64 (n), sums float64 (n, 2), all zero) with n at
    least 512 x ``blocks_bound``: scratch space kept between batches by the caller, restored
    by the read-out.
    """
    m = ends.shape[0]
    bb = BRICK_BITS
    bm = (1 << bb) - 1
    nbj = ((box[1, 1] - 1) >> bb) - (box[0, 1] >> bb) + 1
    nbk = ((box[1, 2] - 1) >> bb) - (box[0, 2] >> bb) + 1
    # a brick's table position is the lattice formula ((bi nbj + bj) nbk + bk) less the first brick's
    first = ((box[0, 0] >> bb) * nbj + (box[0, 1] >> bb)) * nbk + (box[0, 2] >> bb)
    i0 = int(math.floor(start[0]))
    j0 = int(math.floor(start[1]))
    k0 = int(math.floor(start[2]))
    # table: brick -> block; gains: per voxel the sum of the gains of the rays that pass it
    # surely in front of their end (< 0: the voxel holds a return, hit precedence); sums: per
    # voxel lam and eta of every other update.
    table, gains, sums = buffers
    n_blocks = 0
    two_over_tau = 2.0 / tau
    if precedence:
        for r in range(m):
            if returned[r]:
                i = int(math.floor(ends[r, 0]))
                j = int(math.floor(ends[r, 1]))
                k = int(math.floor(ends[r, 2]))
                q, n_blocks = _entry(i, j, k, nbj, nbk, first, table, n_blocks)
                gains[q] = -1.0

    # Per voxel, float32 is enough (as the numpy oracle's float32 path): eq. 14 in float32, sums in float64.
    two_over_tau32 = np.float32(two_over_tau)
    half32 = np.float32(0.5 * voxel)
    inv_voxel = np.float32(1.0 / voxel)
    updates = 0
    for r in range(m):
        hit = returned[r]
        dr = d[r]
        dr32 = np.float32(dr)
        sig_s = sigma_min + zeta * dr
        inv_s2 = weight[r] / (sig_s * sig_s)
        arg = two_over_tau * (np.float64(dr32) - np.float64(half32))
        gain = math.exp(arg) * inv_s2 if arg < EXP_LIMIT else 0.0
        # Per axis: direction, crossings left, the next plane and its parameter t.
        dx = ends[r, 0] - start[0]
        dy = ends[r, 1] - start[1]
        dz = ends[r, 2] - start[2]
        i1 = int(math.floor(ends[r, 0]))
        j1 = int(math.floor(ends[r, 1]))
        k1 = int(math.floor(ends[r, 2]))
        si = 1 if dx > 0 else -1
        sj = 1 if dy > 0 else -1
        sk = 1 if dz > 0 else -1
        ni = abs(i1 - i0)
        nj = abs(j1 - j0)
        nk = abs(k1 - k0)
        pi = i0 + 1 if dx > 0 else i0
        pj = j0 + 1 if dy > 0 else j0
        pk = k0 + 1 if dz > 0 else k0
        ti = (pi - start[0]) / dx if ni > 0 else np.inf
        tj = (pj - start[1]) / dy if nj > 0 else np.inf
        tk = (pk - start[2]) / dz if nk > 0 else np.inf
        # Surely in front: the voxels the ray leaves before t_front, where its points are nearer
        # than d - e/2 - (a voxel's half diagonal), less a margin for float32 rounding; then
        # every point of the voxel, its centre included, is nearer than d - e/2. Only when the
        # gain is usable as is (finite, non-zero, at most LAM_MAX, and exp(-2 r / tau) > 0).
        t_front = -1.0
        if gain > 0.0 and gain <= LAM_MAX and two_over_tau * dr < EXP_LIMIT - 2.0:
            length = voxel * math.sqrt(dx * dx + dy * dy + dz * dz)
            t_front = (dr - (0.5 + HALF_DIAGONAL + 1e-3) * voxel - 1e-5 * dr) / length
        i, j, k = i0, j0, k0
        brick = first - 1  # the brick of the ray's current block (none yet: no brick is below first)
        base = 0
        while True:
            t = min(ti, tj, tk)  # where the ray leaves voxel (i, j, k); inf in its end voxel
            last = t == np.inf
            here = ((i >> bb) * nbj + (j >> bb)) * nbk + (k >> bb)
            if here != brick:
                brick = here
                block, n_blocks = _block(brick - first, table, n_blocks)
                base = block << (3 * bb)
            q = base | ((i & bm) << (2 * bb)) | ((j & bm) << bb) | (k & bm)
            if t < t_front:
                g = gains[q]
                if g >= 0.0:
                    gains[q] = g + gain
                    updates += 1
            else:
                marked = gains[q] < 0.0
                if not (marked and not (hit and last)):
                    r32 = centre_distance(i, j, k, voxel, centre_offset)
                    diff = r32 - dr32
                    if diff < -half32 and t_front > 0.0 and not marked:
                        gains[q] += gain
                    else:
                        lam = voxel_information(diff, r32, half32, two_over_tau, two_over_tau32, inv_s2, gain)
                        sums[q, 0] += lam
                        if hit:
                            sums[q, 1] += voxel_mean(diff, inv_voxel) * lam
                    updates += 1
            if last:
                break
            # Step every axis whose next plane comes first (two or three at an edge or corner);
            # only a stepped axis's next plane parameter is recomputed, exactly as t = (p - s) / d.
            if ti == t:
                i += si
                ni -= 1
                pi += si
                ti = (pi - start[0]) / dx if ni > 0 else np.inf
            if tj == t:
                j += sj
                nj -= 1
                pj += sj
                tj = (pj - start[1]) / dy if nj > 0 else np.inf
            if tk == t:
                k += sk
                nk -= 1
                pk += sk
                tk = (pk - start[2]) / dz if nk > 0 else np.inf
        if not hit:
            continue
        # The voxel behind the hit: leave the hit voxel through its nearest face(s).
        ei = (i1 + 1 if dx > 0 else i1) if dx != 0 else 0
        ej = (j1 + 1 if dy > 0 else j1) if dy != 0 else 0
        ek = (k1 + 1 if dz > 0 else k1) if dz != 0 else 0
        te_i = (ei - start[0]) / dx if dx != 0 else np.inf
        te_j = (ej - start[1]) / dy if dy != 0 else np.inf
        te_k = (ek - start[2]) / dz if dz != 0 else np.inf
        t = min(te_i, te_j, te_k)
        bi = i1 + (si if (dx != 0 and te_i == t) else 0)
        bj = j1 + (sj if (dy != 0 and te_j == t) else 0)
        bk = k1 + (sk if (dz != 0 and te_k == t) else 0)
        if bi < box[0, 0] or bj < box[0, 1] or bk < box[0, 2]:
            continue
        if bi >= box[1, 0] or bj >= box[1, 1] or bk >= box[1, 2]:
            continue
        q, n_blocks = _entry(bi, bj, bk, nbj, nbk, first, table, n_blocks)
        r32 = centre_distance(bi, bj, bk, voxel, centre_offset)
        diff = r32 - dr32
        lam = voxel_information(diff, r32, half32, two_over_tau, two_over_tau32, inv_s2, gain)
        sums[q, 0] += lam
        sums[q, 1] += voxel_mean(diff, inv_voxel) * lam
        updates += 1
    return n_blocks, updates


@njit(cache=True, nogil=True, error_model="numpy")
def _collect(table, gains, sums, n_blocks, box, voxel, centre_offset, two_over_tau):
    """The touched voxels in C order within ``box``: (idx uint32, lam, eta float32); restores table and pool.

    A voxel's lam is its gain sum times its damping exp(-2 r / tau), plus its other sums.
    Walks the box's rows (i, j) through the bricks that hold a block, skipping (brick i,
    brick j) columns that hold none, so each block is read once, in order.
    """
    lo_i, lo_j, lo_k = box[0, 0], box[0, 1], box[0, 2]
    hi_i, hi_j, hi_k = box[1, 0], box[1, 1], box[1, 2]
    ny, nz = hi_j - lo_j, hi_k - lo_k
    bb = BRICK_BITS
    bm = (1 << bb) - 1
    b0i, b0j, b0k = lo_i >> bb, lo_j >> bb, lo_k >> bb
    nbi = ((hi_i - 1) >> bb) - b0i + 1
    nbj = ((hi_j - 1) >> bb) - b0j + 1
    nbk = ((hi_k - 1) >> bb) - b0k + 1
    columns = np.zeros(nbi * nbj, np.bool_)
    for brick in range(table.shape[0]):
        if table[brick] >= 0:
            columns[brick // nbk] = True
    cap = n_blocks << (3 * bb)
    idx = np.empty(cap, np.uint32)
    lam = np.empty(cap, np.float32)
    eta = np.empty(cap, np.float32)
    n = 0
    for i in range(lo_i, hi_i):
        for cj in range(nbj):
            column = ((i >> bb) - b0i) * nbj + cj
            if not columns[column]:
                continue
            j_brick = (b0j + cj) << bb
            for j in range(max(lo_j, j_brick), min(hi_j, j_brick + (1 << bb))):
                for ck in range(nbk):
                    block = table[column * nbk + ck]
                    if block < 0:
                        continue
                    base = (block << (3 * bb)) | ((i & bm) << (2 * bb)) | ((j & bm) << bb)
                    k_brick = (b0k + ck) << bb
                    for k in range(max(lo_k, k_brick), min(hi_k, k_brick + (1 << bb))):
                        q = base | (k & bm)
                        g = gains[q]
                        other = sums[q, 0]
                        if g == 0.0 and other == 0.0:
                            continue
                        # Every touched voxel has a positive sum (a marked one, its own return's).
                        idx[n] = ((i - lo_i) * ny + (j - lo_j)) * nz + (k - lo_k)
                        lam[n] = voxel_lam(g, other, i, j, k, voxel, centre_offset, two_over_tau)
                        eta[n] = sums[q, 1]
                        n += 1
                        gains[q] = 0.0
                        sums[q, 0] = 0.0
                        sums[q, 1] = 0.0
    for brick in range(table.shape[0]):
        table[brick] = -1
    if 2 * n < cap:
        return idx[:n].copy(), lam[:n].copy(), eta[:n].copy()
    return idx[:n], lam[:n], eta[:n]
