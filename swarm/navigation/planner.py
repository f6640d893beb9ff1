"""Shortest paths on a 2-D traversability grid (8-connected, no corner cutting).

Moves go to the 8 neighbours of a cell, orthogonal ones cost 1 cell and diagonal ones
sqrt(2); a diagonal move needs both orthogonal cells it passes between to be free, so a
path never cuts the corner of a blocked cell. Only ``free`` cells are ever entered, so a
path never crosses occupied or unknown space (the grid's inflation keeps the robot's
disc off it). With that rule, two cells are connected exactly when they are 4-connected,
which makes ``reachable_mask`` a labelling.

``GridPlanner`` builds the graph of one grid once (scipy.sparse.csgraph) and answers
several queries: ``plan`` (one path), ``cost_map`` (path length from a start to every
cell, for scoring many targets). Waypoints are world x-y positions of cell centres; by
default the path is shortened by dropping waypoints while the straight segment between the
kept ones stays on navigable cells.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from swarm.navigation import grid_kernels as kernels
from swarm.navigation.traversability import TraversabilityGrid, build_traversability

_FOUR = ndimage.generate_binary_structure(2, 1)


def _free_of(grid: TraversabilityGrid | np.ndarray) -> np.ndarray:
    return np.asarray(grid.free if isinstance(grid, TraversabilityGrid) else grid, dtype=bool)


def reachable_mask(grid: TraversabilityGrid | np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """Cells reachable from cell ``start`` (all False when the start is outside or not free)."""
    free = _free_of(grid)
    i, j = int(start[0]), int(start[1])
    if not (0 <= i < free.shape[0] and 0 <= j < free.shape[1]) or not free[i, j]:
        return np.zeros_like(free)
    labels, _ = ndimage.label(free, structure=_FOUR)
    return labels == labels[i, j]


def path_cost(waypoints: np.ndarray) -> float:
    """Length of a polyline (K, 2 or 3) in its own units (metres for world waypoints); 0 for K < 2."""
    pts = np.asarray(waypoints, dtype=np.float64)
    if len(pts) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


class GridPlanner:
    """Dijkstra on the free cells of one traversability grid (or a plain bool ``free`` array)."""

    def __init__(self, grid: TraversabilityGrid | np.ndarray) -> None:
        self.grid = grid if isinstance(grid, TraversabilityGrid) else None
        self.free = _free_of(grid)
        self.resolution = self.grid.resolution if self.grid is not None else 1.0
        flat_free = self.free.ravel()
        self._node_of = np.full(flat_free.size, -1, dtype=np.int64)
        self._cell_of = np.flatnonzero(flat_free)
        self._node_of[self._cell_of] = np.arange(self._cell_of.size)
        self._graph = self._build_graph()
        self._last_tree: tuple[int, np.ndarray, np.ndarray] | None = None

    def _build_graph(self) -> csr_matrix:
        # Both directions, diagonals only between two free cells (no corner cutting); rows in
        # the order scipy's undirected Dijkstra would scan them (see grid_kernels.grid_graph).
        indptr, indices, weights = kernels.grid_graph(
            np.ascontiguousarray(self.free), self._node_of, math.sqrt(2.0)
        )
        n = self._cell_of.size
        return csr_matrix((weights, indices, indptr), shape=(n, n))

    def _tree(self, node: int) -> tuple[np.ndarray, np.ndarray]:
        """Dijkstra from ``node``: (distance in cells, predecessor) per node; the last one is kept,
        so that a cost map and a path from the same start run it once."""
        if self._last_tree is None or self._last_tree[0] != node:
            dist, pred = dijkstra(self._graph, directed=True, indices=node, return_predecessors=True)
            self._last_tree = (node, dist, pred)
        return self._last_tree[1], self._last_tree[2]

    def _node(self, cell: tuple[int, int]) -> int:
        i, j = int(cell[0]), int(cell[1])
        if not (0 <= i < self.free.shape[0] and 0 <= j < self.free.shape[1]):
            return -1
        return int(self._node_of[i * self.free.shape[1] + j])

    def cost_map(self, start: tuple[int, int]) -> np.ndarray:
        """Path length (metres; cells for a bare array) from ``start`` to every cell; inf if unreachable."""
        out = np.full(self.free.shape, np.inf)
        node = self._node(start)
        if node < 0:
            return out
        dist, _ = self._tree(node)
        out.ravel()[self._cell_of] = dist * self.resolution
        return out

    def plan_cells(self, start: tuple[int, int], goal: tuple[int, int]) -> np.ndarray | None:
        """Cells (K, 2) of a shortest path from ``start`` to ``goal`` inclusive, or None if none exists."""
        s, g = self._node(start), self._node(goal)
        if s < 0 or g < 0:
            return None
        if s == g:
            return np.array([[int(start[0]), int(start[1])]], dtype=np.int64)
        dist, pred = self._tree(s)
        if not np.isfinite(dist[g]):
            return None
        chain = [g]
        while chain[-1] != s:
            chain.append(int(pred[chain[-1]]))
        flat = self._cell_of[np.array(chain[::-1])]
        return np.stack(np.unravel_index(flat, self.free.shape), axis=-1).astype(np.int64)

    def plan(self, start_xy: np.ndarray, goal_xy: np.ndarray, shorten: bool = True) -> np.ndarray | None:
        """World waypoints (K, 2) from the cell of ``start_xy`` to the cell of ``goal_xy``, or None.

        The first waypoint is the start position itself and the last the goal cell's centre.
        Needs a TraversabilityGrid (for coordinates).
        """
        if self.grid is None:
            raise TypeError("plan() needs a TraversabilityGrid; use plan_cells() on a bare array")
        start_xy = np.asarray(start_xy, dtype=np.float64)[:2]
        cells = self.plan_cells(tuple(self.grid.cell_of(start_xy)), tuple(self.grid.cell_of(goal_xy)))
        if cells is None:
            return None
        points = _drop_collinear(cells, self.grid.centre(cells))
        # Start from the robot's own position, through its cell centre if the direct line is not clear.
        if len(points) == 1 or self.grid.segment_is_free(start_xy, points[1]):
            points[0] = start_xy
        else:
            points = np.vstack([start_xy, points])
        return shorten_path(self.grid, points) if shorten else points


def cost_map(grid: TraversabilityGrid | np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """``GridPlanner(grid).cost_map(start)`` (metres; cells for a bare array; inf where
    unreachable), the same values, without building the graph: for one query per grid (the
    coordinator plans each request on a new grid). Compiled (``grid_kernels.grid_distances``)."""
    free = np.ascontiguousarray(_free_of(grid))
    resolution = grid.resolution if isinstance(grid, TraversabilityGrid) else 1.0
    dist = kernels.grid_distances(free, int(start[0]), int(start[1]), math.sqrt(2.0))
    return dist * resolution if resolution != 1.0 else dist


def plan_path(grid: TraversabilityGrid, start_xy: np.ndarray, goal_xy: np.ndarray) -> np.ndarray | None:
    """One-off shortest path in world coordinates (see ``GridPlanner.plan``); None when unreachable."""
    return GridPlanner(grid).plan(start_xy, goal_xy)


def nearest_free_cell(
    grid: TraversabilityGrid | np.ndarray, cell: tuple[int, int], max_cells: int = 10
) -> tuple[int, int] | None:
    """The free cell nearest to ``cell`` within ``max_cells`` (e.g. to leave an inflated zone), or None."""
    free = _free_of(grid)
    i, j = int(cell[0]), int(cell[1])
    i0, i1 = max(i - max_cells, 0), min(i + max_cells + 1, free.shape[0])
    j0, j1 = max(j - max_cells, 0), min(j + max_cells + 1, free.shape[1])
    if i0 >= i1 or j0 >= j1:
        return None
    ii, jj = np.nonzero(free[i0:i1, j0:j1])
    if ii.size == 0:
        return None
    d2 = (ii + i0 - i) ** 2 + (jj + j0 - j) ** 2
    k = int(np.argmin(d2))
    if d2[k] > max_cells**2:
        return None
    return int(ii[k] + i0), int(jj[k] + j0)


def large_free_areas(free: np.ndarray, min_cells: int) -> np.ndarray:
    """Free cells (bool (nx, ny)) in 8-connected free areas of at least ``min_cells`` cells."""
    labels, count = ndimage.label(free, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return np.zeros_like(free, dtype=bool)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return sizes[labels] >= min_cells


def _drop_collinear(cells: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Keep the first, the last and the cells where the step direction changes."""
    if len(cells) <= 2:
        return points
    step = np.diff(cells, axis=0)
    turn = np.any(step[1:] != step[:-1], axis=1)
    keep = np.concatenate([[True], turn, [True]])
    return points[keep]


def shorten_path(grid: TraversabilityGrid, points: np.ndarray) -> np.ndarray:
    """Drop waypoints while the straight segment between kept ones stays on navigable cells."""
    if len(points) <= 2:
        return points
    kept = [0]
    anchor = 0
    k = anchor + 2
    while k < len(points):
        if grid.segment_is_free(points[anchor], points[k]):
            k += 1
            continue
        anchor = k - 1
        kept.append(anchor)
        k = anchor + 2
    kept.append(len(points) - 1)
    return points[kept]


def warm_up_kernels() -> tuple:
    """The compiled kernels :func:`warm_up` loads (a first run: compiles), for its progress lines."""
    from swarm.map.coverage_map import add_information
    from swarm.navigation.view_kernels import stand_for

    return (
        add_information,
        kernels.band_occupancy,
        kernels.disc_cells,
        kernels.disc_count,
        kernels.grid_graph,
        kernels.grid_distances,
        kernels.inflate_blocked,
        kernels.segment_is_free,
        stand_for,
    )


def warm_up() -> None:
    """Load (on a fresh install: compile into Numba's cache) the compiled navigation kernels
    (``swarm.navigation.grid_kernels``: traversability grid, planner graph, segment checks, the
    graphless cost map and swept-floor counts of the coordinator;
    ``swarm.navigation.view_kernels``: where to stand for a 3-D view) now, not on the first
    decision, by planning once on a tiny map and searching one standing point. The view search
    runs only once the slab is explored, minutes into a mission: compiling it then stalled an
    agent past the world's 10 s answer timeout on a busy 2-core machine."""
    from swarm.map.coverage_map import CoverageMap
    from swarm.map.delta import Delta
    from swarm.map.grid import Grid
    from swarm.navigation.view_kernels import stand_for

    cmap = CoverageMap(Grid((0.0, 0.0, 0.0), 0.1, (8, 8, 6)))
    cmap.apply(Delta.empty())
    cmap.lam[:] = 1e4  # known and free everywhere
    cmap.eta[:] = 0.0
    trav = build_traversability(cmap, robot_radius=0.1, swept=np.full((1, 2), 0.4))
    GridPlanner(trav).plan(np.array([0.35, 0.35]), np.array([0.45, 0.45]))
    cost_map(trav, (3, 3))
    kernels.disc_count(np.zeros((8, 8), dtype=np.int64), 0.4, 0.4, 0.0, 0.0, 0.1, 0.1, 1)
    # the argument types of view_targets._stand_for (C-contiguous arrays, Python scalars)
    cells = np.ones((4, 4), dtype=bool)
    centres = (np.arange(4) + 0.5) * 0.1
    stand_for(cells, ~cells, np.zeros((4, 4)), 0, 0, centres, centres, ~cells, 3, 3, 0.0, 1.0, 2)
