"""The mission's ``ros2`` section (``swarm.config.ros2``) and ``swarm agent --ros2 ...``: defaults,
per-robot overrides, names resolved under each robot's namespace, and errors naming the field."""

from __future__ import annotations

import pytest
import yaml

from swarm.cli import main
from swarm.config import ConfigError, load_mission, mission_from_dict
from tests.support.paths import CONFIGS

OFFICE = CONFIGS / "office.yaml"


def _office(**changes) -> dict:
    data = yaml.safe_load(OFFICE.read_text())
    data["floor_plan"] = str(OFFICE.parent / data["floor_plan"])
    data.update(changes)
    return data


def test_defaults_put_each_robot_in_its_namespace():
    mission = load_mission(OFFICE)
    r2 = mission.ros2_for("r2")
    assert (r2.domain_id, r2.distro, r2.namespace, r2.fixed_frame) == (0, "jazzy", "/r2", "map")
    topics = {name: r2.topic(name) for name in ("left", "right", "left_info", "tf", "tf_static", "clock")}
    assert topics == {"left": "/r2/left/image_raw", "right": "/r2/right/image_raw",
                      "left_info": "/r2/left/camera_info", "tf": "/r2/tf", "tf_static": "/r2/tf_static",
                      "clock": "/clock"}  # fmt: skip
    assert (r2.topic("cmd"), r2.topic("goal")) == ("/r2/cmd_vel", "/r2/goal_pose")
    assert r2.cmd.mode == "twist_stamped" and r2.cmd.watchdog_s == 0.5


def test_a_robot_overrides_the_mission_section_field_by_field():
    data = _office(ros2={"domain_id": 7, "fixed_frame": "world", "cmd": {"rate_hz": 20}})
    data["robots"][0]["ros2"] = {
        "namespace": "/zed_robot",
        "left": "/zed/zed_node/left/image_rect_color",
        "rectified": True,
        "cmd": {"mode": "nav2"},
    }
    mission = mission_from_dict(data, "team.yaml")
    r1, r2 = mission.ros2_for("r1"), mission.ros2_for("r2")
    assert (
        r1.topic("left") == "/zed/zed_node/left/image_rect_color"
        and r1.topic("right") == "/zed_robot/right/image_raw"
    )
    assert (r1.domain_id, r1.fixed_frame, r1.rectified, r1.cmd.mode, r1.cmd.rate_hz) == (
        7,
        "world",
        True,
        "nav2",
        20,
    )
    assert (r2.namespace, r2.cmd.mode, r2.cmd.rate_hz) == ("/r2", "twist_stamped", 20)


@pytest.mark.parametrize(
    "where, value, message",
    [
        ("robot", {"left": "a//b"}, "team.yaml: robots[1].ros2.left: topic 'a//b': no empty tokens"),
        ("robot", {"cmd": {"mode": "joystick"}}, "team.yaml: robots[1].ros2.cmd.mode: must be one of"),
        ("robot", {"namespace": "9lives"}, "team.yaml: robots[1].ros2.namespace: namespace '9lives'"),
        ("robot", {"camera": "x"}, "team.yaml: robots[1].ros2.camera: unknown field"),
        ("mission", {"distro": "foxy"}, "team.yaml: ros2.distro: must be one of humble, jazzy"),
        ("mission", {"domain_id": 300}, "team.yaml: ros2.domain_id:"),
        ("mission", {"fixed_frame": " "}, "team.yaml: ros2.fixed_frame: a frame id is a non-empty name"),
    ],
)
def test_errors_name_the_file_and_the_field(where, value, message):
    data = _office(**({"ros2": value} if where == "mission" else {}))
    if where == "robot":
        data["robots"][1]["ros2"] = value
    with pytest.raises(ConfigError, match="^" + message.replace("(", r"\(").replace("[", r"\[")):
        mission_from_dict(data, "team.yaml")


def test_a_robot_id_that_is_no_ros_name_matters_only_on_the_ros2_path():
    data = _office()
    data["robots"][0]["id"] = "robot-1"
    mission = mission_from_dict(data, "team.yaml")  # our protocol: fine
    with pytest.raises(ConfigError, match=r"team.yaml: ros2.namespace: namespace '/robot-1'"):
        mission.ros2_for("robot-1")


def test_agent_options_need_ros2_and_are_checked(capsys):
    assert main(["agent", "--id", "r1", "--config", str(OFFICE), "--ros2-namespace", "/a"]) == 2
    assert "swarm: error: --ros2-* options need --ros2" in capsys.readouterr().err
    assert main(["agent", "--id", "r1", "--config", str(OFFICE), "--ros2", "--ros2-left", "a b"]) == 2
    assert "swarm: error: --ros2-left: topic 'a b'" in capsys.readouterr().err
    assert main(["agent", "--id", "r1", "--config", str(OFFICE), "--ros2", "--ros2-domain", "999"]) == 2
    assert "swarm: error: --ros2-domain:" in capsys.readouterr().err
