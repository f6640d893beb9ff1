"""TeamReplica without a bus: counts, the owner's own deltas, gaps, the byte budget, catch-ups.

``fetch`` is given a function returning a snapshot built here (the replica's input, not a stand-in
for Zenoh: the bus tests are in test_merged_stream.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from swarm.map.coverage_map import CoverageMap
from swarm.protocol.byte_budget import ByteBudget
from swarm.protocol.merged_stream import encode_position
from swarm.protocol.team_replica import MAX_RESYNC_INTERVAL_S, TeamReplica
from swarm.protocol.wire import DeltaMessage, Snapshot, WireError
from tests.support.map_server_mission import EPOCH, robot_batches, small_mission


@pytest.fixture()
def world():
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, robots=2, per_robot=4, rays=40)
    payloads = [
        DeltaMessage(rid, EPOCH, seq, float(seq), grid, d.idx, d.dlam, d.deta).encode()
        for rid, ds in batches.items()
        for seq, d in enumerate(ds, start=1)
    ]
    return grid, sensor, batches, payloads


def test_counts_own_duplicates_and_refusals(world):
    grid, sensor, batches, payloads = world
    replica = TeamReplica(grid, sensor, own=lambda: ("r2", EPOCH))
    for payload in payloads + payloads[:2]:
        replica.receive(payload)
    assert replica.drain() == 4
    other = DeltaMessage(
        "r1",
        EPOCH,
        9,
        0.0,
        grid,
        np.array([0], np.uint32),
        np.array([1e31], np.float32),
        np.zeros(1, np.float32),
    )
    with pytest.raises(WireError):
        replica.apply_payload(other.encode())
    with pytest.raises(WireError):
        replica.apply_payload(b"\xc1")
    assert replica.counts == {
        "applied": 4,
        "own": 4,
        "duplicate": 2,
        "rejected": 2,
        "rejected_out_of_range": 1,
        "rejected_malformed": 1,
    }
    expected = CoverageMap(grid, sensor)
    for d in batches["r1"]:
        expected.apply(d)
    np.testing.assert_array_equal(replica.map.lam, expected.lam)
    np.testing.assert_array_equal(replica.map.eta, expected.eta)


def test_a_batched_drain_ends_with_the_entropy_of_one_update_per_delta(world):
    grid, sensor, batches, payloads = world
    bad = DeltaMessage(
        "r1",
        EPOCH,
        99,
        0.0,
        grid,
        np.array([0], np.uint32),
        np.array([1e31], np.float32),
        np.zeros(1, np.float32),
    ).encode()
    queued = payloads[:3] + [bad] + payloads[3:] + payloads[:1]  # a refusal and a duplicate inside
    per_delta, batched = TeamReplica(grid, sensor), TeamReplica(grid, sensor, entropy_per_delta=False)
    for replica in (per_delta, batched):
        for payload in queued:
            replica.receive(payload)
        assert replica.drain() == len(payloads)
    np.testing.assert_array_equal(batched.map.lam, per_delta.map.lam)
    np.testing.assert_array_equal(batched.entropy.values, per_delta.entropy.values)
    assert batched.counts == per_delta.counts
    exact = float(np.sum(batched.entropy.values, dtype=np.float64))
    assert batched.entropy.total == pytest.approx(exact, rel=1e-12)
    assert per_delta.entropy.total == pytest.approx(exact, rel=1e-12)
    assert batched._stale is None  # a later apply outside a drain updates the entropy at once


def test_a_gap_or_a_drop_makes_one_catch_up_then_queued_deltas_apply_once(world):
    grid, sensor, batches, payloads = world
    server = CoverageMap(grid, sensor)
    for d in batches["r1"][:2]:
        server.apply(d)
    snap = Snapshot(grid, server.lam.copy(), server.eta.copy(), {"r1": {EPOCH: 2}})
    fetched = []
    replica = TeamReplica(grid, sensor, fetch=lambda: fetched.append(1) or snap)
    replica.receive(payloads[0], encode_position(5, 1))
    replica.receive(payloads[2], encode_position(5, 3))  # number 2 was lost
    assert replica.resync_due
    replica.receive(payloads[3], encode_position(5, 4))
    replica.drain()
    assert fetched == [1] and replica.counts["resyncs"] == 1 and not replica.resync_due
    # r1's seq 1 is in the snapshot: a duplicate; seq 3 and 4 are applied on top
    assert replica.counts["applied"] == 2 and replica.counts["duplicate"] == 1
    expected = CoverageMap(grid, sensor, snap.lam, snap.eta)
    for d in batches["r1"][2:]:
        expected.apply(d)
    np.testing.assert_array_equal(replica.map.lam, expected.lam)
    # a payload over the budget is dropped, counted, and makes a catch-up due (rate-limited)
    replica.budget = ByteBudget(1)
    assert not replica.receive(payloads[4]) and replica.counts["dropped"] == 1 and replica.resync_due
    replica.drain()
    assert fetched == [1]  # under resync_interval_s since the last one: not yet
    assert replica.resync(force=True) and fetched == [1, 1]


def test_a_failed_catch_up_keeps_the_map_and_waits_longer_each_time(world):
    grid, sensor, _batches, payloads = world

    def no_server() -> Snapshot:
        raise ConnectionError("no map server answered")

    replica = TeamReplica(grid, sensor, fetch=no_server)
    replica.receive(payloads[1], encode_position(1, 1))
    replica.receive(payloads[2], encode_position(1, 3))
    replica.drain()
    assert replica.counts["resync_failed"] == 1 and replica.resync_due
    assert replica.counts["applied"] == 2  # the queued deltas are applied all the same
    interval = replica.resync_interval_s
    replica.feeds[0].last_resync -= interval  # as if the interval had passed
    assert not replica.resync() and replica.counts["resync_failed"] == 1  # the wait doubled: not tried
    replica.feeds[0].last_resync -= interval
    assert not replica.resync() and replica.counts["resync_failed"] == 2  # tried, failed again
    assert replica.feeds[0].resync_wait == min(4 * interval, MAX_RESYNC_INTERVAL_S)
