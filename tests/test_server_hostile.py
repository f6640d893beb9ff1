"""Hostile deltas against a running map server on real Zenoh sessions (loopback, explicit
endpoints, scouting off): each is refused alone and counted, the map stays bit-identical to
the map of the valid deltas, and the other robots' deltas are applied and acked (issue 19)."""

from __future__ import annotations

import json
from pathlib import Path

import msgpack
import numpy as np
import pytest

from map_server.options import ServerOptions
from map_server.team_map import MergedMap
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient, MapQueryError
from swarm.protocol.wire import DeltaMessage
from tests.test_server_merge import (
    EPOCH,
    all_acked,
    client_session,
    encode_all,
    publishers,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)
from tests.test_server_rejects import good, tamper


def strict_json(text: bytes) -> dict:
    """JSON as RFC 8259 has it: NaN and Infinity are not JSON."""

    def refuse(name: str):
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def oracle(mission, payloads: list[bytes]) -> MergedMap:
    """The map of exactly these valid deltas, merged without a server."""
    team = MergedMap(mission.workspace.grid(), mission.sensor.model())
    for p in payloads:
        msg = DeltaMessage.decode(p)
        if team.admit(msg):
            team.apply(msg)
    return team


def honest_stream(mission, robots=("r1", "r2", "r3"), per_robot: int = 4, seed: int = 0):
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, robots=len(robots), per_robot=per_robot, seed=seed)
    return encode_all(grid, batches)


def run_hostile(tmp_path: Path, hostile: list[tuple[str, bytes]], options: ServerOptions | None = None):
    """Interleave ``hostile`` (key robot, payload) with honest deltas of r1..r3; wait until every
    honest one is acked. Returns (stats, snapshot, honest payloads)."""
    mission = small_mission()
    honest = honest_stream(mission)
    with (
        running_server(mission, tmp_path / "store", options) as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        merged, merged_inbox = bus.subscribe_queue(session, f"swarm/{mission.mission}/merged")
        robots = {"r1", "r2", "r3"} | {r for r, _ in hostile}
        pubs = publishers(session, mission.mission, sorted(robots))
        for i, (rid, _seq, payload) in enumerate(honest):
            pubs[rid].put(payload)
            for bad_rid, bad in hostile[i :: len(honest)]:
                pubs[bad_rid].put(bad)
        wait_until(lambda: all_acked(client, {"r1": 4, "r2": 4, "r3": 4}), 20, "every honest delta acked")
        stats_raw = session.get(f"swarm/{mission.mission}/map/stats", timeout=5.0)
        text = next(r.ok.payload.to_bytes() for r in stats_raw if r.ok is not None)
        stats = strict_json(text)
        snap = client.snapshot()
        wait_until(lambda: merged_inbox.qsize() >= len(honest), 10, "the merged stream")
        merged.undeclare()
    in_order = [merged_inbox.get_nowait()[1] for _ in range(merged_inbox.qsize())]
    assert sorted(in_order) == sorted(p for _, _, p in honest)  # each honest delta once, nothing else
    expected = oracle(mission, in_order)  # the same sums in the same order
    np.testing.assert_array_equal(snap.lam, expected.cmap.lam)  # bit-identical
    np.testing.assert_array_equal(snap.eta, expected.cmap.eta)
    assert stats["deltas_applied"] == len(honest)
    return stats, snap, honest


def test_a_poisoned_delta_in_a_batch_is_refused_alone(tmp_path: Path):
    """Finding 1: grid.shape inf (OverflowError in the old validator) stalled the whole batch."""
    grid = small_mission().workspace.grid()
    ok = good(grid, robot="r1", seq=99)
    poison = [
        tamper(ok, grid={**grid.to_dict(), "shape": [float("inf"), 20, 10]}),
        tamper(ok, grid={**grid.to_dict(), "shape": [2**64 - 1, 20, 10]}),
        tamper(ok, grid={**grid.to_dict(), "voxel": 1e-320}),
        tamper(ok, grid={**grid.to_dict(), "origin": [float("nan"), 0, 0]}),
        tamper(ok, grid=[1, 2, 3]),
        tamper(ok, epoch=-1),
        tamper(ok, seq=2**64 - 1),
        tamper(ok, robot=b"r1"),
        tamper(ok, t=float("inf")),
        msgpack.packb({"v": 1, **{str(i): None for i in range(100)}}),
    ]
    stats, _snap, _ = run_hostile(tmp_path, [("r1", p) for p in poison])
    assert sum(stats["rejected"].values()) == len(poison), stats["rejected"]
    assert stats["rejected"]["internal_error"] == 0


def test_flood_is_refused_at_the_inbox_and_oversized_payloads_before_decoding(tmp_path: Path):
    """Finding 2: no backpressure, no size limit. A robot's flood fills only its own queue."""
    mission = small_mission()
    grid = mission.workspace.grid()
    options = ServerOptions(inbox_messages=4, max_payload_bytes=64 << 10)
    with (
        running_server(mission, tmp_path / "store", options) as (server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        pubs = publishers(session, mission.mission, ["r1", "r2", "r3"])
        big = np.arange(0, grid.size, dtype=np.uint32)[:6000]  # 72 KB of arrays: over the cap
        dlam = np.full(len(big), 1.0, np.float32)
        pubs["r3"].put(DeltaMessage("r3", EPOCH, 1, 1.0, grid, big, dlam, dlam * 0.5).encode())
        pubs["r3"].put(msgpack.packb([None] * 60_000))  # 60 KB declaring 60,000 nils
        # r2 floods one delta per seq, far more than its 4 slots, without waiting
        flood = [good(grid, "r2", seq=s, idx=(s % grid.size,)) for s in range(1, 401)]
        for p in flood:
            pubs["r2"].put(p)
        pubs["r1"].put(good(grid, "r1", seq=1, idx=(5, 6)))
        wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10, "r1's delta acked")
        wait_until(lambda: len(server._inbox) == 0, 20, "the inbox drained")
        inbox = client.stats()["inbox"]
        assert inbox["high_water"] <= 3 * 4 and inbox["max_per_robot"] == 4
        refused = inbox["refused"].get("r2", 0)
        assert refused > 0  # the flood met the bound
        # the sender's resends recover what was refused: every seq applied exactly once
        for _ in range(300):
            acked = client.acks().get("r2", {}).get(EPOCH, 0)
            if acked == len(flood):
                break
            for p in flood[acked : acked + 4]:
                pubs["r2"].put(p)
            wait_until(lambda a=acked: client.acks()["r2"][EPOCH] > a, 10, "progress after a resend")
        stats = client.stats()
    assert stats["robots"]["r2"]["deltas"] == len(flood) and stats["robots"]["r2"]["acked_seq"] == len(flood)
    assert stats["rejected"]["too_large"] == 1 and stats["rejected"]["malformed"] == 1


def test_information_beyond_the_rig_is_refused_and_the_map_stays_finite(tmp_path: Path):
    """Finding 3: dlam 1e30 wiped the entropy; 3e38 twice overflowed float32 into NaN stats."""
    grid = small_mission().workspace.grid()
    every = np.arange(grid.size, dtype=np.uint32)

    def flat(value: float, seq: int) -> bytes:
        d = np.full(grid.size, value, np.float32)
        return DeltaMessage("r2", EPOCH + 1, seq, 1.0, grid, every, d, d * 0.5).encode()

    ok = good(grid, robot="r1")
    hostile = [
        ("r2", flat(1e30, 1)),
        ("r2", flat(3e38, 2)),
        ("r2", flat(3e38, 3)),
        ("r2", flat(1e8, 4)),  # plausible per voxel, over 20 frames' worth on 6,000 voxels
        ("r1", tamper(ok, seq=50, deta=np.array([-1.0, 1.0, 1.0], np.float32).tobytes())),
        ("r1", tamper(ok, seq=51, deta=np.array([1.0, 1.0, 60.0], np.float32).tobytes())),
    ]
    stats, snap, _ = run_hostile(tmp_path, hostile)
    assert stats["rejected"]["too_much_information"] == 4
    assert stats["rejected"]["mean_outside_unit"] == 2
    assert np.all(np.isfinite(snap.lam)) and np.all(np.isfinite(snap.eta))
    assert stats["entropy_bits"] > 0.5 * stats["initial_entropy_bits"]


def test_only_the_missions_robots_are_taken(tmp_path: Path):
    """Finding 4: deltas of 20,000 invented robot ids were kept forever."""
    grid = small_mission().workspace.grid()
    invented = [(f"x{i}", good(grid, robot=f"x{i}")) for i in range(300)]
    stats, _snap, _ = run_hostile(tmp_path, invented)
    assert stats["rejected"]["unknown_robot"] == 300
    assert set(stats["robots"]) == {"r1", "r2", "r3"}
    assert len(json.dumps(stats)) < 4000


def test_loose_values_are_refused_and_replies_are_strict(tmp_path: Path):
    """Finding 5: v true / 1.0 passed, region took '1_0' and non-ASCII digits and echoed 200 KB,
    the snapshot's integer map keys broke msgpack's default reader."""
    grid = small_mission().workspace.grid()
    ok = good(grid, robot="r1", seq=70)
    hostile = [("r1", tamper(ok, v=True)), ("r1", tamper(ok, v=1.0)), ("r1", tamper(ok, seq=70.0))]
    mission = small_mission()
    stats, _snap, _ = run_hostile(tmp_path, hostile)
    assert stats["rejected"]["unsupported_version"] == 2 and stats["rejected"]["malformed"] == 1
    with (
        running_server(mission, tmp_path / "store2") as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        for params in ("lo=1_0,0,0;hi=2,2,2", "lo=\u0661,0,0;hi=2,2,2", "lo=inf,0,0;hi=1,1,1",
                       "lo=0x1,0,0;hi=1,1,1", "lo=" + "9" * 200_000 + ",0,0;hi=1,1,1"):  # fmt: skip
            with pytest.raises(MapQueryError) as info:
                client._get("region", params)
            assert len(str(info.value)) < 400
        pubs = publishers(session, mission.mission, ["r1"])
        pubs["r1"].put(good(grid, robot="r1", seq=1))
        wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10, "acked")
        reply = next(iter(session.get(f"swarm/{mission.mission}/map/snapshot", timeout=5.0)))
        raw = msgpack.unpackb(reply.ok.payload.to_bytes())  # msgpack's defaults: string keys only
        assert raw["acks"] == {"r1": {str(EPOCH): 1}}
