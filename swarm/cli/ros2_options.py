"""``swarm agent --ros2 ...``: the options that point an agent at a robot running ROS 2 (rmw_zenoh).

Each option overrides one field of the robot's ``ros2`` settings in the mission file
(``swarm.config.ros2``; docs/ros2.md).
"""

from __future__ import annotations

import argparse

from swarm.config import ConfigError, Mission
from swarm.config.ros2 import Ros2Config, resolve_robot_ros2

#: option -> the Ros2Config field it sets
_FIELDS = {
    "ros2_namespace": "namespace",
    "ros2_domain": "domain_id",
    "ros2_distro": "distro",
    "ros2_connect": "connect",
    "ros2_left": "left",
    "ros2_right": "right",
    "ros2_left_info": "left_info",
    "ros2_right_info": "right_info",
    "ros2_fixed_frame": "fixed_frame",
    "ros2_camera_frame": "camera_frame",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "ROS 2 robot (docs/ros2.md)",
        "Take frames from the robot's ROS 2 camera topics and tf, and send its commands on cmd_vel (or "
        "goals to Nav2), over rmw_zenoh: no ROS install here. Defaults come from the mission's ros2 section.",
    )
    group.add_argument(
        "--ros2", action="store_true", help="the robot runs ROS 2 (RMW_IMPLEMENTATION=rmw_zenoh_cpp)"
    )
    group.add_argument("--ros2-namespace", metavar="NS", help="the robot's namespace (default /<id>)")
    group.add_argument("--ros2-domain", type=int, metavar="N", help="ROS_DOMAIN_ID (default 0)")
    group.add_argument("--ros2-distro", metavar="NAME", help="jazzy (default), kilted, rolling, humble")
    group.add_argument(
        "--ros2-connect",
        action="append",
        metavar="ENDPOINT",
        help="the robot's rmw_zenohd router, e.g. tcp/192.168.1.20:7447 (a client session of its own; "
        "default: this agent's session)",
    )
    for side in ("left", "right"):
        group.add_argument(
            f"--ros2-{side}", metavar="TOPIC", help=f"{side} image topic (default {side}/image_raw)"
        )
        group.add_argument(
            f"--ros2-{side}-info",
            metavar="TOPIC",
            help=f"{side} CameraInfo topic (default {side}/camera_info)",
        )
    group.add_argument("--ros2-fixed-frame", metavar="FRAME", help="the map's frame in tf (default map)")
    group.add_argument(
        "--ros2-camera-frame",
        metavar="FRAME",
        help="the left camera's optical frame (default: its images' frame_id)",
    )
    group.add_argument(
        "--ros2-cmd", choices=["twist_stamped", "twist", "nav2"], help="commands out (default twist_stamped)"
    )
    group.add_argument(
        "--ros2-use-sim-time", action="store_true", help="the robot's clock is /clock (a simulator's)"
    )


def ros2_config(mission: Mission, robot_id: str, args: argparse.Namespace) -> Ros2Config | None:
    """The robot's ROS 2 settings with the options applied, or None without ``--ros2``.
    Raises ConfigError naming the option."""
    given = {name: getattr(args, name) for name in _FIELDS if getattr(args, name, None) is not None}
    if not args.ros2:
        if given or args.ros2_cmd or args.ros2_use_sim_time:
            raise ConfigError("--ros2-* options need --ros2")
        return None
    overrides: dict = {_FIELDS[name]: value for name, value in given.items()}
    if args.ros2_cmd:
        overrides["cmd"] = {"mode": args.ros2_cmd}
    if args.ros2_use_sim_time:
        overrides["use_sim_time"] = True
    try:
        config = resolve_robot_ros2(mission.ros2_for(robot_id), overrides, "swarm agent", "--ros2")
    except ConfigError as exc:  # name the option, not the field
        text = str(exc).replace("swarm agent: ", "")
        for option, field in _FIELDS.items():
            text = text.replace(f"--ros2.{field}:", f"--{option.replace('_', '-')}:")
        raise ConfigError(text.replace("--ros2.cmd.mode:", "--ros2-cmd:")) from None
    try:
        return config.for_robot(robot_id)
    except ValueError as exc:
        raise ConfigError(f"--ros2-namespace: {exc}") from None
