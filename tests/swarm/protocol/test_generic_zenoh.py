"""Reading map/stats and map/region from a plain Zenoh client: zenoh, msgpack, json and numpy only.

The server side is the project's; the client side below uses no project code, as a client in
another language would (docs/interop.md, "Queries from any Zenoh client").
"""

from __future__ import annotations

import json
import time

import msgpack
import numpy as np
import zenoh

from swarm.protocol.map_client import MapClient
from tests.support.map_server_mission import (
    all_acked,
    central_fusion,
    client_session,
    encode_all,
    publishers,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)


def plain_get(endpoint: str, selector: str, timeout: float = 5.0) -> bytes:
    """One reply's payload to a Zenoh get, from a client session of zenoh alone."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for reply in session.get(selector, timeout=2.0):
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes()
                raise AssertionError(f"error reply: {reply.err.payload.to_string()}")
            time.sleep(0.2)  # no queryable matched yet
    raise AssertionError(f"no reply to {selector}")


def test_stats_and_region_from_zenoh_alone(tmp_path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, robots=2, per_robot=2, rays=300, seed=4)
    with (
        running_server(mission, tmp_path / "store") as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        pubs = publishers(session, mission.mission, batches)
        for rid, _seq, payload in encode_all(grid, batches):
            pubs[rid].put(payload)
        client = MapClient(session, mission.mission, endpoint=endpoint)
        wait_until(lambda: all_acked(client, dict.fromkeys(batches, 2)), 20, "every delta acked")
        central = central_fusion(grid, sensor, batches)

        stats = json.loads(plain_get(endpoint, f"swarm/{mission.mission}/map/stats"))
        assert stats["deltas_applied"] == 4 and stats["shape"] == list(grid.shape)
        assert abs(stats["known_fraction"] - np.mean(central.known_mask())) < 1e-3

        lo, hi = (0.5, 0.5, 0.2), (1.0, 0.8, 0.4)
        selector = (
            f"swarm/{mission.mission}/map/region?lo={','.join(map(str, lo))};hi={','.join(map(str, hi))}"
        )
        region = msgpack.unpackb(plain_get(endpoint, selector), raw=False)
        assert region["v"] == 1
        idx = np.frombuffer(region["idx"], "<u4")
        mu = np.frombuffer(region["mu"], "<f4")
        sigma = np.frombuffer(region["sigma"], "<f4")
        shape = tuple(region["grid"]["shape"])
        origin = np.array(region["grid"]["origin"])
        voxel = region["grid"]["voxel"]
        centres = origin + (np.stack(np.unravel_index(idx, shape), axis=1) + 0.5) * voxel
        # the voxels whose cells overlap the box, as docs/protocol.md says
        assert np.all(centres + voxel / 2 > lo) and np.all(centres - voxel / 2 < hi)
        assert len(idx) == 5 * 3 * 2
        np.testing.assert_allclose(mu, central.mean(idx.astype(np.int64)), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(sigma, central.sigma(idx.astype(np.int64)), rtol=1e-5)
