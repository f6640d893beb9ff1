"""Compiled (Numba) loops behind the traversability grid and the planner's graph.

Each function computes exactly what a few numpy/scipy calls computed before (same float
operations in the same order, so the same answers); the numpy versions are kept in
``tests/support/navigation_oracle.py`` and the tests compare the two. They exist because on the
agent's grids (about 160 x 100 cells) the per-call overheads of those numpy calls, not the
arithmetic, took most of a planning step. Compiled with ``cache=True``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Below this sigma (after E[C]'s clamp) a belief with mean mu has |E[C] - clip(mu, 0, 1)|
#: <= CERTAIN_BOUND * sigma: for mu in [0, 1], E[C] = mu + sigma (phi(a) - phi(b)) / Z with
#: a = -mu / sigma, b = (1 - mu) / sigma, |phi(a) - phi(b)| <= phi(0) and, as b - a >= 20,
#: Z = Phi(b) - Phi(a) >= Phi(10) - 1/2; so the bound phi(0) / (Phi(10) - 1/2) = 0.7979 < 0.8.
#: Outside [0, 1], E[C] is monotone in mu, so the bound at the nearest end holds.
CERTAIN_SIGMA = 0.05
CERTAIN_BOUND = 0.8
#: Margin for E[C]'s rounding (its absolute error is about 1e-13).
CERTAIN_MARGIN = 1e-6


@njit(cache=True, nogil=True)
def band_occupancy(lam, eta, shape, k0, k1, lam_known, threshold, sigma_min, sigma_max):
    """The band of layers [k0, k1) of a map, per column: unknown, and occupied where sure.

    ``lam``, ``eta`` flat C-order float32 (nx * ny * nz); a voxel is known when its lam
    exceeds ``lam_known`` (float32), occupied when known and E[C] >= ``threshold``. Returns
    ``unknown`` (nx * ny,) bool: a band voxel of the column is not known; ``occupied``
    (nx * ny,) bool: a band voxel is surely occupied (the bound of ``CERTAIN_BOUND``); and
    the known voxels the bound leaves undecided: ``mu`` (K,) = eta / lam, ``sigma`` (K,) =
    1 / sqrt(lam) (float64), ``column`` (K,) their flat column i * ny + j, whose E[C] the
    caller computes. ``sigma_min``, ``sigma_max``: E[C]'s clamp of sigma.
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    unknown = np.zeros(nx * ny, np.bool_)
    occupied = np.zeros(nx * ny, np.bool_)
    size = nx * ny * (k1 - k0)
    mu = np.empty(size)
    sigma = np.empty(size)
    column = np.empty(size, np.int64)
    n = 0
    for c in range(nx * ny):
        base = c * nz
        for k in range(k0, k1):
            lv = lam[base + k]
            if not lv > lam_known:
                unknown[c] = True
                continue
            if occupied[c]:
                continue  # the column's answer is known; the voxel cannot change it
            lv64 = np.float64(lv)
            m = np.float64(eta[base + k]) / lv64
            sg = 1.0 / math.sqrt(lv64)
            s = min(max(sg, sigma_min), sigma_max)
            if s <= CERTAIN_SIGMA and math.isfinite(m):  # (E[C] of a non-finite mean is NaN)
                slack = CERTAIN_BOUND * s + CERTAIN_MARGIN
                if max(m, 0.0) + slack < threshold:
                    continue  # surely E[C] < threshold
                if min(m, 1.0) - slack >= threshold:
                    occupied[c] = True
                    continue
            mu[n] = m
            sigma[n] = sg
            column[n] = c
            n += 1
    return unknown, occupied, mu[:n], sigma[:n], column[:n]


@njit(cache=True, nogil=True)
def inflate_blocked(blocked, threshold):
    """Navigable mask (nx, ny) bool: cells whose centre is farther than ``threshold`` (cells)
    from the centre of every blocked cell and of every cell of the ring just outside the grid.

    A blocked cell at offset (di, dj) counts when sqrt(di^2 + dj^2) <= threshold, as the
    Euclidean distance transform's distance compared with the threshold; row di of that
    disc is |dj| <= width[di]. Few blocked cells stamp their disc; many are found per cell
    and disc row with prefix counts (the work is then nx * ny times the disc's rows).
    """
    nx, ny = blocked.shape
    reach = int(math.floor(threshold))
    width = np.full(2 * reach + 1, -1, np.int64)  # per row offset di: the largest |dj| in the disc
    for di in range(-reach, reach + 1):
        dj = 0
        while math.sqrt(np.float64(di * di + dj * dj)) <= threshold:
            width[di + reach] = dj
            dj += 1
    free = np.ones((nx, ny), np.bool_)
    # The ring outside the grid: its nearest cell to (i, j) lies straight along an axis.
    for i in range(nx):
        for j in range(ny):
            edge = min(i + 1, nx - i, j + 1, ny - j)
            if math.sqrt(np.float64(edge * edge)) <= threshold:
                free[i, j] = False
    count = 0
    for i in range(nx):
        for j in range(ny):
            count += blocked[i, j]
    if count * (2 * reach + 1) <= nx * ny:
        for bi in range(nx):
            for bj in range(ny):
                if not blocked[bi, bj]:
                    continue
                for di in range(-reach, reach + 1):
                    i = bi + di
                    w = width[di + reach]
                    if i < 0 or i >= nx or w < 0:
                        continue
                    for j in range(max(bj - w, 0), min(bj + w, ny - 1) + 1):
                        free[i, j] = False
        return free
    prefix = np.zeros((nx, ny + 1), np.int64)  # prefix[i, j]: blocked cells of row i before column j
    for i in range(nx):
        for j in range(ny):
            prefix[i, j + 1] = prefix[i, j] + blocked[i, j]
    for i in range(nx):
        for j in range(ny):
            if not free[i, j]:
                continue
            for di in range(-reach, reach + 1):
                ii = i + di
                w = width[di + reach]
                if ii < 0 or ii >= nx or w < 0:
                    continue
                if prefix[ii, min(j + w, ny - 1) + 1] > prefix[ii, max(j - w, 0)]:
                    free[i, j] = False
                    break
    return free


@njit(cache=True, nogil=True)
def disc_cells(xy, origin_x, origin_y, res, nx, ny, r):
    """Cells (nx, ny) bool whose centre lies within ``r`` of any finite point of ``xy`` (M, 2), metres."""
    out = np.zeros((nx, ny), np.bool_)
    reach = int(math.ceil(r / res)) + 1
    rr = r * r
    for m in range(xy.shape[0]):
        px, py = xy[m, 0], xy[m, 1]
        if not (math.isfinite(px) and math.isfinite(py)):
            continue  # a non-finite position clears nothing
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


@njit(cache=True, nogil=True)
def disc_count(counts, px, py, origin_x, origin_y, res, r, step):
    """Add ``step`` to ``counts`` (nx, ny) int64 on the cells ``disc_cells`` gives for the one
    point (px, py) (same arithmetic, so the same cells; nothing for a non-finite point):
    a count of discs per cell, kept as points come and go."""
    nx, ny = counts.shape
    if not (math.isfinite(px) and math.isfinite(py)):
        return
    reach = int(math.ceil(r / res)) + 1
    rr = r * r
    ci = int(math.floor((px - origin_x) / res))
    cj = int(math.floor((py - origin_y) / res))
    for i in range(max(ci - reach, 0), min(ci + reach + 1, nx)):
        cx = origin_x + (i + 0.5) * res - px
        for j in range(max(cj - reach, 0), min(cj + reach + 1, ny)):
            cy = origin_y + (j + 0.5) * res - py
            if cx * cx + cy * cy <= rr:
                counts[i, j] += step


@njit(cache=True, nogil=True)
def grid_graph(free, node_of, diagonal):
    """The planner's graph, both directions, as CSR arrays (indptr, indices int32; weights float64).

    Node n is the n-th free cell in C order (``node_of`` (nx * ny,) int64, -1 where not free).
    Moves: the 4 orthogonal neighbours at cost 1, the 4 diagonal ones at cost ``diagonal``
    when both cells they pass between are free. Each row lists first the neighbours after
    the node (increasing), then those before it (increasing): the order in which scipy's
    undirected Dijkstra scans a graph of forward edges and then its transpose, so a directed
    Dijkstra on this graph relaxes the same edges in the same order.
    """
    nx, ny = free.shape
    nodes = 0
    for i in range(nx):
        for j in range(ny):
            nodes += free[i, j]
    indptr = np.zeros(nodes + 1, np.int32)
    indices = np.empty(8 * nodes, np.int32)
    weights = np.empty(8 * nodes)
    n = 0
    e = 0
    for i in range(nx):
        for j in range(ny):
            if not free[i, j]:
                continue
            left = j >= 1 and free[i, j - 1]
            right = j + 1 < ny and free[i, j + 1]
            # after the node: (i, j+1), (i+1, j-1), (i+1, j), (i+1, j+1)
            if right:
                indices[e] = node_of[i * ny + j + 1]
                weights[e] = 1.0
                e += 1
            if i + 1 < nx and free[i + 1, j]:
                if left and free[i + 1, j - 1]:
                    indices[e] = node_of[(i + 1) * ny + j - 1]
                    weights[e] = diagonal
                    e += 1
                indices[e] = node_of[(i + 1) * ny + j]
                weights[e] = 1.0
                e += 1
                if right and free[i + 1, j + 1]:
                    indices[e] = node_of[(i + 1) * ny + j + 1]
                    weights[e] = diagonal
                    e += 1
            # before the node: (i-1, j-1), (i-1, j), (i-1, j+1), (i, j-1)
            if i >= 1 and free[i - 1, j]:
                if left and free[i - 1, j - 1]:
                    indices[e] = node_of[(i - 1) * ny + j - 1]
                    weights[e] = diagonal
                    e += 1
                indices[e] = node_of[(i - 1) * ny + j]
                weights[e] = 1.0
                e += 1
                if right and free[i - 1, j + 1]:
                    indices[e] = node_of[(i - 1) * ny + j + 1]
                    weights[e] = diagonal
                    e += 1
            if left:
                indices[e] = node_of[i * ny + j - 1]
                weights[e] = 1.0
                e += 1
            n += 1
            indptr[n] = e
    return indptr, indices[:e], weights[:e]


@njit(cache=True, nogil=True)
def segment_is_free(free, ax, ay, bx, by):
    """True if every cell the segment a -> b (cell units from the grid's origin) passes through
    is inside ``free`` (nx, ny) and free: the cells of ``TraversabilityGrid.segment_cells``
    (the cell of each stretch between line crossings, the four cells around a crossed
    corner, the cells of both ends), checked without building the set.
    """
    nx, ny = free.shape
    if not (math.isfinite(ax) and math.isfinite(ay) and math.isfinite(bx) and math.isfinite(by)):
        return False  # no cell holds a non-finite point
    dx = bx - ax
    dy = by - ay
    # The parameters t in [0, 1] where the segment crosses a grid line, with 0 and 1.
    count = 2
    for a, b, d in ((ax, bx, dx), (ay, by, dy)):
        if d != 0:
            lo, hi = min(a, b), max(a, b)
            count += max(int(math.floor(hi) - math.ceil(lo)) + 1, 0)
    ts = np.empty(count)
    ts[0] = 0.0
    ts[1] = 1.0
    n = 2
    for a, b, d in ((ax, bx, dx), (ay, by, dy)):
        if d != 0:
            lo, hi = min(a, b), max(a, b)
            line = math.ceil(lo)
            while line <= math.floor(hi):
                ts[n] = min(max((line - a) / d, 0.0), 1.0)
                n += 1
                line += 1.0
    ts = np.unique(ts[:n])
    cells = np.empty((len(ts) + 1 + 4 * len(ts) + 2, 2), np.int64)
    c = 0
    for m in range(len(ts) - 1):
        mid = 0.5 * (ts[m] + ts[m + 1])
        cells[c, 0] = int(math.floor(ax + mid * dx))
        cells[c, 1] = int(math.floor(ay + mid * dy))
        c += 1
    eps = 1e-9
    for m in range(len(ts)):
        px = ax + ts[m] * dx
        py = ay + ts[m] * dy
        if abs(px - round(px)) < eps and abs(py - round(py)) < eps:
            for sx in (-2 * eps, 2 * eps):
                for sy in (-2 * eps, 2 * eps):
                    cells[c, 0] = int(math.floor(px + sx))
                    cells[c, 1] = int(math.floor(py + sy))
                    c += 1
    cells[c, 0], cells[c, 1] = int(math.floor(ax)), int(math.floor(ay))
    cells[c + 1, 0], cells[c + 1, 1] = int(math.floor(bx)), int(math.floor(by))
    c += 2
    for m in range(c):
        i, j = cells[m, 0], cells[m, 1]
        if i < 0 or j < 0 or i >= nx or j >= ny or not free[i, j]:
            return False
    return True


@njit(cache=True, nogil=True)
def _sift_up(keys, cells, pos, k):
    while k > 0:
        parent = (k - 1) // 2
        if keys[parent] <= keys[k]:
            break
        keys[parent], keys[k] = keys[k], keys[parent]
        cells[parent], cells[k] = cells[k], cells[parent]
        pos[cells[k]] = k
        pos[cells[parent]] = parent
        k = parent


@njit(cache=True, nogil=True)
def _sift_down(keys, cells, pos, k, n):
    while True:
        small = k
        left, right = 2 * k + 1, 2 * k + 2
        if left < n and keys[left] < keys[small]:
            small = left
        if right < n and keys[right] < keys[small]:
            small = right
        if small == k:
            break
        keys[small], keys[k] = keys[k], keys[small]
        cells[small], cells[k] = cells[k], cells[small]
        pos[cells[k]] = k
        pos[cells[small]] = small
        k = small


@njit(cache=True, nogil=True)
def grid_distances(free, si, sj, diagonal):
    """Path lengths (cells, float64 (nx, ny); inf: not reached) from cell (si, sj) over the
    planner's graph (``grid_graph``'s moves) without building it: Dijkstra with an indexed
    binary heap (each cell in it at most once, its key lowered in place).

    A shortest distance is the least left-to-right float sum of move costs over the paths to
    a cell whatever order the edges are relaxed in (float addition is monotone), so it equals
    scipy's on ``grid_graph`` bit for bit. All inf when the start is outside or not free.
    """
    nx, ny = free.shape
    dist = np.full((nx, ny), np.inf)
    if not (0 <= si < nx and 0 <= sj < ny) or not free[si, sj]:
        return dist
    flat = dist.ravel()
    pos = np.full(nx * ny, -1, np.int64)  # place in the heap; -2: settled
    keys = np.empty(nx * ny)
    cells = np.empty(nx * ny, np.int64)
    n = 1
    keys[0], cells[0], pos[si * ny + sj] = 0.0, si * ny + sj, 0
    flat[si * ny + sj] = 0.0
    while n > 0:
        c, d = cells[0], keys[0]
        pos[c] = -2
        n -= 1
        if n > 0:
            keys[0], cells[0] = keys[n], cells[n]
            pos[cells[0]] = 0
            _sift_down(keys, cells, pos, 0, n)
        i, j = c // ny, c % ny
        for di in range(-1, 2):
            ni = i + di
            if ni < 0 or ni >= nx:
                continue
            for dj in range(-1, 2):
                nj = j + dj
                if (di == 0 and dj == 0) or nj < 0 or nj >= ny or not free[ni, nj]:
                    continue
                m = ni * ny + nj
                if pos[m] == -2:
                    continue
                if di != 0 and dj != 0:
                    if not (free[ni, j] and free[i, nj]):
                        continue  # no corner cutting
                    nd = d + diagonal
                else:
                    nd = d + 1.0
                if nd < flat[m]:
                    flat[m] = nd
                    if pos[m] < 0:
                        pos[m] = n
                        keys[n], cells[n] = nd, m
                        n += 1
                    else:
                        keys[pos[m]] = nd
                    _sift_up(keys, cells, pos, pos[m])
    return dist
