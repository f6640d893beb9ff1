"""What a stranger on the bus can make the replicas spend: the agent's, the coordinator's and the
mission monitor's, under floods of bad frames, malformed assign requests, merged deltas of invented
robots and merged faster than they apply, and a coordinator asking for a snapshot of a busy server.
Real Zenoh sessions on loopback, explicit endpoints, multicast scouting off."""

from __future__ import annotations

import time

import numpy as np
import pytest
import zenoh

from map_server.options import ServerOptions
from map_server.snapshot_stream import MapStreams, StreamCache, held_snapshot
from swarm.protocol import bus
from swarm.protocol.map_chunks import CHUNK_BYTES
from swarm.protocol.wire import DeltaMessage
from tests.support.log_lines import LogLines, allowed_lines
from tests.support.malformed_deltas import good
from tests.support.map_server_mission import (
    UnsignedPublisher,
    client_session,
    small_mission,
    wait_until,
)

ROBOTS = ("r1", "r2", "r3", "r4")  # r4: the attacker, a robot the server takes
OPTIONS = ServerOptions(robots=ROBOTS)


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
        with LogLines("coordinator") as logged:
            coordinator.start()
            key = assign_key(m.mission, "r1")
            # the queryable's declaration reaches the stranger's session a little after start
            wait_until(
                lambda: list(stranger.get(key, payload=b"\xc1", timeout=5.0)) != [], 10, "the queryable"
            )
            handles = [stranger.get(key, payload=b"\xc1%d" % i, timeout=10.0) for i in range(300)]
            errors = sum(r.err is not None for h in handles for r in h)
        allowed = allowed_lines(since)
    finally:
        coordinator.stop()
        coord_session.close()
        stranger.close()
        server.close()
    assert errors == 300
    rejected_lines = [line for line in logged.lines if line.startswith("rejected assign request")]
    assert 1 <= len(rejected_lines) <= allowed, rejected_lines[:5]


def test_an_agent_logs_floods_of_bad_frames_and_merged_deltas_a_line_per_reason():
    """An agent logged each undecodable frame and each bad message on ``merged`` (which anyone
    on an open bus can publish): 300 of each, 600 lines."""
    from robot_agent.agent import Agent

    mission = small_mission()
    endpoint = bus.tcp_endpoint(bus.free_port())
    session = bus.open_session(listen=[endpoint])
    try:
        since = time.monotonic()
        with LogLines("swarm.agent") as logged, client_session(endpoint) as stranger:
            agent = Agent(mission, "r1", session, coordination=False)
            merged = bus.reliable_publisher(stranger, bus.key(mission.mission, "merged"))
            assert bus.wait_for_subscribers([merged], 10.0)
            for i in range(300):
                merged.put(b"\xc1 not a delta %d" % i)
                assert agent.handle(b"\xc1 not a frame %d" % i) is None
            wait_until(
                lambda: agent.apply_merged() >= 0 and agent.merged_counts["rejected"] == 300, 20, "the flood"
            )
        allowed = allowed_lines(since)
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
        with LogLines("swarm.monitor") as logged, client_session(endpoint) as stranger:
            # no map server: the stranger's deltas go without a MAC (the monitor does not check one)
            pubs = {f"x{i}": UnsignedPublisher(stranger, mission.mission, f"x{i}") for i in range(invented)}
            assert bus.wait_for_subscribers([p.pub for p in pubs.values()], timeout=10.0)
            for i, pub in enumerate(pubs.values()):
                pub.put(good(grid, f"x{i}", idx=(i,)))
            for i in range(malformed):
                pubs["x0"].put(b"\xc1 not a delta %d" % i)
            wait_until(lambda: monitor.applied + monitor.rejected == invented + malformed, 20, "the flood")
        allowed = allowed_lines(since)
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

    def slow_apply(payload: bytes, shard: int = 0) -> str:
        time.sleep(0.02)  # a large map on a loaded machine
        return real(payload, shard)

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
