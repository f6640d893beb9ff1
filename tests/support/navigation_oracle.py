"""The numpy/scipy traversability grid and planner graph: the oracles of the compiled versions.

This was the project's code before ``swarm.navigation.grid_kernels``: a Euclidean distance
transform for the robot's inflation, numpy masks for the band's beliefs, one disc per swept
position and the planner's graph as a COO matrix. The tests compare the fast versions with
these, which are slower on the agent's grids because of per-call overheads, not arithmetic.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import dijkstra

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.navigation.traversability import TraversabilityGrid, band_layers


def reference_inflate(blocked: np.ndarray, resolution: float, radius: float) -> np.ndarray:
    """``traversability.inflate`` by the distance transform (outside the grid blocked)."""
    blocked = np.asarray(blocked, dtype=bool)
    padded = np.pad(blocked, 1, constant_values=True)
    cells = ndimage.distance_transform_edt(~padded)[1:-1, 1:-1]
    return cells > radius / resolution + 0.5 + 1e-9  # ties count as blocked


def reference_build_traversability(
    cmap: CoverageMap,
    floor_clearance: float = 0.1,
    robot_height: float = 0.5,
    robot_radius: float = 0.18,
    free_threshold: float = 0.2,
    margin: float = 0.0,
    swept: np.ndarray | None = None,
) -> TraversabilityGrid:
    """``traversability.build_traversability`` with numpy masks over the band's layers."""
    grid = cmap.grid
    nx, ny, nz = grid.shape
    layers = band_layers(cmap, floor_clearance, robot_height)
    lam = cmap.lam.reshape(nx, ny, nz)[:, :, layers]
    eta = cmap.eta.reshape(nx, ny, nz)[:, :, layers]
    known = cmap.known_mask().reshape(nx, ny, nz)[:, :, layers]
    unknown = ~known.all(axis=2)
    occ = np.zeros(known.shape, dtype=bool)
    mu = eta[known].astype(np.float64) / lam[known]
    sigma = 1.0 / np.sqrt(lam[known].astype(np.float64))
    occ[known] = expected_coverage(mu, sigma) >= free_threshold
    occupied = occ.any(axis=2)
    origin = (float(grid.lo[0]), float(grid.lo[1]))
    if swept is not None and len(swept):
        unknown &= ~_discs(np.asarray(swept, dtype=np.float64), origin, grid.voxel, (nx, ny), robot_radius)
    free = reference_inflate(occupied, grid.voxel, robot_radius + margin) & ~unknown
    return TraversabilityGrid(free, occupied, unknown, origin, grid.voxel, robot_radius)


def _discs(
    xy: np.ndarray, origin: tuple[float, float], res: float, shape: tuple[int, int], r: float
) -> np.ndarray:
    """Cells whose centre lies within r of any of the points xy (M, 2)."""
    out = np.zeros(shape, dtype=bool)
    reach = int(np.ceil(r / res)) + 1
    for px, py in np.unique(xy[:, :2], axis=0):
        ci, cj = int(np.floor((px - origin[0]) / res)), int(np.floor((py - origin[1]) / res))
        i0, i1 = max(ci - reach, 0), min(ci + reach + 1, shape[0])
        j0, j1 = max(cj - reach, 0), min(cj + reach + 1, shape[1])
        if i0 >= i1 or j0 >= j1:
            continue
        cx = origin[0] + (np.arange(i0, i1) + 0.5) * res - px
        cy = origin[1] + (np.arange(j0, j1) + 0.5) * res - py
        out[i0:i1, j0:j1] |= cx[:, None] ** 2 + cy[None, :] ** 2 <= r * r
    return out


def reference_graph(free: np.ndarray) -> csr_matrix:
    """``GridPlanner``'s graph of a bool grid, edge lists as numpy masks, assembled as COO."""
    f = np.asarray(free, dtype=bool)
    nx, ny = f.shape
    node_of = np.full(f.size, -1, dtype=np.int64)
    cell_of = np.flatnonzero(f.ravel())
    node_of[cell_of] = np.arange(cell_of.size)
    idx = np.arange(nx * ny).reshape(nx, ny)
    rows, cols, weights = [], [], []

    def add(a: np.ndarray, b: np.ndarray, ok: np.ndarray, w: float) -> None:
        rows.append(node_of[a[ok]])
        cols.append(node_of[b[ok]])
        weights.append(np.full(int(ok.sum()), w))

    add(idx[:-1, :], idx[1:, :], f[:-1, :] & f[1:, :], 1.0)
    add(idx[:, :-1], idx[:, 1:], f[:, :-1] & f[:, 1:], 1.0)
    d = math.sqrt(2.0)
    add(idx[:-1, :-1], idx[1:, 1:], f[:-1, :-1] & f[1:, 1:] & f[1:, :-1] & f[:-1, 1:], d)
    add(idx[:-1, 1:], idx[1:, :-1], f[:-1, 1:] & f[1:, :-1] & f[:-1, :-1] & f[1:, 1:], d)
    n = cell_of.size
    return coo_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    ).tocsr()


def reference_tree(free: np.ndarray, node: int) -> tuple[np.ndarray, np.ndarray]:
    """Dijkstra on ``reference_graph``: (distance in cells, predecessor) of every node from ``node``."""
    return dijkstra(reference_graph(free), directed=False, indices=node, return_predecessors=True)


def reference_clear(opaque: np.ndarray, a: int, b: int, i: int, j: int) -> bool:
    """``view_kernels.clear_line`` with numpy: no opaque cell on the segment (a, b) -> (i, j)."""
    steps = max(abs(i - a), abs(j - b)) * 2 + 1
    t = np.arange(1, steps) / steps
    si = np.rint(a + t * (i - a)).astype(np.int64)
    sj = np.rint(b + t * (j - b)).astype(np.int64)
    blocked = opaque[si, sj] & ~((si == i) & (sj == j))
    return not blocked.any()


def reference_stand_for(
    usable, avoid, cost, start, cx, cy, opaque, i, j, d_lo, d_hi, half_width
) -> tuple[int, int] | None:
    """``view_kernels.stand_for`` with numpy masks, a stable argsort and the 64 cheapest cells."""
    nx, ny = usable.shape
    i0, i1, j0, j1 = (
        max(i - half_width, 0),
        min(i + half_width + 1, nx),
        max(j - half_width, 0),
        min(j + half_width + 1, ny),
    )
    pool = usable[i0:i1, j0:j1] & ~avoid[i0:i1, j0:j1]
    ii, jj = np.nonzero(pool)
    if ii.size == 0:
        return None
    ii, jj = ii + i0, jj + j0
    d = np.hypot(cx[ii] - cx[i], cy[jj] - cy[j])
    ok = (d >= d_lo - 1e-9) & (d <= d_hi + 1e-9)
    ii, jj = ii[ok], jj[ok]
    if ii.size == 0:
        return None
    c = np.where((ii == start[0]) & (jj == start[1]), 0.0, cost[ii, jj])
    for m in np.argsort(c, kind="stable")[:64]:
        if reference_clear(opaque, int(ii[m]), int(jj[m]), i, j):
            return int(ii[m]), int(jj[m])
    return None


def reference_surely_occupied(
    cmap: CoverageMap, floor_clearance: float, robot_height: float, sure: float
) -> np.ndarray:
    """Columns (nx, ny) with a known band voxel at E[C] >= ``sure``, with numpy over every
    band voxel: the oracle of ``probing.optimistic_traversability``'s ``occupied`` mask."""
    nx, ny, nz = cmap.grid.shape
    layers = band_layers(cmap, floor_clearance, robot_height)
    idx = (np.arange(nx * ny, dtype=np.int64)[:, None] * nz + layers[None, :]).ravel()
    known = cmap.lam[idx] > cmap.known_threshold()
    cov = np.zeros(idx.size)
    cov[known] = expected_coverage(cmap.mean(idx[known]), cmap.sigma(idx[known]))
    return (cov.reshape(nx * ny, layers.size) >= sure).any(axis=1).reshape(nx, ny)
