"""Compiled loops of the block-sparse map (Numba): scatter into blocks, index, gather, sum.

The map keeps per-voxel values of its allocated blocks in flat float32 arrays, block
``slot`` owning entries ``slot * B^3`` to ``(slot + 1) * B^3`` (B = 2^bits, C order inside
the block, ``swarm.map.lattice``). These loops are the per-entry work that numpy would do
with temporaries or sorts:

- ``ray_box``: the lattice box a batch's rays reach;
- ``collect_blocks``: the sums ``fusion_kernel.traverse_rays`` leaves, read out block by block
  (blocks of 8^3 voxels or more: whole kernel bricks);
- ``scatter_box``: flat C-order indices over a voxel box (what the fusion kernel returns) to
  entries grouped by block, by a counting sort (no comparison sort);
- ``find_slots``: the slots of block keys, by binary search of the sorted packed keys;
- ``global_index``: a block delta's entries to positions in the map's arrays, checked;
- ``take_touched`` / ``put_touched``: the per-voxel entropy cache's update of touched voxels,
  each voxel once, with per-block sums;
- ``gather``: the values of a lattice region, from the blocks that meet it;
- ``region_sums``: per-voxel values summed over the allocated voxels of a region.

Compiled with ``cache=True``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from swarm.map.ray_batch import BRICK_BITS
from swarm.map.voxel_information import voxel_lam

#: What ``take_touched`` writes into a voxel's cached entropy while it is being updated.
MARK = np.float32(-1.0)
#: ``global_index`` statuses.
OK, BAD_OFFSET, OUTSIDE_BOUNDS = 0, 1, 2


@njit(cache=True, nogil=True, error_model="numpy")
def collect_blocks(table, gains, sums, n_blocks, box, voxel, centre_offset, two_over_tau, bits):
    """The voxels ``fusion_kernel.traverse_rays`` touched, grouped by block of 2^bits (bits >= 3):
    (keys (K, 3) int64 in lexicographic order, counts (K,) int64, offsets (N,) uint16 in C order
    within each block, lam, eta (N,) float32), each voxel's lam as ``fuse_rays`` gives it.
    Restores the table and the pool as ``fuse_rays`` does."""
    bb = BRICK_BITS
    bm = (1 << bb) - 1
    m = (1 << bits) - 1
    per = 1 << (bits - bb)  # bricks along a block's edge
    b0 = box[0] >> bb  # the table's first brick
    nb1 = ((box[1, 1] - 1) >> bb) - b0[1] + 1
    nb2 = ((box[1, 2] - 1) >> bb) - b0[2] + 1
    c0 = box[0] >> bits  # the first block meeting the box, and how many along each axis
    nc1 = ((box[1, 1] - 1) >> bits) - c0[1] + 1
    nc2 = ((box[1, 2] - 1) >> bits) - c0[2] + 1
    nc0 = ((box[1, 0] - 1) >> bits) - c0[0] + 1
    marked = np.zeros(nc0 * nc1 * nc2, np.bool_)
    for t in range(table.shape[0]):
        if table[t] >= 0:
            bi, bj, bk = b0[0] + t // (nb1 * nb2), b0[1] + (t // nb2) % nb1, b0[2] + t % nb2
            marked[
                (((bi >> (bits - bb)) - c0[0]) * nc1 + (bj >> (bits - bb)) - c0[1]) * nc2
                + (bk >> (bits - bb))
                - c0[2]
            ] = True
    blocks = 0
    for c in range(marked.shape[0]):
        blocks += marked[c]
    keys = np.empty((blocks, 3), np.int64)
    counts = np.empty(blocks, np.int64)
    cap = n_blocks << (3 * bb)
    offsets = np.empty(cap, np.uint16)
    lam = np.empty(cap, np.float32)
    eta = np.empty(cap, np.float32)
    n = 0
    q_key = 0
    for c in range(marked.shape[0]):
        if not marked[c]:
            continue
        ci, cj, ck = c0[0] + c // (nc1 * nc2), c0[1] + (c // nc2) % nc1, c0[2] + c % nc2
        first = n
        for i in range(max(box[0, 0], ci << bits), min(box[1, 0], (ci + 1) << bits)):
            for j in range(max(box[0, 1], cj << bits), min(box[1, 1], (cj + 1) << bits)):
                row = (((i >> bb) - b0[0]) * nb1 + (j >> bb) - b0[1]) * nb2 - b0[2]
                for kb in range(ck * per, (ck + 1) * per):  # the block's bricks along k
                    if kb < b0[2] or kb >= b0[2] + nb2:
                        continue
                    pool = table[row + kb]
                    if pool < 0:
                        continue
                    base = (pool << (3 * bb)) | ((i & bm) << (2 * bb)) | ((j & bm) << bb)
                    for k in range(max(box[0, 2], kb << bb), min(box[1, 2], (kb + 1) << bb)):
                        q = base | (k & bm)
                        g = gains[q]
                        other = sums[q, 0]
                        if g == 0.0 and other == 0.0:
                            continue
                        offsets[n] = ((i & m) << (2 * bits)) | ((j & m) << bits) | (k & m)
                        lam[n] = voxel_lam(g, other, i, j, k, voxel, centre_offset, two_over_tau)
                        eta[n] = sums[q, 1]
                        n += 1
                        gains[q] = 0.0
                        sums[q, 0] = 0.0
                        sums[q, 1] = 0.0
        if n > first:
            keys[q_key, 0], keys[q_key, 1], keys[q_key, 2] = ci, cj, ck
            counts[q_key] = n - first
            q_key += 1
    for t in range(table.shape[0]):
        table[t] = -1
    return keys[:q_key], counts[:q_key], offsets[:n].copy(), lam[:n].copy(), eta[:n].copy()


@njit(cache=True, nogil=True, error_model="numpy")
def scatter_box(idx, lam, eta, box_lo, shape, bits):
    """Entries ``idx`` (flat C order over a box of ``shape`` whose first voxel is lattice voxel
    ``box_lo``), with ``lam``, ``eta``, grouped by block: (keys (K, 3) int64 in lexicographic
    order, counts (K,) int64, offsets (N,) uint16, lam, eta (N,) float32, ok). Within a block the
    entries keep their input order, so sorted ``idx`` gives sorted offsets. ``ok`` is False
    (and the rest empty) when an index lies outside the box."""
    n = idx.shape[0]
    size = shape[0] * shape[1] * shape[2]
    for e in range(n):
        if idx[e] < 0 or idx[e] >= size:
            empty = np.zeros(0, np.float32)
            return (
                np.zeros((0, 3), np.int64),
                np.zeros(0, np.int64),
                np.zeros(0, np.uint16),
                empty,
                empty,
                False,
            )
    nz = np.uint64(shape[2])
    ny = np.uint64(shape[1])
    m = (1 << bits) - 1
    b0 = box_lo >> bits
    nb1 = ((box_lo[1] + shape[1] - 1) >> bits) - b0[1] + 1
    nb2 = ((box_lo[2] + shape[2] - 1) >> bits) - b0[2] + 1
    nb0 = ((box_lo[0] + shape[0] - 1) >> bits) - b0[0] + 1
    first = np.zeros(nb0 * nb1 * nb2 + 1, np.int64)
    block = np.empty(n, np.int64)
    offsets = np.empty(n, np.uint16)
    row_start = np.uint64(1)  # the flat index of the current row's first voxel (none yet)
    row_end = np.uint64(0)
    i = j = np.int64(0)
    for e in range(n):
        t = np.uint64(idx[e])
        if t < row_start or t >= row_end:  # another row (i, j): sorted input divides once per row
            row = t // nz
            row_start = row * nz
            row_end = row_start + nz
            j = np.int64(row % ny) + box_lo[1]
            i = np.int64(row // ny) + box_lo[0]
        k = np.int64(t - row_start) + box_lo[2]
        b = (((i >> bits) - b0[0]) * nb1 + ((j >> bits) - b0[1])) * nb2 + ((k >> bits) - b0[2])
        block[e] = b
        offsets[e] = ((i & m) << (2 * bits)) | ((j & m) << bits) | (k & m)
        first[b + 1] += 1
    blocks = 0
    for b in range(nb0 * nb1 * nb2):
        if first[b + 1] > 0:
            blocks += 1
    keys = np.empty((blocks, 3), np.int64)
    counts = np.empty(blocks, np.int64)
    q = 0
    for b in range(nb0 * nb1 * nb2):
        c = first[b + 1]
        if c > 0:
            keys[q, 0] = b0[0] + b // (nb1 * nb2)
            keys[q, 1] = b0[1] + (b // nb2) % nb1
            keys[q, 2] = b0[2] + b % nb2
            counts[q] = c
            q += 1
        first[b + 1] += first[b]
    out_off = np.empty(n, np.uint16)
    out_lam = np.empty(n, np.float32)
    out_eta = np.empty(n, np.float32)
    for e in range(n):
        p = first[block[e]]
        first[block[e]] = p + 1
        out_off[p] = offsets[e]
        out_lam[p] = lam[e]
        out_eta[p] = eta[e]
    return keys, counts, out_off, out_lam, out_eta, True


@njit(cache=True, nogil=True, error_model="numpy")
def find_slots(keys, packed, slot_of, limit):
    """Slots (K,) int64 of block ``keys`` (K, 3) among the allocated blocks (``packed``: their
    packed keys, sorted, as ``lattice.pack_keys``; ``slot_of``: the slot of each), -1 for a key not
    allocated; and False when a key lies outside (-limit, limit)."""
    n = keys.shape[0]
    slots = np.full(n, -1, np.int64)
    for r in range(n):
        a, b, c = np.int64(keys[r, 0]), np.int64(keys[r, 1]), np.int64(keys[r, 2])
        if min(a, b, c) <= -limit or max(a, b, c) >= limit:
            return slots, False
        key = ((a + limit) << 42) | ((b + limit) << 21) | (c + limit)
        at = np.searchsorted(packed, key)
        if at < packed.shape[0] and packed[at] == key:
            slots[r] = slot_of[at]
    return slots, True


@njit(cache=True, nogil=True, error_model="numpy")
def ray_box(start, ends, limit):
    """Voxel box (2, 3) int64 (lo inclusive, hi exclusive) of the voxels holding ``start`` (3,) and
    ``ends`` (M, 3) (voxel units), one voxel wider on every side (the voxel behind a hit);
    coordinates clamped to +-``limit`` first."""
    lo0, lo1, lo2 = start[0], start[1], start[2]
    hi0, hi1, hi2 = lo0, lo1, lo2
    for r in range(ends.shape[0]):
        x, y, z = ends[r, 0], ends[r, 1], ends[r, 2]
        lo0, hi0 = min(lo0, x), max(hi0, x)
        lo1, hi1 = min(lo1, y), max(hi1, y)
        lo2, hi2 = min(lo2, z), max(hi2, z)
    box = np.empty((2, 3), np.int64)
    for a, (lo, hi) in enumerate(((lo0, hi0), (lo1, hi1), (lo2, hi2))):
        box[0, a] = np.int64(np.floor(min(max(lo, -limit), limit))) - 1
        box[1, a] = np.int64(np.floor(min(max(hi, -limit), limit))) + 2
    return box


@njit(cache=True, nogil=True, error_model="numpy")
def global_index(keys, counts, offsets, slots, bits, box, bounded):
    """Positions (N,) int64 in the map's arrays of a delta's entries (block n at ``slots[n]``),
    and a status: OK, BAD_OFFSET (an offset >= B^3), or with ``bounded`` OUTSIDE_BOUNDS (a
    voxel outside ``box`` (2, 3), lo inclusive, hi exclusive)."""
    bv = 1 << (3 * bits)
    m = (1 << bits) - 1
    out = np.empty(offsets.shape[0], np.int64)
    e = 0
    for n in range(keys.shape[0]):
        base = slots[n] * bv
        for _ in range(counts[n]):
            o = np.int64(offsets[e])
            if o >= bv:
                return out, BAD_OFFSET
            if bounded:
                i = (np.int64(keys[n, 0]) << bits) + ((o >> (2 * bits)) & m)
                j = (np.int64(keys[n, 1]) << bits) + ((o >> bits) & m)
                k = (np.int64(keys[n, 2]) << bits) + (o & m)
                if i < box[0, 0] or j < box[0, 1] or k < box[0, 2]:
                    return out, OUTSIDE_BOUNDS
                if i >= box[1, 0] or j >= box[1, 1] or k >= box[1, 2]:
                    return out, OUTSIDE_BOUNDS
            out[e] = base + o
            e += 1
    return out, OK


@njit(cache=True, nogil=True, error_model="numpy")
def take_touched(values, positions, sums, block_shift):
    """The distinct ``positions`` (first-seen order): each one's cached value is taken out of its
    block's sum (``sums[position >> block_shift]``) and marked (MARK) so a repeat is skipped."""
    out = np.empty(positions.shape[0], np.int64)
    u = 0
    for e in range(positions.shape[0]):
        q = positions[e]
        v = values[q]
        if v == MARK:
            continue
        sums[q >> block_shift] -= v
        values[q] = MARK
        out[u] = q
        u += 1
    return out[:u]


@njit(cache=True, nogil=True, error_model="numpy")
def put_touched(values, positions, new, sums, block_shift):
    """Store ``new`` values at ``positions`` and add them to their blocks' sums."""
    for e in range(positions.shape[0]):
        q = positions[e]
        values[q] = new[e]
        sums[q >> block_shift] += new[e]


@njit(cache=True, nogil=True, error_model="numpy")
def gather(values, keys, bits, region_lo, out):
    """Copy the per-voxel ``values`` of the blocks ``keys`` (K, 3) (block s at slot s) that meet
    the region of ``out.shape`` from lattice voxel ``region_lo`` into ``out`` (which holds the
    value of voxels in no block)."""
    b = 1 << bits
    for s in range(keys.shape[0]):
        lo0, lo1, lo2 = keys[s, 0] << bits, keys[s, 1] << bits, keys[s, 2] << bits
        ilo, ihi = max(lo0, region_lo[0]), min(lo0 + b, region_lo[0] + out.shape[0])
        jlo, jhi = max(lo1, region_lo[1]), min(lo1 + b, region_lo[1] + out.shape[1])
        klo, khi = max(lo2, region_lo[2]), min(lo2 + b, region_lo[2] + out.shape[2])
        if ilo >= ihi or jlo >= jhi or klo >= khi:
            continue
        base = s << (3 * bits)
        for i in range(ilo, ihi):
            for j in range(jlo, jhi):
                row = base + ((i - lo0) << (2 * bits)) + ((j - lo1) << bits) - lo2
                for k in range(klo, khi):
                    out[i - region_lo[0], j - region_lo[1], k - region_lo[2]] = values[row + k]


@njit(cache=True, nogil=True, error_model="numpy")
def region_sums(values, sums, keys, bits, region_lo, region_hi):
    """(sum of ``values`` over the allocated voxels inside the region, float64; how many there
    are): a block wholly inside adds its ``sums`` entry, one across the region's edge its voxels
    inside."""
    b = 1 << bits
    total = 0.0
    voxels = 0
    for s in range(keys.shape[0]):
        lo0, lo1, lo2 = keys[s, 0] << bits, keys[s, 1] << bits, keys[s, 2] << bits
        ilo, ihi = max(lo0, region_lo[0]), min(lo0 + b, region_hi[0])
        jlo, jhi = max(lo1, region_lo[1]), min(lo1 + b, region_hi[1])
        klo, khi = max(lo2, region_lo[2]), min(lo2 + b, region_hi[2])
        if ilo >= ihi or jlo >= jhi or klo >= khi:
            continue
        inside = (ihi - ilo) * (jhi - jlo) * (khi - klo)
        voxels += inside
        if inside == b * b * b:
            total += sums[s]
            continue
        base = s << (3 * bits)
        for i in range(ilo, ihi):
            for j in range(jlo, jhi):
                row = base + ((i - lo0) << (2 * bits)) + ((j - lo1) << bits) - lo2
                for k in range(klo, khi):
                    total += values[row + k]
    return total, voxels
