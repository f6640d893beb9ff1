"""The team map as ROS 2 messages, without Zenoh: the 2-D projection and the occupied cloud
against computations from the exported map file alone (tests/support/ros2_map_oracle.py), the messages'
layouts through rosbags' CDR, when whole grids, updates and clouds go out, and a replica that
refuses every bad merged delta and keeps its map."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros2_map.options import Ros2MapOptions
from ros2_map.outputs import CloudOutput, GridOutput
from ros2_map.replica import FollowedMap
from swarm.cli.main import main
from swarm.formats.map_file import save_map
from swarm.map.coverage_map import CoverageMap
from swarm.map.fusion import batch_information
from swarm.map.grid import Grid
from swarm.map.projection import (
    CLOUD_FIELDS,
    band_layers,
    changed_box,
    occupied_cloud,
    project,
    project_columns,
)
from swarm.map.sensor_model import SensorModel
from swarm.protocol.wire import DeltaMessage, Snapshot, WireError
from swarm.ros2.map_messages import (
    OCCUPANCY_GRID,
    OCCUPANCY_GRID_UPDATE,
    POINT_CLOUD2,
    cloud_points,
    grid_cells,
    occupancy_grid,
    occupancy_grid_update,
    point_cloud,
    register_map_msgs,
)
from swarm.ros2.types import Ros2Types
from tests.support.map_server_mission import EPOCH, robot_batches
from tests.support.ros2_map_oracle import apply_update, oracle_cloud, oracle_grid, sort_rows

GRID = Grid((-0.5, 0.2, 0.0), 0.1, (24, 17, 9))
SENSOR = SensorModel()


def explored_map(seed: int = 0, per_robot: int = 6) -> CoverageMap:
    """Random rays through the box; the columns of x >= 1.5 m left unexplored (the prior)."""
    cmap = CoverageMap(GRID, SENSOR)
    for deltas in robot_batches(GRID, SENSOR, robots=2, per_robot=per_robot, rays=150, seed=seed).values():
        for d in deltas:
            cmap.apply(d)
    prior = CoverageMap(GRID, SENSOR)
    for mine, first in ((cmap.lam, prior.lam), (cmap.eta, prior.eta)):
        mine.reshape(GRID.shape)[20:] = first.reshape(GRID.shape)[20:]
    return cmap


def followed(cmap: CoverageMap) -> FollowedMap:
    return FollowedMap(Snapshot(cmap.grid, cmap.lam.copy(), cmap.eta.copy()), cmap.sensor)


def test_band_layers_are_those_whose_centres_lie_in_the_band():
    assert band_layers(GRID, 0.1, 0.5) == (1, 5)  # centres 0.15 .. 0.45
    assert band_layers(GRID, 0.15, 0.15) == (1, 2)
    with pytest.raises(ValueError, match="no map layer"):
        band_layers(GRID, 2.0, 3.0)


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["all", "any"])
def test_projection_equals_the_column_oracle_of_the_map_file(tmp_path, rule):
    cmap = explored_map()
    save_map(tmp_path / "map.npz", cmap)
    fmap = followed(cmap)
    layers = band_layers(GRID, 0.1, 0.5)
    cells = project(GRID, fmap.coverage, cmap.lam, fmap.known_lam, layers, 0.5, rule)
    expected = oracle_grid(tmp_path / "map.npz", (0.1, 0.5), 0.5, rule)
    np.testing.assert_array_equal(cells, expected)
    assert {100, 0, -1} <= set(np.unique(cells).tolist())  # the test map holds all three
    columns = np.array([0, 5, 17 * 3 + 2, GRID.shape[0] * GRID.shape[1] - 1])
    part = project_columns(GRID, fmap.coverage, cmap.lam, fmap.known_lam, layers, columns, 0.5, rule)
    np.testing.assert_array_equal(part, cells.reshape(-1)[columns])


def test_occupied_cloud_is_the_exported_maps_occupied_voxels(tmp_path):
    cmap = explored_map(seed=5)
    save_map(tmp_path / "map.npz", cmap)
    fmap = followed(cmap)
    points = occupied_cloud(GRID, fmap.coverage, cmap.lam, cmap.eta, fmap.entropy.values)
    ours = sort_rows(np.column_stack([points[f] for f in CLOUD_FIELDS]))
    expected = oracle_cloud(tmp_path / "map.npz")
    assert len(expected) > 20
    np.testing.assert_array_equal(ours, expected)


def test_changed_box_is_the_smallest_box_of_the_differences():
    a = np.zeros((6, 5), np.int8)
    assert changed_box(a, a) is None
    b = a.copy()
    b[1, 3] = 100
    b[4, 1] = -1
    assert changed_box(a, b) == (slice(1, 5), slice(1, 4))


def test_messages_keep_rosbags_layouts_through_cdr():
    types = Ros2Types("jazzy")
    register_map_msgs(types)
    cells = np.arange(12, dtype=np.int8).reshape(4, 3)  # cell (i, j) holds 3 i + j
    grid_msg = occupancy_grid(types, cells, (1.0, 2.0, 0.1), 0.1, "map", 12.5)
    back = types.deserialize(types.serialize(grid_msg, OCCUPANCY_GRID), OCCUPANCY_GRID)
    assert (back.info.width, back.info.height) == (4, 3)
    assert back.data[2 * 4 + 1] == 3 * 1 + 2  # data[j * width + i] is cell (i, j): x fastest
    np.testing.assert_array_equal(grid_cells(back), cells)
    assert back.info.resolution == pytest.approx(0.1)
    assert (back.info.origin.position.x, back.info.origin.position.z, back.info.origin.orientation.w) == (
        1.0, pytest.approx(0.1), 1.0)  # fmt: skip
    assert (back.header.frame_id, back.header.stamp.sec, back.header.stamp.nanosec) == ("map", 12, 5e8)
    update = occupancy_grid_update(types, cells, (slice(1, 3), slice(0, 2)), "map", 1.0)
    back = types.deserialize(types.serialize(update, OCCUPANCY_GRID_UPDATE), OCCUPANCY_GRID_UPDATE)
    assert (back.x, back.y, back.width, back.height) == (1, 0, 2, 2)
    target = np.zeros_like(cells)
    apply_update(target, back.x, back.y, back.width, back.height, back.data)
    np.testing.assert_array_equal(target[1:3, 0:2], cells[1:3, 0:2])
    points = np.zeros(3, dtype=[(f, "<f4") for f in CLOUD_FIELDS])
    points["x"], points["entropy"] = [1, 2, 3], [0.5, 0.25, 7.0]
    cloud = types.deserialize(
        types.serialize(point_cloud(types, points, "map", 1.0), POINT_CLOUD2), POINT_CLOUD2
    )
    assert [f.name for f in cloud.fields] == list(CLOUD_FIELDS)
    assert [f.offset for f in cloud.fields] == [0, 4, 8, 12, 16, 20] and cloud.point_step == 24
    assert (cloud.width, cloud.height, cloud.row_step, cloud.is_dense) == (3, 1, 72, True)
    np.testing.assert_array_equal(cloud_points(cloud)["entropy"], points["entropy"])
    assert types.type_hash(OCCUPANCY_GRID_UPDATE).startswith("RIHS01_")


def _opts(**kw) -> Ros2MapOptions:
    return Ros2MapOptions(**kw)


def _change(fmap: FollowedMap, seed: int) -> np.ndarray:
    """A merged delta of rays within a 0.6 m box somewhere in the map; returns the refreshed voxels."""
    rng = np.random.default_rng(seed)
    corner = rng.uniform(GRID.lo, GRID.hi - 0.6)
    points = rng.uniform(corner, corner + 0.6, size=(40, 3))
    d = batch_information(GRID, SENSOR, corner + 0.3, points).delta
    fmap.apply_payload(DeltaMessage(f"x{seed}", EPOCH, 1, 0.0, GRID, d.idx, d.dlam, d.deta).encode())
    return fmap.refresh()


def test_a_small_grid_goes_out_whole_when_it_changed_at_most_once_per_period():
    types = Ros2Types()
    fmap = followed(explored_map())
    out = GridOutput(fmap, _opts(period_s=1.0), types)
    kind, _ = out.take(0.0, 1.0)
    assert kind == "full"
    assert out.take(5.0, 1.0) is None  # nothing changed
    out.note(_change(fmap, 11))
    assert out.take(0.5, 1.0) is None  # within the period
    kind, message = out.take(5.5, 1.0)
    assert kind == "full"
    np.testing.assert_array_equal(grid_cells(message), out.cells)


def test_a_large_grid_sends_updates_that_rebuild_it_and_a_whole_grid_per_full_period():
    types = Ros2Types()
    register_map_msgs(types)
    fmap = followed(explored_map(per_robot=2))
    out = GridOutput(fmap, _opts(period_s=1.0, full_period_s=10.0, incremental_above=0), types)
    kind, message = out.take(0.0, 1.0)
    assert kind == "full"
    held = grid_cells(message).copy()  # what RViz holds
    kinds = []
    for step in range(1, 9):
        out.note(_change(fmap, 100 + step))
        sent = out.take(float(step), 1.0)
        if sent is None:
            continue
        kinds.append(sent[0])
        m = sent[1]
        if sent[0] == "update":
            assert m.width * m.height < out.cells.size
            apply_update(held, m.x, m.y, m.width, m.height, m.data)
        else:
            held = grid_cells(m).copy()
        np.testing.assert_array_equal(held, out.cells)
    assert "update" in kinds
    np.testing.assert_array_equal(out.cells, project(GRID, fmap.coverage, fmap.map.lam, fmap.known_lam,
                                                     out.layers))  # fmt: skip
    assert out.latched_behind
    assert out.take(9.5, 1.0) is None  # behind, but the full period has not passed
    kind, message = out.take(10.0, 1.0)  # no change, but the latched grid is behind
    assert kind == "full" and not out.latched_behind
    np.testing.assert_array_equal(grid_cells(message), out.cells)


def test_the_cloud_waits_for_a_change_and_longer_after_a_larger_cloud():
    fmap = followed(explored_map())
    out = CloudOutput(fmap, _opts(cloud_period_s=1.0, cloud_bytes_per_s=1000.0), Ros2Types())
    first = out.take(0.0, 1.0)
    assert first is not None and first.width == out.points > 0
    wait = first.width * 24 / 1000.0
    assert wait > 1.0
    out.note(_change(fmap, 7))
    assert out.take(wait - 0.01, 1.0) is None
    assert out.take(wait, 1.0) is not None
    assert out.take(100.0, 1.0) is None  # nothing changed since


def test_the_replica_refuses_every_bad_merged_delta_and_keeps_its_map():
    fmap = followed(explored_map())
    lam, eta = fmap.map.lam.copy(), fmap.map.eta.copy()
    idx = np.array([3, 40], np.uint32)
    one = np.ones(2, np.float32)

    def delta(grid=GRID, dlam=one, deta=one * 0.5, seq=1, i=idx) -> bytes:
        return DeltaMessage("r9", EPOCH, seq, 0.0, grid, i, dlam, deta).encode()

    bad = {
        "garbage": b"\x93\x00\xff not msgpack",
        "other grid": delta(grid=Grid((0.0, 0.0, 0.0), 0.1, (5, 5, 5))),
        "zeros": delta(dlam=one * 0, deta=one * 0),
        "mean above one": delta(dlam=one * 1e-3, deta=one * 1e6),
        "NaN": delta(deta=np.array([np.nan, 0.0], np.float32)),
        "negative": delta(dlam=-one),
        "outside the grid": delta(i=np.array([3, GRID.size], np.uint32)),
    }
    for name, payload in bad.items():
        with pytest.raises(WireError):
            fmap.apply_payload(payload)
        assert not fmap.pending, name
    np.testing.assert_array_equal(fmap.map.lam, lam)
    np.testing.assert_array_equal(fmap.map.eta, eta)
    assert fmap.counts["rejected"] == len(bad) and fmap.counts["applied"] == 0
    assert fmap.counts["rejected_other_grid"] == 1 and fmap.counts["rejected_out_of_range"] == 1
    assert fmap.apply_payload(delta()) == "applied" and fmap.apply_payload(delta()) == "duplicate"
    np.testing.assert_array_equal(fmap.refresh(), idx)
    assert fmap.coverage[3] != pytest.approx(0.5)


@pytest.mark.parametrize(
    "fields, problem",
    [
        ({"namespace": "/r 1"}, "namespace"),
        ({"band": (0.5, 0.1)}, "above the bottom"),
        ({"frame_id": "/map"}, "frame id"),
        ({"distro": "foxy"}, "humble"),
        ({"map_topic": "a//b"}, "empty tokens"),
        ({"threshold": 1.5}, "less than 1"),
        ({"domain_id": 300}, "less than or equal to 232"),
    ],
)
def test_options_refuse_what_ros_would_refuse(fields, problem):
    with pytest.raises(ValueError, match=problem):
        Ros2MapOptions(**fields)


def test_bad_options_are_one_line_each_naming_the_option(capsys):
    assert main(["map", "ros2", "--band", "1", "0", "--frame-id", "/x"]) == 2
    err = capsys.readouterr().err
    assert "swarm: error: --band: " in err and "swarm: error: --frame-id: " in err
    assert main(["map", "ros2", "--period", "nan"]) == 2
    assert main(["map", "ros2", "--no-grid", "--no-cloud"]) == 2
    assert main(["map", "ros2", "--ros-connect", "127.0.0.1:7447"]) == 2
    assert "write tcp/127.0.0.1:7447" in capsys.readouterr().err


def test_default_updates_topic_follows_the_map_topic():
    assert Ros2MapOptions(map_topic="team_map").updates == "team_map_updates"
    assert math.isclose(Ros2MapOptions().band[1], 0.5)
