"""The coordinator role: replica of the merged stream, coord/assign over real Zenoh on loopback."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from coordinator.answer_report import answer_time_summary
from coordinator.assignment import CoordinationParams
from coordinator.command import add_arguments
from coordinator.role import Coordinator
from swarm.map.grid import Grid
from swarm.protocol import bus
from swarm.protocol.coord_client import ask_for_target, coordinator_stats
from swarm.protocol.wire import AssignReply, AssignRequest, DeltaMessage, Pose, Snapshot
from tests.support.coordinator_scene import (
    FOOTPRINT,
    MISSION,
    MapServerStandIn,
    corridor_map,
    deltas_of,
    far_apart,
    mission,
    pose,
    query,
    wait_until,
)


@pytest.mark.slow
def test_coordinator_role_over_zenoh():
    m = mission()
    name = m.mission
    full = corridor_map(m)
    left, right = corridor_map(m, x_hi=4.0), corridor_map(m, x_lo=4.0001)
    # the server has applied r9's three deltas (the left part) when the coordinator starts
    old = deltas_of(m, left, "r9", 1, 3)
    rest = deltas_of(m, right, "r8", 7, 4)
    snap = Snapshot(left.grid, left.lam, left.eta, acks={"r9": {1: 3}})
    server = MapServerStandIn(name, snap)
    coord_session = bus.open_session(connect=[server.endpoint])
    client = bus.open_session(connect=[server.endpoint])
    params = CoordinationParams(beta=0.1, footprint_radius=FOOTPRINT, robot_timeout_s=1.5, status_grace_s=0.2)
    coordinator = Coordinator(m, coord_session, params, snapshot_timeout=5.0)
    try:
        coordinator.start()
        assert coordinator.started_from_snapshot
        assert bus.wait_for_subscribers([server.merged], timeout=5.0)
        # replays of what the snapshot holds, the rest once, a duplicate, and two bad messages
        for msg in [*old, *rest, rest[0]]:
            server.merged.put(msg.encode())
        server.merged.put(b"\x93not a delta")
        other_grid = DeltaMessage("r8", 7, 99, 0.0, Grid((0, 0, 0), 0.2, (4, 4, 4)), *(np.zeros(0),) * 3)
        server.merged.put(other_grid.encode())
        assert wait_until(lambda: coordinator.counts["merged_applied"] == 4), coordinator.counts
        assert wait_until(lambda: coordinator.counts["merged_rejected"] == 2), coordinator.counts
        counts = coordinator.counts
        assert counts["merged_duplicate"] == 4
        replica, _ = coordinator.state.team.copy()
        assert np.allclose(replica.lam, full.lam, rtol=1e-5) and np.allclose(replica.eta, full.eta, atol=1e-3)

        for r in ("r1", "r2", "r3"):
            server.publish_status(r, None, "look_around")
        assert wait_until(lambda: len(coordinator.state.book.live()) == 3)

        # three robots ask one after the other: distinct targets, one footprint apart
        replies = {}
        for r in ("r1", "r2", "r3"):
            reply = ask_for_target(client, name, r, pose(r), timeout=5.0)
            assert reply is not None and reply.target is not None
            replies[r] = reply
        assert far_apart([rep.target for rep in replies.values()], FOOTPRINT)

        # malformed requests get an error reply; the coordinator keeps serving
        bad = [
            b"garbage",
            msgpack.packb({"v": 1, "robot": "r1"}),
            AssignRequest("r1", Pose((50.0, 2.0, 0.4))).encode(),
            msgpack.packb({"v": 2, "robot": "r1", "pose": pose("r1").to_wire()}),
        ]
        for payload in bad:
            reply = query(client, name, payload)
            assert reply.ok is None and b"coord/assign" in reply.err.payload.to_bytes()
        assert coordinator.counts["requests_rejected"] == len(bad)

        # r2 and r3 keep reporting their targets; r1 falls silent and loses its target,
        # which r4 (standing where r1 stood) then gets
        deadline = time.monotonic() + params.robot_timeout_s + 0.5
        while time.monotonic() < deadline:
            server.publish_status("r2", replies["r2"].target)
            server.publish_status("r3", replies["r3"].target)
            time.sleep(0.2)
        assert wait_until(lambda: "r1" not in coordinator.state.book.live())
        r4 = AssignReply.decode(
            query(client, name, AssignRequest("r4", pose("r1")).encode(), robot="r4").ok.payload.to_bytes()
        )
        assert r4.target == pytest.approx(replies["r1"].target)
        assert coordinator.counts["assigned"] == 4

        # coord/stats: every answered query (good and bad) timed, and the same counters
        stats = coordinator_stats(client, name, timeout=5.0)
        assert stats is not None
        times = stats["answer_ms"]
        assert times["count"] == 4 + len(bad)
        assert 0 < times["p50"] <= times["p95"] <= times["max"] and times["mean"] <= times["max"]
        assert stats["counts"]["assigned"] == 4
        assert stats["counts"]["requests_rejected"] == len(bad)
    finally:
        coordinator.stop()
        coord_session.close()
        client.close()
        server.close()


def test_answer_time_summary_takes_nearest_rank_percentiles():
    rng = np.random.default_rng(3)
    times = rng.lognormal(2.0, 1.0, 101).tolist()
    summary = answer_time_summary(times)
    assert summary["count"] == 101
    assert summary["mean"] == pytest.approx(np.mean(times))
    for key, q in (("p50", 50), ("p95", 95)):
        assert summary[key] == np.percentile(times, q, method="inverted_cdf")
    assert summary["max"] == max(times)
    assert answer_time_summary([]) == {"count": 0, "mean": 0.0, "p50": 0.0, "p95": 0.0, "max": 0.0}


def test_without_a_coordinator_the_agent_is_told_nothing_and_decides_alone():
    endpoint = bus.tcp_endpoint(bus.free_port())
    router = bus.open_session(listen=[endpoint])
    client = bus.open_session(connect=[endpoint])
    try:
        assert ask_for_target(client, "nobody", "r1", pose("r1"), timeout=1.0) is None
    finally:
        client.close()
        router.close()


@pytest.mark.slow
def test_command_line_runs_without_a_map_server_and_stops_on_sigterm(tmp_path: Path):
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--config", "x.yaml", "--connect", "tcp/127.0.0.1:1", "--mission", "m2"])
    assert (args.config, args.connect, args.mission) == (Path("x.yaml"), ["tcp/127.0.0.1:1"], "m2")

    import yaml

    config = tmp_path / "mission.yaml"
    config.write_text(yaml.safe_dump(MISSION))
    endpoint = bus.tcp_endpoint(bus.free_port())
    router = bus.open_session(listen=[endpoint])
    code = (
        "import argparse, sys\n"
        "from coordinator.command import add_arguments, run\n"
        "p = argparse.ArgumentParser(); add_arguments(p)\n"
        "sys.exit(run(p.parse_args(sys.argv[1:])))\n"
    )
    cmd = [sys.executable, "-c", code, "--config", str(config), "--connect", endpoint, "--mission", "other"]
    cmd += ["--snapshot-timeout", "0.5"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        reply = None
        deadline = time.monotonic() + 60.0  # generous: a loaded CI machine starts Python slowly
        while reply is None and time.monotonic() < deadline:
            reply = ask_for_target(router, "other", "r1", pose("r1"), timeout=1.0)
            time.sleep(0.1)
        # the prior map holds nothing informative to stand in front of: nothing left
        assert reply is not None and reply.target is None and reply.gaze is None
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
        router.close()
    assert proc.returncode == 0, err
    assert "coordinator: " in out and "requests 1" in out
    assert "assign r1 -> nothing left" in err
