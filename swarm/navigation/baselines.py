"""The two baselines of the study: the nearest frontier (Yamauchi 1997) and a random reachable target."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from swarm.navigation.search_context import SearchContext, grow
from swarm.navigation.targets import ExplorationTarget
from swarm.navigation.traversability import TraversabilityGrid


# ---------------------------------------------------------------------------------------
# Frontier baseline (Yamauchi 1997)
# ---------------------------------------------------------------------------------------
def frontier_cells(trav: TraversabilityGrid) -> np.ndarray:
    """Frontier cells (nx, ny) bool: free cells 8-adjacent to cells blocked only by unknown.

    Yamauchi's frontier (known free next to unknown) in the robot's configuration space: a
    free cell borders a non-free cell that would be free if the unknown (not occupied)
    columns were free, i.e. one farther than the inflation distance from every occupied
    column. With build_traversability (unknown columns blocked but not inflated) these
    are the unknown columns clear of the walls' inflation, so this is "free cells
    8-adjacent to unknown cells"; with a grid that also inflates unknown columns
    (TraversabilityGrid.from_blocked) it is the ring of free cells around their inflation.
    Unknown space behind a known wall gives no frontier.
    """
    unknown = trav.unknown & ~trav.occupied
    if not unknown.any():
        return np.zeros(trav.shape, dtype=bool)
    nonfree = ~trav.free
    # inflation distance (cells): that of the robot's radius, or more if a margin was added
    d_blocked = distance_to(trav.occupied | unknown)
    threshold = max(trav.robot_radius / trav.resolution + 0.5, float(d_blocked[nonfree].max()))
    shadow = nonfree & (distance_to(trav.occupied) > threshold + 1e-9)
    return trav.free & grow(shadow, square=True)


def distance_to(mask: np.ndarray) -> np.ndarray:
    """Distance (cells) from each cell centre to the nearest ``mask`` cell, the outside counting."""
    padded = np.pad(mask, 1, constant_values=True)
    return ndimage.distance_transform_edt(~padded)[1:-1, 1:-1]


def frontier_target(
    ctx: SearchContext, view_range: float = 1.0, min_travel: float = 0.5
) -> ExplorationTarget | None:
    """The reachable frontier cell of least path cost (ignoring ones nearer than ``min_travel``
    unless only those remain); gaze at the mean direction of the nearest unknown columns."""
    front = frontier_cells(ctx.trav) & ctx.reach & ctx.allowed
    if not front.any():
        return None
    far = front & (ctx.cost >= min_travel)
    pool = far if far.any() else front
    i, j = np.unravel_index(int(np.argmin(np.where(pool, ctx.cost, np.inf))), pool.shape)
    unk = np.argwhere(ctx.trav.unknown & ~ctx.trav.occupied)
    vec = (unk - np.array([i, j])).astype(np.float64)
    d = np.linalg.norm(vec, axis=1)
    near = d <= d.min() + 1.0  # the nearest unknown columns, within one cell of the nearest
    direction = (vec[near] / d[near, None]).mean(axis=0)
    if np.linalg.norm(direction) < 1e-9:
        direction = vec[int(np.argmin(d))]
    return ExplorationTarget(
        xy=ctx.centre(i, j),
        gaze_yaw=math.atan2(direction[1], direction[0]),
        utility=ctx.unknown_area(i, j, view_range),
        voxel=None,
        kind="frontier",
    )


# ---------------------------------------------------------------------------------------
# Random baseline and wandering
# ---------------------------------------------------------------------------------------
def random_target(
    ctx: SearchContext, radius: float, rng: np.random.Generator, view_range: float = 1.0
) -> ExplorationTarget | None:
    """A uniformly random reachable cell within ``radius`` (not the robot's own), random gaze.

    None when no unknown slab voxel is in view (sensor range) of reachable space, so
    missions stop; the robot's own cell (turn in place) when it has nowhere else to go.
    """
    if not ctx.reach.any() or not ctx.unknown_in_view():
        return None
    return random_cell_target(ctx, radius, rng, "random", None, view_range)


def random_cell_target(
    ctx: SearchContext,
    radius: float,
    rng: np.random.Generator,
    kind: str,
    utility: float | None,
    view_range: float = 1.0,
) -> ExplorationTarget:
    """Uniform reachable cell within ``radius`` of the robot, else any reachable one, else its own."""
    x, y = ctx.position[:2]
    pool = ctx.reach & ctx.allowed
    pool[ctx.start] = False
    near = pool & ((ctx.cx[:, None] - x) ** 2 + (ctx.cy[None, :] - y) ** 2 <= radius**2)
    if near.any():
        pool = near
    elif not pool.any():  # nowhere else to go: turn in place
        pool[ctx.start] = True
    cells = np.flatnonzero(pool)
    i, j = np.unravel_index(int(cells[rng.integers(cells.size)]), pool.shape)
    yaw = float(rng.uniform(-math.pi, math.pi))
    if utility is None:
        utility = ctx.unknown_area(int(i), int(j), view_range)
    return ExplorationTarget(xy=ctx.centre(i, j), gaze_yaw=yaw, utility=utility, voxel=None, kind=kind)
