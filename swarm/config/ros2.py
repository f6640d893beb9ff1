"""The ``ros2:`` section of a mission: how a robot running ROS 2 (rmw_zenoh) gives its agent
frames and takes its commands (docs/ros2.md, "Robots").

The section's fields are the defaults of every robot; a robot's own ``ros2:`` mapping overrides
any of them (``robots[i].ros2``). Topic names follow ROS 2: relative names resolve under the
robot's ``namespace``, in which ``{robot}`` stands for the robot's id (default ``/{robot}``, so
robot r1's ``left/image_raw`` is ``/r1/left/image_raw``).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, FiniteFloat, ValidationError, field_validator

from swarm.config.models import ConfigError, Section
from swarm.formats.validation_errors import describe_validation_error
from swarm.ros2.graph import check_namespace, qualified_name
from swarm.ros2.types import DEFAULT_DISTRO, DISTROS

#: the topic fields, resolved under the namespace
TOPIC_FIELDS = ("left", "right", "left_info", "right_info", "tf", "tf_static", "clock")


def _topic_name(value: str) -> str:
    """A ROS 2 topic name, relative (``cmd_vel``, ``~/x``) or absolute (``/tf``); ValueError if not."""
    qualified_name(value, "/", "node")
    return value


class Ros2CommandConfig(Section):
    """The agent's motion out: ``twist_stamped`` (Jazzy's diff_drive_controller takes it) or
    ``twist`` on ``topic`` at ``rate_hz`` with a watchdog (zero velocity once no decision came for
    ``watchdog_s``), or ``nav2``: the target as a ``geometry_msgs/PoseStamped`` on ``goal_topic``
    for a robot whose own stack (Nav2's bt_navigator) drives."""

    mode: Literal["twist_stamped", "twist", "nav2"] = "twist_stamped"
    topic: str = "cmd_vel"
    frame_id: str = "base_link"
    rate_hz: FiniteFloat = Field(default=10.0, ge=0, le=1000)
    watchdog_s: FiniteFloat = Field(default=0.5, gt=0)
    goal_topic: str = "goal_pose"

    _topics = field_validator("topic", "goal_topic")(classmethod(lambda cls, value: _topic_name(value)))


class Ros2TiltConfig(Section):
    """A tilt head's command (rigs with ``tilt_range_deg`` > 0): a ``trajectory_msgs/JointTrajectory``
    of ``joint`` on ``topic`` (a ros2_control joint_trajectory_controller's input), stamped with the
    image it answers, before each velocity command."""

    topic: str = "camera_tilt_controller/joint_trajectory"
    joint: str = "camera_tilt_joint"

    _topics = field_validator("topic")(classmethod(lambda cls, value: _topic_name(value)))


class Ros2Config(Section):
    """One robot's ROS 2 link: where its topics are, which frames, how long to wait for what."""

    domain_id: int = Field(default=0, ge=0, le=232)
    distro: str = DEFAULT_DISTRO
    #: the robot's rmw_zenohd router (client-mode session); empty: the agent's own session
    connect: list[str] = []
    namespace: str = "/{robot}"
    left: str = "left/image_raw"
    right: str = "right/image_raw"
    left_info: str = "left/camera_info"
    right_info: str = "right/camera_info"
    compressed: bool = False  # sensor_msgs/CompressedImage on the image topics
    rectified: bool = False  # the images are rectified already: only CameraInfo's P is used
    tf: str = "tf"
    tf_static: str = "tf_static"
    clock: str = "/clock"
    fixed_frame: str = "map"
    camera_frame: str | None = None  # the left camera's optical frame; None: the left images' frame_id
    stamp_tolerance_s: FiniteFloat = Field(default=0.01, ge=0, le=1)
    tf_tolerance_s: FiniteFloat = Field(default=0.01, ge=0, le=10)
    tf_wait_s: FiniteFloat = Field(default=0.2, ge=0, le=10)
    max_future_s: FiniteFloat = Field(default=1.0, gt=0)
    use_sim_time: bool = False
    pixel_bits: Literal[8, 10, 12, 14, 16] | None = None  # 16-bit images; None: the brightest seen
    cmd: Ros2CommandConfig = Ros2CommandConfig()
    tilt: Ros2TiltConfig = Ros2TiltConfig()

    @field_validator("distro")
    @classmethod
    def _distro(cls, value: str) -> str:
        if value not in DISTROS:
            raise ValueError(f"must be one of {', '.join(DISTROS)} (got {value!r})")
        return value

    @field_validator("fixed_frame", "camera_frame")
    @classmethod
    def _frame(cls, value: str | None) -> str | None:
        if value is not None and not value.strip("/ "):
            raise ValueError("a frame id is a non-empty name, e.g. map")
        return value

    @field_validator("namespace")
    @classmethod
    def _namespace(cls, value: str) -> str:
        check_namespace(value.replace("{robot}", "r1"))
        return value

    _topics = field_validator(*TOPIC_FIELDS)(classmethod(lambda cls, value: _topic_name(value)))

    def for_robot(self, robot_id: str) -> Ros2Config:
        """This link with ``{robot}`` in the namespace replaced by ``robot_id``."""
        return self.model_copy(
            update={"namespace": check_namespace(self.namespace.replace("{robot}", robot_id))}
        )

    def topic(self, field: str) -> str:
        """The fully qualified name of a topic field (``left``, ``tf``, ...; ``cmd``, ``goal``, ``tilt``)."""
        name = {"cmd": self.cmd.topic, "goal": self.cmd.goal_topic, "tilt": self.tilt.topic}.get(field)
        return qualified_name(name if name is not None else getattr(self, field), self.namespace)


def resolve_robot_ros2(
    defaults: Ros2Config, overrides: dict[str, Any] | None, where: str, field: str
) -> Ros2Config:
    """A robot's ROS 2 link: the mission's ``ros2`` section with the robot's ``overrides`` (nested
    ``cmd`` and ``tilt`` merged field by field; ``{robot}`` still in the namespace). Raises
    ConfigError naming ``where`` and ``field``."""
    merged = defaults.model_dump()
    for key, value in (overrides or {}).items():
        if key in ("cmd", "tilt") and isinstance(value, dict):
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    try:
        return Ros2Config.model_validate(merged)
    except ValidationError as exc:
        lines = describe_validation_error(exc, where, Ros2Config).splitlines()
        prefix = f"{where}: "
        raise ConfigError("\n".join(f"{prefix}{field}.{line[len(prefix) :]}" for line in lines)) from exc
