"""Which voxels any sensor of a mission can ever observe: the simulator's knowledge of the world.

A voxel is *observable* when some ray of some robot's camera, from some pose the robot can
reach, crosses it (or ends in it) on its way to a surface that returns a range within the
sensor's reach. Everything else can never leave its prior, whatever the robots do: the
inside of walls and furniture, what hides behind them, the air above the walls that only
rays into the empty sky would cross, and corners out of every reachable camera's view.

The model, from the mission alone:

- *Reachable floor*: the floor points whose clearance from every obstacle exceeds the
  robot's radius, in the connected free region of some robot's start (a raster of the
  floor plan at ``raster`` m, a ROS map's cell when finer, its Euclidean distance transform),
  and near floor the robots' planner reaches on a perfect map (``planner_floor``): a passage
  the body fits through but the planner's inflated map closes leaves the rooms behind it
  out (on a SLAM map of a lab, 4.2 m^2 behind a 0.41 m door).
- *Sensor poses*: the camera at ``camera_height`` above reachable floor points sampled
  every ``spacing`` m (one per ``spacing`` square, so narrow doors keep theirs), any yaw
  (robots turn on the spot), any elevation the camera can look along: its vertical field
  of view around its mounting pitch, widened by the tilt head's range.
- *Rays*: cast in all those directions, ``angle_step`` apart, through the obstacles'
  height field (obstacles stand on the floor; the floor z = 0 returns too). A ray
  observes the voxels it crosses up to and including the one it ends in and the one
  behind it (the fusion updates the voxel behind a hit too, ``swarm.map.fusion``), when
  it ends on a surface at a range in [``min_range``, ``hit_range``]. A ray that ends on a
  surface between ``hit_range`` and ``max_range`` observes only the voxels it crosses up
  to ``hit_range`` (the agent fuses it as free space up to there, no hit:
  ``swarm.config.RigConfig.hit_range_m``). A ray that meets nothing within ``max_range``
  returns nothing and observes nothing (the agent drops returns beyond the sensor's range,
  so no free-space evidence either).

This is a sampling of poses and directions: a voxel seen by only a few grazing rays may be
missed, so the mask errs towards "unobservable" at the fringes; the spacing and angle step
trade that against time (the office: about 10 s). Source of the rule that builds on it:
the paper's own end point (Rocha et al. 2005, section V) and docs/study.md, "The
threshold".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

from swarm.formats.floor_plan import FloorPlan
from swarm.map.grid import Grid
from swarm.navigation.traversability import FLOOR_CLEARANCE, FREE_THRESHOLD, inflate, robot_band_top

__all__ = ["ObservabilityModel", "observable_voxels", "planner_floor", "reachable_floor", "sensor_positions"]


#: The finest floor raster (m) ``ObservabilityModel.for_mission`` takes for a fine ROS map.
MIN_RASTER = 0.01


@dataclass(frozen=True)
class ObservabilityModel:
    """The sensor's reach: ranges (m), elevation band (radians, positive up) and sampling."""

    camera_height: float
    elevation_lo: float
    elevation_hi: float
    max_range: float
    min_range: float = 0.0
    hit_range: float | None = None  # None: max_range
    robot_radius: float = 0.18
    spacing: float = 0.5
    angle_step: float = math.radians(1.5)
    raster: float = 0.05

    @classmethod
    def for_mission(cls, mission, **overrides) -> ObservabilityModel:
        """The model of a ``swarm.config.Mission``: the widest reach of its robots' rigs.

        Elevation band: the mounting pitch (positive down) +- half the vertical field of
        view +- the tilt head's range. Range: the sensor model's ``max_range``, capped by a
        depth camera's ``max_range``; stereo rigs return nothing nearer than their
        ``min_depth`` (the matcher's disparity range). Hit range: the rig's (``RigConfig.hit_range_m`` at the
        workspace's voxel), at most its range; the widest over the robots.
        """
        rigs = [mission.rig_for(r) for r in mission.robot_ids]
        lo, hi, far, near, hit = math.inf, -math.inf, 0.0, math.inf, 0.0
        for rig in rigs:
            half_v = math.atan(0.5 * rig.height / rig.fx)
            centre = -math.radians(rig.pitch_deg)
            tilt = math.radians(rig.tilt_range_deg)
            lo = min(lo, centre - half_v - tilt)
            hi = max(hi, centre + half_v + tilt)
            reach = mission.sensor.max_range
            if rig.max_range is not None:
                reach = min(reach, rig.max_range)
            far = max(far, reach)
            hit_range = rig.hit_range_m(mission.workspace.voxel)
            hit = max(hit, reach if hit_range is None else min(reach, hit_range))
            near = min(near, rig.min_depth if rig.mode == "stereo" else 0.0)
        heights = {rig.camera_height for rig in rigs}
        if len(heights) != 1:
            raise ValueError(f"robots with different camera heights {sorted(heights)} are not supported")
        # A floor raster coarser than a ROS map's cells misses walls one cell thick: at 0.025 m
        # per cell, Willow Garage's map let the reachable floor leak from 796 to 4,005 m^2.
        plan = mission.load_floor_plan()
        ros_map = getattr(plan, "ros_map", None)
        if ros_map is not None and ros_map.resolution < cls.raster:
            overrides = {"raster": max(ros_map.resolution, MIN_RASTER), **overrides}
        params = dict(
            camera_height=heights.pop(),
            elevation_lo=max(lo, -math.pi / 2),
            elevation_hi=min(hi, math.pi / 2),
            max_range=far,
            min_range=near,
            hit_range=hit if hit < far else None,
            robot_radius=mission.robot.radius,
        )
        params.update(overrides)
        return cls(**params)


def _raster(plan: FloorPlan, lo: np.ndarray, hi: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Obstacle tops on a lattice of cell centres over [lo, hi] (x, y), and its origin."""
    n = np.maximum(np.ceil((hi - lo) / step).astype(int), 1)
    xs = lo[0] + (np.arange(n[0]) + 0.5) * step
    ys = lo[1] + (np.arange(n[1]) + 0.5) * step
    return plan.height_field(xs, ys), lo


def reachable_floor(
    plan: FloorPlan, lo: np.ndarray, hi: np.ndarray, starts: np.ndarray, robot_radius: float, step: float
) -> np.ndarray:
    """Floor cells (step-m raster of [lo, hi], shape (nx, ny)) a robot's centre can reach.

    A cell is free when its centre is farther than ``robot_radius`` from every obstacle
    cell (the raster's outside counts as open floor); reachable when it is in the
    8-connected free region of one of ``starts`` ((N, 2) x, y).
    """
    top, origin = _raster(plan, np.asarray(lo, float), np.asarray(hi, float), step)
    clearance = ndimage.distance_transform_edt(top <= 0) * step
    free = clearance > robot_radius
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), dtype=bool))
    cells = np.floor((np.asarray(starts, float).reshape(-1, 2) - origin) / step).astype(int)
    cells = np.clip(cells, 0, np.array(free.shape) - 1)
    keep = {int(labels[i, j]) for i, j in cells} - {0}
    return np.isin(labels, list(keep))


def planner_floor(
    plan: FloorPlan, grid: Grid, starts: np.ndarray, robot_radius: float, camera_height: float
) -> np.ndarray:
    """Voxel columns (nx, ny) of ``grid`` that the robots' planner can reach from ``starts``
    ((N, 2) x, y) on a perfect map of ``plan``, bool.

    As ``swarm.navigation.traversability.build_traversability`` sees the true map: a column
    is occupied when a voxel of the robot's band holds ``FREE_THRESHOLD`` of obstacle or
    more (its coverage sampled 4 x 4 per column), occupied columns are inflated by the
    robot's radius, and the planner moves between 4-connected free columns (its diagonal
    steps need both orthogonal neighbours free). A start on an inflated column joins the
    region of its nearest free column.
    """
    from sim2d.ground_truth import coverage

    z = grid.lo[2] + (np.arange(grid.shape[2]) + 0.5) * grid.voxel
    band = np.flatnonzero((z >= FLOOR_CLEARANCE - 1e-9) & (z <= robot_band_top(camera_height) + 1e-9))
    nx, ny, _ = grid.shape
    if band.size == 0:
        return np.zeros((nx, ny), dtype=bool)
    sub = Grid((grid.lo[0], grid.lo[1], grid.lo[2] + band[0] * grid.voxel), grid.voxel, (nx, ny, band.size))
    occupied = (coverage(plan, sub) >= FREE_THRESHOLD).any(axis=2)
    free = inflate(occupied, grid.voxel, robot_radius)
    labels, _ = ndimage.label(free)
    if not free.any():
        return free
    _, (ni, nj) = ndimage.distance_transform_edt(~free, return_indices=True)
    cells = np.floor((np.asarray(starts, float).reshape(-1, 2) - grid.lo[:2]) / grid.voxel).astype(int)
    cells = np.clip(cells, 0, np.array([nx, ny]) - 1)
    keep = {int(labels[ni[i, j], nj[i, j]]) for i, j in cells} - {0}
    return np.isin(labels, list(keep))


def sensor_positions(reach: np.ndarray, origin: np.ndarray, step: float, spacing: float) -> np.ndarray:
    """One reachable cell centre (x, y) per ``spacing`` square: the one nearest its middle."""
    block = max(int(round(spacing / step)), 1)
    ii, jj = np.nonzero(reach)
    if ii.size == 0:
        return np.zeros((0, 2))
    bi, bj = ii // block, jj // block
    mid = (block - 1) / 2
    d = (ii - bi * block - mid) ** 2 + (jj - bj * block - mid) ** 2
    key = bi * (reach.shape[1] // block + 2) + bj
    order = np.lexsort((d, key))
    first = np.ones(order.size, dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    pick = order[first]
    return origin + (np.stack([ii[pick], jj[pick]], axis=1) + 0.5) * step


def _directions(elevation_lo: float, elevation_hi: float, step: float) -> np.ndarray:
    """Unit ray directions (D, 3): elevations ``step`` apart, azimuths ~``step`` apart at each."""
    n_el = max(int(math.ceil((elevation_hi - elevation_lo) / step)) + 1, 1)
    out = []
    for el in np.linspace(elevation_lo, elevation_hi, n_el):
        n_az = max(int(math.ceil(2 * math.pi * math.cos(el) / step)), 1)
        az = np.arange(n_az) * (2 * math.pi / n_az)
        c = math.cos(el)
        out.append(np.stack([c * np.cos(az), c * np.sin(az), np.full(n_az, math.sin(el))], axis=1))
    return np.concatenate(out)


def observable_voxels(
    plan: FloorPlan | None, grid: Grid, starts: np.ndarray, model: ObservabilityModel
) -> np.ndarray:
    """Voxels some reachable sensor pose can observe, bool of shape ``grid.shape``.

    ``starts``: the robots' start points (N, 2). The world's obstacles are ``plan`` (None:
    an empty floor) over the grid's x-y extent widened by the range, so rays that leave the
    grid may still return from walls beyond it. See the module docstring for the model.
    """
    pad = model.max_range + model.raster
    lo = grid.lo[:2] - pad
    hi = grid.hi[:2] + pad
    empty = FloorPlan(quads=np.zeros((0, 4, 2)), heights=np.zeros(0), lo=lo, hi=hi)
    plan = plan if plan is not None else empty
    reach = reachable_floor(plan, lo, hi, starts, model.robot_radius, model.raster)
    reach &= _near_columns(
        planner_floor(plan, grid, starts, model.robot_radius, model.camera_height),
        grid,
        lo,
        model.raster,
        reach.shape,
        1.5 * grid.voxel,
    )
    positions = sensor_positions(reach, lo, model.raster, model.spacing)
    top, origin = _raster(plan, lo, hi, model.raster)
    dirs = _directions(model.elevation_lo, model.elevation_hi, model.angle_step)
    cut = model.max_range if model.hit_range is None else min(model.max_range, model.hit_range)
    seen = np.zeros(grid.size, dtype=np.uint8)
    if positions.size:
        eye = np.column_stack([positions, np.full(len(positions), model.camera_height)])
        _cast(
            top, origin.astype(np.float64), float(model.raster), eye, dirs,
            float(model.min_range), float(model.max_range), float(cut),
            0.5 * min(grid.voxel, 2 * model.raster),
            float(top.max(initial=0.0)),
            grid.lo.astype(np.float64), float(grid.voxel), np.asarray(grid.shape, np.int64), seen,
        )  # fmt: skip
    return seen.reshape(grid.shape).astype(bool)


def _near_columns(
    columns: np.ndarray, grid: Grid, lo: np.ndarray, step: float, shape: tuple[int, int], within: float
) -> np.ndarray:
    """Floor raster cells (``shape``, ``step`` m from ``lo``) whose centre lies within ``within``
    (m) of a centre of ``columns`` ((nx, ny) of ``grid``): the planner's region widened back
    over the strip along the walls where the body fits but no column centre is left (at most
    1.5 voxel edges: a wall covering a fifth of a voxel blocks it, and the inflation keeps
    centres radius + half a voxel from a blocked centre), so that the floor raster loses only
    what lies behind a passage the planner does not take."""
    reach = ndimage.distance_transform_edt(~columns) * grid.voxel <= within
    xs = lo[0] + (np.arange(shape[0]) + 0.5) * step
    ys = lo[1] + (np.arange(shape[1]) + 0.5) * step
    i = np.floor((xs - grid.lo[0]) / grid.voxel).astype(int)
    j = np.floor((ys - grid.lo[1]) / grid.voxel).astype(int)
    inside_i = (i >= 0) & (i < grid.shape[0])
    inside_j = (j >= 0) & (j < grid.shape[1])
    out = np.zeros(shape, dtype=bool)
    out[np.ix_(inside_i, inside_j)] = reach[np.ix_(i[inside_i], j[inside_j])]
    return out


@njit(cache=True)
def _cast(top, origin, res, eyes, dirs, near, far, cut, ds, ztop, glo, e, shape, seen):  # pragma: no cover
    """March every ray of every eye through the height field; mark the voxels of rays that return.

    A ray returning at range s in [near, far] marks the voxels it crossed up to min(s, cut),
    and, when s <= cut, the one behind its hit. A ray that rises above the tallest obstacle
    (``ztop``) can return nothing any more.
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    hx, hy = top.shape
    steps = int(far / ds) + 1
    buf = np.empty(steps + 2, dtype=np.int64)
    for p in range(eyes.shape[0]):
        ex, ey, ez = eyes[p, 0], eyes[p, 1], eyes[p, 2]
        for r in range(dirs.shape[0]):
            dx, dy, dz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
            if dz >= 0.0 and ez >= ztop:
                continue
            n = 0
            last = -1
            hit = False
            for k in range(1, steps + 1):
                s = k * ds
                x, y, z = ex + s * dx, ey + s * dy, ez + s * dz
                if z < 0.0:
                    hit = True
                elif dz >= 0.0 and z >= ztop:
                    break
                else:
                    ci = int(math.floor((x - origin[0]) / res))
                    cj = int(math.floor((y - origin[1]) / res))
                    if 0 <= ci < hx and 0 <= cj < hy and z < top[ci, cj]:
                        hit = True
                vi = int(math.floor((x - glo[0]) / e))
                vj = int(math.floor((y - glo[1]) / e))
                vk = int(math.floor((z - glo[2]) / e))
                if s <= cut and 0 <= vi < nx and 0 <= vj < ny and 0 <= vk < nz:
                    flat = (vi * ny + vj) * nz + vk
                    if flat != last:
                        buf[n] = flat
                        n += 1
                        last = flat
                if hit:
                    if s >= near:
                        if s <= cut:  # a hit; beyond the cut: free space up to it, no hit
                            # the fusion also updates the voxel behind the hit (the surface's far side)
                            for b in range(1, int(2.0 * e / ds) + 2):
                                sb = s + b * ds
                                bi = int(math.floor((ex + sb * dx - glo[0]) / e))
                                bj = int(math.floor((ey + sb * dy - glo[1]) / e))
                                bk = int(math.floor((ez + sb * dz - glo[2]) / e))
                                if not (0 <= bi < nx and 0 <= bj < ny and 0 <= bk < nz):
                                    break
                                behind = (bi * ny + bj) * nz + bk
                                if behind != last:
                                    buf[n] = behind
                                    n += 1
                                    break
                        for q in range(n):
                            seen[buf[q]] = 1
                    break
