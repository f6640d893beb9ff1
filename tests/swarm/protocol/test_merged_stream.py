"""The numbered merged stream: DROP, gap detection, catch-up from the snapshot, a stalled subscriber.

Real Zenoh sessions on loopback; the map server runs in this process. The stalled subscriber
is a real Zenoh session behind a TCP relay that stops reading (swarm.bench.stall_relay), so
the server's link to it fills up as a frozen subscriber's does.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh

from map_server.options import ServerOptions
from swarm.bench.stall_relay import StallRelay
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy_cache import EntropyCache
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from swarm.protocol.merged_stream import MergedNumbering, StreamPosition, decode_position, encode_position
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import (
    EPOCH,
    delta_publisher,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)

NO_SHM = "transport/shared_memory/enabled"


def open_client(endpoint: str) -> zenoh.Session:
    """A client session to ``endpoint`` whose payloads take the TCP link (no shared memory)."""
    conf, _, _ = bus.session_config([], [endpoint])
    conf.insert_json5(NO_SHM, "false")
    return zenoh.open(conf)


def test_positions_tell_gaps_new_runs_and_strangers():
    numbers = MergedNumbering(run=7)
    first, second, third = numbers.next(), numbers.next(), numbers.next()
    assert decode_position(first) == (7, 1) and decode_position(third) == (7, 3)
    assert decode_position(b"short") is None and decode_position(None) is None
    pos = StreamPosition()
    assert pos.observe(first) is None  # the first one sets the place
    assert pos.observe(third) == "gap" and pos.missed == 1
    assert pos.observe(second) is None  # older than the place: no new gap
    assert pos.observe(encode_position(7, 4)) is None
    assert pos.observe(b"a stranger's") is None and pos.unnumbered == 1
    assert pos.observe(encode_position(9, 1)) == "new_run" and pos.new_runs == 1
    assert pos.observe(encode_position(9, 5)) == "gap" and pos.missed == 4


def _payloads(grid, sensor, robots: int, per_robot: int, rays: int, seed: int = 0) -> dict[str, list[bytes]]:
    batches = robot_batches(grid, sensor, robots=robots, per_robot=per_robot, rays=rays, seed=seed)
    return {
        rid: [
            DeltaMessage(rid, EPOCH, seq, float(seq), grid, d.idx, d.dlam, d.deta).encode()
            for seq, d in enumerate(ds, start=1)
        ]
        for rid, ds in batches.items()
    }


def test_a_replica_that_misses_merged_samples_catches_up_to_the_servers_map_exactly(tmp_path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    payloads = _payloads(grid, sensor, robots=3, per_robot=12, rays=80)
    with running_server(mission, tmp_path / "store") as (server, endpoint):
        with bus.open_session(connect=[endpoint]) as session:
            client = MapClient(session, mission.mission, timeout=5.0)
            replica = TeamReplica(grid, sensor, fetch=client.snapshot, name="test")
            replica.resync_interval_s = 0.0
            last = [0]  # the number of the newest sample that reached the subscriber

            def lossy(sample: zenoh.Sample) -> None:  # the network loses every third sample
                (_run, number) = decode_position(sample.attachment.to_bytes())
                last[0] = max(last[0], number)
                if number % 3 != 2:  # never the last (total is a multiple of 3)
                    replica.on_sample(sample)

            sub = session.declare_subscriber(bus.key(mission.mission, "merged"), lossy)
            pubs = {rid: delta_publisher(session, mission.mission, rid) for rid in payloads}
            assert bus.wait_for_subscribers(pubs.values(), timeout=10.0)
            total = sum(len(p) for p in payloads.values())
            for seq in range(12):
                for rid, ps in payloads.items():
                    pubs[rid].put(ps[seq])
            # DROP may lose more on a loaded machine: those are gaps too, caught up alike
            wait_until(lambda: last[0] == total, 20.0, "the last merged sample")
            replica.drain()
            sub.undeclare()
            snap = client.snapshot()
    assert replica.stream.missed > 0 and replica.counts["resyncs"] >= 1
    assert server.merged_numbers.number == total
    np.testing.assert_array_equal(replica.map.lam, snap.lam)
    np.testing.assert_array_equal(replica.map.eta, snap.eta)
    fresh = EntropyCache.from_information(snap.lam, snap.eta, table=replica.table)
    np.testing.assert_array_equal(replica.entropy.values, fresh.values)
    assert replica.entropy.total == pytest.approx(fresh.total, rel=1e-9)
    for ps in payloads.values():  # every delta counts as applied: a repeat is a duplicate
        assert replica.apply_payload(ps[0]) == "duplicate"


def test_after_a_catch_up_the_agent_holds_the_snapshot_plus_its_own_unacked_information(tmp_path):
    """The agent's map after a catch-up: the server's snapshot, then its own deltas the snapshot
    does not hold (sent, not acked: lost on the way), then what it has not sent yet. Its own
    deltas the server acked are in the snapshot and not added twice."""
    from robot_agent.agent import Agent

    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    others = _payloads(grid, sensor, robots=3, per_robot=6, rays=60, seed=1)
    own = robot_batches(grid, sensor, robots=1, per_robot=5, rays=60, seed=2)["r1"]
    with running_server(mission, tmp_path / "store") as (server, endpoint):
        with bus.open_session(connect=[endpoint]) as session:
            agent = Agent(mission, "r1", session, coordination=False)
            assert agent.catch_up(timeout=5.0)
            assert agent.team.map is agent.explorer.map and agent.team.entropy is agent.explorer.entropy
            # two own deltas sent and acked (in every later snapshot)
            agent.sender.start()  # asks map/epoch/r1
            wait_until(lambda: agent.epoch is not None, 10.0, "r1's epoch")
            for d in own[:2]:
                agent.team.add_local(d)
                agent.outbox.add(d)
                agent._share(flush=True)
            wait_until(lambda: agent.acks.query() == 2, 10.0, "the first two own deltas acked")
            agent.outbox.acknowledge(2)
            # two more taken from the outbox, as if sent, but lost on the way: not acked
            lost = []
            for d in own[2:4]:
                agent.team.add_local(d)
                agent.outbox.add(d)
                lost.append(agent.outbox.take(agent.team.map.lam, agent.team.map.eta, flush=True)[1])
            # one gathered and not sent yet
            agent.team.add_local(own[4])
            agent.outbox.add(own[4])
            # the teammates' deltas, of which the agent misses every other merged sample
            real_receive, got = agent.team.receive, [0]

            def lossy(payload: bytes, attachment: bytes | None = None, shard: int = 0) -> bool:
                got[0] += 1
                return real_receive(payload, attachment, shard) if got[0] % 2 else False

            agent.team.receive = lossy
            pub = {rid: delta_publisher(session, mission.mission, rid) for rid in ("r2", "r3")}
            assert bus.wait_for_subscribers(pub.values(), timeout=10.0)
            mine = {rid: others[rid] for rid in ("r2", "r3")}
            for seq in range(6):
                for rid, ps in mine.items():
                    pub[rid].put(ps[seq])
            wait_until(lambda: server.merged_numbers.number == 14, 20.0, "the teammates' deltas merged")
            wait_until(lambda: got[0] >= 12, 20.0, "the teammates' merged samples")
            time.sleep(0.2)
            assert agent.team.resync_due
            agent.apply_merged()
            snap = MapClient(session, mission.mission, timeout=5.0).snapshot()
            agent.team.peer_log = None
            agent.stop()
    assert agent.merged_counts["resyncs"] == 1
    expected = CoverageMap(grid, sensor, snap.lam, snap.eta)
    for d in [*lost, agent.outbox.pending()]:
        expected.apply(d)
    np.testing.assert_array_equal(agent.explorer.map.lam, expected.lam)
    np.testing.assert_array_equal(agent.explorer.map.eta, expected.eta)
    assert len(agent.outbox.pending()) == len(own[4])
    # and that is every delta once: the server's deltas plus the agent's own not in it
    central = CoverageMap(grid, sensor)
    for payload in [p for ps in mine.values() for p in ps]:
        msg = DeltaMessage.decode(payload)
        central.apply(Delta(msg.idx, msg.dlam, msg.deta))
    for d in own:
        central.apply(d)
    np.testing.assert_allclose(agent.explorer.map.lam, central.lam, rtol=1e-5)
    fresh = EntropyCache.from_information(expected.lam, expected.eta, table=agent.explorer.table)
    np.testing.assert_array_equal(agent.explorer.entropy.values, fresh.values)


def _ack_latencies(endpoint: str, mission: str, rid: str, payloads: list[bytes], out: list[float]) -> None:
    """One robot: put each delta, then poll ``map/acks`` until it covers it; its latency (s) each."""
    with open_client(endpoint) as session:
        pub = delta_publisher(session, mission, rid)
        assert bus.wait_for_subscribers([pub], timeout=10.0)
        client = MapClient(session, mission, timeout=5.0)
        for seq, payload in enumerate(payloads, start=1):
            t0 = time.monotonic()
            pub.put(payload)
            while client.acks().get(rid, {}).get(EPOCH, 0) < seq:
                if time.monotonic() - t0 > 30.0:
                    raise AssertionError(f"{rid} seq {seq} not acked in 30 s")
                time.sleep(0.002)
            out.append(time.monotonic() - t0)


class TimedPublisher:
    """The server's merged publisher, timing each put (the merge worker's only wait on others)."""

    def __init__(self, pub) -> None:
        self.pub, self.longest = pub, 0.0

    def put(self, payload, **kw) -> None:
        t0 = time.monotonic()
        self.pub.put(payload, **kw)
        self.longest = max(self.longest, time.monotonic() - t0)

    def undeclare(self) -> None:
        self.pub.undeclare()


def test_a_stalled_merged_subscriber_costs_the_other_robots_nothing(tmp_path):
    """A subscriber of merged behind a link that stops draining, while three robots send deltas
    and wait for each ack: the merge worker's put never waits, every ack comes within a bound far
    below the 5 s a blocking put cost, and the stalled link did fill up (it got a small part of
    the stream)."""
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    per_robot = 150
    payloads = _payloads(grid, sensor, robots=3, per_robot=per_robot, rays=400, seed=3)
    options = ServerOptions(information_bound=False)
    with running_server(mission, tmp_path / "store", options) as (server, endpoint):
        timed = server._merged_pub = TimedPublisher(server._merged_pub)
        port = int(endpoint.rsplit(":", 1)[1])
        relay = StallRelay(("127.0.0.1", port))
        got = [0]
        with open_client(relay.endpoint) as slow:
            slow.declare_subscriber(
                bus.key(mission.mission, "merged"), lambda _s: got.__setitem__(0, got[0] + 1)
            )
            time.sleep(0.5)
            relay.stall()
            latencies: dict[str, list[float]] = {rid: [] for rid in ("r1", "r2", "r3")}
            threads = [
                threading.Thread(
                    target=_ack_latencies, args=(endpoint, mission.mission, rid, ps, latencies[rid])
                )
                for rid, ps in zip(latencies, payloads.values(), strict=True)
            ]
            for t in threads:
                t.start()
            for t in threads:
                t.join(timeout=300)
            published = server.merged_numbers.number
            relay.close()
    every = np.concatenate([np.asarray(v) for v in latencies.values()])
    assert len(every) == 3 * per_robot
    assert published == 3 * per_robot
    sent_mb = sum(len(p) for ps in payloads.values() for p in ps) / 1e6
    assert sent_mb > 10, sent_mb  # more than the link's buffers hold
    assert got[0] < published  # the stalled subscriber did not get the stream
    assert timed.longest < 1.0, timed.longest
    # (with congestion control BLOCK: one put waits 5 s, until Zenoh closes the link, and so do acks)
    assert float(np.percentile(every, 99)) < 1.0 and every.max() < 2.0, np.percentile(every, [50, 99, 100])


def test_the_live_view_follows_merged_to_the_servers_map(tmp_path):
    """``swarm view``'s replica: started from the snapshot, then every merged delta once."""
    pytest.importorskip("rerun")
    from swarm.view.live import TeamView, open_recording

    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    payloads = _payloads(grid, sensor, robots=3, per_robot=4, rays=60, seed=4)
    with running_server(mission, tmp_path / "store") as (server, endpoint):
        with bus.open_session(connect=[endpoint]) as session:
            pubs = {rid: delta_publisher(session, mission.mission, rid) for rid in payloads}
            assert bus.wait_for_subscribers(pubs.values(), timeout=10.0)
            for rid, ps in payloads.items():  # before the view: in its snapshot
                pubs[rid].put(ps[0])
            wait_until(lambda: server.merged_numbers.number == 3, 10.0, "the first deltas")
            view = TeamView(
                session, mission.mission, open_recording(mission.mission, tmp_path / "v.rrd"), 0.2
            )
            view.catch_up(timeout=10.0)
            view.start()
            for seq in range(1, 4):
                for rid, ps in payloads.items():
                    pubs[rid].put(ps[seq])
            wait_until(lambda: view.deltas == 9, 20.0, "the view's merged deltas")
            view.stop()
            snap = MapClient(session, mission.mission, timeout=5.0).snapshot()
    assert view.team.counts["applied"] == 9 and view.rejected == 0
    np.testing.assert_array_equal(view.cmap.lam, snap.lam)
    np.testing.assert_array_equal(view.cmap.eta, snap.eta)


def test_the_coordinator_catches_up_after_missed_samples_and_keeps_attributing(tmp_path):
    from coordinator.role import Coordinator

    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    payloads = _payloads(grid, sensor, robots=3, per_robot=7, rays=60, seed=5)
    with running_server(mission, tmp_path / "store") as (server, endpoint):
        with bus.open_session(connect=[endpoint]) as session:
            coordinator = Coordinator(mission, session, snapshot_timeout=5.0)
            team = coordinator.state.team
            team.resync_interval_s = 0.0
            real_receive, got = team.receive, [0]

            def lossy(payload: bytes, attachment: bytes | None = None, shard: int = 0) -> bool:
                got[0] += 1
                return real_receive(payload, attachment, shard) if got[0] % 4 else False

            team.receive = lossy
            coordinator.start()
            try:
                pubs = {rid: delta_publisher(session, mission.mission, rid) for rid in payloads}
                assert bus.wait_for_subscribers(pubs.values(), timeout=10.0)
                for seq in range(6):
                    for rid, ps in payloads.items():
                        pubs[rid].put(ps[seq])
                wait_until(lambda: got[0] == 18, 20.0, "the merged samples")
                wait_until(lambda: coordinator.counts["merged_resyncs"] >= 1, 20.0, "a catch-up")
                snap = MapClient(session, mission.mission, timeout=5.0).snapshot()
                wait_until(lambda: np.array_equal(team.copy()[0].lam, snap.lam), 20.0, "the server's map")
                np.testing.assert_array_equal(team.copy()[0].eta, snap.eta)
                pubs["r2"].put(payloads["r2"][6])  # (sample 19: kept) a delta after the catch-up
                wait_until(lambda: team.teammates_ground("r1").any(), 20.0, "r2's ground attributed")
            finally:
                coordinator.stop()
