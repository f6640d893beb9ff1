"""An agent and the team map: a late agent starts from the server's snapshot, then adds the
merged deltas of the other robots once, never its own (real map server, real Zenoh)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from robot_agent.agent import Agent
from swarm.map.coverage_map import CoverageMap
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import (
    assert_maps_equal,
    central_fusion,
    client_session,
    encode_all,
    publishers,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)


def test_a_late_agent_catches_up_from_a_snapshot_then_follows_the_merged_stream(tmp_path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    early = robot_batches(grid, sensor, robots=3, per_robot=4, seed=1)
    early.pop("r1")  # r2 and r3 have mapped before r1's agent starts
    later = robot_batches(grid, sensor, robots=3, per_robot=6, seed=2)
    with running_server(mission, tmp_path / "store") as (_server, endpoint):
        with client_session(endpoint) as robots, client_session(endpoint) as agent_side:
            pubs = publishers(robots, mission.mission, ["r2", "r3"])
            for rid, _seq, payload in encode_all(grid, early):
                pubs[rid].put(payload)
            client = MapClient(robots, mission.mission, timeout=2.0)
            wait_until(lambda: client.stats()["deltas_applied"] == 8, 10.0, "the early deltas")

            agent = Agent(mission, "r1", agent_side, coordination=False)
            assert agent.catch_up(timeout=5.0)
            assert_maps_equal(
                agent.explorer.map.lam, agent.explorer.map.eta, central_fusion(grid, sensor, early)
            )
            assert agent.explorer.map_entropy < 0.99 * CoverageMap(grid, sensor).lam.size * 7

            # Then: r2's next deltas (each sent twice), r3's first delta again (in the snapshot
            # already), and a delta of r1's own agent, which its local map holds already.
            own = later["r1"][0]
            agent.sender.start()  # asks map/epoch/r1
            wait_until(lambda: agent.epoch is not None, 10.0, "r1's epoch")
            mine = DeltaMessage("r1", agent.epoch, 1, 1.0, grid, own.idx, own.dlam, own.deta)
            agent.team.add_local(own)  # as fusing that frame did locally
            extra = [(rid, p) for rid, _s, p in encode_all(grid, {"r2": early["r2"] + later["r2"][:2]})][4:]
            merged_pub = bus.reliable_publisher(robots, bus.key(mission.mission, "merged"))
            assert bus.wait_for_subscribers([merged_pub], timeout=10.0)
            for _rid, payload in extra + extra:
                merged_pub.put(payload)
            merged_pub.put(encode_all(grid, {"r3": early["r3"]})[0][2])
            merged_pub.put(mine.encode())

            applied = 0
            deadline = time.monotonic() + 10.0
            while sum(agent.merged_counts.values()) < 6 and time.monotonic() < deadline:
                applied += agent.apply_merged()
                time.sleep(0.02)
            assert applied == 2
            assert agent.merged_counts == {"applied": 2, "duplicate": 3, "own": 1}
            expected = central_fusion(grid, sensor, {**early, "r2": early["r2"] + later["r2"][:2]})
            expected.apply(own)
            assert_maps_equal(agent.explorer.map.lam, agent.explorer.map.eta, expected)
            entropy = agent.explorer.entropy
            recomputed = type(entropy).from_information(
                agent.explorer.map.lam, agent.explorer.map.eta, table=agent.explorer.table
            )
            assert np.isclose(entropy.total, recomputed.total, rtol=1e-6)
            agent.shutdown()


@pytest.mark.slow
def test_an_agent_without_a_server_starts_from_the_prior(tmp_path):
    mission = small_mission()
    endpoint = bus.tcp_endpoint(bus.free_port())
    lonely = bus.open_session(listen=[endpoint])
    try:
        agent = Agent(mission, "r1", lonely, coordination=False)
        assert not agent.catch_up(timeout=0.3)
        prior = CoverageMap(mission.workspace.grid(), mission.sensor.model())
        np.testing.assert_array_equal(agent.explorer.map.lam, prior.lam)
        agent.shutdown()
    finally:
        lonely.close()
