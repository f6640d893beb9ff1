"""A `swarm server` process killed with SIGKILL mid-stream loses no acked delta: restarted on
the same store it has every acked delta (and nothing half-applied), and once the unacked
ones are published again the map equals one central fusion of every batch."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from map_server.store import WAL_HEADER
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
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
    small_mission,
    wait_until,
)

PER_ROBOT = 30


def start_server(config: Path, store: Path, endpoint: str, log: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "swarm.cli", "server", "--listen", endpoint, "--store", str(store)]
    cmd += ["--config", str(config), "--compact-records", "8", "--log-every", "1"]
    with open(log, "a") as out:
        return subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)


def wait_for_server(client: MapClient, proc: subprocess.Popen, log: Path) -> None:
    deadline = time.monotonic() + 60
    while True:
        try:
            client.stats()
            return
        except ConnectionError:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"server did not come up:\n{log.read_text()[-3000:]}") from None


@pytest.mark.slow
def test_sigkill_mid_stream_loses_no_acked_delta(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, robots=2, per_robot=PER_ROBOT, rays=400, seed=11)
    sent = encode_all(grid, batches)
    by_robot = {rid: [p for r, _, p in sent if r == rid] for rid in batches}
    config = tmp_path / "mission.yaml"
    config.write_text(MISSION_YAML)
    store, log = tmp_path / "store", tmp_path / "server.log"
    endpoint = bus.tcp_endpoint(bus.free_port())

    proc = start_server(config, store, endpoint, log)
    try:
        with client_session(endpoint) as session:
            client = MapClient(session, mission.mission, timeout=1.0, endpoint=endpoint)
            wait_for_server(client, proc, log)
            pubs = publishers(session, mission.mission, batches)
            grants = {rid: pub.grant for rid, pub in pubs.items()}  # the restarted server keeps them
            stop = threading.Event()

            def publish() -> None:  # interleaved, in order per robot, until the kill
                for n in range(PER_ROBOT):
                    for rid in batches:
                        if stop.is_set():
                            return
                        pubs[rid].put(by_robot[rid][n])
                    time.sleep(0.02)

            publisher = threading.Thread(target=publish)
            publisher.start()
            acked: dict[str, int] = {}
            deadline = time.monotonic() + 30
            while sum(acked.values()) < 20:
                assert time.monotonic() < deadline, log.read_text()[-3000:]
                acks = client.acks()
                acked = {rid: acks.get(rid, {}).get(EPOCH, 0) for rid in batches}
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
            stop.set()
            publisher.join()
        assert sum(acked.values()) < 2 * PER_ROBOT, "the kill came too late to be mid-stream"

        proc = start_server(config, store, endpoint, log)
        with client_session(endpoint) as session:
            client = MapClient(session, mission.mission, timeout=2.0, endpoint=endpoint)
            wait_for_server(client, proc, log)
            acks = client.acks()
            recovered = {rid: acks.get(rid, {}).get(EPOCH, 0) for rid in batches}
            for rid in batches:
                assert recovered[rid] >= acked[rid], (recovered, acked)
            # exactly the recovered prefixes are in the map: nothing lost, nothing half-applied
            prefix = {rid: batches[rid][: recovered[rid]] for rid in batches}
            snap = client.snapshot()
            assert_maps_equal(snap.lam, snap.eta, central_fusion(grid, sensor, prefix))
            assert client.stats()["deltas_applied"] == sum(recovered.values())

            # the agents' part: publish again what is not acked (and, harmlessly, a few that are)
            pubs = publishers(session, mission.mission, batches, grants)
            for rid in batches:
                for payload in by_robot[rid][max(recovered[rid] - 3, 0) :]:
                    pubs[rid].put(payload)
            wait_until(lambda: all_acked(client, dict.fromkeys(batches, PER_ROBOT)), 30, "all acked")
            snap = client.snapshot()
            stats = client.stats()
        assert_maps_equal(snap.lam, snap.eta, central_fusion(grid, sensor, batches))
        assert stats["deltas_applied"] == len(sent)
        assert stats["duplicates"] == sum(min(3, recovered[rid]) for rid in batches)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
    # a clean stop compacts: the next start finds everything in the snapshot
    assert proc.returncode == 0, log.read_text()[-3000:]
    wals = sorted(store.glob("wal-*.log"))
    assert len(wals) == 1 and wals[0].stat().st_size == len(WAL_HEADER)
    assert (store / "snapshot.npz").exists()
