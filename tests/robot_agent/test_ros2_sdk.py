"""An independent ROS 2-over-Zenoh implementation, ``zenoh-ros2-sdk`` (its own RIHS01 hashes, CDR,
attachments and liveliness tokens), publishes the shipped EuRoC pairs as raw Image, CameraInfo and
tf (tests/support/ros2_sdk_robot.py, a process of its own); our agent fuses them over its ROS 2 path into
the map our own protocol gives for the same pairs, and answers each on cmd_vel, which the SDK reads.
The SDK's message definitions are the few shipped in tests/data/ros2_msgs (no network)."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from replay.asl import AslRecording
from replay.ros2_player import camera_infos
from robot_agent.agent import Agent
from robot_agent.ros2_link import Ros2Link
from swarm.mission.replay_run import default_mission
from swarm.protocol import bus
from swarm.ros2.messages import Stamp, quaternion_of
from swarm.streams.frames import make_frame, rectified_camera
from tests.support.euroc_replay import EUROC_MINI
from tests.support.paths import SUPPORT, TEST_DATA

pytest.importorskip("zenoh_ros2_sdk")

HERE = Path(__file__).resolve().parent
PAIRS = 3


def _recording_npz(recording: AslRecording, path: Path) -> list:
    pairs = list(recording.pairs(0, PAIRS))
    stamps = [Stamp.from_seconds(p.t) for p in pairs]
    (lk, ld, lr, lp), (rk, rd, rr, rp) = camera_infos(recording.calibration)
    np.savez(
        path, left=np.stack([p.left for p in pairs]), right=np.stack([p.right for p in pairs]),
        sec=np.array([s.sec for s in stamps]), nsec=np.array([s.nanosec for s in stamps]),
        position=np.stack([p.position for p in pairs]),
        quaternion=np.array([quaternion_of(p.world_R_optical) for p in pairs]),
        left_k=lk, left_d=ld, left_r=lr, left_p=lp, right_k=rk, right_d=rd, right_r=rr, right_p=rp,
    )  # fmt: skip
    return pairs


@pytest.mark.slow
def test_an_independent_ros2_implementation_feeds_our_agent(tmp_path):
    recording = AslRecording(EUROC_MINI)
    pairs = _recording_npz(recording, tmp_path / "pairs.npz")
    mission = default_mission(recording)
    port = bus.free_port()
    session = bus.open_session(listen=[bus.tcp_endpoint(port)], timestamping=True)
    link = Ros2Link.open(mission, "r1", session)
    agent = Agent(mission, "r1", session, coordination=False, link=link)
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            item = agent._frames.take(0.1)
            if item is not None:
                agent.handle(item)

    worker = threading.Thread(target=loop, daemon=True)
    worker.start()
    try:
        done = subprocess.run(
            [sys.executable, str(SUPPORT / "ros2_sdk_robot.py"), str(port), str(tmp_path / "pairs.npz"),
             str(TEST_DATA / "ros2_msgs"), "/r1", "map"],
            capture_output=True, text=True, timeout=240,
        )  # fmt: skip
    finally:
        stop.set()
        worker.join(10)
    try:
        assert done.returncode == 0, f"{done.stdout}{done.stderr}\nrefused: {link.frames.all_counters()}"
        assert f"answered {PAIRS}" in done.stdout, done.stdout
        # the SDK's discovery parses our node's liveliness tokens: our subscriptions and cmd_vel
        topics = next(line for line in done.stdout.splitlines() if line.startswith("topics "))
        wanted = [
            "/r1/left/image_raw=sensor_msgs/msg/Image",
            "/r1/tf=tf2_msgs/msg/TFMessage",
            "/r1/cmd_vel=geometry_msgs/msg/TwistStamped",
            "/r1/right/camera_info=sensor_msgs/msg/CameraInfo",
        ]
        for seen in wanted:
            assert seen in topics, topics
        assert agent.frames_fused == PAIRS and link.frames.all_counters() == {}
        reference = Agent(mission, "r1", session, coordination=False)
        camera = rectified_camera(recording.calibration)
        for seq, pair in enumerate(pairs, start=1):
            reference.handle(make_frame("r1", seq, pair, recording.calibration, camera).encode())
        got, want = agent.explorer.map, reference.explorer.map
        assert np.array_equal(got.known_mask(), want.known_mask()) and got.known_mask().sum() > 5_000
        assert np.allclose(got.lam, want.lam, rtol=1e-6) and np.allclose(
            got.eta, want.eta, rtol=1e-6, atol=1e-9
        )
        reference.shutdown(ack_wait_s=0)
    finally:
        agent.shutdown(ack_wait_s=0)
        session.close()
