"""``swarm map ros2`` seen by an independent ROS 2-over-Zenoh implementation: zenoh-ros2-sdk
(from the package registry; its own RIHS01 hashes, type definitions and key expressions)
subscribes to the team map's topics as a late joiner and decodes the same map as
``swarm map export``; its discovery finds our node and publishers with the right topics, types
and QoS. A real map server runs in this process; the message definitions the SDK needs are in
tests/data/ros2_msgs (no network: the SDK would otherwise clone them from GitHub).
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from tests.support.paths import TEST_DATA

sdk = pytest.importorskip("zenoh_ros2_sdk", reason="the conformance tests need zenoh-ros2-sdk (test extras)")
from zenoh_ros2_sdk import _cache, message_registry, utils  # noqa: E402
from zenoh_ros2_sdk.entity import NodeEntity  # noqa: E402
from zenoh_ros2_sdk.keyexpr import node_liveliness_keyexpr  # noqa: E402
from zenoh_ros2_sdk.qos import QosDurability, QosProfile, QosReliability  # noqa: E402

from ros2_map.options import Ros2MapOptions  # noqa: E402
from ros2_map.role import TeamMapTopics  # noqa: E402
from swarm.map.fusion import batch_information  # noqa: E402
from swarm.protocol import bus  # noqa: E402
from swarm.protocol.map_client import MapClient, export_map  # noqa: E402
from swarm.protocol.wire import DeltaMessage  # noqa: E402
from tests.support.map_server_mission import (  # noqa: E402
    EPOCH,
    all_acked,
    client_session,
    encode_all,
    publishers,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)
from tests.support.ros2_map_oracle import apply_update, oracle_cloud, oracle_grid, sort_rows  # noqa: E402

MSG_DIR = TEST_DATA / "ros2_msgs"
GRID_TYPE, CLOUD_TYPE = "nav_msgs/msg/OccupancyGrid", "sensor_msgs/msg/PointCloud2"
UPDATE_TYPE = "map_msgs/msg/OccupancyGridUpdate"
LATCHED = QosProfile(durability=QosDurability.TRANSIENT_LOCAL, history_depth=1)
FAST = dict(period_s=0.1, cloud_period_s=0.1)


@pytest.fixture
def offline_sdk(monkeypatch, tmp_path):
    """The SDK reading definitions from MSG_DIR only; its one shared session closed after."""

    def offline(*_args, **_kw):  # a guard, not a mock: the SDK's git clone must not be reached
        raise RuntimeError(f"tests run offline: a message definition is missing from {MSG_DIR}")

    _close_sdk_session()
    monkeypatch.setenv("ZENOH_ROS2_SDK_CACHE", str(tmp_path / "sdk-cache"))
    monkeypatch.setattr(_cache, "clone_to_cache", offline)
    monkeypatch.setattr(message_registry, "_registry", message_registry.MessageRegistry(str(MSG_DIR)))
    yield sdk
    _close_sdk_session()


def _close_sdk_session() -> None:
    if sdk.ZenohSession._instance is not None:
        sdk.ZenohSession._instance.close()


def sdk_hash(type_name: str) -> str:
    """The RIHS01 hash the SDK computes from the shipped definitions."""
    registry = message_registry.get_registry()
    text = registry.get_msg_file_path(type_name).read_text()
    deps = utils.load_dependencies_recursive(type_name, text, registry)
    return utils.get_type_hash(type_name, msg_definition=text, dependencies=deps)


def corner_batches(grid, sensor) -> dict[str, list]:
    """Two deltas per robot, each of rays within a 0.8 m box in its own corner of the map."""
    rng = np.random.default_rng(31)
    out = {}
    for n, corner in enumerate(([0.1, 0.1], [2.1, 0.1], [1.1, 1.1]), start=1):
        lo = np.array([*corner, 0.0])
        hi = lo + [0.8, 0.8, 1.0]
        out[f"r{n}"] = [
            batch_information(grid, sensor, (lo + hi) / 2, rng.uniform(lo, hi, size=(80, 3))).delta
            for _ in range(2)
        ]
    return out


def _port(endpoint: str) -> int:
    return int(endpoint.rsplit(":", 1)[1])


class _Topics:
    """TeamMapTopics reading ``session`` and publishing on a timestamped session of its own."""

    def __init__(self, session, endpoint, mission, options):
        self.ros = bus.open_session(connect=[endpoint], timestamping=True)
        self.topics = TeamMapTopics(session, mission, options, self.ros)

    def __enter__(self) -> TeamMapTopics:
        self.topics.start()
        return self.topics

    def __exit__(self, *_exc) -> None:
        self.topics.stop()
        self.ros.close()


def _send(session, mission, grid, batches) -> None:
    pubs = publishers(session, mission.mission, batches)
    for rid, _seq, payload in encode_all(grid, batches):
        pubs[rid].put(payload)


def _settle(topics: TeamMapTopics, applied: int) -> None:
    wait_until(lambda: topics.fmap.counts["applied"] >= applied and topics.caught_up(), 20, "the topics")
    time.sleep(0.3)
    wait_until(topics.caught_up, 10, "the topics")


def _subscribe(topic: str, type_name: str, port: int, qos=LATCHED, **kw) -> list:
    got: list = []
    sdk.ROS2Subscriber(topic, type_name, got.append, router_port=port, qos=qos, **kw)
    return got


def _cloud_rows(message) -> np.ndarray:
    assert [(f.name, f.offset, f.datatype, f.count) for f in message.fields] == [
        (name, 4 * n, 7, 1) for n, name in enumerate(("x", "y", "z", "mu", "sigma", "entropy"))
    ]
    assert message.point_step == 24 and not message.is_bigendian and message.height == 1
    data = np.asarray(message.data, np.uint8).view("<f4").reshape(-1, 6)
    assert len(data) == message.width
    return sort_rows(data)


@pytest.mark.slow
def test_a_late_sdk_subscriber_decodes_the_exported_map_and_discovers_our_node(tmp_path, offline_sdk):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    early = robot_batches(grid, sensor, robots=2, per_robot=3, seed=21)
    late = {"r3": robot_batches(grid, sensor, robots=1, per_robot=4, seed=22)["r1"]}
    with running_server(mission, tmp_path / "store") as (_server, endpoint), client_session(endpoint) as s:
        _send(s, mission, grid, early)  # before the topics start: they take it from the snapshot
        client = MapClient(s, mission.mission)
        wait_until(lambda: all_acked(client, {"r1": 3, "r2": 3}), 20, "the first deltas")
        with _Topics(s, endpoint, mission.mission, Ros2MapOptions(**FAST)) as topics:
            _send(s, mission, grid, late)  # after: from the merged stream
            _settle(topics, applied=4)
            export_map(client, tmp_path / "map.npz")
            port = _port(endpoint)
            grids = _subscribe("/map", GRID_TYPE, port)  # late joiners: the latched samples
            clouds = _subscribe("/team_map_cloud", CLOUD_TYPE, port)
            wait_until(lambda: grids and clouds, 10, "the SDK's latched samples")
            np.testing.assert_array_equal(
                oracle_grid(tmp_path / "map.npz", (0.1, 0.5)), _grid_cells(grids[-1])
            )
            info = grids[-1].info
            assert info.resolution == pytest.approx(0.1) and grids[-1].header.frame_id == "map"
            assert (info.origin.position.x, info.origin.position.y) == (0.0, 0.0)
            assert info.origin.position.z == pytest.approx(0.1)  # the band's bottom layer
            expected = oracle_cloud(tmp_path / "map.npz")
            assert len(expected) > 50
            np.testing.assert_array_equal(_cloud_rows(clouds[-1]), expected)
            _check_discovery(topics, port, domain=0, namespace="/", prefix="")


def _grid_cells(message) -> np.ndarray:
    return np.asarray(message.data, np.int8).reshape(message.info.height, message.info.width).T


def _check_discovery(topics: TeamMapTopics, port: int, domain: int, namespace: str, prefix: str) -> None:
    """The SDK's ``ros2 topic list`` / ``topic info -v`` / node tokens show our node and publishers."""
    listed = dict(sdk.get_topic_names_and_types(domain_id=domain, router_port=port, timeout=2.0))
    for topic, type_name in (
        ("map", GRID_TYPE),
        ("map_updates", UPDATE_TYPE),
        ("team_map_cloud", CLOUD_TYPE),
    ):
        assert listed[f"{prefix}/{topic}"] == [type_name]
    humble = topics.options.distro == "humble"
    for topic, type_name, latched in (("map", GRID_TYPE, True), ("map_updates", UPDATE_TYPE, False),
                                      ("team_map_cloud", CLOUD_TYPE, True)):  # fmt: skip
        info = sdk.get_topic_info(
            f"{prefix}/{topic}", domain_id=domain, router_port=port, timeout=2.0, verbose=True
        )
        ours = [p for p in info.publishers if p.node_name == "swarm_team_map"]
        assert len(ours) == 1 and ours[0].node_namespace == namespace
        assert ours[0].type_hash == ("TypeHashNotSupported" if humble else sdk_hash(type_name))
        qos = QosProfile.decode(ours[0].qos)
        assert qos.reliability == QosReliability.RELIABLE
        assert qos.durability == (QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE)
        assert qos.history_depth == (1 if latched else 10)
    node = NodeEntity(domain, topics.context.session_id, topics._node.node_id, "swarm_team_map", namespace)
    session = sdk.ZenohSession.get_instance()
    tokens = {
        str(r.ok.key_expr) for r in session.liveliness.get(f"@ros2_lv/{domain}/**", timeout=2.0) if r.ok
    }
    assert node_liveliness_keyexpr(node) in tokens  # ros2 node list's token, built by the SDK


@pytest.mark.slow
def test_domain_namespace_humble_and_updates_as_nav2_and_rviz_apply_them(tmp_path, offline_sdk):
    """Domain 7, namespace /team, Humble (type hash 'TypeHashNotSupported'), every grid after the
    first as OccupancyGridUpdate boxes: the SDK's grid with the updates applied is the export's."""
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    options = Ros2MapOptions(domain_id=7, namespace="/team", distro="humble", incremental_above=0,
                             full_period_s=600, **FAST)  # fmt: skip
    with running_server(mission, tmp_path / "store") as (_server, endpoint), client_session(endpoint) as s:
        # subscribed before the node starts: zenoh-ros2-sdk 0.1.8 asks a latched topic's history
        # of '%team/map' publishers, not of the '%team%map' their tokens carry, so a late joiner
        # of a namespaced topic gets no history from it (the first test covers late joining)
        port = _port(endpoint)
        kw = dict(domain_id=7, type_hash="TypeHashNotSupported")
        grids = _subscribe("/team/map", GRID_TYPE, port, **kw)
        updates = _subscribe("/team/map_updates", UPDATE_TYPE, port, qos=QosProfile(), **kw)
        time.sleep(0.5)  # the subscriptions reach the router
        with _Topics(s, endpoint, mission.mission, options) as topics:
            wait_until(lambda: grids, 10, "the first (prior) grid")
            batches = corner_batches(grid, sensor)
            for rid, deltas in batches.items():  # one robot at a time: several updates
                _send(s, mission, grid, {rid: deltas})
                _settle(topics, applied=2 * (int(rid[1:])))
            export_map(MapClient(s, mission.mission), tmp_path / "map.npz")
            wait_until(lambda: len(updates) == topics.counts["grid_updates"], 10, "every update")
            assert len(grids) == 1 and topics.counts["grid_updates"] >= 2
            held = _grid_cells(grids[0]).copy()
            assert (held == -1).all()  # the prior: nothing known
            for u in updates:
                assert u.header.frame_id == "map" and u.width * u.height <= held.size
                apply_update(held, u.x, u.y, u.width, u.height, u.data)
            np.testing.assert_array_equal(held, oracle_grid(tmp_path / "map.npz", (0.1, 0.5)))
            _check_discovery(topics, port, domain=7, namespace="/team", prefix="/team")


@pytest.mark.slow
def test_a_hostile_merged_stream_is_refused_and_the_published_map_stays_the_servers(tmp_path, offline_sdk):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    with running_server(mission, tmp_path / "store") as (_server, endpoint), client_session(endpoint) as s:
        with _Topics(s, endpoint, mission.mission, Ros2MapOptions(**FAST)) as topics:
            merged = bus.reliable_publisher(s, bus.key(mission.mission, "merged"))
            idx, one = np.array([5, 77], np.uint32), np.ones(2, np.float32)
            forged = [
                b"\x00" * 64,
                b"\x81\xa1v\x01",  # msgpack {v: 1} and nothing else
                DeltaMessage("x", EPOCH, 1, 0.0, grid, idx, one * 1e-3, one * 1e6).encode(),  # mean > 1
                DeltaMessage("x", EPOCH, 2, 0.0, grid, idx, one * 0, one * 0).encode(),  # changes nothing
                b"\xff" * (13 * grid.size + (64 << 10)),  # larger than any delta of the grid
            ]
            for payload in forged * 20:
                merged.put(payload)
            batches = robot_batches(grid, sensor, robots=2, per_robot=2, seed=41)
            _send(s, mission, grid, batches)
            _settle(topics, applied=4)
            wait_until(lambda: topics.fmap.counts["rejected"] == 80, 10, "the refusals")
            assert topics.counts["merged_too_large"] == 20 and topics.counts["worker_errors"] == 0
            export_map(MapClient(s, mission.mission), tmp_path / "map.npz")
            clouds = _subscribe("/team_map_cloud", CLOUD_TYPE, _port(endpoint))
            wait_until(lambda: clouds, 10, "the cloud")
            np.testing.assert_array_equal(_cloud_rows(clouds[-1]), oracle_cloud(tmp_path / "map.npz"))
            np.testing.assert_array_equal(
                topics.outputs.grid.cells, oracle_grid(tmp_path / "map.npz", (0.1, 0.5))
            )


@pytest.mark.slow
def test_the_command_publishes_the_team_map_until_its_duration(tmp_path, offline_sdk):
    """``swarm map ros2`` as a user runs it, on domain 3: a late SDK subscriber gets the grid."""
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    with running_server(mission, tmp_path / "store") as (_server, endpoint), client_session(endpoint) as s:
        _send(s, mission, grid, robot_batches(grid, sensor, robots=2, per_robot=2, seed=51))
        client = MapClient(s, mission.mission)
        wait_until(lambda: all_acked(client, {"r1": 2, "r2": 2}), 20, "the deltas")
        export_map(client, tmp_path / "map.npz")
        command = [sys.executable, "-m", "swarm.cli", "map", "ros2", "--connect", endpoint,
                   "--domain-id", "3", "--duration", "8", "--progress-every", "1"]  # fmt: skip
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            first = proc.stdout.readline()
            assert "mission 'srvtest' as ROS 2 domain 3 (jazzy): /map (nav_msgs/msg/OccupancyGrid)" in first
            grids: list = []
            deadline = time.monotonic() + 6
            while not grids and time.monotonic() < deadline:  # until its first grid is out
                grids = _subscribe("/map", GRID_TYPE, _port(endpoint), domain_id=3)
                time.sleep(0.5)
            assert grids, "no latched grid from the command"
            expected = oracle_grid(tmp_path / "map.npz", (0.1, 0.5))
            np.testing.assert_array_equal(_grid_cells(grids[-1]), expected)
            out, err = proc.communicate(timeout=30)
        finally:
            proc.kill()
        assert proc.returncode == 0, err
        assert "sent 1 grids" in out.splitlines()[-1]
