"""The whole mission file: its sections together (``swarm.config.models``), and what the roles
ask of it: each robot's rig and sensor model, the sensor reach, file paths, H_th, and the
mission as YAML for run folders. How a robot's rig is found (the default ``rig``, named
``rigs``, files, inline overrides): the package's docstring, ``swarm.config``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import Field, PrivateAttr

from swarm.config.models import (
    DEFAULT_THRESHOLD_FRACTION,
    NAME_PATTERN,
    PRIOR_BITS_PER_VOXEL,
    ConfigError,
    CoordinationConfig,
    ExplorationConfig,
    FloorPlanRef,
    MapServiceConfig,
    Pose2D,
    RigConfig,
    RobotBodyConfig,
    RobotSpec,
    Section,
    SensorConfig,
    SharingConfig,
    SimConfig,
    StopConfig,
    WorkspaceConfig,
)
from swarm.config.ros2 import Ros2Config
from swarm.formats.errors import user_path
from swarm.map.sensor_model import SensorModel
from swarm.map.shard_layout import ShardLayout


class Mission(Section):
    """A whole mission file. Use ``load_mission`` to read and check one."""

    mission: str = Field(default="default", pattern=NAME_PATTERN)
    workspace: WorkspaceConfig
    floor_plan: str | FloorPlanRef | None = None
    #: a previous map (map.npz or OctoMap .bt or .ot) the mission starts from (paper section II.C.1)
    prior_map: str | None = None
    robots: list[RobotSpec] = Field(min_length=1)
    rig: RigConfig = RigConfig()
    rigs: dict[str, dict[str, Any]] = {}
    sensor: SensorConfig = SensorConfig()
    exploration: ExplorationConfig = ExplorationConfig()
    sharing: SharingConfig = SharingConfig()
    coordination: CoordinationConfig = CoordinationConfig()
    map_service: MapServiceConfig = MapServiceConfig()
    robot: RobotBodyConfig = RobotBodyConfig()
    stop: StopConfig = StopConfig()
    sim: SimConfig = SimConfig()
    #: how robots running ROS 2 give frames and take commands (docs/ros2.md); robots may override
    ros2: Ros2Config = Ros2Config()

    _source: Path | None = PrivateAttr(default=None)
    _base_dir: Path = PrivateAttr(default_factory=Path.cwd)
    _robot_rigs: dict[str, RigConfig] = PrivateAttr(default_factory=dict)
    _robot_ros2: dict[str, Ros2Config] = PrivateAttr(default_factory=dict)
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

    def start_of(self, robot_id: str) -> Pose2D:
        """A robot's start pose, where the simulator places it (m, m, rad).

        Raises ConfigError naming the file and ``robots[i].start`` when the mission gives none
        (a mission of real robots needs none: their poses come from their frames), KeyError
        when the mission has no such robot.
        """
        spec = self.robot_spec(robot_id)
        if spec.start is None:
            raise ConfigError(self._missing_starts([self.robots.index(spec)]))
        return spec.start

    def start_poses(self) -> list[Pose2D]:
        """Every robot's start pose, in the order of ``robots``: what the simulated world needs.

        Raises ConfigError, one line naming the file and each robot's missing ``robots[i].start``.
        """
        missing = [i for i, spec in enumerate(self.robots) if spec.start is None]
        if missing:
            raise ConfigError(self._missing_starts(missing))
        return [spec.start for spec in self.robots]

    def _missing_starts(self, indices: list[int]) -> str:
        fields = ", ".join(f"robots[{i}].start" for i in indices)
        robots = ", ".join(repr(self.robots[i].id) for i in indices)
        verb, whom, each = ("is", "robot", "") if len(indices) == 1 else ("are", "robots", " each")
        return (
            f"{self.source or '<mission>'}: {fields}: {verb} required by the simulator, which places "
            f"{whom} {robots} there: give{each} start: {{x: X, y: Y, yaw: YAW}} (m, m, rad); without the "
            "simulator the robots' poses come from their frames (docs/deployment.md)"
        )

    def rig_for(self, robot_id: str) -> RigConfig:
        """The resolved rig of a robot (its own overrides applied to the default rig)."""
        self.robot_spec(robot_id)
        return self._robot_rigs.get(robot_id, self.rig)

    def ros2_for(self, robot_id: str) -> Ros2Config:
        """The resolved ROS 2 link of a robot (its ``ros2`` overrides on the mission's section,
        ``{robot}`` in the namespace replaced by its id). ConfigError when the id does not make a
        ROS namespace (``-`` is not allowed in ROS names)."""
        spec = self.robot_spec(robot_id)
        try:
            return self._robot_ros2.get(robot_id, self.ros2).for_robot(robot_id)
        except ValueError as exc:
            field = "ros2.namespace" if spec.ros2 is None or "namespace" not in spec.ros2 else (
                f"robots[{self.robots.index(spec)}].ros2.namespace")  # fmt: skip
            raise ConfigError(f"{self.source or '<mission>'}: {field}: {exc}") from None

    def sensor_model_for(self, robot_id: str) -> SensorModel:
        """The sensor model a robot fuses its frames with (``sensor_model_of`` its rig)."""
        return self.sensor_model_of(self.rig_for(robot_id))

    def sensor_model_of(self, rig: RigConfig) -> SensorModel:
        """The sensor model of frames from ``rig``: its camera's size decides
        ``discretize: auto``, its hit range (``RigConfig.hit_range_m`` at the workspace's
        voxel) cuts its far returns."""
        return self.sensor.model(
            pixels=rig.width * rig.height, hit_range=rig.hit_range_m(self.workspace.voxel)
        )

    def sensor_reach(self) -> float:
        """The widest range (m) up to which a robot's frames update the map: the largest
        ``SensorModel.reach`` of its robots' sensor models (``sensor_model_for``)."""
        return max(self.sensor_model_for(r).reach for r in self.robot_ids)

    def floor_plan_ref(self) -> FloorPlanRef | None:
        """The floor plan reference with its path made absolute."""
        if self.floor_plan is None:
            return None
        ref = self.floor_plan
        if isinstance(ref, str):
            ref = FloorPlanRef(path=ref)
        return ref.model_copy(update={"path": str(user_path(ref.path, self._base_dir).resolve())})

    def prior_map_path(self) -> Path | None:
        """The previous map's file, made absolute, or None."""
        return None if self.prior_map is None else (self._base_dir / self.prior_map).resolve()

    def load_floor_plan(self):
        """The mission's ``swarm.formats.floor_plan.FloorPlan`` (cached), or None without one."""
        if self._plan is None and self.floor_plan is not None:
            from swarm.formats.floor_plan import load_floor_plan

            ref = self.floor_plan_ref()
            self._plan = load_floor_plan(ref.path, ref.wall_height)
        return self._plan

    def shard_layout(self) -> ShardLayout:
        """Which map server shard owns which voxels (``map_service``; swarm.map.shard_layout).

        Raises ConfigError naming the file and ``map_service.shards`` or ``map_service.cuts_x``
        when the slabs do not fit the workspace's grid.
        """
        grid, service = self.workspace.grid(), self.map_service
        try:
            if service.cuts_x is not None:
                return ShardLayout.at(grid, service.cuts_x)
            return ShardLayout.even(grid, service.shards)
        except ValueError as exc:
            field = "cuts_x" if service.cuts_x is not None else "shards"
            raise ConfigError(f"{self.source or '<mission>'}: map_service.{field}: {exc}") from None

    def threshold_bits(self) -> float:
        """H_th: the configured threshold, else 25% of the prior entropy (7 bits per voxel).

        Raises ConfigError when the threshold is ``stop.observable_fraction`` and has not
        been resolved to bits yet (``swarm.mission.threshold.resolve_threshold`` does that).
        """
        if self.stop.entropy_threshold_bits is not None:
            return float(self.stop.entropy_threshold_bits)
        if self.stop.observable_fraction is not None:
            raise ConfigError(
                f"{self.source or '<mission>'}: stop.observable_fraction: the threshold needs the "
                "simulator's ground truth; run the mission with `swarm sim`, or set "
                "stop.entropy_threshold_bits"
            )
        return DEFAULT_THRESHOLD_FRACTION * PRIOR_BITS_PER_VOXEL * self.workspace.grid().size

    def to_yaml(self) -> str:
        """The mission as YAML, with file paths made absolute (for run folders)."""
        data = self.model_dump(mode="json")
        ref = self.floor_plan_ref()
        if ref is not None:
            data["floor_plan"] = ref.model_dump(mode="json")
        if self.prior_map is not None:
            data["prior_map"] = str(self.prior_map_path())
        for robot in data["robots"]:
            if robot.get("start", ...) is None:
                del robot["start"]  # a robot whose pose comes from its frames
            rig = robot.get("rig")
            if isinstance(rig, str) and rig.endswith((".yaml", ".yml")):
                robot["rig"] = str(user_path(rig, self._base_dir).resolve())
        return yaml.safe_dump(data, sort_keys=False)
