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
from map_server.snapshot_stream import MapStreams, StreamCache, held_snapshot
from swarm.protocol import bus
from swarm.protocol.map_chunks import CHUNK_BYTES
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage
from tests.support.hostile_oracle import oracle
from tests.support.malformed_deltas import good
from tests.support.map_server_mission import (
    EPOCH,
    UnsignedPublisher,
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


class _Lines(logging.Handler):
    """The log lines of one logger, while in a ``with`` block."""

    def __init__(self, name: str) -> None:
        super().__init__(logging.DEBUG)
        self.logger, self.lines = logging.getLogger(name), []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())

    def __enter__(self):
        self.logger.addHandler(self)
        self.logger.setLevel(logging.DEBUG)
        return self

    def __exit__(self, *exc) -> None:
        self.logger.removeHandler(self)


def _allowed_lines(since: float) -> int:
    """Lines of one reason a 10 s limiter may write from ``since`` (time.monotonic()) to now."""
    return 1 + int((time.monotonic() - since) / 10.0)


def test_a_flood_of_malformed_deltas_logs_a_line_per_reason_not_per_delta(tmp_path: Path):
    """3,000 malformed deltas logged 13 lines (the first ten of a kind, then every thousandth):
    a sustained flood wrote one line per thousand deltas without end. Now one line per kind
    per 10 s, which counts the unlogged ones."""
    mission = small_mission()
    grid = mission.workspace.grid()
    flood, rounds = 3000, 15
    since = time.monotonic()
    with (
        _Lines("swarm.server") as logged,
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
    allowed = _allowed_lines(since)
    rejected_lines = [line for line in logged.lines if line.startswith("rejected delta")]
    assert 1 <= len(rejected_lines) <= allowed, rejected_lines


def test_a_flood_of_malformed_assign_requests_logs_a_line_per_reason():
    """Each malformed coord/assign request logged a line: 300 requests, 300 lines."""
    from coordinator.role import Coordinator
    from swarm.protocol.coord_client import assign_key
    from swarm.protocol.wire import Snapshot
    from tests.support.coordinator_scene import MapServerStandIn, corridor_map
    from tests.support.coordinator_scene import mission as coordinated_mission

    m = coordinated_mission()
    full = corridor_map(m)
    server = MapServerStandIn(m.mission, Snapshot(full.grid, full.lam, full.eta))
    coord_session = bus.open_session(connect=[server.endpoint])
    stranger = bus.open_session(connect=[server.endpoint])
    coordinator = Coordinator(m, coord_session, snapshot_timeout=5.0)
    since = time.monotonic()
    try:
        with _Lines("coordinator") as logged:
            coordinator.start()
            key = assign_key(m.mission, "r1")
            # the queryable's declaration reaches the stranger's session a little after start
            wait_until(
                lambda: list(stranger.get(key, payload=b"\xc1", timeout=5.0)) != [], 10, "the queryable"
            )
            handles = [stranger.get(key, payload=b"\xc1%d" % i, timeout=10.0) for i in range(300)]
            errors = sum(r.err is not None for h in handles for r in h)
        allowed = _allowed_lines(since)
    finally:
        coordinator.stop()
        coord_session.close()
        stranger.close()
        server.close()
    assert errors == 300
    rejected_lines = [line for line in logged.lines if line.startswith("rejected assign request")]
    assert 1 <= len(rejected_lines) <= allowed, rejected_lines[:5]


def test_the_log_limiter_counts_what_it_left_unlogged():
    from swarm.log_limit import LogLimiter

    now = [0.0]
    with _Lines("test.limiter") as logged:
        limiter = LogLimiter(logging.getLogger("test.limiter"), interval_s=10.0, clock=lambda: now[0])
        for i in range(5):
            limiter.warning("a", "bad %d", i)
        limiter.warning("b", "other")
        now[0] = 12.0
        limiter.warning("a", "bad %d", 99)
    assert logged.lines == ["bad 0", "other", "bad 99 (4 more like it unlogged in the last 12 s)"]


def test_an_agent_logs_floods_of_bad_frames_and_merged_deltas_a_line_per_reason():
    """An agent logged each undecodable frame and each bad message on ``merged`` (which anyone
    on an open bus can publish): 300 of each, 600 lines."""
    from robot_agent.agent import Agent

    mission = small_mission()
    endpoint = bus.tcp_endpoint(bus.free_port())
    session = bus.open_session(listen=[endpoint])
    try:
        since = time.monotonic()
        with _Lines("swarm.agent") as logged, client_session(endpoint) as stranger:
            agent = Agent(mission, "r1", session, coordination=False)
            merged = bus.reliable_publisher(stranger, bus.key(mission.mission, "merged"))
            assert bus.wait_for_subscribers([merged], 10.0)
            for i in range(300):
                merged.put(b"\xc1 not a delta %d" % i)
                assert agent.handle(b"\xc1 not a frame %d" % i) is None
            wait_until(
                lambda: agent.apply_merged() >= 0 and agent.merged_counts["rejected"] == 300, 20, "the flood"
            )
        allowed = _allowed_lines(since)
    finally:
        session.close()
    assert agent.rejected_frames == 300
    frames = [line for line in logged.lines if "rejected frame" in line]
    deltas = [line for line in logged.lines if "rejected merged delta" in line]
    assert 1 <= len(frames) <= allowed and 1 <= len(deltas) <= allowed, (len(frames), len(deltas))


def test_deltas_of_invented_robots_on_merged_cost_the_coordinator_a_bounded_amount():
    """The coordinator's replica kept 8 bytes per map column for every robot id seen on
    ``merged`` and went through all of them for each answer: 3,000 one-voxel deltas of invented
    robots (about 600 KB on the wire) took 411 MB of the office's coordinator and made each
    answer 0.11 s slower. It tracks the mission's robots and 65 more; empty deltas are refused."""
    from coordinator.role import Coordinator
    from swarm.protocol.coord_client import assign_key
    from swarm.protocol.message_size import PATTERN_ROBOTS
    from swarm.protocol.wire import AssignRequest, Snapshot
    from tests.support.coordinator_scene import MapServerStandIn, corridor_map, pose
    from tests.support.coordinator_scene import mission as coordinated_mission

    m = coordinated_mission()
    grid = m.workspace.grid()
    full = corridor_map(m)
    server = MapServerStandIn(m.mission, Snapshot(full.grid, full.lam, full.eta))
    coord_session = bus.open_session(connect=[server.endpoint])
    coordinator = Coordinator(m, coord_session, snapshot_timeout=5.0)
    invented, empty = 400, 100
    one = np.ones(1, np.float32)
    try:
        coordinator.start()
        assert bus.wait_for_subscribers([server.merged], 10.0)
        for i in range(invented):
            idx = np.array([i % grid.size], np.uint32)
            server.merged.put(DeltaMessage(f"x{i}", 1, 1, 0.0, grid, idx, one, one * 0.5).encode())
        for i in range(empty):
            nothing = np.zeros(0, np.float32)
            server.merged.put(
                DeltaMessage(f"y{i}", 1, 1, 0.0, grid, np.zeros(0, np.uint32), nothing, nothing).encode()
            )
        counts = coordinator.state.team.counts
        wait_until(lambda: counts["applied"] + counts["rejected"] == invented + empty, 20, "the merged flood")
        request = AssignRequest("r1", pose("r1")).encode()
        replies = list(coord_session.get(assign_key(m.mission, "r1"), payload=request, timeout=10.0))
        tracked = coordinator.state.team.columns.robots()
    finally:
        coordinator.stop()
        coord_session.close()
        server.close()
    assert len(replies) == 1 and replies[0].ok is not None
    assert counts["rejected"] == empty and counts["applied"] == invented
    assert len(tracked) == len(m.robot_ids) + PATTERN_ROBOTS + 1
    assert counts["unattributed"] == invented - len(tracked)


def test_the_mission_monitor_attributes_a_bounded_number_of_robots():
    """The runner's monitor kept a 4-byte-per-voxel array for every robot id seen on delta/*
    (1.4 MB each on the office grid) and printed every refused delta."""
    from swarm.mission.team_monitor import TeamMonitor
    from swarm.protocol.message_size import PATTERN_ROBOTS

    mission = small_mission()
    grid = mission.workspace.grid()
    endpoint = bus.tcp_endpoint(bus.free_port())
    session = bus.open_session(listen=[endpoint])
    monitor = TeamMonitor(mission)
    sub = bus.subscribe(session, bus.key_pattern(mission.mission, "delta", "*"), monitor.on_delta)
    invented, malformed = 200, 100
    bound = len(mission.robot_ids) + PATTERN_ROBOTS + 1
    try:
        since = time.monotonic()
        with _Lines("swarm.monitor") as logged, client_session(endpoint) as stranger:
            # no map server: the stranger's deltas go without a MAC (the monitor does not check one)
            pubs = {f"x{i}": UnsignedPublisher(stranger, mission.mission, f"x{i}") for i in range(invented)}
            assert bus.wait_for_subscribers([p.pub for p in pubs.values()], timeout=10.0)
            for i, pub in enumerate(pubs.values()):
                pub.put(good(grid, f"x{i}", idx=(i,)))
            for i in range(malformed):
                pubs["x0"].put(b"\xc1 not a delta %d" % i)
            wait_until(lambda: monitor.applied + monitor.rejected == invented + malformed, 20, "the flood")
        allowed = _allowed_lines(since)
    finally:
        sub.undeclare()
        session.close()
    assert len(monitor.first_delta) == bound and monitor.unattributed == invented - bound
    assert monitor.applied == invented
    assert 1 <= len([line for line in logged.lines if "rejected delta" in line]) <= allowed


@pytest.mark.slow
def test_the_coordinator_asks_again_for_a_snapshot_while_the_server_is_busy():
    """A "busy" answer to the coordinator's start-up map/snapshot (a stranger's query burst at
    that moment) made it start from the prior and never see the map built so far."""
    from coordinator.role import Coordinator
    from swarm.protocol.wire import Snapshot
    from tests.support.coordinator_scene import corridor_map
    from tests.support.coordinator_scene import mission as coordinated_mission

    m = coordinated_mission()
    full = corridor_map(m)
    snap = Snapshot(full.grid, full.lam, full.eta)
    streams = MapStreams(StreamCache(), CHUNK_BYTES)
    asked = []

    def busy_twice(query: zenoh.Query) -> None:
        asked.append(1)
        if len(asked) <= 2:
            query.reply_err(f"{query.key_expr}: busy: 8 whole-map queries are being answered".encode())
        else:  # streamed, as the map server answers it (the map fits in one window)
            streams.answer(query, lambda _q: held_snapshot(snap, 0, 0, CHUNK_BYTES))

    endpoint = bus.tcp_endpoint(bus.free_port())
    router = bus.open_session(listen=[endpoint])
    queryable = router.declare_queryable(bus.key(m.mission, "map", "snapshot"), busy_twice)
    coord_session = bus.open_session(connect=[endpoint])
    key = bus.key(m.mission, "map", "snapshot")
    wait_until(lambda: list(coord_session.get(key, timeout=5.0)) != [], 10, "the queryable")
    asked.clear()
    coordinator = Coordinator(m, coord_session, snapshot_timeout=10.0)
    try:
        coordinator.start()
        started_from_snapshot = coordinator.started_from_snapshot
    finally:
        coordinator.stop()
        coord_session.close()
        queryable.undeclare()
        router.close()
    assert started_from_snapshot and len(asked) == 3


@pytest.mark.slow
def test_a_flood_on_merged_faster_than_the_coordinator_applies_is_bounded():
    """Merged payloads waited for the coordinator's worker in an unbounded queue: a stranger
    putting deltas on merged faster than it applies them grew its memory without end. The
    bytes waiting are bounded (here 1 MiB); beyond, a payload is dropped and counted."""
    from coordinator.role import Coordinator
    from swarm.protocol.wire import Snapshot
    from tests.support.coordinator_scene import MapServerStandIn, corridor_map
    from tests.support.coordinator_scene import mission as coordinated_mission

    m = coordinated_mission()
    grid = m.workspace.grid()
    full = corridor_map(m)
    server = MapServerStandIn(m.mission, Snapshot(full.grid, full.lam, full.eta))
    coord_session = bus.open_session(connect=[server.endpoint])
    coordinator = Coordinator(m, coord_session, snapshot_timeout=5.0, max_queued_merged_bytes=1 << 20)
    real = coordinator.state.team.apply_payload

    def slow_apply(payload: bytes) -> str:
        time.sleep(0.02)  # a large map on a loaded machine
        return real(payload)

    coordinator.state.team.apply_payload = slow_apply
    idx = np.arange(min(grid.size, 8000), dtype=np.uint32)
    lam = np.full(len(idx), 1e-3, np.float32)
    flood = [DeltaMessage("r2", 1, seq, 0.0, grid, idx, lam, lam * 0.5).encode() for seq in range(1, 201)]
    try:
        coordinator.start()
        assert bus.wait_for_subscribers([server.merged], 10.0)
        for payload in flood:
            server.merged.put(payload)
        wait_until(
            lambda: sum(coordinator.counts[k] for k in ("merged_applied", "merged_dropped")) == len(flood),
            30,
            "the flood handled",
        )
        counts = coordinator.counts
    finally:
        coordinator.stop()
        coord_session.close()
        server.close()
    assert counts["merged_dropped"] > 0 and counts["merged_applied"] > 0
    assert 0 < counts["merged_queued_bytes_high_water"] <= 1 << 20


def test_a_flood_on_merged_between_two_frames_is_bounded_in_the_agent():
    """The agent queued every merged payload until its next frame, without bound: a stranger
    flooding merged grew a robot's memory at the flood's rate. The bytes waiting are bounded
    (here 1 MiB); beyond, a payload is dropped and counted."""
    from robot_agent.agent import Agent
    from swarm.protocol.byte_budget import ByteBudget

    mission = small_mission()
    grid = mission.workspace.grid()
    endpoint = bus.tcp_endpoint(bus.free_port())
    session = bus.open_session(listen=[endpoint])
    idx = np.arange(min(grid.size, 8000), dtype=np.uint32)
    lam = np.full(len(idx), 1e-3, np.float32)
    flood = [DeltaMessage("r2", 1, seq, 0.0, grid, idx, lam, lam * 0.5).encode() for seq in range(1, 101)]
    try:
        with client_session(endpoint) as stranger:
            agent = Agent(mission, "r1", session, coordination=False)
            agent.team.budget = ByteBudget(1 << 20)
            merged = bus.reliable_publisher(stranger, bus.key(mission.mission, "merged"))
            assert bus.wait_for_subscribers([merged], 10.0)
            for payload in flood:  # no frame meanwhile: nothing is taken from the queue
                merged.put(payload)
            counts = agent.merged_counts
            wait_until(lambda: counts["dropped"] + agent.team.queued == len(flood), 20, "the flood")
            waiting = agent.team.budget.taken
            applied = agent.apply_merged()
    finally:
        session.close()
    assert counts["dropped"] > 0 and 0 < waiting <= 1 << 20
    assert applied == len(flood) - counts["dropped"]
