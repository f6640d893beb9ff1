"""Server-issued epochs (map_server.epochs): per-robot counters never reused, keys kept across
SIGKILL and every power-cut state the crash model makes, fencing of unused epochs first, and
the v2 wire pieces (the grant, the MAC's test vector, a v1 delta's refusal)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from map_server.epochs import EpochRegistry
from map_server.ledger import Rejected, validate_delta
from map_server.server import MapServer
from swarm.bench.crash_model import RecordingFiles, crash_states, materialize
from swarm.protocol.epochs import EpochGrant, delta_mac, mac_matches
from tests.support.malformed_deltas import good, tamper
from tests.support.map_server_mission import encode_all, robot_batches, signed, small_mission


def test_the_mac_is_hmac_sha256_truncated_to_16_bytes():
    """The test vector docs/protocol.md gives a client in another language."""
    assert delta_mac(bytes(range(16)), b"swarm").hex() == "482132fe03cbb9b2c05d018b29a07158"
    key = bytes(range(16))
    assert mac_matches(key, b"swarm", bytes.fromhex("482132fe03cbb9b2c05d018b29a07158"))
    assert not mac_matches(key, b"swarM", delta_mac(key, b"swarm")) and not mac_matches(key, b"x", None)
    grant = EpochGrant("r1", 3, key)
    assert EpochGrant.decode(grant.encode()) == grant


def test_a_v1_delta_is_refused_with_a_reason_that_says_to_ask_for_an_epoch():
    grid = small_mission().workspace.grid()
    with pytest.raises(Rejected) as info:
        validate_delta(tamper(good(grid), v=1), grid, "r1")
    assert info.value.kind == "unsupported_version" and "map/epoch" in str(info.value)


def test_unused_epochs_are_fenced_first_and_the_active_one_survives():
    reg = EpochRegistry(None, max_live=4)
    first, _, _ = reg.issue("r1")
    reg.touch("r1", first)  # r1 sends on its first epoch
    fenced = [f for _ in range(20) for f in reg.issue("r1")[2]]
    assert reg.live()["r1"][0] == first and len(reg.live()["r1"]) == 4
    assert first not in fenced and len(fenced) == 17
    assert reg.refusal("r1", first) is None
    assert reg.refusal("r1", fenced[0])[0] == "stale_epoch"
    assert reg.refusal("r1", 10**9)[0] == "unknown_epoch" and reg.refusal("r2", first)[0] == "unknown_epoch"
    # all four active: the least recently active goes
    reg = EpochRegistry(None, max_live=2)
    a, b = reg.issue("r1")[0], reg.issue("r1")[0]
    reg.touch("r1", b)
    reg.touch("r1", a)
    assert reg.issue("r1")[2] == [b]


@pytest.mark.slow
def test_a_restarted_server_never_issues_an_epoch_again_and_keeps_the_keys(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    server = MapServer(mission, tmp_path / "store")
    grants = [server.admission.issue("r1") for _ in range(3)]
    sent = encode_all(grid, robot_batches(grid, sensor, robots=1, per_robot=2, seed=5))
    assert server.merge(signed(server, sent)) == 2  # epoch 1
    server.store.close()  # as a SIGKILL leaves it: no compaction, no clean stop
    again = MapServer(mission, tmp_path / "store")
    assert [g.epoch for g in grants] == [1, 2, 3]
    assert all(again.admission.registry.key_of("r1", g.epoch) == g.key for g in grants)
    assert again.admission.issue("r1").epoch == 4
    assert again.admission.acks()["r1"] == {1: 2, 2: 0, 3: 0, 4: 0}
    again.stop()


@pytest.mark.slow
def test_no_power_cut_makes_a_server_reissue_an_epoch_or_forget_a_key(tmp_path: Path):
    mission = small_mission()
    root = tmp_path / "live"
    root.mkdir()
    files = RecordingFiles(root)
    server = MapServer(mission, root / "store", files=files)
    for _ in range(3):
        grant = server.admission.issue("r2")
        files.note("issued", grant.epoch, grant.key)
    server.store.close()
    states, checked = 0, 0
    for n, (cut, variant, tree) in enumerate(crash_states(files.ops)):
        issued = [(op[1], op[2]) for op in files.ops[:cut] if op[0] == "issued"]
        folder = tmp_path / f"cut-{n}"
        folder.mkdir()
        materialize(tree, folder)
        if (folder / "store" / "store.json").exists():
            states += 1
            again = MapServer(mission, folder / "store")
            try:
                for epoch, key in issued:  # every grant answered before the cut is live, same key
                    assert again.admission.registry.key_of("r2", epoch) == key, (cut, variant)
                checked = max(checked, len(issued))
                assert again.admission.issue("r2").epoch > max((e for e, _ in issued), default=0)
            finally:
                again.store.close()
        shutil.rmtree(folder)
    # the state after the last grant equals one the model gave before (it gives each once);
    # the restart test above opens it
    assert states > 10 and checked >= 2
