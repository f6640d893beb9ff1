"""Loading a mission: YAML to a checked :class:`Mission`, and a mission built from a bare ROS map."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from swarm.config.mission import Mission
from swarm.config.models import (
    OBSERVABLE_FRACTION,
    ConfigError,
    RigConfig,
    RobotBodyConfig,
)
from swarm.config.ros2 import resolve_robot_ros2
from swarm.formats.errors import refuse_non_finite, user_path
from swarm.formats.validation_errors import describe_validation_error
from swarm.formats.yaml_file import read_yaml

# -- loading and checking ------------------------------------------------------------------


def load_mission(path: str | Path) -> Mission:
    """Read, validate and check a mission YAML file; raise ConfigError on any problem."""
    path = Path(path)
    return mission_from_dict(read_yaml(path, ConfigError), source=path)


def mission_from_dict(
    data: object, source: str | Path | None = None, base_dir: str | Path | None = None
) -> Mission:
    """Validate a parsed mission; relative paths are taken from ``base_dir`` or the source's folder."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source or '<mission>'}: (top level): must be a mapping of sections")
    refuse_non_finite(data, source or "<mission>", ConfigError)
    try:
        mission = Mission.model_validate(data)
    except ValidationError as e:
        raise ConfigError(describe_validation_error(e, source, Mission)) from e
    mission._source = Path(source) if source is not None else None
    if base_dir is not None:
        mission._base_dir = Path(base_dir)
    elif source is not None:
        mission._base_dir = Path(source).resolve().parent
    check_mission(mission)
    return mission


def check_mission(mission: Mission) -> None:
    """Cross-field checks: unique ids, rigs, and the starts given inside the workspace and in
    free space (a robot without ``start`` is checked by the simulator: ``Mission.start_poses``)."""
    where = mission.source or "<mission>"

    def fail(field: str, problem: str) -> None:
        raise ConfigError(f"{where}: {field}: {problem}")

    seen: set[str] = set()
    for i, robot in enumerate(mission.robots):
        if robot.id in seen:
            fail(f"robots[{i}].id", f"duplicate robot id {robot.id!r}")
        seen.add(robot.id)
        mission._robot_rigs[robot.id] = _resolve_rig(mission, robot.rig, f"robots[{i}].rig")
        field = f"robots[{i}].ros2"
        mission._robot_ros2[robot.id] = resolve_robot_ros2(mission.ros2, robot.ros2, where, field)
    for name, overrides in mission.rigs.items():
        _resolve_rig(mission, overrides, f"rigs.{name}")

    lo, hi = mission.workspace.lo, mission.workspace.hi
    #: (index in robots, robot) of the robots with a start pose
    placed = [(i, robot) for i, robot in enumerate(mission.robots) if robot.start is not None]
    for i, robot in placed:
        x, y = robot.start.x, robot.start.y
        if not (lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]):
            fail(
                f"robots[{i}].start",
                f"({x:g}, {y:g}) is outside the workspace x [{lo[0]:g}, {hi[0]:g}], y [{lo[1]:g}, {hi[1]:g}]",
            )

    prior = mission.prior_map_path()
    if prior is not None:
        if not prior.is_file():
            fail("prior_map", f"file not found: {prior}")
        if prior.suffix.lower() not in (".npz", ".bt", ".ot"):
            fail("prior_map", f"{prior}: must be a map .npz or an OctoMap .bt or .ot")

    if mission.floor_plan is not None:
        from swarm.formats.floor_plan import FloorPlanError

        ref = mission.floor_plan_ref()
        if not Path(ref.path).is_file():
            fail("floor_plan", f"file not found: {ref.path}")
        try:
            plan = mission.load_floor_plan()
        except FloorPlanError as e:
            fail("floor_plan", str(e))
        starts = np.array([[r.start.x, r.start.y] for _, r in placed]).reshape(-1, 2)
        clearance = plan.clearance(starts) if len(placed) else np.zeros(0)
        radius = mission.robot.radius
        for k, (i, robot) in enumerate(placed):
            at = f"({robot.start.x:g}, {robot.start.y:g})"
            if clearance[k] <= 0:
                fail(
                    f"robots[{i}].start",
                    f"{at} lies inside a wall/box of the floor plan{_free_hint(plan, starts[k], radius)}",
                )
            if clearance[k] < radius:
                fail(
                    f"robots[{i}].start",
                    f"{at} is {clearance[k]:.3f} m from a wall/box, closer than the robot "
                    f"radius {radius:g} m{_free_hint(plan, starts[k], radius)}",
                )
            if plan.ros_map is not None:
                (row, col), (rows, cols) = plan.ros_map.to_cell(starts[k]), plan.ros_map.shape
                if not (0 <= row < rows and 0 <= col < cols):
                    fail(
                        f"robots[{i}].start",
                        f"{at} is outside the image of {plan.ros_map.source}"
                        f"{_free_hint(plan, starts[k], radius)}",
                    )
                if not plan.ros_map.free[row, col]:
                    fail(
                        f"robots[{i}].start",
                        f"{at} is not on the mapped floor: the cell (row {rows - 1 - row}, column {col} of "
                        f"{plan.ros_map.source.name}'s image) is unknown"
                        f"{_free_hint(plan, starts[k], radius)}",
                    )

    for k, (i, a) in enumerate(placed):
        for _, b in placed[:k]:
            gap = math.hypot(a.start.x - b.start.x, a.start.y - b.start.y)
            if gap < 2 * mission.robot.radius:
                fail(
                    f"robots[{i}].start",
                    f"overlaps robot {b.id!r} (centres {gap:.3f} m apart, "
                    f"need {2 * mission.robot.radius:g} m)",
                )


def _free_hint(plan, xy: np.ndarray, radius: float) -> str:
    """``; the nearest free point ...`` of a ROS-map floor plan where a robot of ``radius`` fits."""
    ros_map = plan.ros_map
    if ros_map is None:
        return ""
    # Half a cell more than the radius: the raster's clearance may exceed the exact one (the
    # walls' quads that the start is checked against) by up to 0.21 cell on a diagonal.
    rows, cols = np.nonzero(ros_map.clearance() > radius + 0.5 * ros_map.resolution)
    if rows.size == 0:
        return f"; the map has no free space where a robot of radius {radius:g} m fits"
    centres = ros_map.to_world(cols + 0.5, rows + 0.5)
    best = centres[np.argmin(np.linalg.norm(centres - xy, axis=1))]
    return f"; the nearest free point where the robot fits is ({best[0]:.2f}, {best[1]:.2f})"


def _resolve_rig(mission: Mission, rig: str | dict | None, field: str) -> RigConfig:
    where = mission.source or "<mission>"
    if rig is None:
        return mission.rig
    if isinstance(rig, str):
        if rig in ("default", ""):
            return mission.rig
        if rig in mission.rigs:
            rig = mission.rigs[rig]
        elif rig.endswith((".yaml", ".yml")):
            rig_path = user_path(rig, mission._base_dir)
            try:
                rig = read_yaml(rig_path, ConfigError) or {}
            except ConfigError as e:
                raise ConfigError(f"{where}: {field}: rig file {e}") from e
            if not isinstance(rig, dict):
                raise ConfigError(f"{where}: {field}: rig file {rig_path} is not a mapping")
        else:
            known = ", ".join(["default", *mission.rigs]) or "default"
            raise ConfigError(f"{where}: {field}: unknown rig {rig!r} (known: {known})")
    merged = {**mission.rig.model_dump(), **rig}
    try:
        return RigConfig.model_validate(merged)
    except ValidationError as e:
        lines = describe_validation_error(e, where, RigConfig).splitlines()
        prefix = f"{where}: "
        raise ConfigError("\n".join(f"{prefix}{field}.{line[len(prefix) :]}" for line in lines)) from e


# -- a mission from a bare ROS map -----------------------------------------------------------


def mission_from_map(
    map_yaml: str | Path,
    robots: int = 1,
    start: tuple[float, float] | None = None,
    *,
    voxel: float = 0.1,
    wall_height: float = 2.0,
    z_margin: float = 0.2,
    spacing: float = 1.0,
    name: str | None = None,
) -> Mission:
    """A mission over a ROS map: workspace = known part of the map x [0, wall_height + z_margin].

    The workspace's corners are whole voxels from the world origin (OctoMap's lattice), so
    its maps export to ``.bt`` without a shift; the box grows by under a voxel per side.

    Robots start in known free space with at least robot radius + 0.15 m clearance
    (:meth:`RosMap.clearance`: to the nearest wall, unknown cell or the image's edge), in the
    free region connected to ``start`` (default: the largest free region, from its cell
    closest to the middle of the known part of the map), at least ``spacing`` metres apart,
    each facing into the most open space around it (:func:`_open_heading`). H_th follows the
    observable rule (``stop.observable_fraction`` = OBSERVABLE_FRACTION): the entropy of the
    voxels no sensor can ever observe + 16% of the observable prior, resolved by the
    simulator when the mission runs.
    """
    from scipy import ndimage

    from swarm.formats.floor_plan import load_ros_map

    map_yaml = Path(map_yaml)
    if not (isinstance(robots, int) and robots >= 1):
        raise ConfigError(f"{map_yaml}: robots: must be a whole number of at least 1 (got {robots!r})")
    _refuse_non_ros_map(map_yaml)
    body = RobotBodyConfig()
    ros_map = load_ros_map(map_yaml)
    known = ros_map.occupied | ros_map.free
    rows_all, cols_all = ros_map.shape
    size = (
        f"{cols_all:,} x {rows_all:,} cells at {ros_map.resolution:g} m: "
        f"{cols_all * ros_map.resolution:g} m x {rows_all * ros_map.resolution:g} m"
    )
    if not ros_map.free.any():
        raise ConfigError(
            f"{map_yaml}: the map has no free cells ({size}; {int(ros_map.occupied.sum()):,} occupied, "
            "the rest unknown); check mode, negate, free_thresh and occupied_thresh against the image"
        )

    rows, cols = np.nonzero(known)
    corners = ros_map.to_world(
        np.array([cols.min(), cols.max() + 1, cols.max() + 1, cols.min()]),
        np.array([rows.min(), rows.min(), rows.max() + 1, rows.max() + 1]),
    )
    # The box in whole voxels from the world origin (OctoMap's lattice, so the map exports
    # to .bt as it is); the rounding keeps 10.2 / 0.1 = 101.99999... at 102 voxels.
    lo_xy = np.floor(np.round(corners.min(axis=0) / voxel, 6)) * voxel
    hi_xy = np.ceil(np.round(corners.max(axis=0) / voxel, 6)) * voxel
    lo_xy, hi_xy = np.round(lo_xy, 9), np.round(hi_xy, 9)

    clearance = ros_map.clearance()
    ok = clearance > body.radius + 0.15
    if not ok.any():
        raise ConfigError(
            f"{map_yaml}: no free space wide enough for a robot: a start needs {body.radius + 0.15:g} m "
            f"from every wall and unknown cell, the most the map offers is {clearance.max():.3g} m ({size}); "
            "check resolution (metres per cell)"
        )
    ok_rows, ok_cols = np.nonzero(ok)
    centres = ros_map.to_world(ok_cols + 0.5, ok_rows + 0.5)
    labels, _ = ndimage.label(ok)
    region = labels[ok_rows, ok_cols]
    if start is None:
        # The largest free region: the one nearest the middle may be a pocket of a few
        # cells (a SLAM map's free specks in a courtyard, Willow Garage's map).
        largest = np.argmax(np.bincount(region)[1:]) + 1
        candidates = np.flatnonzero(region == largest)
        anchor = (lo_xy + hi_xy) / 2
    else:
        candidates = np.arange(len(centres))
        anchor = np.asarray(start, dtype=np.float64)
    first = candidates[int(np.argmin(np.linalg.norm(centres[candidates] - anchor, axis=1)))]
    seed = centres[first]
    reachable = centres[region == region[first]]
    chosen: list[np.ndarray] = []
    for p in reachable[np.argsort(np.linalg.norm(reachable - seed, axis=1))]:
        if all(np.linalg.norm(p - q) >= spacing for q in chosen):
            chosen.append(p)
            if len(chosen) == robots:
                break
    if len(chosen) < robots:
        area = len(reachable) * ros_map.resolution**2
        raise ConfigError(
            f"{map_yaml}: room for only {len(chosen)} robot(s) {spacing:g} m apart in the free region "
            f"around ({seed[0]:.2f}, {seed[1]:.2f}) ({area:.1f} m^2 where a robot's centre fits); "
            "ask for fewer robots"
        )

    yaws = [_open_heading(ros_map, p) for p in chosen]
    data = {
        "mission": name or _safe_name(map_yaml.stem),
        "workspace": {
            "lo": [float(lo_xy[0]), float(lo_xy[1]), 0.0],
            "hi": [float(hi_xy[0]), float(hi_xy[1]), wall_height + z_margin],
            "voxel": voxel,
        },
        "floor_plan": {"path": str(map_yaml.resolve()), "wall_height": wall_height},
        "stop": {"observable_fraction": OBSERVABLE_FRACTION},
        "robots": [
            {"id": f"r{i + 1}", "start": {"x": float(p[0]), "y": float(p[1]), "yaw": yaw}}
            for i, (p, yaw) in enumerate(zip(chosen, yaws, strict=True))
        ],
    }
    return mission_from_dict(data, source=map_yaml, base_dir=map_yaml.parent)


#: How far (m) a start looks for open space: the default sensor's range (``sensor.max_range``).
OPEN_VIEW_M = 5.0
#: Headings a start may face: every 5 degrees, counter-clockwise from +x.
HEADINGS = np.deg2rad(np.arange(0, 360, 5))


def _open_heading(ros_map, xy: np.ndarray) -> float:
    """The yaw (radians, in [0, 2 pi)) a robot starting at ``xy`` faces: into the most open space.

    For each of :data:`HEADINGS`, the mean length of the free rays (:meth:`RosMap.free_ray_lengths`,
    up to :data:`OPEN_VIEW_M`) over that heading and its two neighbours on either side (a
    20 degree fan, so a slit between two walls does not win over an open room); the heading
    with the longest mean wins, the first counter-clockwise from +x on a tie (so a start with
    open space all round faces +x, as before). Rays stop at walls and unknown cells, which a
    farthest free cell of the region (behind a wall) or the clearance's gradient (zero in the
    middle of a room) would not.
    """
    rays = ros_map.free_ray_lengths(xy, HEADINGS, OPEN_VIEW_M)
    fan = sum(np.roll(rays, k) for k in range(-2, 3)) / 5
    best = np.flatnonzero(fan >= fan.max() - 1e-9)[0]
    return round(float(HEADINGS[best]), 6)


_IMAGE_SUFFIXES = (".pgm", ".pbm", ".ppm", ".pnm", ".pam", ".png", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg")


def _refuse_non_ros_map(path: Path) -> None:
    """A ConfigError saying what ``path`` is and what to give instead, unless it is a map.yaml."""
    expected = "a ROS map_server map.yaml (image:, resolution:, origin:)"
    if path.suffix.lower() in _IMAGE_SUFFIXES:
        raise ConfigError(
            f"{path}: a map image, where {expected} is expected: give the map.yaml that names this image "
            "(map_server and map_saver write one beside it)"
        )
    from swarm.formats.ros_map import is_ros_map

    data = read_yaml(path, ConfigError)
    if isinstance(data, dict) and not is_ros_map(data):
        if "workspace" in data or "robots" in data:
            raise ConfigError(
                f"{path}: a mission, where {expected} is expected: run it as CONFIG, without --map"
            )
        if {"walls", "boxes", "bounds"} & set(data):
            raise ConfigError(
                f"{path}: a project floor plan, where {expected} is expected: name it as floor_plan "
                "in a mission"
            )


def _safe_name(text: str) -> str:
    return "".join(c if c.isalnum() or c in "_-" else "_" for c in text) or "default"
