"""Compiled fusion of one batch (Numba): one ray at a time, straight into per-voxel sums.

``fuse_rays`` is the kernel behind ``swarm.map.fusion.batch_information`` (after
``swarm.map.ray_batch`` has prepared the rays): exact Amanatides-Woo traversal of each ray
(the semantics of ``swarm.map.traversal``, whose numpy implementation the tests use as the
oracle), the sensor model of eq. 14 per voxel, and the sums of lam and eta per voxel, with
hit precedence.

- Per-voxel sums live in compact arrays in first-touch order; the brick-ordered slot map
  of ``swarm.map.ray_batch`` finds a voxel's entry and is restored to -1 before returning,
  so one map serves every batch on the same grid. Nothing allocates per (ray, voxel).
- A voxel's distance r to the sensor and its damping factor exp(-2 r / tau) are computed
  once, when the batch first touches it: in front of a ray's end eq. 14's lam is the ray's
  factor times the voxel's, so a voxel update costs no square root and no exp.
- Only the axis that steps gets its next plane parameter (one division per step).

Compiled with ``cache=True``: a second process loads the machine code from Numba's cache.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarm.map.ray_batch import BRICK_BITS
from swarm.map.ray_batch import brick_index as _brick

#: Upper bound of one measurement's information lam = 1/sigma^2 on one voxel (sigma >= 1e-12).
#: Eq. 14's damping makes lam grow as exp(2 (d - d_l) / tau), which overflows float32 for rays
#: longer than about 85 m (tau = 2 m); the bound keeps any finite input finite.
LAM_MAX = 1e24


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _slot(b, i, j, k, geometry, store, n_touched):
    """The compact entry of voxel (i, j, k) at slot-map position ``b``, created if new.

    ``geometry`` = (ny, nz, voxel, centre_offset, 2 / tau); ``store`` = (slots, touched,
    rec, is_hit). A new entry holds zero sums, the distance r from the sensor to the voxel's
    centre (float32, as eq. 14 is evaluated) and its damping factor exp(-2 r / tau) (0 when
    it would underflow). Returns (slot, new count).
    """
    ny, nz, voxel, centre_offset, two_over_tau = geometry
    slots, touched, rec, is_hit = store
    s = slots[b]
    if s < 0:
        s = n_touched
        slots[b] = s
        touched[s] = (i * ny + j) * nz + k
        ox = i * voxel + centre_offset[0]
        oy = j * voxel + centre_offset[1]
        oz = k * voxel + centre_offset[2]
        r = np.float32(math.sqrt(np.float32(ox * ox + oy * oy + oz * oz)))
        rec[s, 0] = 0.0
        rec[s, 1] = 0.0
        rec[s, 2] = r
        arg = two_over_tau * np.float64(r)
        rec[s, 3] = math.exp(-arg) if arg < EXP_LIMIT else 0.0
        is_hit[s] = False
        n_touched += 1
    return s, n_touched


@njit(cache=True, nogil=True, error_model="numpy")
def entries_bound(start, ends, shape):
    """At most how many voxels ``fuse_rays`` touches: each ray's voxels (its L1 length in voxel
    steps, plus one) and the voxel behind its end, and never more than the grid's size."""
    i0 = int(math.floor(start[0]))
    j0 = int(math.floor(start[1]))
    k0 = int(math.floor(start[2]))
    bound = 0
    for r in range(ends.shape[0]):
        bound += 2
        bound += abs(int(math.floor(ends[r, 0])) - i0)
        bound += abs(int(math.floor(ends[r, 1])) - j0)
        bound += abs(int(math.floor(ends[r, 2])) - k0)
    return min(bound, shape[0] * shape[1] * shape[2])


#: exp() arguments up to this stay far from float64's overflow and underflow.
EXP_LIMIT = 600.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _information(diff, half32, two_over_tau32, inv_s2, gain, w):
    """Eq. 14's lam of one voxel at float32 offset ``diff`` = r - d from the ray's end.

    Inside the end voxel's half width lam = 1 / sigma_s^2; in front of it
    lam = exp(2 (d - e/2 - r) / tau) / sigma_s^2, computed as ``gain * w`` with the ray's
    gain = exp(2 (d - e/2) / tau) / sigma_s^2 and the voxel's w = exp(-2 r / tau) when both
    are finite and non-zero (one exp per voxel and per ray, not per update); otherwise, and
    behind the end, from eq. 14 directly. Bounded by LAM_MAX.
    """
    ad = abs(diff)
    if ad <= half32:
        lam = inv_s2
    elif diff < 0 and gain > 0.0 and w > 0.0:
        lam = gain * w
    else:
        lam = np.float64(math.exp((ad - half32) * two_over_tau32)) * inv_s2
    return min(lam, LAM_MAX)


@njit(cache=True, nogil=True, error_model="numpy")
def fuse_rays(
    start,
    ends,
    d,
    returned,
    weight,
    shape,
    voxel,
    centre_offset,
    sigma_min,
    zeta,
    tau,
    precedence,
    slots,
    buffers,
):
    """Sum eq. 14's information over every ray's voxels: (idx sorted uint32, lam, eta float32, updates).

    ``start`` (3,) and ``ends`` (M, 3) in voxel units (inside the grid), ``d`` (M,) the model's
    range in metres, ``returned`` (M,) bool: a ray with a return updates its hit voxel and
    the voxel behind it (eq. 8); one without updates free space (mean 0). ``weight`` (M,):
    a ray's information is eq. 14's lam times its weight (1 for one measurement; the number
    of rays a weighted discretize measurement stands for), bounded by ``LAM_MAX``. ``centre_offset``
    (3,) = grid lo - sensor + voxel / 2 (metres). With ``precedence`` a voxel holding a
    return of the batch gets no update from the batch's other rays except as their
    behind voxel. ``slots`` (grid size, int32, all -1) is restored before returning.
    ``buffers`` = (touched int64, records (n, 4) float64, is_hit bool), each of at least
    ``entries_bound`` entries: scratch space, kept between batches by the caller.
    """
    m = ends.shape[0]
    nx, ny, nz = shape[0], shape[1], shape[2]
    size = nx * ny * nz
    nbj = (ny + 7) >> BRICK_BITS
    nbk = (nz + 7) >> BRICK_BITS
    i0 = int(math.floor(start[0]))
    j0 = int(math.floor(start[1]))
    k0 = int(math.floor(start[2]))
    touched, rec, is_hit = buffers
    # One record per entry (32 bytes, so one cache line at most): sums of lam and eta, the
    # distance r from the sensor to the voxel centre, and exp(-2 r / tau).
    n_touched = 0
    two_over_tau = 2.0 / tau
    geometry = (ny, nz, voxel, centre_offset, two_over_tau)
    store = (slots, touched, rec, is_hit)
    if precedence:
        for r in range(m):
            if returned[r]:
                i = int(math.floor(ends[r, 0]))
                j = int(math.floor(ends[r, 1]))
                k = int(math.floor(ends[r, 2]))
                s, n_touched = _slot(_brick(i, j, k, nbj, nbk), i, j, k, geometry, store, n_touched)
                is_hit[s] = True

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
        i, j, k = i0, j0, k0
        while True:
            last = ni == 0 and nj == 0 and nk == 0
            b = _brick(i, j, k, nbj, nbk)
            s = slots[b]
            if s < 0:
                s, n_touched = _slot(b, i, j, k, geometry, store, n_touched)
            if not (precedence and is_hit[s] and not (hit and last)):
                diff = np.float32(rec[s, 2]) - dr32
                lam = _information(diff, half32, two_over_tau32, inv_s2, gain, rec[s, 3])
                rec[s, 0] += lam
                if hit:
                    mu = min(max(np.float32(0.5) + diff * inv_voxel, np.float32(0.0)), np.float32(1.0))
                    rec[s, 1] += mu * lam
                updates += 1
            if last:
                break
            # Step every axis whose next plane comes first (two or three at an edge or corner);
            # only a stepped axis's next plane parameter is recomputed, exactly as t = (p - s) / d.
            t = min(ti, tj, tk)
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
        if bi < 0 or bj < 0 or bk < 0 or bi >= nx or bj >= ny or bk >= nz:
            continue
        s, n_touched = _slot(_brick(bi, bj, bk, nbj, nbk), bi, bj, bk, geometry, store, n_touched)
        diff = np.float32(rec[s, 2]) - dr32
        lam = _information(diff, half32, two_over_tau32, inv_s2, gain, rec[s, 3])
        mu = min(max(np.float32(0.5) + diff * inv_voxel, np.float32(0.0)), np.float32(1.0))
        rec[s, 0] += lam
        rec[s, 1] += mu * lam
        updates += 1

    # Sorted output: scan the grid when the batch touched much of it, else sort.
    idx = np.empty(n_touched, np.uint32)
    lam_out = np.empty(n_touched, np.float32)
    eta_out = np.empty(n_touched, np.float32)
    if n_touched * 16 > size:
        n = 0
        for i in range(nx):
            for j in range(ny):
                for k in range(nz):
                    b = _brick(i, j, k, nbj, nbk)
                    s = slots[b]
                    if s >= 0:
                        idx[n] = (i * ny + j) * nz + k
                        lam_out[n] = rec[s, 0]
                        eta_out[n] = rec[s, 1]
                        slots[b] = -1
                        n += 1
    else:
        order = np.sort(touched[:n_touched])
        for n in range(n_touched):
            v = order[n]
            k = v % nz
            j = (v // nz) % ny
            i = v // (ny * nz)
            b = _brick(i, j, k, nbj, nbk)
            s = slots[b]
            idx[n] = v
            lam_out[n] = rec[s, 0]
            eta_out[n] = rec[s, 1]
            slots[b] = -1
    return idx, lam_out, eta_out, updates
