"""A TeamReplica over a sharded map service, without a bus: per-shard ledgers, slab offsets,
refusals, and a catch-up of one shard from its own snapshot.

The oracle is central fusion: the same deltas applied whole to one unsharded CoverageMap.
``fetch`` is a function returning a shard snapshot built here (the replica's input; the bus
tests are in tests/map_server/test_shards.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy_cache import EntropyCache
from swarm.map.shard_layout import ShardLayout
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import DeltaMessage, Snapshot, WireError
from tests.support.map_server_mission import EPOCH, robot_batches, small_mission


@pytest.fixture()
def world():
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    layout = ShardLayout.even(grid, 3)
    batches = robot_batches(grid, sensor, robots=3, per_robot=4, rays=60)
    # what each shard's merged stream carries: every delta's part, numbered per (robot, shard)
    sent: list[tuple[int, bytes]] = []
    for rid, deltas in batches.items():
        seqs = [0] * layout.count
        for d in deltas:
            for k, part in layout.split(d).items():
                seqs[k] += 1
                msg = DeltaMessage(
                    rid, EPOCH, seqs[k], 0.0, layout.grid_of(k), part.idx, part.dlam, part.deta
                )
                sent.append((k, msg.encode()))
    central = CoverageMap(grid, sensor)
    for deltas in batches.values():
        for d in deltas:
            central.apply(d)
    return grid, sensor, layout, sent, central


def test_shards_deltas_make_the_central_map_once_each(world):
    grid, sensor, layout, sent, central = world
    replica = TeamReplica(grid, sensor, layout=layout)
    assert [f.offset for f in replica.feeds] == [layout.offset(k) for k in range(3)]
    rng = np.random.default_rng(3)
    order = [sent[i] for i in rng.permutation(len(sent))]
    for k, payload in order + order[: len(order) // 2]:  # half of them twice
        replica.receive(payload, None, k)
    assert replica.drain() == len(sent)
    assert replica.counts["duplicate"] == len(order) // 2
    # the same (robot, epoch, seq) on different shards are different deltas: each applied once
    seq_ones = {(k, p) for k, p in sent if DeltaMessage.decode(p).seq == 1}
    assert len({k for k, _ in seq_ones}) == 3
    np.testing.assert_allclose(replica.map.lam, central.lam, rtol=1e-6)
    np.testing.assert_allclose(replica.map.eta, central.eta, rtol=1e-6, atol=1e-6)
    fresh = EntropyCache.from_information(replica.map.lam, replica.map.eta)
    assert replica.entropy_bits == pytest.approx(float(fresh.total), rel=1e-9)


def test_a_shards_delta_on_another_grid_or_outside_its_slab_is_refused(world):
    grid, sensor, layout, sent, _central = world
    replica = TeamReplica(grid, sensor, layout=layout)
    before = replica.map.lam.copy()
    k0 = next(p for k, p in sent if k == 0)
    with pytest.raises(WireError) as refused:
        replica.apply_payload(k0, shard=1)  # shard 0's grid on shard 1's stream
    assert refused.value.kind == "other_grid"
    beyond = layout.grid_of(1).size  # the first voxel past shard 1's slab
    msg = DeltaMessage(
        "r1",
        EPOCH,
        9,
        0.0,
        layout.grid_of(1),
        np.array([beyond], np.uint32),
        np.ones(1, np.float32),
        np.zeros(1, np.float32),
    )
    with pytest.raises(WireError) as refused:
        replica.apply_payload(msg.encode(), shard=1)
    assert refused.value.kind == "out_of_grid"  # the decoder checks the indices against its grid
    with pytest.raises(WireError) as refused:
        replica.apply_message(msg, shard=1)  # and the replica again: it would land in shard 2
    assert refused.value.kind == "out_of_range"
    np.testing.assert_array_equal(replica.map.lam, before)
    with pytest.raises(ValueError):
        TeamReplica(grid, sensor, layout=layout, fetch=[None, None])  # one per shard, or none


def test_one_shard_catches_up_from_its_own_snapshot(world):
    grid, sensor, layout, sent, central = world
    servers = [CoverageMap(layout.grid_of(k), sensor) for k in range(layout.count)]
    for k, payload in sent:  # what each shard's server holds
        msg = DeltaMessage.decode(payload)
        servers[k].apply_received(Delta(msg.idx, msg.dlam, msg.deta))
    fetched = []

    def fetch_of(k):
        def fetch():
            fetched.append(k)
            return Snapshot(layout.grid_of(k), servers[k].lam.copy(), servers[k].eta.copy())

        return fetch

    replica = TeamReplica(grid, sensor, layout=layout, fetch=[fetch_of(k) for k in range(layout.count)])
    replica.resync_interval_s = 0.0
    for k, payload in sent:
        if k != 1:
            replica.receive(payload, None, k)
    replica.feeds[1].resync_due.set()  # shard 1's samples were all missed
    replica.drain()
    assert fetched == [1], "only the shard that missed samples is asked for its snapshot"
    np.testing.assert_allclose(replica.map.lam, central.lam, rtol=1e-6)
    np.testing.assert_allclose(replica.map.eta, central.eta, rtol=1e-6, atol=1e-6)
    fresh = EntropyCache.from_information(replica.map.lam, replica.map.eta)
    assert replica.entropy_bits == pytest.approx(float(fresh.total), rel=1e-9)
