"""Where a ground robot may drive: a 2-D traversability grid from the 3-D coverage map.

A column (i, j) of the map is considered over the robot's height band: the voxels whose
centre z lies in [floor_clearance, robot_height]. The column is

* *occupied* if any voxel of the band is known and its expected coverage E[C] is at least
  ``free_threshold`` (default 0.2),
* *unknown* if any voxel of the band carries no information beyond the prior,
* *free* otherwise (every band voxel known, with E[C] < free_threshold).

Occupied and unknown columns are blocked. The robot is a disc of radius ``robot_radius``:
a cell is navigable (``free``) only if its centre is farther than radius + voxel/2 from
the centre of every blocked cell (exact along the axes, up to 0.21 voxel optimistic on
diagonals; add ``margin`` for more room). Everything outside the map counts as blocked.
Cell (i, j) has its centre at origin + (i + 0.5, j + 0.5) * resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import SIGMA_MAX, SIGMA_MIN, expected_coverage
from swarm.navigation import grid_kernels as kernels

#: Default height (m) of the bottom of the robot's band: lower obstacles do not block it.
FLOOR_CLEARANCE = 0.1
#: Default E[C] at or above which a band voxel blocks its column.
FREE_THRESHOLD = 0.2


def robot_band_top(camera_height: float) -> float:
    """The top (m) of the height band the agents and the coordinator plan a robot in: 0.1 m
    above its camera, at least 0.3 m."""
    return max(camera_height + 0.1, 0.3)


@dataclass(frozen=True, eq=False)
class TraversabilityGrid:
    """A 2-D grid over the map's x-y extent; ``free`` (nx, ny) bool is where the robot's centre may be.

    ``occupied`` and ``unknown`` are the raw column states before inflation.
    """

    free: np.ndarray
    occupied: np.ndarray
    unknown: np.ndarray
    origin: tuple[float, float]
    resolution: float
    robot_radius: float = 0.0

    @property
    def shape(self) -> tuple[int, int]:
        return self.free.shape

    @property
    def blocked(self) -> np.ndarray:
        """Raw blocked columns (occupied or unknown), before inflation."""
        return self.occupied | self.unknown

    @classmethod
    def from_blocked(
        cls,
        blocked: np.ndarray,
        origin: tuple[float, float],
        resolution: float,
        robot_radius: float,
        margin: float = 0.0,
        unknown: np.ndarray | None = None,
    ) -> TraversabilityGrid:
        """Inflate a raw 2-D blocked mask by the robot radius (``unknown`` is kept for reference)."""
        blocked = np.asarray(blocked, dtype=bool)
        unknown = np.zeros_like(blocked) if unknown is None else np.asarray(unknown, dtype=bool)
        free = inflate(blocked, resolution, robot_radius + margin)
        return cls(
            free, blocked & ~unknown, unknown, (float(origin[0]), float(origin[1])), resolution, robot_radius
        )

    # -- coordinates -----------------------------------------------------------------------
    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """Cell indices (..., 2) int64 of world points (..., 2); outside points give out-of-range cells."""
        xy = np.asarray(xy, dtype=np.float64)[..., :2]
        return np.floor((xy - np.asarray(self.origin)) / self.resolution).astype(np.int64)

    def centre(self, cells: np.ndarray) -> np.ndarray:
        """World x-y centres (..., 2) of cells (..., 2)."""
        return np.asarray(self.origin) + (np.asarray(cells, dtype=np.float64) + 0.5) * self.resolution

    def contains(self, cells: np.ndarray) -> np.ndarray:
        """Boolean mask of cells (..., 2) inside the grid."""
        cells = np.asarray(cells)
        return np.all((cells >= 0) & (cells < np.asarray(self.shape)), axis=-1)

    def is_free(self, cells: np.ndarray) -> np.ndarray:
        """Boolean mask of navigable cells (..., 2); cells outside the grid are not free."""
        cells = np.asarray(cells, dtype=np.int64)
        inside = self.contains(cells)
        out = np.zeros(cells.shape[:-1], dtype=bool)
        out[inside] = self.free[cells[inside][:, 0], cells[inside][:, 1]]
        return out

    def segment_cells(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Every cell (K, 2) the straight world segment a -> b passes through (exact supercover).

        Where the segment passes exactly through a cell corner, all four cells around the
        corner are included, so a segment never slips diagonally between two cells.
        """
        a = (np.asarray(a, dtype=np.float64)[:2] - np.asarray(self.origin)) / self.resolution
        b = (np.asarray(b, dtype=np.float64)[:2] - np.asarray(self.origin)) / self.resolution
        d = b - a
        ts = [np.array([0.0, 1.0])]
        for ax in range(2):
            if d[ax] != 0:
                lo, hi = sorted((a[ax], b[ax]))
                lines = np.arange(np.ceil(lo), np.floor(hi) + 1)
                ts.append((lines - a[ax]) / d[ax])
        t = np.unique(np.clip(np.concatenate(ts), 0.0, 1.0))
        mids = 0.5 * (t[:-1] + t[1:]) if len(t) > 1 else t
        cells = [np.floor(a + mids[:, None] * d)]
        eps = 1e-9
        points = a + t[:, None] * d
        corners = points[np.all(np.abs(points - np.round(points)) < eps, axis=1)]
        for step in ((-2 * eps, -2 * eps), (-2 * eps, 2 * eps), (2 * eps, -2 * eps), (2 * eps, 2 * eps)):
            cells.append(np.floor(corners + np.array(step)))
        cells.append(np.floor(a)[None])
        cells.append(np.floor(b)[None])
        return np.unique(np.concatenate(cells).astype(np.int64), axis=0)

    def segment_is_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True if every cell the straight world segment a -> b passes through is navigable
        (every cell of ``segment_cells(a, b)``; compiled, without building the set)."""
        ox, oy = self.origin
        res = self.resolution
        return bool(
            kernels.segment_is_free(
                self.free,
                (float(a[0]) - ox) / res,
                (float(a[1]) - oy) / res,
                (float(b[0]) - ox) / res,
                (float(b[1]) - oy) / res,
            )
        )

    def path_is_free(self, waypoints: np.ndarray) -> bool:
        """True if every segment of a world polyline (K, 2) is navigable."""
        pts = np.asarray(waypoints, dtype=np.float64)
        if len(pts) == 0:
            return True
        if len(pts) == 1:
            return bool(self.is_free(self.cell_of(pts[0])))
        return all(self.segment_is_free(pts[k], pts[k + 1]) for k in range(len(pts) - 1))


def inflate(blocked: np.ndarray, resolution: float, radius: float) -> np.ndarray:
    """Navigable mask: cells whose centre is farther than radius + resolution/2 from every blocked
    cell centre; the area outside the grid counts as blocked."""
    blocked = np.ascontiguousarray(blocked, dtype=bool)
    return kernels.inflate_blocked(blocked, radius / resolution + 0.5 + 1e-9)  # ties count as blocked


def band_layers(cmap: CoverageMap, floor_clearance: float, robot_height: float) -> np.ndarray:
    """Indices k of the map layers whose voxel centre z lies in [floor_clearance, robot_height]."""
    grid = cmap.grid
    z = grid.lo[2] + (np.arange(grid.shape[2]) + 0.5) * grid.voxel
    layers = np.flatnonzero((z >= floor_clearance - 1e-9) & (z <= robot_height + 1e-9))
    if layers.size == 0:
        raise ValueError(
            f"no map layer has its centre in the robot band z = [{floor_clearance}, {robot_height}] m "
            f"(layer centres {z.min():.3f}..{z.max():.3f} m)"
        )
    return layers


def band_columns(
    cmap: CoverageMap, floor_clearance: float, robot_height: float, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """(occupied, unknown), bool (nx, ny): columns with a known band voxel (``band_layers``)
    at E[C] >= ``threshold``, and columns with an unknown band voxel (none occupied).

    E[C] is computed only where a bound on it leaves the answer open (most known voxels
    have a small sigma and a mean far from the threshold): ``grid_kernels.band_occupancy``.
    """
    nx, ny, _nz = cmap.grid.shape
    layers = band_layers(cmap, floor_clearance, robot_height)  # contiguous: z grows with k
    unknown, occupied, mu, sigma, column = kernels.band_occupancy(
        cmap.lam,
        cmap.eta,
        cmap.grid.shape,
        int(layers[0]),
        int(layers[-1]) + 1,
        cmap.known_threshold(),
        float(threshold),
        SIGMA_MIN,
        SIGMA_MAX,
    )
    occupied[column[expected_coverage(mu, sigma) >= threshold]] = True
    return occupied.reshape(nx, ny), unknown.reshape(nx, ny)


def build_traversability(
    cmap: CoverageMap,
    floor_clearance: float = FLOOR_CLEARANCE,
    robot_height: float = 0.5,
    robot_radius: float = 0.18,
    free_threshold: float = FREE_THRESHOLD,
    margin: float = 0.0,
    swept: np.ndarray | None = None,
) -> TraversabilityGrid:
    """The traversability grid of a coverage map for a robot of the given height band and radius.

    ``swept``: optional (M, 2) x-y positions the robot's centre has occupied; the discs of
    ``robot_radius`` around them are known empty, so their unknown columns count as free
    (occupied ones stay occupied). Cameras rarely see the floor right around the robot.
    """
    if not robot_height > floor_clearance:
        raise ValueError(f"robot_height {robot_height} must exceed floor_clearance {floor_clearance}")
    grid = cmap.grid
    nx, ny, _nz = grid.shape
    occupied, unknown = band_columns(cmap, floor_clearance, robot_height, free_threshold)
    origin = (float(grid.lo[0]), float(grid.lo[1]))
    if swept is not None and len(swept):
        xy = np.ascontiguousarray(np.asarray(swept, dtype=np.float64)[:, :2])
        unknown &= ~kernels.disc_cells(xy, origin[0], origin[1], grid.voxel, nx, ny, float(robot_radius))
    # Occupied space is inflated by the robot's radius; unknown space is blocked but not
    # inflated, so a robot may stand next to what it has not seen yet (its camera sees
    # nothing of the floor right around it) and looks at it before it gets there.
    free = inflate(occupied, grid.voxel, robot_radius + margin) & ~unknown
    return TraversabilityGrid(free, occupied, unknown, origin, grid.voxel, robot_radius)
