"""What one target search shares: the map and its entropy, the robot, its reachable floor, the
slab at sensor height, and what it can see from where (line of sight through known-transparent
voxels).

A caller builds one :class:`SearchContext` per decision (:meth:`SearchContext.build`) and hands
it to the searches of :mod:`swarm.navigation.exploration` with a
:class:`swarm.navigation.exploration.SearchOptions`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.navigation.traversability import TraversabilityGrid

#: Known slab voxels with E[C] at least this block the view: the traversability grid's
#: free threshold, so that ambiguous surface voxels do not let the view leak into solids.
OPAQUE_COVERAGE = 0.2


# ---------------------------------------------------------------------------------------
# Shared state of one call
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SearchContext:
    """Everything the strategies share, computed once per decision (2-D arrays are (nx, ny)).

    ``entropy`` is the map's per-voxel entropy (bits, flat, as kept by EntropyCache)."""

    cmap: CoverageMap
    entropy: np.ndarray
    trav: TraversabilityGrid
    position: np.ndarray  # sensor position x (3,), eq. 30
    yaw: float
    k0: int  # slab layer holding the sensor
    cost: np.ndarray
    reach: np.ndarray  # reachable free cells and the robot's own cell
    start: tuple[int, int]  # the robot's cell
    cx: np.ndarray  # column centre x (nx,)
    cy: np.ndarray  # column centre y (ny,)
    allowed: np.ndarray  # columns farther than the radii from every excluded / kept-away point
    slab_known: np.ndarray
    slab_cov: np.ndarray  # E[C] of slab voxels (unknown: prior mean)
    opaque: np.ndarray  # known slab voxels with E[C] >= OPAQUE_COVERAGE

    @classmethod
    def build(
        cls,
        cmap: CoverageMap,
        entropy: np.ndarray,
        pose: tuple[float, float, float],
        sensor_height: float,
        trav: TraversabilityGrid,
        planner_cost: np.ndarray,
        *,
        exclude: Sequence[np.ndarray] = (),
        exclude_radius: float = 1.0,
        keep_away: Sequence[np.ndarray] = (),
        keep_away_radius: float = 0.0,
        slab: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> SearchContext:
        """The context of one search on ``cmap`` with its per-voxel ``entropy`` (bits, flat).

        ``pose`` is the robot's (x, y, yaw) (m, rad), ``sensor_height`` the sensor's world z (m),
        ``trav`` the map's x-y columns (same origin, voxel and shape, as
        :func:`swarm.navigation.traversability.build_traversability` makes it), ``planner_cost``
        the GridPlanner.cost_map from the robot's cell (m, inf where unreachable; from
        ``nearest_free_cell`` when inflation blocks the robot's own cell). Targets and standing
        points stay farther than ``exclude_radius`` (m) from the x-y points ``exclude`` (other
        robots' targets, recently failed ones) and than ``keep_away_radius`` from ``keep_away``
        (where teammates head). ``slab``: (known (nx, ny) bool, E[C] (nx, ny)) of the slab
        voxels when kept already (the coordinator's cache; None: read from ``cmap``, a pass over
        the whole map). ValueError when the grids or the sensor height do not fit."""
        grid = cmap.grid
        if np.shape(entropy) != (grid.size,):
            raise ValueError(
                f"entropy has shape {np.shape(entropy)}, expected ({grid.size},) (flat, per voxel)"
            )
        nx, ny, nz = grid.shape
        e = grid.voxel
        if trav.shape != (nx, ny) or not (
            math.isclose(trav.resolution, e) and np.allclose(trav.origin, grid.lo[:2], atol=1e-9)
        ):
            raise ValueError("traversability grid must cover the map's x-y columns (origin, voxel, shape)")
        cost = np.asarray(planner_cost, dtype=np.float64)
        if cost.shape != (nx, ny):
            raise ValueError(f"planner_cost has shape {cost.shape}, expected {(nx, ny)}")
        k0 = int(np.floor((float(sensor_height) - grid.lo[2]) / e))
        if not 0 <= k0 < nz:
            raise ValueError(f"sensor height {sensor_height} m is outside the map's z range")
        x, y, yaw = (float(v) for v in pose)
        cx = grid.lo[0] + (np.arange(nx) + 0.5) * e
        cy = grid.lo[1] + (np.arange(ny) + 0.5) * e
        allowed = np.ones((nx, ny), dtype=bool)
        for points, r in ((exclude, exclude_radius), (keep_away, keep_away_radius)):
            for p in points:
                p = np.asarray(p, dtype=np.float64)
                allowed &= (cx[:, None] - p[0]) ** 2 + (cy[None, :] - p[1]) ** 2 > r**2
        # reachable: free cells the planner reaches, and the cell the robot stands on
        reach = trav.free & np.isfinite(cost)
        own = trav.cell_of(np.array([x, y]))
        if trav.contains(own):
            start = (int(own[0]), int(own[1]))
            reach[start] = True
        else:
            start = np.unravel_index(int(np.argmin(cost)), cost.shape)
        if slab is None:
            known, cov = slab_beliefs(cmap, k0)
        else:
            known, cov = slab
        return cls(
            cmap=cmap,
            entropy=np.asarray(entropy),
            trav=trav,
            position=np.array([x, y, float(sensor_height)]),
            yaw=yaw,
            k0=k0,
            cost=cost,
            reach=reach,
            start=(int(start[0]), int(start[1])),
            cx=cx,
            cy=cy,
            allowed=allowed,
            slab_known=known,
            slab_cov=cov,
            opaque=known & (cov >= OPAQUE_COVERAGE),
        )

    @property
    def voxel(self) -> float:
        return self.cmap.grid.voxel

    def centre(self, i: int, j: int) -> np.ndarray:
        return np.array([self.cx[i], self.cy[j]])

    def in_view(self, max_range: float) -> np.ndarray:
        """Slab columns in view of reachable space within ``max_range`` (see the module doc)."""
        return in_view(self.reach, ~self.opaque, int(math.ceil(max_range / self.voxel - 1e-9)))

    def unknown_in_view(self) -> bool:
        """Is any unknown slab voxel that borders known free space (4-neighbours) in view of
        reachable space within the sensor's reach (``SensorModel.reach``)? (Unknown voxels
        enclosed by surfaces or by other unknown voxels alone do not count: no view would
        reach them.)"""
        border = ~self.slab_known & grow(self.slab_known & ~self.opaque, square=False)
        if not border.any():
            return False
        return bool(np.any(self.in_view(self.cmap.sensor.reach) & border))

    def unknown_area(self, i: int, j: int, max_range: float) -> float:
        """Unknown floor area (m^2, traversability columns) within ``max_range`` of cell (i, j)."""
        unk = self.trav.unknown & ~self.trav.occupied
        d2 = (self.cx[:, None] - self.cx[i]) ** 2 + (self.cy[None, :] - self.cy[j]) ** 2
        return float(np.count_nonzero(unk & (d2 <= max_range**2))) * self.voxel**2


def slab_beliefs(cmap: CoverageMap, k0: int, cols: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(known, E[C]) of layer ``k0``'s voxels of the columns ``cols`` (flat i * ny + j, any
    shape; None: all, (nx, ny)): lam above the prior's, and the expected coverage (float64)."""
    nx, ny, nz = cmap.grid.shape
    cols = np.arange(nx * ny, dtype=np.int64).reshape(nx, ny) if cols is None else np.asarray(cols, np.int64)
    flat = cols.ravel() * nz + k0
    known = (cmap.lam[flat] > cmap.known_threshold()).reshape(cols.shape)
    cov = expected_coverage(cmap.mean(flat), cmap.sigma(flat)).reshape(cols.shape)
    return known, cov


def grow(mask: np.ndarray, square: bool) -> np.ndarray:
    """One dilation step of a 2-D mask: 8-neighbour (``square``) or 4-neighbour."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    src = out.copy() if square else mask
    out[:, 1:] |= src[:, :-1]
    out[:, :-1] |= src[:, 1:]
    return out


def in_view(sources: np.ndarray, transparent: np.ndarray, steps: int) -> np.ndarray:
    """Cells within ``steps`` of ``sources`` through transparent cells (octagonal metric).

    Opaque cells are reached (their surface is seen) but never passed through.
    """
    seen = sources.copy()
    for s in range(steps):
        seen |= grow(seen & transparent, square=s % 2 == 1)
    return seen
