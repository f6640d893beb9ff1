"""The agent's delta publisher runs off its loop (robot_agent.delta_sender): a link that stops
draining holds the sender's thread, never the hand-over, and once the link drains again the
resends (as the agent's ack poll makes them) get every delta acked. The stall is real: a TCP
relay between the agent's session and the map server that stops reading (swarm.bench.stall_relay)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from robot_agent.delta_sender import DeltaSender
from swarm.bench.stall_relay import StallRelay
from swarm.map.delta import Delta
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from tests.support.map_server_mission import (
    assert_maps_equal,
    central_fusion,
    client_session,
    running_server,
    small_mission,
    wait_until,
)

pytestmark = pytest.mark.slow  # real Zenoh sessions, seconds each


def _full_grid_deltas(grid, sensor, count: int) -> list[Delta]:
    """Deltas as large as the grid allows (every voxel once: 72 KB each on 6,000 voxels)."""
    rng = np.random.default_rng(31)
    idx = np.arange(grid.size, dtype=np.uint32)
    out = []
    for _ in range(count):
        dlam = rng.uniform(0.01, 0.1, grid.size).astype(np.float32)
        out.append(Delta(idx, dlam, dlam * np.float32(0.5)))
    return out


def test_a_link_that_stops_draining_holds_the_sender_not_the_loop(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    deltas = _full_grid_deltas(grid, sensor, 300)  # 21 MB
    with running_server(mission, tmp_path / "store") as (_server, endpoint), client_session(endpoint) as tool:
        host, port = endpoint.removeprefix("tcp/").split(":")
        relay = StallRelay((host, int(port)), stall_from="client")
        robot = bus.open_session(connect=[bus.tcp_endpoint(relay.port)])
        try:
            sender = DeltaSender(robot, mission.mission, "r1", grid)
            sender.start()
            wait_until(lambda: sender.epoch is not None, 15, "r1's epoch through the relay")
            client = MapClient(tool, mission.mission, timeout=5.0)
            relay.stall()
            handed = []
            for seq, delta in enumerate(deltas, start=1):
                started = time.perf_counter()
                sender.send(seq, float(seq), delta)
                handed.append(time.perf_counter() - started)
            stuck = not sender.drain(2.0)  # its put waits on the full link
            worst_ms = max(handed) * 1e3
            relay.resume()
            # what the agent's ack poll does: send again what is unacked and not sent lately
            deadline = time.monotonic() + 90
            while (acked := client.acks().get("r1", {}).get(sender.epoch, 0)) < len(deltas):
                assert time.monotonic() < deadline, f"only {acked} of {len(deltas)} acked"
                now = time.monotonic()
                for seq in range(acked + 1, len(deltas) + 1):
                    if now - sender.last_sent(seq) > 2.0:
                        sender.send(seq, float(seq), deltas[seq - 1])
                time.sleep(0.5)
            snap = client.snapshot()
            sender.stop()
        finally:
            robot.close()
            relay.close()
    print(f"hand-over during the stall: worst {worst_ms:.2f} ms; sender blocked: {stuck}")
    assert stuck, "the stalled link did not fill: the test shows nothing"
    assert worst_ms < 20.0
    assert_maps_equal(snap.lam, snap.eta, central_fusion(grid, sensor, {"r1": deltas}))
