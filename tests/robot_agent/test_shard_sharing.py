"""An agent sharing with a map service of two shards (robot_agent.shard_sharing): each fused
delta goes to its owners' outboxes, each shard gets the part of every take that an unsharded
outbox would have sent, in its own local indices, under its own epoch, and its acks drain its
outbox (real Zenoh on loopback, two real map servers, one per slab)."""

from __future__ import annotations

import math
from contextlib import ExitStack, contextmanager

import numpy as np
import pytest
import yaml

from map_server.server import MapServer
from robot_agent.agent import Agent
from robot_agent.sharing import DeltaOutbox
from swarm.config import Mission, mission_from_dict
from swarm.config.models import MapServiceConfig
from swarm.map.coverage_map import CoverageMap
from swarm.map.shard_layout import ShardLayout
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import MISSION_YAML, robot_batches, wait_until


def two_shard_mission() -> Mission:
    """The map-server tests' office (30 x 20 x 10 voxels) with ``map_service: {shards: 2}``."""
    data = yaml.safe_load(MISSION_YAML)
    data["map_service"] = {"shards": 2}
    return mission_from_dict(data)


def slab_mission(mission: Mission, layout: ShardLayout, shard: int) -> Mission:
    """What shard ``shard``'s server runs on: the same mission, its workspace the slab (one
    unsharded service over it). Built here until map_server grows its own ``shard=`` option; a
    copy, not a reload, since the robots' starts may lie outside the slab."""
    grid = layout.grid_of(shard)
    workspace = mission.workspace.model_copy(update={"lo": tuple(grid.lo), "hi": tuple(grid.hi)})
    slab = mission.model_copy(update={"workspace": workspace, "map_service": MapServiceConfig()})
    assert slab.workspace.grid() == grid, "the slab mission's grid must be the shard's grid"
    return slab


@contextmanager
def shard_servers(mission: Mission, store):
    """Both shards' map servers in this process, under ``<mission>/shard/<k>`` on one loopback
    session; yields the endpoint."""
    layout = mission.shard_layout()
    endpoint = bus.tcp_endpoint(bus.free_port())
    session = bus.open_session(listen=[endpoint])
    with ExitStack() as stack:
        stack.callback(session.close)
        for k in range(layout.count):
            prefix = bus.shard_mission(mission.mission, k, layout.count)
            server = MapServer(slab_mission(mission, layout, k), store / f"shard-{k}", mission_name=prefix)
            server.start(session)
            stack.callback(server.stop)
        yield endpoint


def test_each_shard_gets_its_part_of_what_an_unsharded_outbox_sends_and_acks_drain_it(tmp_path):
    mission = two_shard_mission()
    layout = mission.shard_layout()
    assert layout.count == 2
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    deltas = robot_batches(grid, sensor, robots=1, per_robot=5, seed=3)["r1"]
    with shard_servers(mission, tmp_path) as endpoint, ExitStack() as stack:
        agent_side = bus.open_session(connect=[endpoint])
        stack.callback(agent_side.close)
        listener = bus.open_session(connect=[endpoint])
        stack.callback(listener.close)
        received: dict[int, list[DeltaMessage]] = {0: [], 1: []}
        for k in range(2):
            key = bus.key(bus.shard_mission(mission.mission, k, 2), "delta", "r1")
            sub = listener.declare_subscriber(
                key, lambda s, k=k: received[k].append(DeltaMessage.decode(s.payload.to_bytes()))
            )
            stack.callback(sub.undeclare)

        agent = Agent(mission, "r1", agent_side, coordination=False)
        sharing = agent.sharing
        assert [link.prefix for link in sharing.links] == ["srvtest/shard/0", "srvtest/shard/1"]
        held = mission.sharing.max_held_bits
        oracle = DeltaOutbox(
            grid.size,
            mission.sharing.share_min_bits,
            agent.explorer.table,
            max_held_bits=math.inf if held is None else held,
        )
        cmap = CoverageMap(grid, sensor)
        sharing.start()
        wait_until(lambda: all(link.epoch is not None for link in sharing.links), 15.0, "both epochs")

        # take by take: which seq each shard's part of it went out under, and the oracle's take
        takes = []
        for i, delta in enumerate(deltas):
            cmap.apply(delta)  # as fusing the frame did locally, before the outbox judges
            sharing.add(delta)
            oracle.add(delta)
            flush = i == len(deltas) - 1
            before = [link.outbox.seq for link in sharing.links]
            sharing.share(cmap.lam, cmap.eta, flush=flush)
            after = [link.outbox.seq for link in sharing.links]
            expected = oracle.take(cmap.lam, cmap.eta, flush=flush)
            takes.append(([a if a > b else None for a, b in zip(after, before, strict=True)], expected))
        sent = [link.outbox.seq for link in sharing.links]
        assert all(n >= 2 for n in sent), f"both shards should get several deltas, got {sent}"

        wait_until(lambda: all(len(received[k]) == sent[k] for k in range(2)), 10.0, "every delta on the bus")
        by_seq = {k: {m.seq: m for m in received[k]} for k in range(2)}
        assert all(set(by_seq[k]) == set(range(1, sent[k] + 1)) for k in range(2))
        for seqs, expected in takes:
            parts = []
            for k, seq in enumerate(seqs):
                if seq is None:
                    continue
                msg = by_seq[k][seq]
                assert msg.robot == "r1" and msg.epoch == sharing.links[k].epoch
                assert msg.grid == layout.grid_of(k)
                parts.append((layout.to_global(k, msg.idx), msg.dlam, msg.deta))
            if expected is None:
                assert parts == []
                continue
            _seq, want = expected
            np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), want.idx.astype(np.int64))
            np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), want.dlam)
            np.testing.assert_array_equal(np.concatenate([p[2] for p in parts]), want.deta)
        assert oracle.stats.voxels_sent == sharing.stats.voxels_sent
        assert oracle.stats.deltas_sent <= sharing.stats.deltas_sent

        # the acks of each shard drain its outbox; each server's map is its slab of the whole
        agent.shutdown(ack_wait_s=15.0)
        assert sharing.acked == sent and sharing.unacked == 0 and agent.acked == sum(sent)
        for k, link in enumerate(sharing.links):
            assert not link.outbox.unacked and len(link.outbox.pending()) == 0
            snap = MapClient(listener, link.prefix, timeout=5.0).snapshot()
            start, stop = layout.span(k)
            np.testing.assert_allclose(snap.lam, cmap.lam[start:stop], rtol=2e-6, atol=0)
            np.testing.assert_allclose(snap.eta, cmap.eta[start:stop], rtol=2e-6, atol=1e-6)


def test_an_unsharded_agent_keeps_one_link_under_the_missions_keys_and_a_sharded_one_names_its_links():
    one = mission_from_dict(yaml.safe_load(MISSION_YAML))
    session = bus.open_session(listen=[bus.tcp_endpoint(bus.free_port())])
    try:
        agent = Agent(one, "r1", session, coordination=False)
        (link,) = agent.sharing.links
        assert link.prefix == "srvtest" and link.grid == one.workspace.grid()
        assert agent.outbox is link.outbox and agent.sender is link.sender and agent.acks is link.acks
        assert agent.sharing.stats is link.outbox.stats
        delta = robot_batches(link.grid, one.sensor.model(), robots=1, per_robot=1)["r1"][0]
        agent.sharing.add(delta)
        assert np.array_equal(agent.outbox.pending().idx, delta.idx)
        agent.shutdown(ack_wait_s=0.0)

        sharded = Agent(two_shard_mission(), "r1", session, coordination=False)
        assert sharded.epoch is None and sharded.acked == 0
        with pytest.raises(ValueError, match="2 shards"):
            sharded.outbox  # noqa: B018 (the property is what is tested)
        sharded.sharing.add(delta)
        parts = sharded.sharing.layout.split(delta)
        assert set(parts) == {0, 1}
        for k, part in parts.items():
            assert np.array_equal(sharded.sharing.links[k].outbox.pending().idx, part.idx)
        assert sum(len(p) for p in parts.values()) == len(delta)
        sharded.shutdown(ack_wait_s=0.0)
    finally:
        session.close()
