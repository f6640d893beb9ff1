"""What a stranger on the bus can make the map server spend on others: messages it would
log durably and send on to every replica, queries whose answers cost memory per voxel.
Real Zenoh sessions on loopback, explicit endpoints, multicast scouting off."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from map_server.options import ServerOptions
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage
from tests.support.hostile_oracle import oracle
from tests.support.log_lines import LogLines, allowed_lines
from tests.support.malformed_deltas import good
from tests.support.map_server_mission import (
    EPOCH,
    client_session,
    publishers,
    running_server,
    small_mission,
    wait_until,
)
from tests.support.paths import CONFIGS

ROBOTS = ("r1", "r2", "r3", "r4")  # r4: the attacker, a robot the server takes
OPTIONS = ServerOptions(robots=ROBOTS)


def zero_information_deltas(grid, robot: str, count: int) -> list[bytes]:
    """Deltas that change nothing, each with a fresh seq: empty ones, and zeros on voxels."""
    out = []
    for seq in range(1, count + 1):
        idx = np.arange(seq % 2 * (1 + seq % 50), dtype=np.uint32)  # empty, or 1..50 voxels
        zeros = np.zeros(len(idx), np.float32)
        out.append(DeltaMessage(robot, EPOCH, seq, float(seq), grid, idx, zeros, zeros).encode())
    return out


@pytest.mark.slow
def test_a_flood_of_zero_information_deltas_is_neither_logged_nor_sent_on(tmp_path: Path):
    """Empty deltas and deltas of zeros, with fresh seqs, were each appended to the write-ahead
    log, fsynced and republished on ``merged`` to every replica: a flood cost the server's disk
    and every subscriber. They are refused (``no_information``) and change nothing."""
    mission = small_mission()
    grid = mission.workspace.grid()
    flood = zero_information_deltas(grid, "r4", 600)
    honest = good(grid, "r1", seq=1, idx=(5, 60, 61))
    with (
        running_server(mission, tmp_path / "store", OPTIONS) as (server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        merged, merged_inbox = bus.subscribe_queue(session, bus.key(mission.mission, "merged"))
        pubs = publishers(session, mission.mission, ["r1", "r4"])
        for i, payload in enumerate(flood):
            pubs["r4"].put(payload)
            if i == len(flood) // 2:
                pubs["r1"].put(honest)

        def flood_handled() -> bool:
            stats = client.stats()
            refused = stats["inbox"]["refused"].get("r4", 0)
            applied = stats["robots"].get("r4", {}).get("deltas", 0)  # before the fix: all of them
            return stats["rejected"]["no_information"] + refused + applied == len(flood)

        wait_until(flood_handled, 30, "every delta of the flood handled")
        wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10, "r1's delta")
        stats, acks, snap = client.stats(), client.acks(), client.snapshot()
        time.sleep(0.3)  # the merged stream's tail
        merged.undeclare()
    sent_on = [merged_inbox.get_nowait()[1] for _ in range(merged_inbox.qsize())]
    assert sent_on == [honest]
    # what the robot's inbox had room for was refused as no_information, the rest as a full
    # inbox (how many of each depends on how fast the worker ran): none was logged or applied
    assert stats["rejected"]["no_information"] > 0
    assert stats["rejected"]["no_information"] + stats["inbox"]["refused"].get("r4", 0) == len(flood)
    assert stats["wal_records"] == 1 and stats["deltas_applied"] == 1
    assert not any(acks.get("r4", {}).values()) and "r4" not in stats["robots"]  # its epoch: 0
    expected = oracle(mission, [honest])
    np.testing.assert_array_equal(snap.lam, expected.cmap.lam)
    np.testing.assert_array_equal(snap.eta, expected.cmap.eta)


def _slow_to_answer(answer, seconds: float):
    """``MapStreams.answer`` taking ``seconds`` more (a large map's chunks on a busy machine)."""

    def slow(query, start):
        time.sleep(seconds)
        answer(query, start)

    return slow


@pytest.mark.slow
def test_a_flood_of_snapshot_queries_gets_busy_replies_and_deltas_go_on(tmp_path: Path):
    """64 snapshot queries at once, each taking 0.2 s to answer: all were taken on and answered
    one after the other (13 s of work for one stranger's burst, every team member's snapshot
    behind it). At most 8 are taken on (2 answered at once); the others get "busy" at once,
    and r1's deltas are merged meanwhile; a MapClient told "busy" asks again."""
    mission = small_mission()
    grid = mission.workspace.grid()
    burst = 64
    with (
        running_server(mission, tmp_path / "store", OPTIONS) as (server, endpoint),
        client_session(endpoint) as session,
        client_session(endpoint) as stranger,
    ):
        client = MapClient(session, mission.mission, timeout=10.0, endpoint=endpoint)
        key = bus.key(mission.mission, "map", "snapshot")
        # the queryables' declarations reach each session a little after start
        wait_until(lambda: list(stranger.get(key, timeout=5.0)) != [], 10, "the stranger sees map/snapshot")
        real = server.streams.answer
        server.streams.answer = _slow_to_answer(real, 0.2)
        pub = publishers(session, mission.mission, ["r1"])["r1"]
        handles = [stranger.get(key, timeout=60.0) for _ in range(burst)]
        for seq in range(1, 6):
            pub.put(good(grid, "r1", seq=seq, idx=(seq, 200 + seq)))
        wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 5, 10, "r1's deltas during the burst")
        during = client.snapshot()  # a team member's client asks again while it is told "busy"
        replies = [r for h in handles for r in h]
        stats = client.stats()
        server.streams.answer = real
        snap = client.snapshot()
    errors = [r.err.payload.to_string() for r in replies if r.err is not None]
    assert len(replies) == burst
    assert len(errors) >= burst - stats["queries"]["max"], errors[:3]
    assert all(": busy: " in e for e in errors), errors[:3]
    assert stats["queries"]["high_water"] <= stats["queries"]["max"] == 8
    assert stats["queries"]["busy"]["snapshot"] >= len(errors)  # and the MapClient's, told to wait
    expected = oracle(mission, [good(grid, "r1", seq=s, idx=(s, 200 + s)) for s in range(1, 6)])
    np.testing.assert_array_equal(snap.lam, expected.cmap.lam)
    assert during.acks["r1"][EPOCH] >= 1


def test_the_query_gate_bounds_each_requester_and_all_of_them():
    from map_server.query_gate import QueryGate

    gate = QueryGate(total=3, per_requester=2, workers=1)
    try:
        assert gate._enter("a") is None and gate._enter("a") is None
        assert "queries of 'a'" in gate._enter("a")  # a's third
        assert gate._enter(None) is None  # no stated id: only the total binds it
        assert "3 whole-map queries" in gate._enter("b")
        gate._leave("a")
        assert gate._enter("b") is None and gate.stats()["in_flight"] == 3
    finally:
        gate.close()


def _remote_stranger(endpoint: str) -> zenoh.Session:
    """A client session without shared memory, as a stranger on another machine has."""
    conf = bus.make_config(connect=[endpoint], mode="client")
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return zenoh.open(conf)


def test_the_server_session_drops_a_message_over_its_bound(tmp_path: Path):
    """Zenoh put together any fragmented message up to 1 GiB on the server's links before the
    server's own size check saw it. The server's session now takes at most its bound (here
    2 MiB, set small for the test): a 3 MiB message never reaches the server, a 1 MiB one is
    refused by the server (too_large), and the link goes on carrying r4's deltas."""
    from map_server.process import server_session
    from map_server.server import MapServer

    mission = small_mission()
    grid = mission.workspace.grid()
    options = ServerOptions(robots=ROBOTS, max_message_bytes=2 << 20)
    endpoint = bus.tcp_endpoint(bus.free_port())
    server = MapServer(mission, tmp_path / "store", options=options)
    session = server_session(server, mission, [endpoint])
    server.start(session)
    stranger = _remote_stranger(endpoint)
    try:
        with client_session(endpoint) as team:
            client = MapClient(team, mission.mission, timeout=5.0, endpoint=endpoint)
            pub = publishers(stranger, mission.mission, ["r4"])["r4"]
            pub.put(bytes(3 << 20))  # over the session's bound
            pub.put(bytes(1 << 20))  # under it, over the server's payload limit
            pub.put(good(grid, "r4", seq=1))
            wait_until(lambda: client.acks().get("r4", {}).get(EPOCH) == 1, 20, "r4's delta")
            stats = client.stats()
    finally:
        stranger.close()
        server.stop()
        session.close()
    assert stats["rejected"]["too_large"] == 1


def test_the_coordinator_and_server_bounds_fit_the_largest_legitimate_messages(tmp_path: Path):
    """The bounds are twice the largest message each role must take, at least 64 MiB, far below
    Zenoh's 1 GiB; a config file's own value wins."""
    from coordinator.command import message_limit_of
    from map_server.options import max_payload_for, message_limit_for
    from swarm.config import load_mission
    from swarm.protocol.message_size import delta_bytes, frame_bytes, snapshot_bytes

    office = load_mission(CONFIGS / "office.yaml")
    grid = office.workspace.grid()
    coordinator = message_limit_of(office)
    assert coordinator >= 2 * snapshot_bytes(grid, len(office.robot_ids) + 64) >= 2 * delta_bytes(grid)
    server = message_limit_for(office, ServerOptions(), max_payload_for(grid))
    rig = office.rig_for(office.robot_ids[0])
    assert server >= max(64 << 20, 2 * max_payload_for(grid), 2 * frame_bytes(rig.width, rig.height))
    assert max(server, coordinator) < 1 << 30
    conf, _, _ = bus.session_config([], ["tcp/127.0.0.1:1"], max_message_bytes=coordinator)
    assert json.loads(conf.get_json("transport/link/rx/max_message_size")) == coordinator
    own = tmp_path / "zenoh.json5"
    own.write_text("{transport: {link: {rx: {max_message_size: 5000000}}}}")
    conf, _, _ = bus.session_config([], ["tcp/127.0.0.1:1"], config_file=own, max_message_bytes=coordinator)
    assert json.loads(conf.get_json("transport/link/rx/max_message_size")) == 5_000_000


def test_a_flood_of_malformed_deltas_logs_a_line_per_reason_not_per_delta(tmp_path: Path):
    """3,000 malformed deltas logged 13 lines (the first ten of a kind, then every thousandth):
    a sustained flood wrote one line per thousand deltas without end. Now one line per kind
    per 10 s, which counts the unlogged ones."""
    mission = small_mission()
    grid = mission.workspace.grid()
    flood, rounds = 3000, 15
    since = time.monotonic()
    with (
        LogLines("swarm.server") as logged,
        running_server(mission, tmp_path / "store", OPTIONS) as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        pubs = publishers(session, mission.mission, ["r1", "r4"])
        for n in range(rounds):  # in rounds the inbox holds, so that every delta is refused as malformed
            for i in range(flood // rounds):
                pubs["r4"].put(b"\x00not a delta %d" % i)
            handled = (n + 1) * (flood // rounds)
            wait_until(
                lambda h=handled: client.stats()["rejected"]["malformed"] >= h, 20, f"{handled} refused"
            )
        pubs["r1"].put(good(grid, "r1"))
        wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10, "r1's delta")
    allowed = allowed_lines(since)
    rejected_lines = [line for line in logged.lines if line.startswith("rejected delta")]
    assert 1 <= len(rejected_lines) <= allowed, rejected_lines


def test_the_log_limiter_counts_what_it_left_unlogged():
    from swarm.log_limit import LogLimiter

    now = [0.0]
    with LogLines("test.limiter") as logged:
        limiter = LogLimiter(logging.getLogger("test.limiter"), interval_s=10.0, clock=lambda: now[0])
        for i in range(5):
            limiter.warning("a", "bad %d", i)
        limiter.warning("b", "other")
        now[0] = 12.0
        limiter.warning("a", "bad %d", 99)
    assert logged.lines == ["bad 0", "other", "bad 99 (4 more like it unlogged in the last 12 s)"]
