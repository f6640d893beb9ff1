"""Probing unknown floor: a way into rooms the planner's known free space does not reach.

The planner drives on known free floor only (``build_traversability``: unknown columns and
any column with a band voxel at E[C] >= 0.2 are blocked). Two things then close a room to a
robot although its door is open:

- *door thresholds*: a stereo camera's returns smear at the door's jambs (depth edges), so
  the door's columns hold a few ambiguous voxels (E[C] 0.2-0.5, not the 0.9 of a wall);
- *unknown floor beyond the door*: from the corridor a camera sees a room through the door
  in thin streaks (and with a hit range, only its near part), so its floor stays unknown and
  no eq. 35 candidate in it has a reachable standing cell.

Eq. 35 and the 3-D views (``view_targets``) then find nothing in the room, and the robot
spends its time on small 3-D frontiers of air columns nearby while a large unknown floor area
waits behind a door.

A *probe* handles it. The optimistic grid (:func:`optimistic_traversability`) lets the robot
pass where nothing is *surely* occupied: columns whose band voxels are all either unknown or
below ``SURE_COVERAGE`` (0.5), with only the surely occupied ones inflated by the robot's
radius. The cells it opens that known free space does not reach form *unknown floor
regions*; :func:`probe_target` picks the region of most unknown floor area per metre of
travel (at least ``MIN_PROBE_AREA``), enters it ``PROBE_DEPTH`` beyond its nearest cell (the
doorway) and looks at the rest. With care: the robot goes on driving on the optimistic grid
(its replans see what it sees on the way), the simulator's (or a real robot's bumpers')
contact stops it, and a probe that fails is given up with its region's entry (the caller's
``exclude`` points). Once through, the way back stays open: cells the robot's body has swept
count as free unless surely occupied (:func:`open_swept`), as the door's ambiguous voxels
would otherwise shut the robot in the room.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy import ndimage

from swarm.map.coverage_map import CoverageMap
from swarm.navigation import grid_kernels as kernels
from swarm.navigation.planner import GridPlanner
from swarm.navigation.search_context import SearchContext
from swarm.navigation.targets import ExplorationTarget
from swarm.navigation.traversability import TraversabilityGrid, band_columns, inflate

#: Band voxels at least this E[C] are surely occupied (a wall seen well is above 0.8; the
#: smeared returns at a door's jambs stay below).
SURE_COVERAGE = 0.5
#: Unknown floor (m^2) a region must hold to be probed (smaller ones are left to the 3-D views).
MIN_PROBE_AREA = 1.0
#: How far (m of path) beyond the region's entry the robot goes to look.
PROBE_DEPTH = 0.5
#: Path length (m) added to each region's travel when weighing area against distance.
TRAVEL_OFFSET = 1.0

_FOUR = ndimage.generate_binary_structure(2, 1)


def optimistic_traversability(
    cmap: CoverageMap,
    trav: TraversabilityGrid,
    robot_height: float,
    floor_clearance: float = 0.1,
    sure: float = SURE_COVERAGE,
    surely: np.ndarray | None = None,
) -> TraversabilityGrid:
    """Where a robot may go when only surely occupied columns block it.

    A column is blocked when a band voxel (the layers of ``band_layers(cmap, floor_clearance,
    robot_height)``) is known with E[C] >= ``sure``; blocked columns are inflated by
    ``trav.robot_radius`` as in ``build_traversability``. Every cell free in ``trav`` stays
    free. ``occupied`` is the surely occupied mask, ``unknown`` that of ``trav`` outside it.
    Shapes (nx, ny) as ``trav``; raises ValueError when ``trav`` is not the map's x-y grid.
    ``surely``: the surely occupied columns when kept already (``FloorCache.band`` at ``sure``;
    None: a pass over the map's band).
    """
    grid = cmap.grid
    nx, ny, _nz = grid.shape
    if trav.shape != (nx, ny):
        raise ValueError(f"traversability grid has shape {trav.shape}, the map's columns {(nx, ny)}")
    # the traversability grid's band test, at the "surely occupied" level
    if surely is None:
        surely, _unknown = band_columns(cmap, floor_clearance, robot_height, sure)
    free = inflate(surely, grid.voxel, trav.robot_radius) | trav.free
    return TraversabilityGrid(
        free, surely, trav.unknown & ~surely, trav.origin, trav.resolution, trav.robot_radius
    )


def open_swept(
    trav: TraversabilityGrid, optimistic: TraversabilityGrid, swept: np.ndarray
) -> TraversabilityGrid:
    """``trav`` with the cells within ``trav.robot_radius`` of the robot's past positions
    ``swept`` (M, 2; metres) made free where ``optimistic`` has them free: where the robot's
    body has been, only a surely occupied column may block it (not a door's smeared returns)."""
    xy = np.ascontiguousarray(np.asarray(swept, dtype=np.float64).reshape(-1, 2))
    if xy.shape[0] == 0:
        return trav
    nx, ny = trav.shape
    ox, oy = trav.origin
    body = kernels.disc_cells(xy, ox, oy, trav.resolution, nx, ny, float(trav.robot_radius))
    return replace(trav, free=trav.free | (optimistic.free & body))


def probe_target(
    ctx: SearchContext,
    optimistic: TraversabilityGrid,
    min_area: float = MIN_PROBE_AREA,
    depth: float = PROBE_DEPTH,
) -> ExplorationTarget | None:
    """The probe into the best unknown floor region (see the module doc), or None.

    Regions are the 4-connected cells free in ``optimistic`` but outside ``ctx.reach``, that
    the robot reaches on ``optimistic``. A region counts when its unknown columns cover at
    least ``min_area`` m^2 and its entry (its cell of least path cost) is ``ctx.allowed``
    (not near an excluded point, such as a failed probe). Among those, the one of most unknown
    area per metre of travel (area / (entry cost + TRAVEL_OFFSET)) wins. The goal is its
    allowed cell of least cost at least ``depth`` m beyond the entry (else its farthest), the
    gaze towards the centroid of its unknown columns. ``utility``: the region's unknown floor
    area (m^2); kind ``"probe"``. Plan to it on ``optimistic`` (GridPlanner).
    """
    new = optimistic.free & ~ctx.reach
    if not new.any():
        return None
    # from the planner's start (cost 0: the robot's cell, or the free cell it leaves from)
    start = ctx.start
    if np.isfinite(ctx.cost).any():
        start = np.unravel_index(int(np.argmin(ctx.cost)), ctx.cost.shape)
    cost = GridPlanner(optimistic).cost_map(start)
    labels, count = ndimage.label(new & np.isfinite(cost), structure=_FOUR)
    if count == 0:
        return None
    unknown = optimistic.unknown
    area = ndimage.sum_labels(unknown, labels, np.arange(1, count + 1)) * ctx.voxel**2
    best: tuple[float, int] | None = None
    for n in np.flatnonzero(area >= min_area) + 1:
        cells = labels == n
        entry = np.unravel_index(int(np.argmin(np.where(cells, cost, np.inf))), cells.shape)
        if not ctx.allowed[entry]:
            continue
        value = area[n - 1] / (cost[entry] + TRAVEL_OFFSET)
        if best is None or value > best[0]:
            best = (value, int(n))
    if best is None:
        return None
    cells = labels == best[1]
    c = np.where(cells, cost, np.inf)
    entry_cost = float(c.min())
    pool = np.where(cells & ctx.allowed & (c >= entry_cost + depth), c, np.inf)
    if np.isfinite(pool).any():
        goal = np.unravel_index(int(np.argmin(pool)), c.shape)
    else:
        goal = np.unravel_index(int(np.argmax(np.where(cells, c, -np.inf))), c.shape)
    at = ctx.centre(int(goal[0]), int(goal[1]))
    ii, jj = np.nonzero(cells & unknown)
    look = np.array([ctx.cx[ii].mean(), ctx.cy[jj].mean()]) - at if ii.size else at - ctx.position[:2]
    yaw = math.atan2(look[1], look[0]) if np.linalg.norm(look) > 1e-9 else ctx.yaw
    return ExplorationTarget(xy=at, gaze_yaw=yaw, utility=float(area[best[1] - 1]), voxel=None, kind="probe")
