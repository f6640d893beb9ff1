"""Map server merging: each (robot, epoch, seq) applied exactly once in any order, acks the
contiguous prefix, and the merged map equals one central fusion of every robot's batches.

The mission and server helpers it uses are in tests/support/map_server_mission.py.
"""

from __future__ import annotations

import random
import time
from pathlib import Path

import numpy as np
import pytest

from map_server.ledger import Ledger
from map_server.team_map import MergedMap
from swarm.map.entropy_table import default_table
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import (
    EPOCH,
    assert_maps_equal,
    central_fusion,
    client_session,
    encode_all,
    publishers,
    resend_until_acked,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)

# -- the ledger and the team map, without Zenoh -----------------------------------------------


def test_ledger_applies_each_id_once_and_acks_the_contiguous_prefix():
    ledger = Ledger()
    order = [3, 1, 5, 1, 2, 3, 7, 4]
    added = [ledger.add(("r1", 9, s)) for s in order]
    assert added == [True, True, True, False, True, False, True, True]
    assert ledger.acks() == {"r1": {9: 5}}
    assert ("r1", 9, 7) in ledger and ("r1", 9, 6) not in ledger and ("r1", 8, 1) not in ledger
    assert len(ledger) == 6
    assert ledger.robots()["r1"] == {"deltas": 6, "epoch": 9, "last_seq": 7, "acked_seq": 5}
    ledger.add(("r1", 10, 2))  # a new epoch (agent restart) starts its own prefix
    assert ledger.acks() == {"r1": {9: 5, 10: 0}}
    again = Ledger.from_json(ledger.to_json())
    assert again.acks() == ledger.acks() and ("r1", 9, 7) in again and ("r1", 10, 2) in again
    assert again.add(("r1", 9, 6)) and again.acks()["r1"][9] == 7


def test_team_map_in_any_order_with_duplicates_equals_central_fusion():
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor)
    msgs = [DeltaMessage.decode(p) for _, _, p in encode_all(grid, batches)]
    copies = msgs + random.Random(1).sample(msgs, 7)
    random.Random(2).shuffle(copies)
    team = MergedMap(grid, sensor)
    applied = 0
    for m in copies:
        if team.admit(m):
            team.apply(m)
            applied += 1
    assert applied == len(msgs) and team.duplicates == 7
    central = central_fusion(grid, sensor, batches)
    assert_maps_equal(team.cmap.lam, team.cmap.eta, central)
    exact = float(np.sum(default_table()(central.mean(), central.sigma()), dtype=np.float64))
    assert team.entropy.total == pytest.approx(exact, rel=1e-5)
    assert team.known == int(np.count_nonzero(central.known_mask()))
    assert team.acks() == {rid: {EPOCH: 6} for rid in batches}


def test_region_box_and_point_semantics():
    mission = small_mission()
    team = MergedMap(mission.workspace.grid(), mission.sensor.model())
    assert len(team.region([0, 0, 0], [0.2, 0.2, 0.2])) == 8  # faces do not count
    one = team.region([0.55, 0.25, 0.5], [0.55, 0.25, 0.5])  # a point: the voxel holding it
    assert one.idx.tolist() == [int(team.grid.flat(np.array([5, 2, 5])))]
    np.testing.assert_allclose(one.centres(), [[0.55, 0.25, 0.55]])
    assert len(team.region([-5, -5, -5], [-4, -4, -4])) == 0
    assert len(team.region([-1, -1, -1], [0.05, 0.05, 0.05])) == 1
    with pytest.raises(ValueError, match="hi"):
        team.region([1, 1, 1], [0, 2, 2])


# -- over Zenoh ----------------------------------------------------------------------------------


def test_server_merges_duplicated_reordered_deltas_like_central_fusion(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, seed=3)
    sent = encode_all(grid, batches)
    extra = random.Random(4).sample(sent, 9)
    stream = sent + extra
    random.Random(5).shuffle(stream)
    with (
        running_server(mission, tmp_path / "store") as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        merged, inbox = bus.subscribe_queue(session, bus.key(mission.mission, "merged"))
        pubs = publishers(session, mission.mission, batches)
        client = MapClient(session, mission.mission, endpoint=endpoint)
        for rid, _seq, payload in stream:  # out of order: a seq past the next one is refused
            pubs[rid].put(payload)
        by_robot = {rid: [p for r, _, p in sent if r == rid] for rid in batches}
        resend_until_acked(client, pubs, by_robot)
        snap = client.snapshot()
        stats = client.stats()
        wait_until(lambda: inbox.qsize() >= len(sent), 10, "the merged stream")
        time.sleep(0.2)
        merged.undeclare()
    assert_maps_equal(snap.lam, snap.eta, central_fusion(grid, sensor, batches))
    assert snap.acks == {rid: {EPOCH: 6} for rid in batches}
    assert stats["deltas_applied"] == len(sent) and stats["duplicates"] >= 1
    assert stats["updates_merged"] == sum(len(d) for ds in batches.values() for d in ds)
    assert set(k for k, n in stats["rejected"].items() if n) <= {"seq_gap"}
    assert stats["robots"]["r2"] == {
        "deltas": 6,
        "epoch": EPOCH,
        "last_seq": 6,
        "acked_seq": 6,
        "voxel_updates": sum(len(d) for d in batches["r2"]),
    }
    central = central_fusion(grid, sensor, batches)
    exact = float(np.sum(default_table()(central.mean(), central.sigma()), dtype=np.float64))
    assert stats["entropy_bits"] == pytest.approx(exact, rel=1e-5)
    assert stats["entropy_bits"] < stats["initial_entropy_bits"]
    # the merged stream carries each applied delta once, unchanged
    got = [inbox.get_nowait()[1] for _ in range(inbox.qsize())]
    assert sorted(got) == sorted(p for _, _, p in sent)
