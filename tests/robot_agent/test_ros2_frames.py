"""A robot's frames from its ROS 2 topics (``robot_agent.ros2_frames``) on real loopback Zenoh
sessions: the shipped EuRoC pairs published as raw images, CameraInfo and tf give the frames
``swarm replay asl`` makes of them; bad input of every kind is counted by name, the agent keeps
going, and its map is the map of the good frames alone."""

from __future__ import annotations

import time

import numpy as np
import pytest

from replay.asl import AslRecording
from replay.ros2_player import Ros2Player, camera_infos
from robot_agent.agent import Agent
from robot_agent.frame_inbox import FrameInbox
from robot_agent.ros2_link import Ros2Link
from swarm.config import mission_from_dict
from swarm.mission.replay_run import default_mission
from swarm.protocol import bus
from swarm.ros2 import messages as rm
from swarm.ros2.messages import Stamp
from swarm.streams.frames import make_frame, rectified_camera
from tests.support.euroc_replay import EUROC_MINI


@pytest.fixture(scope="module")
def recording():
    return AslRecording(EUROC_MINI)


@pytest.fixture(scope="module")
def bag_recording(tmp_path_factory):
    """The same pairs in a ROS 2 bag whose calibration is its CameraInfo topics."""
    from replay.bag import BagRecording
    from tests.support.euroc_bags import _write_euroc_bag

    path = tmp_path_factory.mktemp("bag") / "euroc"
    _write_euroc_bag(path, 2)
    return BagRecording(path, "/cam0/image_raw", "/cam1/image_raw", "/cam0/pose",
                        left_info="/cam0/camera_info", right_info="/cam1/camera_info")  # fmt: skip


@pytest.fixture
def sessions():
    endpoint = bus.tcp_endpoint(bus.free_port())
    robot = bus.open_session(listen=[endpoint], timestamping=True)
    agent = bus.open_session(connect=[endpoint], timestamping=True)
    yield robot, agent
    agent.close()
    robot.close()


def _wait(predicate, timeout=30.0):  # generous: a first run on a loaded CI machine
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def _take(inbox: FrameInbox, timeout=30.0, source=None):
    item = inbox.take(timeout)
    why = "" if source is None else f": dropped {source.all_counters()}"
    assert item is not None, f"no pair reached the agent's inbox{why}"
    return item


@pytest.mark.slow
@pytest.mark.parametrize("source", ["asl", "bag"])
def test_euroc_pairs_over_ros2_are_the_frames_of_swarm_replay(sessions, source, request):
    """An ASL folder (CameraInfo from sensor.yaml) and a bag (from its CameraInfo topics), played as
    ROS 2 topics: the frames of ``swarm replay asl|bag``."""
    recording = request.getfixturevalue("recording" if source == "asl" else "bag_recording")
    robot_session, agent_session = sessions
    mission = default_mission(recording)
    link = Ros2Link.open(mission, "r1", agent_session)
    inbox = FrameInbox()
    link.frames.start(inbox)
    player = Ros2Player(robot_session, mission, "r1", recording.calibration)
    assert player.wait_for_agent(10)
    camera = rectified_camera(recording.calibration)
    try:
        for seq, pair in enumerate(recording.pairs(0, 3), start=1):
            stamp = player.send(pair)
            pending = _take(inbox)
            assert pending.seq == seq and pending.stamp == stamp and link.frames.stamp_of(seq) == stamp
            got = pending.frame()
            want = make_frame("r1", seq, pair, recording.calibration, camera)
            assert got.camera == want.camera and got.t == pytest.approx(want.t, abs=1e-6)
            assert np.array_equal(got.left, want.left) and np.array_equal(got.right, want.right)
            assert np.allclose(got.pose.xyz, want.pose.xyz, atol=1e-12)
            assert np.allclose(got.pose.ypr, want.pose.ypr, atol=1e-12)
        assert link.frames.all_counters() == {}
    finally:
        player.close()
        link.close()


def _publishers(ctx, config):
    node = ctx.node("bad_driver", config.namespace)
    pub = node.publisher
    return {
        "left": pub(config.topic("left"), rm.IMAGE),
        "right": pub(config.topic("right"), rm.IMAGE),
        "left_info": pub(config.topic("left_info"), rm.CAMERA_INFO),
        "right_info": pub(config.topic("right_info"), rm.CAMERA_INFO),
        "tf": pub(config.topic("tf"), rm.TF),
    }, node


@pytest.mark.slow
def test_bad_input_is_counted_by_name_and_leaves_the_map_of_the_good_frames(sessions, recording):
    """Wrong encodings, CameraInfo with a zero K, a 10 GB width x height claim, tf loops and stamps
    from the future among good pairs: each refused and counted by name, said in the progress line;
    the agent fuses the good pairs and its map is bit for bit the map of those pairs alone."""
    from swarm.ros2.node import Ros2Context

    robot_session, agent_session = sessions
    mission = default_mission(recording)
    config = mission.ros2_for("r1")
    link = Ros2Link.open(mission, "r1", agent_session)
    agent = Agent(mission, "r1", agent_session, coordination=False, link=link)
    reference = Agent(mission, "r1", robot_session, coordination=False)
    ctx = Ros2Context(robot_session, config.domain_id, config.distro)
    pubs, node = _publishers(ctx, config)
    types = ctx.types
    (k, d, r, p), (k2, d2, r2, p2) = camera_infos(recording.calibration)
    size = recording.calibration.image_size
    assert _wait(lambda: all(pub.has_subscribers() for pub in pubs.values()))

    def tf(stamp, pairs):
        pubs["tf"].publish(
            rm.tf_message(types, [rm.transform(types, stamp, a, b, xyz, q) for a, b, xyz, q in pairs])
        )

    def send(pair, *, shift=0.0, encoding="mono8", left_k=k, info_size=size, width=None, loop=False):
        stamp = Stamp.from_seconds(pair.t + shift)
        pose = (pair.position, rm.quaternion_of(pair.world_R_optical))
        looping = [("odom", "cam0", (0, 0, 0), (1, 0, 0, 0)), ("cam0", "odom", (0, 0, 0), (1, 0, 0, 0))]
        tf(stamp, looping if loop else [("map", "cam0", *pose)])
        pubs["left_info"].publish(rm.camera_info(types, stamp, "cam0", info_size, left_k, d, r, p))
        pubs["right_info"].publish(rm.camera_info(types, stamp, "cam1", info_size, k2, d2, r2, p2))
        for side, image in (("left", pair.left), ("right", pair.right)):
            msg = rm.image(types, stamp, "cam0" if side == "left" else "cam1", image, encoding)
            if width is not None:  # the claim of a huge image over the real, small data
                msg.width, msg.height, msg.step = width, width, width
            pubs[side].publish(msg)

    pairs = list(recording.pairs(0, 3))
    future = time.time() - pairs[0].t + 3600  # an hour ahead of this machine's clock
    bad = [  # (the counter, how the pair is spoilt, whether the agent's inbox gets it)
        ("unsupported image encoding", dict(encoding="yuv420_weird"), True),
        ("camera_info not rectifiable", dict(left_k=np.zeros((3, 3))), True),  # K all zero
        ("camera_info not rectifiable", dict(info_size=(100_000, 100_000)), True),  # 10 GB of maps
        ("image size does not match its data", dict(width=100_000), True),  # 10 GB of pixels
        ("tf loop", dict(loop=True), False),
        ("image stamp in the future", dict(shift=future), False),
        ("tf stamp in the future", dict(shift=future), False),
    ]
    handled = []
    try:
        for n, (reason, options, reaches_agent) in enumerate(bad):
            before = link.frames.counters[reason]
            send(pairs[0], **{"shift": 0.01 * n, **options})
            if reaches_agent:
                assert agent.handle(_take(agent._frames, source=link.frames)) is None, (
                    reason
                )  # refused when made
            assert _wait(lambda r=reason, b=before: link.frames.counters[r] > b), (
                reason,
                link.frames.all_counters(),
            )
        camera = rectified_camera(recording.calibration)
        for pair in pairs[1:]:
            send(pair)
            assert agent.handle(_take(agent._frames, source=link.frames)) is not None
            handled.append(pair)
            reference.handle(make_frame("r1", len(handled), pair, recording.calibration, camera).encode())
        counters = link.frames.all_counters()
        assert {reason for reason, _, _ in bad} <= set(counters), counters
        assert counters["camera_info not rectifiable"] == 2
        note = agent._dropped_frames_note()
        assert "ROS 2 input dropped:" in note and "1 unsupported image encoding" in note and "tf loop" in note
        assert agent.frames_fused == reference.frames_fused == 2
        assert np.array_equal(agent.explorer.map.lam, reference.explorer.map.lam)
        assert np.array_equal(agent.explorer.map.eta, reference.explorer.map.eta)
    finally:
        node.close()
        agent.shutdown(ack_wait_s=0)
        reference.shutdown(ack_wait_s=0)


@pytest.mark.slow
def test_a_robots_own_router_other_domain_and_humble(recording):
    """``ros2.connect``: the agent's link opens a client session of its own to the robot's router;
    the domain and the distro (Humble: ``TypeHashNotSupported`` in the keys) come from the settings.
    The mission gives the robot no start pose: a ROS 2 robot's pose comes from its tf."""
    endpoint = bus.tcp_endpoint(bus.free_port())
    robot_router = bus.open_session(listen=[endpoint], timestamping=True)
    team = bus.open_session(listen=[bus.tcp_endpoint(bus.free_port())])  # the agent's team session
    data = default_mission(recording).model_dump(mode="json")
    data["ros2"] = {"connect": [endpoint], "domain_id": 42, "distro": "humble"}
    del data["robots"][0]["start"]
    mission = mission_from_dict(data)
    link = Ros2Link.open(mission, "r1", team)
    inbox = FrameInbox()
    link.frames.start(inbox)
    player = Ros2Player(robot_router, mission, "r1", recording.calibration)
    try:
        assert link.session is not None and link.session is not team
        assert str(link.session.info.zid()) != str(team.info.zid())
        assert player.wait_for_agent(10)
        pair = next(recording.pairs(0, 1))
        player.send(pair)
        frame = _take(inbox).frame()
        assert frame is not None and np.allclose(frame.pose.xyz, recording.positions()[0], atol=0.05)
        key = link.frames._subs[0].entity.key
        assert key.startswith("42/r1/left/image_raw/sensor_msgs::msg::dds_::Image_/") and key.endswith(
            "TypeHashNotSupported"
        )
    finally:
        player.close()
        link.close()
        team.close()
        robot_router.close()
