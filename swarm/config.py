"""Mission configuration: pydantic models loaded from YAML, validated with readable errors.

``load_mission(path)`` reads a mission file; every problem is raised as a ``ConfigError``
whose message names the file, the dotted field path and what is wrong, e.g.
``configs/x.yaml: workspace.voxel: must be > 0 (got -0.1)``.

Paths inside a mission (``floor_plan``, rig files) are relative to the mission file.
Rigs: the top-level ``rig`` is the default; ``rigs`` holds named variants (each a set of
overrides of the default rig); a robot's ``rig`` is a name from ``rigs``, a path to a
rig YAML file (overrides too) or an inline mapping of overrides.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    FiniteFloat,
    PrivateAttr,
    ValidationError,
    model_validator,
)

from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.wire import Camera
from swarm.yaml_file import read_yaml

#: Entropy of one voxel under the near-uniform prior (128 bins), in bits.
PRIOR_BITS_PER_VOXEL = 7.0
#: Default stopping threshold H_th as a fraction of the initial map entropy.
DEFAULT_THRESHOLD_FRACTION = 0.25

_NAME_PATTERN = r"^[A-Za-z0-9_-]+$"


class ConfigError(ValueError):
    """An invalid mission file: the message names the file, the field and the problem."""


# -- error messages --------------------------------------------------------------------


def _dotted(loc: tuple) -> str:
    """``('robots', 0, 'start')`` -> ``robots[0].start``, dropping pydantic's union tags."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not _is_type_tag(part):
            out += f".{part}" if out else str(part)
    return out or "(top level)"


def _is_type_tag(part: str) -> bool:
    return (
        "[" in part
        or part[:1].isupper()
        or part.startswith("function-")
        or part in {"str", "int", "float", "bool", "dict", "list", "tuple", "none", "literal"}
    )


def _problem(error: dict) -> str:
    kind, ctx = error["type"], error.get("ctx", {})
    got = error.get("input")
    shown = "" if isinstance(got, dict) else f" (got {got!r})"
    bounds = {
        "greater_than": ("gt", ">"),
        "greater_than_equal": ("ge", ">="),
        "less_than": ("lt", "<"),
        "less_than_equal": ("le", "<="),
    }
    if kind in bounds:
        key, op = bounds[kind]
        limit = ctx.get(key)
        limit = f"{limit:g}" if isinstance(limit, float) else limit
        return f"must be {op} {limit}{shown}"
    if kind == "missing":
        return "is required"
    if kind == "extra_forbidden":
        return "unknown field"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected')}{shown}"
    if kind == "finite_number":
        return f"must be a finite number{shown}"
    if kind == "value_error":
        return str(ctx.get("error", error["msg"]))
    return f"{error['msg'][0].lower()}{error['msg'][1:]}{shown}"


def describe_validation_error(err: ValidationError, source: str | Path | None) -> str:
    """One line per problem: ``<file>: <dotted.path>: <problem>``."""
    lines: list[str] = []
    for error in err.errors():
        line = f"{source or '<mission>'}: {_dotted(error['loc'])}: {_problem(error)}"
        if line not in lines:
            lines.append(line)
    return "\n".join(lines)


# -- sections --------------------------------------------------------------------------


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


class WorkspaceConfig(_Section):
    """The mapped box [lo, hi] (metres) and the voxel edge."""

    lo: Vec3
    hi: Vec3
    voxel: FiniteFloat = Field(default=0.1, gt=0)

    @model_validator(mode="after")
    def _hi_above_lo(self) -> WorkspaceConfig:
        if not all(h > lo for lo, h in zip(self.lo, self.hi, strict=True)):
            raise ValueError(f"hi {list(self.hi)} must be above lo {list(self.lo)} on every axis")
        return self

    def grid(self) -> Grid:
        """The voxel grid covering the workspace."""
        return Grid.from_bounds(np.array(self.lo), np.array(self.hi), self.voxel)


class Pose2D(_Section):
    """A pose on the floor: position (m) and yaw (radians, counter-clockwise from +x)."""

    x: FiniteFloat
    y: FiniteFloat
    yaw: FiniteFloat = 0.0


class RigConfig(_Section):
    """A rectified stereo rig (or, in ``range`` mode, a depth camera) on a robot.

    The left camera is the reference, on the robot's centre at ``camera_height``; the right
    one is ``baseline`` metres to its right. ``noise_std`` is image noise in grey levels;
    ``range_noise`` is the depth noise standard deviation per metre of range (range mode);
    ``max_range`` (m) turns farther returns into no return (None: unlimited).
    ``pitch_deg`` is the mounting pitch (positive looks down); ``tilt_range_deg`` > 0 puts
    the camera on a tilt head that commands can point up to that many degrees up or down
    from the mounting pitch (0: a fixed camera).
    """

    width: int = Field(default=160, ge=8)
    height: int = Field(default=120, ge=8)
    hfov_deg: FiniteFloat = Field(default=60.0, gt=0, lt=170)
    baseline: FiniteFloat = Field(default=0.09, ge=0)
    camera_height: FiniteFloat = Field(default=0.4, gt=0)
    pitch_deg: FiniteFloat = Field(default=0.0, ge=-80, le=80)
    tilt_range_deg: FiniteFloat = Field(default=0.0, ge=0, le=80)
    noise_std: FiniteFloat = Field(default=0.0, ge=0)
    mode: Literal["stereo", "range"] = "stereo"
    range_noise: FiniteFloat = Field(default=0.01, ge=0)
    max_range: FiniteFloat | None = Field(default=None, gt=0)

    @model_validator(mode="after")
    def _stereo_needs_baseline(self) -> RigConfig:
        if self.mode == "stereo" and self.baseline <= 0:
            raise ValueError("baseline must be > 0 in stereo mode")
        return self

    @property
    def fx(self) -> float:
        """Focal length in pixels from the horizontal field of view."""
        return 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2)

    def camera(self) -> Camera:
        """Pinhole intrinsics (square pixels, principal point at the image centre)."""
        return Camera(
            width=self.width,
            height=self.height,
            fx=self.fx,
            fy=self.fx,
            cx=(self.width - 1) / 2,
            cy=(self.height - 1) / 2,
            baseline=self.baseline,
        )


class SensorConfig(_Section):
    """Parameters of the Gaussian sensor model (DESIGN.md section 3)."""

    sigma_min: FiniteFloat = Field(default=0.06, gt=0)
    zeta: FiniteFloat = Field(default=0.0375, ge=0)
    tau: FiniteFloat = Field(default=2.0, gt=0)
    max_range: FiniteFloat = Field(default=5.0, gt=0)

    def model(self) -> SensorModel:
        return SensorModel(self.sigma_min, self.zeta, self.tau, self.max_range)


class ExplorationConfig(BaseModel):
    """Entropy-gradient exploration; other keys are kept for the roles that read them."""

    model_config = ConfigDict(extra="allow")

    radius: FiniteFloat = Field(default=1.5, gt=0, description="candidate radius xi (m)")
    gaze: bool = Field(default=True, description="on arrival, look along the entropy gradient")
    random_wander_steps: int = Field(default=20, ge=0)


class SharingConfig(_Section):
    share_min_bits: FiniteFloat = Field(default=0.5, ge=0)


class CoordinationConfig(_Section):
    """The coordinator's Burgard-style assignment (docs/coordinator.md).

    ``footprint_radius`` None: min(2 * exploration.radius, sensor.max_range).
    """

    beta: FiniteFloat = Field(default=0.1, ge=0, description="utility lost per metre of path (1/m)")
    footprint_radius: FiniteFloat | None = Field(default=None, gt=0)
    overlap_weight: FiniteFloat = Field(
        default=1.0, ge=0, le=1, description="utility lost per share of a footprint that is teammates' ground"
    )
    robot_timeout_s: FiniteFloat = Field(default=10.0, gt=0)
    max_candidates: int = Field(default=200, ge=1)
    candidate_spacing: FiniteFloat = Field(default=0.5, ge=0)


class RobotBodyConfig(_Section):
    """The simulated robot: a disc with differential-drive limits."""

    radius: FiniteFloat = Field(default=0.18, gt=0)
    max_speed: FiniteFloat = Field(default=0.5, gt=0)
    max_turn_rate: FiniteFloat = Field(default=1.5, gt=0)


class StopConfig(_Section):
    """Stop when the map entropy reaches H_th (bits) or after ``max_time_s`` of sim time."""

    entropy_threshold_bits: FiniteFloat | None = Field(default=None, ge=0)
    max_time_s: FiniteFloat = Field(default=600.0, gt=0)


class SimConfig(_Section):
    """Simulator clock: physics step ``dt``, one frame every ``frame_period_s``."""

    dt: FiniteFloat = Field(default=0.1, gt=0)
    frame_period_s: FiniteFloat = Field(default=0.5, gt=0)
    seed: int = 0
    agent_timeout_s: FiniteFloat = Field(default=10.0, gt=0)

    @model_validator(mode="after")
    def _frame_after_step(self) -> SimConfig:
        if self.frame_period_s < self.dt:
            raise ValueError(f"frame_period_s ({self.frame_period_s}) must be >= dt ({self.dt})")
        return self


class FloorPlanRef(_Section):
    """A floor plan file (project YAML or ROS map.yaml) and the height of ROS-map walls."""

    path: str
    wall_height: FiniteFloat = Field(default=2.0, gt=0)


class RobotSpec(_Section):
    id: str = Field(pattern=_NAME_PATTERN)
    start: Pose2D
    rig: str | dict[str, Any] | None = None


class Mission(_Section):
    """A whole mission file. Use ``load_mission`` to read and check one."""

    mission: str = Field(default="default", pattern=_NAME_PATTERN)
    workspace: WorkspaceConfig
    floor_plan: str | FloorPlanRef | None = None
    robots: list[RobotSpec] = Field(min_length=1)
    rig: RigConfig = RigConfig()
    rigs: dict[str, dict[str, Any]] = {}
    sensor: SensorConfig = SensorConfig()
    exploration: ExplorationConfig = ExplorationConfig()
    sharing: SharingConfig = SharingConfig()
    coordination: CoordinationConfig = CoordinationConfig()
    robot: RobotBodyConfig = RobotBodyConfig()
    stop: StopConfig = StopConfig()
    sim: SimConfig = SimConfig()

    _source: Path | None = PrivateAttr(default=None)
    _base_dir: Path = PrivateAttr(default_factory=Path.cwd)
    _robot_rigs: dict[str, RigConfig] = PrivateAttr(default_factory=dict)
    _plan: Any = PrivateAttr(default=None)

    # -- accessors -----------------------------------------------------------------------
    @property
    def source(self) -> Path | None:
        """The file this mission was loaded from, if any."""
        return self._source

    @property
    def robot_ids(self) -> list[str]:
        return [r.id for r in self.robots]

    def robot_spec(self, robot_id: str) -> RobotSpec:
        for spec in self.robots:
            if spec.id == robot_id:
                return spec
        raise KeyError(f"no robot {robot_id!r} in mission {self.mission!r}")

    def rig_for(self, robot_id: str) -> RigConfig:
        """The resolved rig of a robot (its own overrides applied to the default rig)."""
        self.robot_spec(robot_id)
        return self._robot_rigs.get(robot_id, self.rig)

    def floor_plan_ref(self) -> FloorPlanRef | None:
        """The floor plan reference with its path made absolute."""
        if self.floor_plan is None:
            return None
        ref = self.floor_plan
        if isinstance(ref, str):
            ref = FloorPlanRef(path=ref)
        return ref.model_copy(update={"path": str((self._base_dir / ref.path).resolve())})

    def load_floor_plan(self):
        """The mission's ``swarm.floor_plan.FloorPlan`` (cached), or None without one."""
        if self._plan is None and self.floor_plan is not None:
            from swarm.floor_plan import load_floor_plan

            ref = self.floor_plan_ref()
            self._plan = load_floor_plan(ref.path, ref.wall_height)
        return self._plan

    def threshold_bits(self) -> float:
        """H_th: the configured threshold, else 25% of the prior entropy (7 bits per voxel)."""
        if self.stop.entropy_threshold_bits is not None:
            return float(self.stop.entropy_threshold_bits)
        return DEFAULT_THRESHOLD_FRACTION * PRIOR_BITS_PER_VOXEL * self.workspace.grid().size

    def to_yaml(self) -> str:
        """The mission as YAML, with file paths made absolute (for run folders)."""
        data = self.model_dump(mode="json", exclude_none=True)
        ref = self.floor_plan_ref()
        if ref is not None:
            data["floor_plan"] = ref.model_dump(mode="json")
        for robot in data["robots"]:
            rig = robot.get("rig")
            if isinstance(rig, str) and rig.endswith((".yaml", ".yml")):
                robot["rig"] = str((self._base_dir / rig).resolve())
        return yaml.safe_dump(data, sort_keys=False)


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
    try:
        mission = Mission.model_validate(data)
    except ValidationError as e:
        raise ConfigError(describe_validation_error(e, source)) from e
    mission._source = Path(source) if source is not None else None
    if base_dir is not None:
        mission._base_dir = Path(base_dir)
    elif source is not None:
        mission._base_dir = Path(source).resolve().parent
    check_mission(mission)
    return mission


def check_mission(mission: Mission) -> None:
    """Cross-field checks: unique ids, rigs, starts inside the workspace and in free space."""
    where = mission.source or "<mission>"

    def fail(field: str, problem: str) -> None:
        raise ConfigError(f"{where}: {field}: {problem}")

    seen: set[str] = set()
    for i, robot in enumerate(mission.robots):
        if robot.id in seen:
            fail(f"robots[{i}].id", f"duplicate robot id {robot.id!r}")
        seen.add(robot.id)
        mission._robot_rigs[robot.id] = _resolve_rig(mission, robot.rig, f"robots[{i}].rig")
    for name, overrides in mission.rigs.items():
        _resolve_rig(mission, overrides, f"rigs.{name}")

    lo, hi = mission.workspace.lo, mission.workspace.hi
    for i, robot in enumerate(mission.robots):
        x, y = robot.start.x, robot.start.y
        if not (lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]):
            fail(
                f"robots[{i}].start",
                f"({x:g}, {y:g}) is outside the workspace x [{lo[0]:g}, {hi[0]:g}], y [{lo[1]:g}, {hi[1]:g}]",
            )

    if mission.floor_plan is not None:
        from swarm.floor_plan import FloorPlanError

        ref = mission.floor_plan_ref()
        if not Path(ref.path).is_file():
            fail("floor_plan", f"file not found: {ref.path}")
        try:
            plan = mission.load_floor_plan()
        except FloorPlanError as e:
            fail("floor_plan", str(e))
        starts = np.array([[r.start.x, r.start.y] for r in mission.robots])
        clearance = plan.clearance(starts)
        for i, robot in enumerate(mission.robots):
            at = f"({robot.start.x:g}, {robot.start.y:g})"
            if clearance[i] <= 0:
                fail(f"robots[{i}].start", f"{at} lies inside a wall/box of the floor plan")
            if clearance[i] < mission.robot.radius:
                fail(
                    f"robots[{i}].start",
                    f"{at} is {clearance[i]:.3f} m from a wall/box, closer than the robot "
                    f"radius {mission.robot.radius:g} m",
                )

    for i, a in enumerate(mission.robots):
        for b in mission.robots[:i]:
            gap = math.hypot(a.start.x - b.start.x, a.start.y - b.start.y)
            if gap < 2 * mission.robot.radius:
                fail(
                    f"robots[{i}].start",
                    f"overlaps robot {b.id!r} (centres {gap:.3f} m apart, "
                    f"need {2 * mission.robot.radius:g} m)",
                )


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
            rig_path = mission._base_dir / rig
            try:
                rig = yaml.safe_load(rig_path.read_text(encoding="utf-8")) or {}
            except (OSError, yaml.YAMLError) as e:
                raise ConfigError(f"{where}: {field}: cannot read rig file {rig_path}: {e}") from e
            if not isinstance(rig, dict):
                raise ConfigError(f"{where}: {field}: rig file {rig_path} is not a mapping")
        else:
            known = ", ".join(["default", *mission.rigs]) or "default"
            raise ConfigError(f"{where}: {field}: unknown rig {rig!r} (known: {known})")
    merged = {**mission.rig.model_dump(), **rig}
    try:
        return RigConfig.model_validate(merged)
    except ValidationError as e:
        lines = describe_validation_error(e, where).splitlines()
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

    Robots start in known free space with at least robot radius + 0.15 m clearance (unknown
    cells count as obstacles), in the free region connected to ``start`` (default: the free
    cell closest to the middle of the known part of the map), at least ``spacing`` metres
    apart, facing +x. H_th is 25% of the prior entropy (7 bits per voxel).
    """
    from scipy import ndimage

    from swarm.floor_plan import load_ros_map

    map_yaml = Path(map_yaml)
    body = RobotBodyConfig()
    ros_map = load_ros_map(map_yaml)
    known = ros_map.occupied | ros_map.free
    if not ros_map.free.any():
        raise ConfigError(f"{map_yaml}: the map has no free cells")

    rows, cols = np.nonzero(known)
    corners = ros_map.to_world(
        np.array([cols.min(), cols.max() + 1, cols.max() + 1, cols.min()]),
        np.array([rows.min(), rows.min(), rows.max() + 1, rows.max() + 1]),
    )
    lo_xy, hi_xy = np.round(corners.min(axis=0), 6), np.round(corners.max(axis=0), 6)

    clearance = ndimage.distance_transform_edt(ros_map.free) * ros_map.resolution
    ok = clearance > body.radius + 0.15
    if not ok.any():
        raise ConfigError(f"{map_yaml}: no free space wide enough for a robot")
    ok_rows, ok_cols = np.nonzero(ok)
    centres = ros_map.to_world(ok_cols + 0.5, ok_rows + 0.5)
    anchor = np.asarray(start if start is not None else (lo_xy + hi_xy) / 2, dtype=np.float64)
    first = int(np.argmin(np.linalg.norm(centres - anchor, axis=1)))
    seed = centres[first]
    labels, _ = ndimage.label(ok)
    reachable = centres[labels[ok_rows, ok_cols] == labels[ok_rows[first], ok_cols[first]]]
    chosen: list[np.ndarray] = []
    for p in reachable[np.argsort(np.linalg.norm(reachable - seed, axis=1))]:
        if all(np.linalg.norm(p - q) >= spacing for q in chosen):
            chosen.append(p)
            if len(chosen) == robots:
                break
    if len(chosen) < robots:
        raise ConfigError(f"{map_yaml}: room for only {len(chosen)} robots {spacing:g} m apart")

    data = {
        "mission": name or _safe_name(map_yaml.stem),
        "workspace": {
            "lo": [float(lo_xy[0]), float(lo_xy[1]), 0.0],
            "hi": [float(hi_xy[0]), float(hi_xy[1]), wall_height + z_margin],
            "voxel": voxel,
        },
        "floor_plan": {"path": str(map_yaml.resolve()), "wall_height": wall_height},
        "robots": [
            {"id": f"r{i + 1}", "start": {"x": float(p[0]), "y": float(p[1]), "yaw": 0.0}}
            for i, p in enumerate(chosen)
        ],
    }
    mission = mission_from_dict(data, source=map_yaml, base_dir=map_yaml.parent)
    mission.stop.entropy_threshold_bits = mission.threshold_bits()
    return mission


def _safe_name(text: str) -> str:
    return "".join(c if c.isalnum() or c in "_-" else "_" for c in text) or "default"
