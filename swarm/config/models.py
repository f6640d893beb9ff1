"""Mission configuration models: the sections of a mission YAML file, validated by pydantic.

The whole file, the sections together, is :class:`swarm.config.mission.Mission`.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    FiniteFloat,
    field_validator,
    model_validator,
)

from swarm.config.rig_defaults import DEFAULT_MIN_DEPTH
from swarm.formats.errors import InputError
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol.bus import MAX_SHARDS
from swarm.protocol.wire import Camera

#: Entropy of one voxel under the near-uniform prior (128 bins), in bits.
PRIOR_BITS_PER_VOXEL = 7.0
#: Default stopping threshold H_th as a fraction of the initial map entropy.
DEFAULT_THRESHOLD_FRACTION = 0.25
#: The share of the observable prior left at H_th under the observable rule: the paper's
#: end point (28,691 bits, 44% in never-observable voxels: an 84% decrease of the rest).
OBSERVABLE_FRACTION = 0.16

NAME_PATTERN = r"^[A-Za-z0-9_-]+$"


class ConfigError(InputError):
    """An invalid mission file: the message names the file, the field and the problem."""


# -- sections --------------------------------------------------------------------------


class Section(BaseModel):
    """A config section: unknown fields are refused (so a misspelt key is an error, not ignored)."""

    model_config = ConfigDict(extra="forbid")


Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


class WorkspaceConfig(Section):
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


class Pose2D(Section):
    """A pose on the floor: position (m) and yaw (radians, counter-clockwise from +x)."""

    x: FiniteFloat
    y: FiniteFloat
    yaw: FiniteFloat = 0.0


#: SGBM's disparity error (standard deviation, px) on the simulator's frames: from the depth
#: errors of 40 rendered frames of the default rig (docs/stereo.md, "Far returns"), where
#: 13 % of points at 3-4 m and 31-38 % at 4-5 m are more than 0.15 m off: sigma_Z = 0.10 m at
#: 3.5 m and 0.16 m at 4.5 m, both sigma_d = sigma_Z fx b / Z^2 = 0.10 px.
DISPARITY_SIGMA_PX = 0.1


class RigConfig(Section):
    """A rectified stereo rig (or, in ``range`` mode, a depth camera) on a robot.

    The left camera is the reference, on the robot's centre at ``camera_height``; the right
    one is ``baseline`` metres to its right. ``noise_std`` is image noise in grey levels (the
    simulator adds it; the agent's texture filter stays above 1.5 x it, ``texture_threshold``);
    ``range_noise`` is the depth noise standard deviation per metre of range (range mode);
    ``max_range`` (m) turns farther returns into no return (None: unlimited).
    ``pitch_deg`` is the mounting pitch (positive looks down); ``tilt_range_deg`` > 0 puts
    the camera on a tilt head that commands can point up to that many degrees up or down
    from the mounting pitch (0: a fixed camera).

    ``hit_range`` (m): a return farther than this gives free space up to it and no hit
    (``hit_range_m``); ``auto`` (the default) derives it from the rig's depth error, None
    turns it off (docs/stereo.md, "Far returns": without it, far stereo returns leave false
    surfaces, offices_corridor's surface accuracy fell from 0.93 to 0.85).
    ``disparity_sigma_px`` is the stereo matcher's disparity error (standard deviation, px)
    that ``auto`` assumes.

    ``min_depth`` (m) is the nearest depth the stereo matcher searches for: SGBM's disparity
    range is fx b / min_depth, and its time grows with it (docs/stereo.md, "Time per pair").
    The default, 0.35 m, is 128 disparities on a 640 x 480 EuRoC camera; nearer surfaces get
    no depth (or, rarely, a wrong one), and the simulator counts nothing nearer as observable.
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
    hit_range: Literal["auto"] | FiniteFloat | None = "auto"
    disparity_sigma_px: FiniteFloat = Field(default=DISPARITY_SIGMA_PX, gt=0)
    min_depth: FiniteFloat = Field(default=DEFAULT_MIN_DEPTH, gt=0)

    @field_validator("hit_range", mode="before")
    @classmethod
    def _hit_range(cls, value: Any) -> Any:
        """``auto``, a range > 0 (m), or null / ``off`` (YAML reads an unquoted one as false)."""
        if value is None or value is False or value == "off":
            return None
        if value == "auto":
            return value
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if number and math.isfinite(value) and value > 0:
            return float(value)
        raise ValueError(f"must be 'auto', a range > 0 (m), or null/off (got {value!r})")

    def hit_range_m(self, voxel: float) -> float | None:
        """The range (m) beyond which a return of this rig is no hit, or None (no such range).

        ``auto``: the range where the depth error (one standard deviation) reaches one voxel
        edge ``voxel``, so that a hit lands in its voxel or a neighbour. Stereo: depth
        Z = fx b / d, so a disparity error sigma_d gives sigma_Z = Z^2 sigma_d / (fx b), and
        the range is sqrt(voxel fx b / sigma_d) (the default rig: 3.5 m at 0.1 m voxels).
        Range mode: sigma = range_noise Z, so voxel / range_noise (None without noise).
        Measured rays are longer than the optical-axis depth off the image centre; the
        range is applied to the ray length, which errs on the side of fewer hits.
        """
        if self.hit_range != "auto":
            return self.hit_range
        if self.mode == "stereo":
            return math.sqrt(voxel * self.fx * self.baseline / self.disparity_sigma_px)
        return voxel / self.range_noise if self.range_noise > 0 else None

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


#: ``discretize: auto`` fuses frames of more pixels than this with ``on`` (320 x 240 = 76,800 does not):
#: above it a frame has many rays per end voxel, and per-ray information would grow with the
#: resolution for no new information. Smaller frames get ``weighted``: their rays' information,
#: traversed once per end voxel.
AUTO_DISCRETIZE_PIXELS = 100_000


class SensorConfig(Section):
    """Parameters of the Gaussian sensor model (docs/design.md section 3)."""

    sigma_min: FiniteFloat = Field(default=0.06, gt=0)
    zeta: FiniteFloat = Field(default=0.0375, ge=0)
    tau: FiniteFloat = Field(default=2.0, gt=0)
    max_range: FiniteFloat = Field(default=5.0, gt=0)
    # On, as OctoMap and SensorModel: it keeps the surfaces (docs/map-core.md gives its effect
    # on the office and depot missions).
    hit_precedence: bool = True
    discretize: Literal["auto", "on", "off", "weighted"] = "auto"

    @field_validator("discretize", mode="before")
    @classmethod
    def _yaml_switch(cls, value: Any) -> Any:
        """YAML reads an unquoted ``on``/``off`` as true/false: take them as meant."""
        if isinstance(value, bool):
            return "on" if value else "off"
        return value

    def model(self, pixels: int | None = None, hit_range: float | None = None) -> SensorModel:
        """The sensor model; ``pixels`` (the camera's width x height) decides ``discretize: auto``.

        ``hit_range``: the rig's (``RigConfig.hit_range_m``; None: max range), as the agent
        fuses its frames (``SensorModel.hit_range``).

        ``hit_precedence``: a voxel holding a return of a frame gets no free-space update from
        the frame's other rays (a departure from the paper's text, as OctoMap; docs/map-core.md).
        ``discretize``: ``off``, one measurement per ray; ``on``, one per end voxel (the mean
        end point of the rays ending there, OctoMap's option); ``weighted``, that measurement
        with the information of all its rays; ``auto``, ``on`` for frames of more than
        ``AUTO_DISCRETIZE_PIXELS`` pixels, else ``weighted`` (``off`` when ``pixels`` is unknown).
        """
        mode = self.discretize
        if mode == "auto":
            if pixels is None:
                mode = "off"
            else:
                mode = "on" if pixels > AUTO_DISCRETIZE_PIXELS else "weighted"
        return SensorModel(
            self.sigma_min,
            self.zeta,
            self.tau,
            self.max_range,
            hit_precedence=self.hit_precedence,
            discretize=mode in ("on", "weighted"),
            weighted=mode == "weighted",
            hit_range=hit_range,
        )


class ExplorationConfig(BaseModel):
    """Entropy-gradient exploration; other keys are kept for the roles that read them."""

    model_config = ConfigDict(extra="allow")

    radius: FiniteFloat = Field(default=1.5, gt=0, description="candidate radius xi (m)")
    gaze: bool = Field(default=True, description="on arrival, look along the entropy gradient")
    random_wander_steps: int = Field(default=20, ge=0)


class SharingConfig(Section):
    """The agent's utility filter (docs/design.md section 3): a voxel goes out once its pending
    information is worth ``share_min_bits``; the voxels held back are worth at most
    ``max_held_bits`` together (null: no bound), beyond which the most valuable go out too."""

    share_min_bits: FiniteFloat = Field(default=0.5, ge=0)
    max_held_bits: FiniteFloat | None = Field(default=2000.0, gt=0)


class MapServiceConfig(Section):
    """The map service: ``shards`` server processes, each owning a slab of the workspace along x
    (swarm.map.shard_layout; docs/sharding.md). ``cuts_x`` (metres, increasing, ``shards - 1`` of
    them) places the slabs' boundaries; null: slabs of equal width."""

    shards: int = Field(default=1, ge=1, le=MAX_SHARDS)
    cuts_x: list[FiniteFloat] | None = None

    @model_validator(mode="after")
    def _cuts_match_shards(self) -> MapServiceConfig:
        if self.cuts_x is not None and len(self.cuts_x) != self.shards - 1:
            raise ValueError(
                f"cuts_x gives {len(self.cuts_x)} cut(s); {self.shards} shards need {self.shards - 1}"
            )
        return self


class CoordinationConfig(Section):
    """The coordinator's Burgard-style assignment (docs/coordinator.md).

    ``footprint_radius`` None: min(2 * exploration.radius, the sensor reach: ``Mission.sensor_reach``).
    """

    beta: FiniteFloat = Field(default=0.1, ge=0, description="utility lost per metre of path (1/m)")
    footprint_radius: FiniteFloat | None = Field(default=None, gt=0)
    overlap_weight: FiniteFloat = Field(
        default=1.0, ge=0, le=1, description="utility lost per share of a footprint that is teammates' ground"
    )
    robot_timeout_s: FiniteFloat = Field(default=10.0, gt=0)
    max_candidates: int = Field(default=200, ge=1)
    candidate_spacing: FiniteFloat = Field(default=0.5, ge=0)


class RobotBodyConfig(Section):
    """The simulated robot: a disc with differential-drive limits."""

    radius: FiniteFloat = Field(default=0.18, gt=0)
    max_speed: FiniteFloat = Field(default=0.5, gt=0)
    max_turn_rate: FiniteFloat = Field(default=1.5, gt=0)


class StopConfig(Section):
    """Stop when the map entropy reaches H_th (bits) or after ``max_time_s`` of sim time.

    H_th is ``entropy_threshold_bits`` when given. Else, with ``observable_fraction`` f,
    H_th = the entropy of the voxels no sensor of the mission can ever observe + f times
    the prior entropy of the others; the simulator (``swarm sim``) computes it from the
    floor plan and writes the figure into the run's config.yaml (docs/study.md, "The
    threshold"). Else 25% of the prior entropy.
    """

    entropy_threshold_bits: FiniteFloat | None = Field(default=None, ge=0)
    observable_fraction: FiniteFloat | None = Field(default=None, ge=0, le=1)
    max_time_s: FiniteFloat = Field(default=600.0, gt=0)


class SimConfig(Section):
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


class FloorPlanRef(Section):
    """A floor plan file (project YAML or ROS map.yaml) and the height of ROS-map walls."""

    path: str
    wall_height: FiniteFloat = Field(default=2.0, gt=0)


class RobotSpec(Section):
    """One robot of the mission: its id, where the simulator places it, its rig and ROS 2 link.

    ``start`` is the simulator's starting pose; the simulator requires it
    (``Mission.start_poses``). Every other role takes a robot's pose from its frames, so a
    mission of real robots (or of ROS 2 robots localised by their own tf) leaves it out.
    """

    id: str = Field(pattern=NAME_PATTERN)
    start: Pose2D | None = None
    rig: str | dict[str, Any] | None = None
    #: overrides of the mission's ``ros2`` section for this robot (``swarm.config.ros2``)
    ros2: dict[str, Any] | None = None
