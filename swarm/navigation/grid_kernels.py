"""Compiled (Numba) loops behind the traversability grid and the planner's graph.

Each function computes exactly what a few numpy/scipy calls computed before (same float
operations in the same order, so the same answers); the numpy versions are kept in
``tests/navigation_oracle.py`` and the tests compare the two. They exist because on the
agent's grids (about 160 x 100 cells) the per-call overheads of those numpy calls, not the
arithmetic, took most of a planning step. Compiled with ``cache=True``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def band_beliefs(lam, eta, shape, k0, k1, lam_known):
    """The known voxels of the band of layers [k0, k1) of a map: their beliefs and columns.

    ``lam``, ``eta`` flat C-order float32 (nx * ny * nz); a voxel is known when its lam
    exceeds ``lam_known`` (float32). Returns ``unknown`` (nx * ny,) bool: a band voxel of the
    column is not known; ``mu`` (K,) = eta / lam and ``sigma`` (K,) = 1 / sqrt(lam) in float64
    of the K known band voxels; ``column`` (K,) their flat column index i * ny + j.
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    unknown = np.zeros(nx * ny, np.bool_)
    size = nx * ny * (k1 - k0)
    mu = np.empty(size)
    sigma = np.empty(size)
    column = np.empty(size, np.int64)
    n = 0
    for c in range(nx * ny):
        base = c * nz
        for k in range(k0, k1):
            lv = lam[base + k]
            if lv > lam_known:
                lv64 = np.float64(lv)
                mu[n] = np.float64(eta[base + k]) / lv64
                sigma[n] = 1.0 / math.sqrt(lv64)
                column[n] = c
                n += 1
            else:
                unknown[c] = True
    return unknown, mu[:n], sigma[:n], column[:n]


@njit(cache=True, nogil=True)
def inflate_blocked(blocked, threshold):
    """Navigable mask (nx, ny) bool: cells whose centre is farther than ``threshold`` (cells)
    from the centre of every blocked cell and of every cell of the ring just outside the grid.

    The test per blocked cell at offset (di, dj) is sqrt(di^2 + dj^2) <= threshold, as the
    Euclidean distance transform's distance compared with the threshold.
    """
    nx, ny = blocked.shape
    reach = int(math.floor(threshold))
    free = np.ones((nx, ny), np.bool_)
    # The ring outside the grid: its nearest cell to (i, j) lies straight along an axis.
    for i in range(nx):
        for j in range(ny):
            edge = min(i + 1, nx - i, j + 1, ny - j)
            if math.sqrt(np.float64(edge * edge)) <= threshold:
                free[i, j] = False
    for bi in range(nx):
        for bj in range(ny):
            if not blocked[bi, bj]:
                continue
            for di in range(-reach, reach + 1):
                i = bi + di
                if i < 0 or i >= nx:
                    continue
                for dj in range(-reach, reach + 1):
                    j = bj + dj
                    if j < 0 or j >= ny:
                        continue
                    if math.sqrt(np.float64(di * di + dj * dj)) <= threshold:
                        free[i, j] = False
    return free


@njit(cache=True, nogil=True)
def disc_cells(xy, origin_x, origin_y, res, nx, ny, r):
    """Cells (nx, ny) bool whose centre lies within ``r`` of any point of ``xy`` (M, 2), world metres."""
    out = np.zeros((nx, ny), np.bool_)
    reach = int(math.ceil(r / res)) + 1
    rr = r * r
    for m in range(xy.shape[0]):
        px, py = xy[m, 0], xy[m, 1]
        ci = int(math.floor((px - origin_x) / res))
        cj = int(math.floor((py - origin_y) / res))
        i0, i1 = max(ci - reach, 0), min(ci + reach + 1, nx)
        j0, j1 = max(cj - reach, 0), min(cj + reach + 1, ny)
        for i in range(i0, i1):
            cx = origin_x + (i + 0.5) * res - px
            for j in range(j0, j1):
                cy = origin_y + (j + 0.5) * res - py
                if cx * cx + cy * cy <= rr:
                    out[i, j] = True
    return out
