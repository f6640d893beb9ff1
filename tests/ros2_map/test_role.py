"""The ros2_map role with a real map server: when merged deltas must be dropped (the queue is
full), the role starts again from a fresh snapshot, at most once per interval, and its map ends
as the server's."""

from __future__ import annotations

import numpy as np
import pytest

import ros2_map.role as role
from ros2_map.options import Ros2MapOptions
from ros2_map.role import TeamMapTopics
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient, export_map
from tests.support.map_server_mission import (
    all_acked,
    client_session,
    encode_all,
    publishers,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)
from tests.support.ros2_map_oracle import oracle_grid


@pytest.mark.slow
def test_dropped_merged_deltas_make_the_role_start_again_from_a_snapshot(tmp_path, monkeypatch):
    monkeypatch.setattr(role, "RESYNC_INTERVAL_S", 0.5)
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    with running_server(mission, tmp_path / "store") as (_server, endpoint), client_session(endpoint) as s:
        ros = bus.open_session(connect=[endpoint], timestamping=True)
        options = Ros2MapOptions(period_s=0.1, cloud_period_s=0.1)
        topics = TeamMapTopics(s, mission.mission, options, ros, max_queued_bytes=1)  # takes none
        topics.start()
        try:
            batches = robot_batches(grid, sensor, robots=2, per_robot=3, seed=61)
            pubs = publishers(s, mission.mission, batches)
            for rid, _seq, payload in encode_all(grid, batches):
                pubs[rid].put(payload)
            client = MapClient(s, mission.mission)
            wait_until(lambda: all_acked(client, {"r1": 3, "r2": 3}), 20, "the deltas")
            wait_until(lambda: topics.counts["merged_dropped"] == 6, 10, "the drops")
            wait_until(lambda: topics.caught_up() and topics.counts["resyncs"] >= 1, 10, "a fresh snapshot")
            assert topics.counts["resyncs"] <= 2  # one per interval, not one per drop
            assert topics.fmap.counts["applied"] == 0  # every delta came with the snapshot
            export_map(client, tmp_path / "map.npz")
            expected = oracle_grid(tmp_path / "map.npz", (0.1, 0.5))
            np.testing.assert_array_equal(topics.outputs.grid.cells, expected)
            assert (expected != -1).any()
        finally:
            topics.stop()
            ros.close()
