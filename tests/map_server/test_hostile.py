"""A stranger's attack on a running map server over real Zenoh (loopback, explicit endpoints,
scouting off): every field of a delta made hostile, poisoned deltas inside honest batches,
information beyond what the rig can see, robots outside the mission, loose values, replays,
sequence numbers going backwards or jumping (floods and whole-map queries: test_hostile_queries.py). The
server answers each with a named refusal (counted in map/stats) or applies it exactly once,
keeps its map equal to the merge of what it applied (the honest robots' map, bit for bit, where
it refused), and keeps applying the other robots' deltas promptly."""

from __future__ import annotations

import json
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from map_server.ledger import Rejected, validate_delta
from map_server.options import ServerOptions
from map_server.server import MapServer
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient, MapQueryError
from swarm.protocol.wire import DeltaMessage
from tests.support.hostile_oracle import honest_stream, oracle, strict_json
from tests.support.malformed_deltas import good, tamper
from tests.support.map_server_mission import (
    EPOCH,
    all_acked,
    client_session,
    publishers,
    running_server,
    small_mission,
    wait_until,
)

ROBOTS = ("r1", "r2", "r3", "r4")  # r4: the attacker, a robot the server takes
OPTIONS = ServerOptions(robots=ROBOTS)

NAN, INF = float("nan"), float("inf")
#: what a stranger puts in a field: wrong types, missing, non-finite, negative, huge, empty
SCALARS = [None, True, "x", b"x", [], {}, [1.0], NAN, INF, -INF, -1, 0, 0.5, 2**64 - 1, -(2**63), 1e308]


def _arrays(n: int) -> list:
    """Hostile values of a raw array field of ``n`` items."""
    f32 = np.float32
    return [
        b"",
        b"\x00" * (4 * n - 1),
        b"\x00" * (4 * n + 4),
        np.full(n, np.nan, f32).tobytes(),  # variance NaN
        np.full(n, np.inf, f32).tobytes(),  # variance 0
        np.full(n, -1.0, f32).tobytes(),  # negative variance
        np.full(n, 3e38, f32).tobytes(),
        np.zeros(n, f32).tobytes(),  # infinite variance: no information, harmless
        np.array([2**63 - 1] * n, "<i8").tobytes(),  # int64 extremes, 8 bytes each
        [2**63 - 1] * n,
        [0.5] * n,
        np.arange(n, dtype=np.uint32).tobytes(),
    ]


def hostile_deltas(grid) -> list[bytes]:
    """Every field of a delta of r4 made hostile, one field per payload, distinct seqs."""
    out: list[bytes] = []
    seq = 1000
    fields = ["v", "robot", "epoch", "seq", "t", "grid", "idx", "dlam", "deta"]
    for name in fields:
        values = _arrays(3) if name in ("idx", "dlam", "deta") else SCALARS
        if name == "idx":
            values = values + [np.array([0, grid.size, 2**32 - 1], np.uint32).tobytes()]
        for value in values:
            seq += 1
            ok = good(
                grid, robot="r4", seq=seq, idx=(seq % grid.size, 1 + seq % grid.size, 2 + seq % grid.size)
            )
            msg = msgpack.unpackb(ok, raw=False)
            if value is None:
                del msg[name]
            else:
                msg[name] = value
            out.append(msgpack.packb(msg, use_bin_type=True))
    base = grid.to_dict()
    for key in ("origin", "voxel", "shape"):
        for value in SCALARS + [[NAN, 0, 0], [0, 0, 0, 0], [2**64 - 1, 20, 10], [0, 20, 10], [-1, 20, 10]]:
            seq += 1
            g = {k: v for k, v in base.items() if k != key} if value is None else {**base, key: value}
            out.append(tamper(good(grid, robot="r4", seq=seq), grid=g))
    return out


def offline_verdict(grid, payload: bytes) -> bool:
    """Whether validate_delta alone takes the payload (the server may still refuse it on bounds)."""
    try:
        validate_delta(payload, grid, "r4")
        return True
    except Rejected as exc:
        assert exc.kind != "internal_error", exc
        return False


@pytest.mark.slow
def test_every_field_of_a_delta_made_hostile_live(tmp_path: Path):
    mission = small_mission()
    grid = mission.workspace.grid()
    hostile = hostile_deltas(grid)
    honest = honest_stream(mission)
    with (
        running_server(mission, tmp_path / "store", OPTIONS) as (server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        merged, merged_inbox = bus.subscribe_queue(session, f"swarm/{mission.mission}/merged")
        pubs = publishers(session, mission.mission, ROBOTS)
        per_honest = -(-len(hostile) // len(honest))
        for i, (rid, _seq, payload) in enumerate(honest):
            pubs[rid].put(payload)
            for bad in hostile[i * per_honest : (i + 1) * per_honest]:
                pubs["r4"].put(bad)
        wait_until(lambda: all_acked(client, {"r1": 4, "r2": 4, "r3": 4}), 30, "every honest delta acked")
        wait_until(lambda: len(server._inbox) == 0, 30, "the inbox drained")
        stats = strict_json(
            next(r.ok.payload.to_bytes() for r in session.get(f"swarm/{mission.mission}/map/stats"))
        )
        snap = client.snapshot()
        time.sleep(0.3)  # the merged stream's tail
        merged.undeclare()
    applied = [merged_inbox.get_nowait()[1] for _ in range(merged_inbox.qsize())]
    accepted = [p for p in applied if p not in {p for _, _, p in honest}]
    assert sorted(set(applied) - set(accepted)) == sorted(p for _, _, p in honest)
    assert len(applied) == len(set(applied)) == stats["deltas_applied"]
    assert all(offline_verdict(grid, p) for p in accepted)
    assert stats["rejected"]["internal_error"] == 0
    assert sum(stats["rejected"].values()) + len(accepted) + stats["duplicates"] == len(hostile)
    expected = oracle(mission, applied)
    np.testing.assert_array_equal(snap.lam, expected.cmap.lam)
    np.testing.assert_array_equal(snap.eta, expected.cmap.eta)
    assert np.all(np.isfinite(snap.lam)) and np.all(snap.eta >= 0) and np.all(snap.eta <= snap.lam * 1.0001)


def test_replays_backward_and_jumping_seqs_and_a_borrowed_id(tmp_path: Path):
    """Only an epoch's next seq is taken: backward and jumping seqs are refused (seq_gap), replays
    of applied ones are harmless duplicates, and r1's delta on r2's key is refused."""
    mission = small_mission()
    grid = mission.workspace.grid()
    deltas = {s: good(grid, "r1", seq=s, idx=(s, 100 + s)) for s in range(1, 7)}
    with (
        running_server(mission, tmp_path / "store", OPTIONS) as (server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        pubs = publishers(session, mission.mission, ROBOTS)
        for s in (5, 4, 3, 5, 2, 4):  # backwards, with replays, seq 1 still missing
            pubs["r1"].put(deltas[s])
        wait_until(lambda: client.stats()["rejected"]["seq_gap"] == 6, 10, "6 refused")
        assert client.acks()["r1"][EPOCH] == 0 and client.stats()["deltas_applied"] == 0
        for s in range(1, 6):
            pubs["r1"].put(deltas[s])
        wait_until(lambda: client.acks()["r1"][EPOCH] == 5, 10, "the prefix closes at 5")
        jumps = [
            good(grid, "r1", seq=5 + 16_385),
            good(grid, "r1", seq=2**63),
            good(grid, "r1", seq=2**64 - 1),
        ]
        for p in [*jumps, *deltas.values(), *deltas.values()]:  # and every one of them replayed twice
            pubs["r1"].put(p)
        pubs["r2"].put(good(grid, "r1", seq=7))  # r1's delta on r2's key
        pubs["r4"].put(good(grid, "r4", seq=1))
        wait_until(lambda: client.acks().get("r4", {}).get(EPOCH) == 1, 10, "r4's delta after all that")
        wait_until(lambda: client.acks()["r1"][EPOCH] == 6, 10, "seq 6")
        stats = client.stats()
    assert stats["rejected"]["seq_gap"] == 6 + 3 and stats["rejected"]["robot_mismatch"] == 1
    assert stats["duplicates"] == 5 + 6
    assert stats["robots"]["r1"]["deltas"] == 6 and stats["deltas_applied"] == 7


def test_the_information_budget_runs_on_the_servers_clock_whatever_t_says():
    """t = 1e308 then t = -1e308 once gave a span of inf seconds and an infinite budget: the
    bucket never reads t; it refills at the rig's rate per second of the server's clock."""
    from map_server.limits import InformationBound, InformationBucket

    bound = InformationBound(1e6, 0.5, burst_s=10.0)  # 2e6 per second, 2e7 at once
    bucket = InformationBucket(bound, now=100.0)
    assert bound.rate == 2e6 and bound.capacity == 2e7
    assert bucket.refusal(2e7 + 1.0, 100.0) is not None  # never more than a full bucket
    assert bucket.refusal(2e7, 100.0) is None
    bucket.charge(2e7)
    assert bucket.refusal(1.0, 100.0) is not None
    assert bucket.refusal(2e6, 101.0) is None and bucket.refusal(2.1e6, 101.0) is not None
    assert bucket.refusal(2e7, 1e9) is None and bucket.tokens == 2e7  # refilled, capped
    bucket.charge(5.0)
    bucket.refund(5.0)
    assert bucket.tokens == 2e7


def test_epochs_the_server_never_issued_cannot_lock_a_robot_out(tmp_path: Path):
    """Four deltas of r1 with epochs near 2**64 once compacted r1's real epoch away: an epoch is
    now only ever one the server issued, so they are refused and r1 goes on."""
    mission = small_mission()
    grid = mission.workspace.grid()
    now = time.time_ns()
    with (
        running_server(mission, tmp_path / "store", OPTIONS) as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        pub = publishers(session, mission.mission, ["r1"])["r1"]
        pub.put(good(grid, "r1", seq=1))
        wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10, "r1's first delta")
        for epoch in (2**64 - 1, 2**63, now + 2 * 24 * 3600 * 10**9, now + 10**15, EPOCH + 1):
            pub.put(tamper(good(grid, "r1", seq=1), epoch=epoch))  # signed with r1's key, even
        pub.put(good(grid, "r1", seq=2, idx=(7,)))
        wait_until(lambda: client.acks()["r1"].get(EPOCH) == 2, 10, "r1's second delta")
        stats, acks = client.stats(), client.acks()
    assert stats["rejected"]["unknown_epoch"] == 5 and stats["rejected"]["stale_epoch"] == 0
    assert stats["robots"]["r1"]["deltas"] == 2 and set(acks["r1"]) == {EPOCH}


def test_a_robot_pattern_admits_a_bounded_number_of_invented_ids(tmp_path: Path):
    """--robot-pattern took every id matching it: on an open bus 300 invented ids cost the
    server 300 dense contributions (8 bytes per voxel each), queues, budgets and ledger rows."""
    mission = small_mission()
    grid = mission.workspace.grid()
    options = ServerOptions(robot_pattern=r"x[0-9]+", max_pattern_robots=5)
    invented = [(f"x{i}", good(grid, robot=f"x{i}")) for i in range(300)]
    with (
        running_server(mission, tmp_path / "store", options) as (server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        pubs = publishers(session, mission.mission, [rid for rid, _ in invented] + ["r1"])
        for rid, payload in invented:
            pubs[rid].put(payload)
        pubs["r1"].put(good(grid, "r1"))
        wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10, "r1's delta")
        wait_until(lambda: client.stats()["deltas_applied"] == 6, 10, "the five admitted ids")
        stats = client.stats()
        contributors = len(server.team.contributions.by_robot)
    assert stats["rejected"]["unknown_robot"] == 295 and contributors == 6
    restarted = MapServer(mission, tmp_path / "store", options=options)
    try:  # the store's five count: a sixth id is still refused after a restart
        assert not restarted.accepts_robot("x299") and restarted.accepts_robot("x0")
    finally:
        restarted.store.close()


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
        robots = {"r1", "r2", "r3"} | {r for r, _ in hostile}  # an unknown robot gets no epoch
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


def test_information_beyond_the_rig_is_refused_and_the_map_stays_finite(tmp_path: Path):
    """Finding 3: dlam 1e30 wiped the entropy; 3e38 twice overflowed float32 into NaN stats."""
    grid = small_mission().workspace.grid()
    every = np.arange(grid.size, dtype=np.uint32)

    def flat(value: float, seq: int) -> bytes:
        d = np.full(grid.size, value, np.float32)
        return DeltaMessage("r2", EPOCH, 4 + seq, 1.0, grid, every, d, d * 0.5).encode()

    ok = good(grid, robot="r1")
    hostile = [
        ("r2", flat(1e30, 1)),
        ("r2", flat(3e38, 2)),
        ("r2", flat(3e38, 3)),
        ("r2", flat(1e8, 4)),  # plausible per voxel, over 20 frames' worth on 6,000 voxels
        ("r1", tamper(ok, seq=50, deta=np.array([-1.0, 1.0, 1.0], np.float32).tobytes())),
        ("r1", tamper(ok, seq=51, deta=np.array([1.0, 1.0, 60.0], np.float32).tobytes())),
    ]
    # r2's own epoch and seqs 5..8: one that meets the budget is refused for it, the others come
    # out of turn (seq_gap); tests/map_server/test_bus_integrity.py sends such lies in turn
    stats, snap, _ = run_hostile(tmp_path, hostile, ServerOptions(quarantine_after=0))
    assert stats["rejected"]["too_much_information"] + stats["rejected"]["seq_gap"] == 4
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


@pytest.mark.slow
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
