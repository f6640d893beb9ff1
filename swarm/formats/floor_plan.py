"""Floor plans: the project's YAML format and ROS map_server maps, as extruded rectangles.

Every obstacle is a convex quadrilateral on the floor plane (counter-clockwise corners)
extruded from z = 0 up to its height. Walls are polylines with a thickness (each segment a
rectangle, extended by half the thickness at both ends so corners close); boxes are
rectangles with a centre, a size and a yaw; occupied cells of a ROS map are merged into
rectangles and extruded to a wall height.

Project YAML::

    name: lab
    wall_height: 2.5          # default height of walls (m)
    wall_thickness: 0.1       # default thickness of walls (m)
    bounds: [[-1, -1], [5, 3]]   # optional floor extent; default: the obstacles' extent
    walls:
      - points: [[0, 0], [4, 0], [4, 2]]
        closed: false         # optional: also join the last point to the first
        thickness: 0.1        # optional
        height: 2.5           # optional
    boxes:
      - centre: [1.0, 0.5]
        size: [1.2, 0.6]
        height: 0.75
        yaw: 0.0              # radians, optional
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, ValidationError, model_validator

from swarm.formats.errors import FloorPlanError
from swarm.formats.ros_map import RosMap, is_ros_map, load_ros_map
from swarm.formats.validation_errors import describe_validation_error
from swarm.formats.yaml_file import read_yaml

__all__ = [
    "DEFAULT_WALL_HEIGHT",
    "FloorPlan",
    "FloorPlanError",
    "RosMap",
    "is_ros_map",
    "load_floor_plan",
    "load_ros_map",
    "plan_from_ros_map",
    "plan_from_spec",
]

DEFAULT_WALL_HEIGHT = 2.0


# -- the geometry ------------------------------------------------------------------------


@dataclass
class FloorPlan:
    """Obstacles as extruded convex quads: ``quads`` (O, 4, 2) CCW corners, ``heights`` (O,).

    ``lo``/``hi`` bound the floor (x, y); ``kinds`` says where each quad came from
    ("wall", "box" or "cell"); ``ros_map`` is kept when the plan came from a ROS map.
    """

    quads: np.ndarray
    heights: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    kinds: list[str] = field(default_factory=list)
    name: str = ""
    source: Path | None = None
    ros_map: RosMap | None = None

    def __post_init__(self) -> None:
        self.quads = np.asarray(self.quads, dtype=np.float64).reshape(-1, 4, 2)
        self.heights = np.asarray(self.heights, dtype=np.float64).reshape(-1)
        self.lo = np.asarray(self.lo, dtype=np.float64)
        self.hi = np.asarray(self.hi, dtype=np.float64)
        if len(self.quads) != len(self.heights):
            raise ValueError("floor plan: one height per quad")
        if not self.kinds:
            self.kinds = ["box"] * len(self.quads)
        # Counter-clockwise corners, so that inside means "left of every edge".
        area = _signed_areas(self.quads)
        self.quads[area < 0] = self.quads[area < 0, ::-1]

    @property
    def count(self) -> int:
        """Number of obstacles."""
        return len(self.quads)

    @property
    def max_height(self) -> float:
        return float(self.heights.max()) if self.count else 0.0

    def edge_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """Edge start points (O, 4, 2) and unit outward normals (O, 4, 2)."""
        a = self.quads
        d = np.roll(a, -1, axis=1) - a
        n = np.stack([d[..., 1], -d[..., 0]], axis=-1)
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        return a, n

    def quad_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (O, 2) lo and hi of each quad."""
        return self.quads.min(axis=1), self.quads.max(axis=1)

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Top of the tallest obstacle covering each point (..., 2); 0 where none does."""
        xy = np.asarray(xy, dtype=np.float64)
        flat = xy.reshape(-1, 2)
        top = np.zeros(len(flat))
        qlo, qhi = self.quad_bounds()
        for quad, h, lo, hi in zip(self.quads, self.heights, qlo, qhi, strict=True):
            near = np.flatnonzero(np.all((flat >= lo) & (flat <= hi), axis=1))
            if near.size:
                inside = _inside_quad(flat[near], quad)
                top[near[inside]] = np.maximum(top[near[inside]], h)
        return top.reshape(xy.shape[:-1])

    def height_field(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """Obstacle top height on the lattice ``xs`` x ``ys`` (both increasing), shape (nx, ny)."""
        xs = np.asarray(xs, dtype=np.float64)
        ys = np.asarray(ys, dtype=np.float64)
        top = np.zeros((len(xs), len(ys)))
        qlo, qhi = self.quad_bounds()
        for quad, h, lo, hi in zip(self.quads, self.heights, qlo, qhi, strict=True):
            i0, i1 = np.searchsorted(xs, [lo[0], hi[0]], side="left")
            j0, j1 = np.searchsorted(ys, [lo[1], hi[1]], side="left")
            i1 = min(i1 + 1, len(xs))
            j1 = min(j1 + 1, len(ys))
            if i0 >= i1 or j0 >= j1:
                continue
            gx, gy = np.meshgrid(xs[i0:i1], ys[j0:j1], indexing="ij")
            inside = _inside_quad(np.stack([gx, gy], axis=-1), quad)
            block = top[i0:i1, j0:j1]
            block[inside] = np.maximum(block[inside], h)
        return top

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Distance (m) from each point (..., 2) to the nearest obstacle; 0 inside one."""
        xy = np.asarray(xy, dtype=np.float64)
        flat = xy.reshape(-1, 2)
        if not self.count:
            return np.full(xy.shape[:-1], np.inf)
        a = self.quads[None]  # (1, O, 4, 2)
        d = np.roll(self.quads, -1, axis=1)[None] - a
        p = flat[:, None, None, :] - a  # (P, O, 4, 2)
        t = np.clip(np.sum(p * d, axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-18), 0, 1)
        dist = np.linalg.norm(p - t[..., None] * d, axis=-1).min(axis=2)  # (P, O)
        cross = d[..., 0] * p[..., 1] - d[..., 1] * p[..., 0]
        dist[np.all(cross >= 0, axis=2)] = 0.0
        return dist.min(axis=1).reshape(xy.shape[:-1])

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Boolean mask: points (..., 2) inside some obstacle."""
        return self.height_at(xy) > 0


def _signed_areas(quads: np.ndarray) -> np.ndarray:
    x, y = quads[..., 0], quads[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)


def _inside_quad(points: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """Points (..., 2) inside (or on the border of) the CCW convex quad (4, 2)."""
    inside = np.ones(points.shape[:-1], dtype=bool)
    for k in range(4):
        a, b = quad[k], quad[(k + 1) % 4]
        cross = (b[0] - a[0]) * (points[..., 1] - a[1]) - (b[1] - a[1]) * (points[..., 0] - a[0])
        inside &= cross >= -1e-12
    return inside


def rectangle(centre: np.ndarray, size: np.ndarray, yaw: float = 0.0) -> np.ndarray:
    """Corners (4, 2), counter-clockwise, of a rectangle with the given centre, size and yaw."""
    hx, hy = np.asarray(size, dtype=np.float64) / 2
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    c, s = np.cos(yaw), np.sin(yaw)
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(centre, dtype=np.float64)


def wall_segment(a: np.ndarray, b: np.ndarray, thickness: float) -> np.ndarray | None:
    """The rectangle (4, 2) of a wall from a to b, extended by thickness/2 at both ends."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    length = float(np.linalg.norm(b - a))
    if length < 1e-9:
        return None
    return rectangle((a + b) / 2, (length + thickness, thickness), np.arctan2(*(b - a)[::-1]))


# -- the project's YAML format -----------------------------------------------------------


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


Point = tuple[FiniteFloat, FiniteFloat]
Positive = Annotated[FiniteFloat, Field(gt=0)]


class WallSpec(_Strict):
    points: list[Point] = Field(min_length=2)
    closed: bool = False
    thickness: Positive | None = None
    height: Positive | None = None


class BoxSpec(_Strict):
    centre: Point
    size: tuple[Positive, Positive]
    height: Positive
    yaw: FiniteFloat = 0.0


class PlanSpec(_Strict):
    name: str = ""
    wall_height: Positive = 2.5
    wall_thickness: Positive = 0.1
    bounds: tuple[Point, Point] | None = None
    walls: list[WallSpec] = []
    boxes: list[BoxSpec] = []

    @model_validator(mode="after")
    def _bounds_ordered(self) -> PlanSpec:
        if self.bounds is not None:
            (x0, y0), (x1, y1) = self.bounds
            if not (x1 > x0 and y1 > y0):
                raise ValueError(f"bounds: [[xmin, ymin], [xmax, ymax]] with max > min, got {self.bounds}")
        return self


def plan_from_spec(spec: PlanSpec, source: Path | None = None) -> FloorPlan:
    """Build a FloorPlan from a validated project floor-plan spec."""
    quads, heights, kinds = [], [], []
    for wall in spec.walls:
        pts = list(wall.points) + ([wall.points[0]] if wall.closed else [])
        thickness = wall.thickness or spec.wall_thickness
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            quad = wall_segment(a, b, thickness)
            if quad is not None:
                quads.append(quad)
                heights.append(wall.height or spec.wall_height)
                kinds.append("wall")
    for box in spec.boxes:
        quads.append(rectangle(box.centre, box.size, box.yaw))
        heights.append(box.height)
        kinds.append("box")
    quads_arr = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 2)
    if spec.bounds is not None:
        lo, hi = np.asarray(spec.bounds[0]), np.asarray(spec.bounds[1])
    elif len(quads_arr):
        lo, hi = quads_arr.reshape(-1, 2).min(axis=0), quads_arr.reshape(-1, 2).max(axis=0)
    else:
        lo, hi = np.zeros(2), np.ones(2)
    return FloorPlan(quads_arr, heights, lo, hi, kinds, spec.name, source)


# -- ROS map_server maps -----------------------------------------------------------------


def merge_cells(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the True cells of a 2-D mask with disjoint rectangles (r0, c0, r1, c1), end-exclusive.

    Greedy: from each uncovered cell in raster order, grow right as far as possible, then
    down while the whole run is still uncovered and set.
    """
    todo = np.asarray(mask, dtype=bool).copy()
    rects = []
    rows, cols = todo.shape
    for r, c in zip(*np.nonzero(todo), strict=True):
        if not todo[r, c]:
            continue
        run = todo[r, c:]
        c1 = c + (int(np.argmin(run)) if not run.all() else len(run))
        r1 = r + 1
        while r1 < rows and todo[r1, c:c1].all():
            r1 += 1
        todo[r:r1, c:c1] = False
        rects.append((int(r), int(c), int(r1), int(c1)))
    return rects


def wall_cells(ros_map: RosMap) -> tuple[np.ndarray, int]:
    """The cells that become walls, on the map grown by one cell on every side, and that margin.

    The occupied cells, and the unknown ones touching a free cell: they close the edge of
    the mapped floor, so that robots stay on it. SLAM maps often leave a building's outline
    unknown (glass, gaps the laser never saw, walls drawn in grey as in Willow Garage's map).
    Outside the image counts as unknown, so free cells on the image's border are closed too.
    Unknown cells farther in are open floor that no robot reaches.
    """
    free = np.pad(ros_map.free, 1)
    near_free = free.copy()
    near_free[1:] |= free[:-1]
    near_free[:-1] |= free[1:]
    near_free[:, 1:] |= near_free[:, :-1].copy()
    near_free[:, :-1] |= near_free[:, 1:].copy()
    return np.pad(ros_map.occupied, 1) | (near_free & ~free), 1


def plan_from_ros_map(ros_map: RosMap, wall_height: float = DEFAULT_WALL_HEIGHT) -> FloorPlan:
    """Extrude the walls of a ROS map (``wall_cells``) to ``wall_height``, merged into rectangles."""
    walls, margin = wall_cells(ros_map)
    rects = np.asarray(merge_cells(walls), dtype=np.float64).reshape(-1, 4) - margin
    r0, c0, r1, c1 = rects.T
    corners = np.stack(
        [
            ros_map.to_world(c0, r0),
            ros_map.to_world(c1, r0),
            ros_map.to_world(c1, r1),
            ros_map.to_world(c0, r1),
        ],
        axis=1,
    )
    rows, cols = ros_map.shape
    extent = ros_map.to_world(np.array([0, cols, cols, 0]), np.array([0, 0, rows, rows]))
    return FloorPlan(
        quads=corners,
        heights=np.full(len(corners), float(wall_height)),
        lo=extent.min(axis=0),
        hi=extent.max(axis=0),
        kinds=["cell"] * len(corners),
        name=ros_map.source.stem,
        source=ros_map.source,
        ros_map=ros_map,
    )


# -- loading -------------------------------------------------------------------------------


def load_floor_plan(path: str | Path, wall_height: float = DEFAULT_WALL_HEIGHT) -> FloorPlan:
    """Load a project floor-plan YAML or a ROS ``map.yaml`` (extruded to ``wall_height``)."""
    path = Path(path)
    data = _read_yaml(path)
    if is_ros_map(data):
        return plan_from_ros_map(load_ros_map(path), wall_height)
    return plan_from_spec(_validate(PlanSpec, data, path), path)


def _read_yaml(path: Path) -> object:
    data = read_yaml(path, FloorPlanError)
    if data is None:
        raise FloorPlanError(
            f"{path}: (top level): the file is empty; a floor plan has walls, boxes or bounds"
        )
    return data


def _validate(model: type[BaseModel], data: object, path: Path):
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise FloorPlanError(describe_validation_error(e, path, model)) from e
