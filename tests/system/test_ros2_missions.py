"""Whole runs on the ROS 2 path, every role a process: a simulated mission whose agents take their
frames and give their commands only as ROS 2 topics (``swarm sim --ros2``) reaches its threshold,
as the same mission on our protocol does; the shipped EuRoC pairs played as ROS 2 topics (``swarm
replay asl --ros2``) give the map of ``swarm replay asl``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from swarm.bench.ros2_runs import map_difference
from tests.support.euroc_replay import EUROC_MINI, REPLAY_FRAMES, swarm_replay

pytestmark = pytest.mark.slow  # whole missions: every role a process

PLAN = """
name: two rooms
wall_height: 1.0
wall_thickness: 0.1
walls:
  - points: [[-0.05, -0.05], [3.45, -0.05], [3.45, 2.45], [-0.05, 2.45]]
    closed: true
boxes:
  - {centre: [1.7, 1.6], size: [0.4, 0.4], height: 0.6}
"""

# 34 x 24 x 10 voxels, about 57,000 bits at first; two stereo robots on tilt heads. Looking around
# at their starts leaves about 17,000 bits: 9,000 needs them to drive and look behind the box.
MISSION = """
mission: tworooms
workspace: {lo: [0.0, 0.0, 0.0], hi: [3.4, 2.4, 1.0], voxel: 0.1}
floor_plan: plan.yaml
robots:
  - {id: r1, start: {x: 0.6, y: 0.6, yaw: 0.0}}
  - {id: r2, start: {x: 2.8, y: 1.8, yaw: 3.14}}
rig: {camera_height: 0.4, width: 160, height: 120, noise_std: 1.0, tilt_range_deg: 35}
stop: {entropy_threshold_bits: 9000, max_time_s: 300}
sim: {agent_timeout_s: 30}
"""


def test_a_mission_over_ros2_reaches_its_threshold(tmp_path: Path):
    (tmp_path / "plan.yaml").write_text(PLAN)
    (tmp_path / "tworooms.yaml").write_text(MISSION)
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "tworooms.yaml"), "--ros2", "--out",
         str(out)],
        capture_output=True, text=True, timeout=420,
    )  # fmt: skip
    logs = "\n".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    metrics = json.loads((out / "metrics.json").read_text())
    summary = {k: v for k, v in metrics.items() if k != "entropy_curve"}
    assert metrics["robot_link"] == "ros2" and "over ROS 2" in proc.stdout
    assert metrics["reached_threshold"] is True, f"{summary}\n{proc.stdout}\n{logs}"
    assert metrics["final_entropy_bits"] <= 9000 and metrics["surface_accuracy"] >= 0.9
    assert all(metrics["distance_m"][r] > 0.5 for r in ("r1", "r2"))  # they drove on cmd_vel
    world = (out / "world.log").read_text()
    assert "ROS 2" in world and "dead: none, rejected commands: 0" in world
    for robot in ("r1", "r2"):
        log = (out / f"agent-{robot}.log").read_text()
        assert f"waiting for frames on ROS 2 topics /{robot}/left/image_raw" in log
        ros2 = next(line for line in log.splitlines() if line.startswith(f"{robot}: ROS 2:"))
        assert "dropped {}" in ros2, ros2  # every pair made a frame
        assert "robot/" not in log.split("waiting for frames on", 1)[1].split("\n", 1)[0]


def test_euroc_pairs_played_as_ros2_topics_give_the_asl_map(tmp_path, euroc_asl_run):
    out = tmp_path / "ros2"
    swarm_replay(["asl", str(EUROC_MINI), "--frames", str(REPLAY_FRAMES), "--ros2"], out)
    diff = map_difference(euroc_asl_run / "map.npz", out / "map.npz")
    print(f"EuRoC over ROS 2 vs swarm replay asl: {diff}")
    assert diff["known_only_in_one"] == 0 and diff["known_voxels"][0] > 5_000
    assert diff["lam_max_rel_diff"] <= 1e-6 and diff["eta_max_rel_diff"] <= 1e-5
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == REPLAY_FRAMES and metrics["unanswered"] == 0
    assert "ROS 2: 3 pairs taken; dropped {}" in (out / "agent-r1.log").read_text()
