"""Quarantine: a robot's further deltas are refused and its past ones leave the map, durably;
at start (``--quarantine``) and at run time (``<store>/quarantine`` + SIGHUP)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from map_server.ledger import Rejected
from map_server.options import ServerOptions
from map_server.server import MapServer
from map_server.team_map import MergedMap
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import (
    EPOCH,
    MISSION_YAML,
    all_acked,
    assert_maps_equal,
    central_fusion,
    client_session,
    encode_all,
    publishers,
    robot_batches,
    signed,
    small_mission,
    wait_until,
)


def test_quarantine_takes_a_robots_deltas_out_of_the_map():
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=3, seed=8)
    team = MergedMap(grid, sensor)
    for _rid, _seq, payload in encode_all(grid, batches):
        msg = DeltaMessage.decode(payload)
        assert team.admit(msg)
        team.apply(msg)
    assert team.quarantine("r2")
    without = {rid: d for rid, d in batches.items() if rid != "r2"}
    assert_maps_equal(team.cmap.lam, team.cmap.eta, central_fusion(grid, sensor, without))
    exact = MergedMap(grid, sensor, team.cmap.lam.copy(), team.cmap.eta.copy())
    assert team.entropy.total == pytest.approx(exact.entropy.total, rel=1e-6)
    assert team.known == exact.known
    again = DeltaMessage.decode(encode_all(grid, {"r2": batches["r2"]})[0][2])
    with pytest.raises(Rejected) as info:
        team.admit(again)  # neither re-applied nor counted as new
    assert info.value.kind == "quarantined"
    assert team.stats()["robots"]["r2"]["quarantined"] is True


def test_quarantine_survives_a_restart_and_applies_to_a_store_at_start(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=3, seed=9)
    store = tmp_path / "store"
    server = MapServer(mission, store)
    server.merge(signed(server, encode_all(grid, batches)))
    server.stop()  # compacts: the contributions are in the snapshot
    server = MapServer(mission, store, options=ServerOptions(quarantine=("r3",)))
    without = {rid: d for rid, d in batches.items() if rid != "r3"}
    assert_maps_equal(server.team.cmap.lam, server.team.cmap.eta, central_fusion(grid, sensor, without))
    server.merge([("r3", DeltaMessage("r3", EPOCH + 1, 1, 1.0, grid, *_one(grid)).encode(), None)])
    assert server.stats()["rejected"]["quarantined"] == 1
    server.stop()
    server = MapServer(mission, store)  # no option: the quarantine was stored
    assert server.team.quarantined == {"r3"}
    assert_maps_equal(server.team.cmap.lam, server.team.cmap.eta, central_fusion(grid, sensor, without))
    server.stop()


def _one(grid):
    idx = np.array([1], np.uint32)
    dlam = np.array([10.0], np.float32)
    return idx, dlam, dlam * 0.5


@pytest.mark.slow
def test_sighup_quarantines_the_robots_of_the_store_file(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=2, seed=10)
    (tmp_path / "m.yaml").write_text(MISSION_YAML)
    store = tmp_path / "store"
    endpoint = bus.tcp_endpoint(bus.free_port())
    cmd = [sys.executable, "-m", "swarm.cli", "server", "--config", str(tmp_path / "m.yaml")]
    proc = subprocess.Popen([*cmd, "--store", str(store), "--listen", endpoint], stderr=subprocess.PIPE)
    try:
        with client_session(endpoint) as session:
            client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
            wait_until(lambda: _answers(client), 30, "the server")
            pubs = publishers(session, mission.mission, batches)
            for rid, _seq, payload in encode_all(grid, batches):
                pubs[rid].put(payload)
            wait_until(lambda: all_acked(client, dict.fromkeys(batches, 2)), 20, "every delta acked")
            (store / "quarantine").write_text("# bad camera\nr1\n")
            proc.send_signal(signal.SIGHUP)
            wait_until(lambda: client.stats()["quarantined"] == ["r1"], 10, "the quarantine")
            snap = client.snapshot()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err.decode()[-2000:]
    without = {rid: d for rid, d in batches.items() if rid != "r1"}
    assert_maps_equal(snap.lam, snap.eta, central_fusion(grid, sensor, without))


def _answers(client: MapClient) -> bool:
    try:
        client.stats()
        return True
    except Exception:  # noqa: BLE001 (not up yet)
        return False


class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    def __init__(self, key: str, data: bytes) -> None:
        self.key_expr, self.payload = key, _Payload(data)


def test_a_quarantined_robots_payloads_are_refused_before_they_are_read(tmp_path: Path):
    # its agent is never acked and resends its whole outbox every few seconds: the server
    # refuses those as it refuses an unknown robot's, without queueing or decoding them
    mission = small_mission()
    server = MapServer(mission, tmp_path / "store", options=ServerOptions(quarantine=("r3",)))
    try:
        server.intake.on_sample(_Sample(f"swarm/{mission.mission}/delta/r3", b"not even msgpack"))
        stats = server.stats()
        assert stats["rejected"]["quarantined"] == 1 and stats["rejected"]["malformed"] == 0
        assert stats["inbox"]["queued"] == 0
    finally:
        server.stop()
