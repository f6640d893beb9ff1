"""A sharded map service: each map server serves one slab of the grid under its shard's prefix
(docs/sharding.md), over real loopback Zenoh sessions. The shards' maps side by side equal the
central fusion of the same deltas exactly; a duplicate changes nothing; a delta on the mission's
(global) grid is refused; shard 0's end of the mission sums every shard's entropy and waits
while a shard does not answer; ``--shard`` out of range is a clear error."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import yaml

from map_server.server import MapServer
from map_server.shard_peers import ShardPeers
from map_server.shard_role import ShardRole
from swarm.config import ConfigError, mission_from_dict
from swarm.map.coverage_map import CoverageMap
from swarm.protocol import bus
from swarm.protocol.epochs import put_delta, wait_for_epoch
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import MISSION_YAML, robot_batches, wait_until
from tests.support.paths import ROOT
from tests.support.shard_servers import shard_servers, sharded_mission


@pytest.fixture
def two_shards(tmp_path):
    """Two map servers of one two-shard mission on one loopback router, and a client session."""
    with shard_servers(tmp_path, 2) as world:
        yield world


def test_two_shards_serve_the_two_slabs_under_their_prefixes(two_shards) -> None:
    mission, servers, _client = two_shards
    layout = mission.shard_layout()
    assert [s.name for s in servers] == ["srvtest/shard/0", "srvtest/shard/1"]
    assert [s.team.grid for s in servers] == [layout.grid_of(0), layout.grid_of(1)]
    assert sum(s.team.grid.size for s in servers) == mission.workspace.grid().size
    # unsharded: the mission's own grid and name, as always
    one = yaml.safe_load(MISSION_YAML)
    role = ShardRole.of(mission_from_dict(one))
    assert role.prefix == "srvtest" and role.grid == mission.workspace.grid() and not role.sharded


def test_split_deltas_merge_to_central_fusion_exactly(two_shards) -> None:
    mission, servers, session = two_shards
    layout, grid, sensor = mission.shard_layout(), mission.workspace.grid(), mission.sensor.model()
    deltas = robot_batches(grid, sensor, robots=1, per_robot=4)["r1"]
    central = CoverageMap(grid, sensor)
    grants = {k: wait_for_epoch(session, servers[k].name, "r1", 30) for k in range(2)}
    pubs = {k: bus.reliable_publisher(session, bus.key(servers[k].name, "delta", "r1")) for k in range(2)}
    assert bus.wait_for_subscribers(list(pubs.values()), timeout=10.0)
    seqs = {0: 0, 1: 0}
    sent = []
    for d in deltas:
        central.apply(d)
        for k, part in layout.split(d).items():
            seqs[k] += 1
            msg = DeltaMessage(
                "r1", grants[k].epoch, seqs[k], 1.0, layout.grid_of(k), part.idx, part.dlam, part.deta
            )
            payload = msg.encode()
            put_delta(pubs[k], grants[k], payload)
            sent.append((k, payload))
    assert all(seqs.values())  # both shards got a part
    wait_until(
        lambda: all(len(servers[k].team.ledger) == seqs[k] for k in range(2)), 20, "both shards merged"
    )
    clients = [MapClient(session, s.name, timeout=5.0) for s in servers]
    snaps = [c.snapshot() for c in clients]
    lam = np.concatenate([s.lam for s in snaps])
    eta = np.concatenate([s.eta for s in snaps])
    assert lam.dtype == central.lam.dtype
    np.testing.assert_array_equal(lam, central.lam)  # exactly: each voxel sums the same terms
    np.testing.assert_array_equal(eta, central.eta)
    # a duplicate changes nothing
    k, payload = sent[0]
    put_delta(pubs[k], grants[k], payload)
    wait_until(lambda: servers[k].team.duplicates >= 1, 10, "the duplicate counted")
    again = clients[k].snapshot()
    np.testing.assert_array_equal(again.lam, snaps[k].lam)
    np.testing.assert_array_equal(again.eta, snaps[k].eta)
    # a delta on the mission's global grid is not a shard's
    d = deltas[0]
    wrong = DeltaMessage("r1", grants[0].epoch, seqs[0] + 1, 2.0, grid, d.idx, d.dlam, d.deta).encode()
    put_delta(pubs[0], grants[0], wrong)
    wait_until(lambda: servers[0].team.rejected.get("wrong_grid", 0) == 1, 10, "the global delta refused")
    assert len(servers[0].team.ledger) == seqs[0]
    for pub in pubs.values():
        pub.undeclare()


def test_shard_zero_sums_every_shards_entropy(two_shards) -> None:
    mission, servers, session = two_shards
    role = ShardRole.of(mission, 0)
    peers = ShardPeers(session, role, mission.sensor.model(), timeout=3.0)
    assert peers.poll() == []
    own = servers[0].stats()
    team = peers.team_stats(own)
    total = servers[0].team.entropy.total + servers[1].team.entropy.total
    assert team["shards_unknown"] == [] and team["shards"] == 2
    assert team["entropy_bits"] == pytest.approx(total, abs=0.01)
    assert team["entropy_bits"] > own["entropy_bits"]


def test_a_shard_that_does_not_answer_blocks_the_threshold_end(tmp_path) -> None:
    from map_server.mission_end import MissionEnd

    mission = sharded_mission(2)
    endpoint = bus.tcp_endpoint(bus.free_port())
    session = bus.open_session(listen=[endpoint])
    try:
        server = MapServer(mission, tmp_path / "shard-0", shard=0)  # shard 1 never starts
        server.start(session)
        try:
            peers = ShardPeers(session, ShardRole.of(mission, 0), mission.sensor.model(), timeout=0.3)
            assert peers.poll() == [1]
            team = peers.team_stats(server.stats())
            assert team["shards_unknown"] == [1]
            # its figure: its slab's prior entropy, so the sum stays finite
            assert team["entropy_bits"] == pytest.approx(server.team.initial_entropy_bits * 2, rel=0.05)
            end = MissionEnd(session, "srvtest", frozenset({"r1"}), threshold_bits=1e12)
            try:
                assert end.check(team) is None  # far below H_th, but shard 1 is unknown
                assert end.check(team | {"shards_unknown": []}) is not None
            finally:
                end.close()
        finally:
            server.stop()
    finally:
        session.close()


def test_shard_out_of_range_or_missing_names_the_config_field(tmp_path) -> None:
    mission = sharded_mission(2)
    with pytest.raises(ConfigError, match=r"map_service\.shards is 2: no shard 2 \(shards are 0\.\.1\)"):
        ShardRole.of(mission, 2)
    with pytest.raises(ConfigError, match=r"map_service\.shards is 2: give --shard K"):
        ShardRole.of(mission, None)
    with pytest.raises(ConfigError, match="no shard 2"):
        MapServer(mission, tmp_path / "s", shard=2)
    config = tmp_path / "m.yaml"
    data = yaml.safe_load(MISSION_YAML) | {"map_service": {"shards": 2}}
    config.write_text(yaml.safe_dump(data))
    cmd = [
        sys.executable,
        "-m",
        "swarm.cli",
        "server",
        "--config",
        str(config),
        "--store",
        str(tmp_path / "st"),
    ]
    done = subprocess.run([*cmd, "--shard", "5"], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode != 0
    assert "map_service.shards is 2: no shard 5" in done.stderr
    assert not (tmp_path / "st").exists()  # refused before a store is made
