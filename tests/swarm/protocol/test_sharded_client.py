"""Clients of a sharded map service over real loopback Zenoh, against two real map servers:
the fanned-in stats, snapshot and region equal the central fusion of the same deltas, the
layout is discovered from the shards' own stats, the mission is found by name, and a team
replica following both shards' merged streams ends with the central map.
"""

from __future__ import annotations

import numpy as np
import pytest

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy_cache import EntropyCache
from swarm.protocol import bus
from swarm.protocol.epochs import put_delta, wait_for_epoch
from swarm.protocol.map_client import MapClient, missions_answering
from swarm.protocol.sharded_client import ShardedMapClient, discover_layout
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import assert_maps_equal, robot_batches, wait_until
from tests.support.shard_servers import shard_servers


def test_sharded_clients_see_the_central_map(tmp_path) -> None:
    with shard_servers(tmp_path, 2) as (mission, servers, session):
        layout, grid, sensor = mission.shard_layout(), mission.workspace.grid(), mission.sensor.model()
        replica = TeamReplica(grid, sensor, layout=layout, name="follower")
        subs = replica.follow(session, mission.mission)
        central = CoverageMap(grid, sensor)
        batches = robot_batches(grid, sensor, robots=2, per_robot=3)
        sent = [0, 0]
        for rid, deltas in batches.items():
            grants = [wait_for_epoch(session, s.name, rid, 30) for s in servers]
            pubs = [bus.reliable_publisher(session, bus.key(s.name, "delta", rid)) for s in servers]
            assert bus.wait_for_subscribers(pubs, timeout=10.0)
            seqs = [0, 0]
            for d in deltas:
                central.apply(d)
                for k, part in layout.split(d).items():
                    seqs[k] += 1
                    slab = layout.grid_of(k)
                    msg = DeltaMessage(
                        rid, grants[k].epoch, seqs[k], 1.0, slab, part.idx, part.dlam, part.deta
                    )
                    put_delta(pubs[k], grants[k], msg.encode())
            sent = [a + b for a, b in zip(sent, seqs, strict=True)]
            for pub in pubs:
                pub.undeclare()
        assert all(sent)
        wait_until(
            lambda: all(len(s.team.ledger) == n for s, n in zip(servers, sent, strict=True)),
            20,
            "both shards merged",
        )

        client = ShardedMapClient(session, mission.mission, layout, timeout=5.0)
        stats = client.stats()
        assert stats["voxels"] == grid.size and stats["shape"] == list(grid.shape)
        assert stats["deltas_applied"] == sum(sent)
        central_bits = float(EntropyCache.from_information(central.lam, central.eta).total)
        assert stats["entropy_bits"] == pytest.approx(central_bits, rel=1e-6)
        assert stats["robots"]["r1"]["deltas"] == sum(len(layout.split(d)) for d in batches["r1"])
        snap = client.team_snapshot()
        assert_maps_equal(snap.lam, snap.eta, central)  # the servers sum in arrival order
        # a box across the cut: both shards' voxels, in the team grid's indices
        cut_x = layout.grid_of(1).lo[0]
        lo, hi = np.array([cut_x - 0.25, 0.1, 0.1]), np.array([cut_x + 0.25, 0.4, 0.3])
        region = client.region(lo, hi)
        centres = grid.centre(grid.unflat(np.arange(grid.size)))  # every voxel whose cell meets the box
        meets = np.all((centres + grid.voxel / 2 > lo) & (centres - grid.voxel / 2 < hi), axis=1)
        np.testing.assert_array_equal(region.idx, np.flatnonzero(meets))
        assert set(layout.owner(region.idx).tolist()) == {0, 1}
        idx = region.idx.astype(np.int64)
        np.testing.assert_allclose(region.mu, central.eta[idx] / central.lam[idx], rtol=1e-6)
        # found from the servers alone: the layout and the mission's name
        assert discover_layout(session, mission.mission, 5.0) == layout
        assert mission.mission in missions_answering(session, 5.0)
        assert discover_layout(session, "no-such-mission", 0.3) is None
        # no server under the mission's own prefix: an unsharded client is not answered
        with pytest.raises(ConnectionError):
            MapClient(session, mission.mission, timeout=0.5).stats()

        # the follower applied both shards' merged streams: the central map
        wait_until(
            lambda: replica.drain() >= 0 and replica.counts["applied"] >= sum(sent), 20, "the follower"
        )
        assert replica.counts["applied"] == sum(sent)
        assert_maps_equal(replica.map.lam, replica.map.eta, central)
        for sub in subs:
            sub.undeclare()
