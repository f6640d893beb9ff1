"""Streamed map/snapshot and map/region answers (map_server/snapshot_stream.py) over loopback
Zenoh, through MapClient (swarm/protocol/map_stream.py): the assembled answer equals the
server's own; deltas merged between two chunk queries do not tear a snapshot (it is the map at
its consistent point, chunk 0's acks); a stream expired mid-answer is started again; hostile
stream parameters get an error reply and the server goes on answering.

The mission and server helpers are in tests/support/map_server_mission.py.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from map_server.options import ServerOptions
from map_server.snapshot_stream import HeldStream, StreamAsk, StreamCache, parse_stream_parameters
from swarm.protocol import bus
from swarm.protocol.map_chunks import EXPIRED, SNAPSHOT_KIND, SNAPSHOT_VOXEL_BYTES, Chunk
from swarm.protocol.map_client import MapClient
from swarm.protocol.replies import ask_all
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
)

#: 600 voxels a chunk: the small mission's 6000-voxel map is 10 chunks
SMALL_CHUNKS = ServerOptions(chunk_bytes=600 * SNAPSHOT_VOXEL_BYTES)


def _payloads(grid, batches, seqs: range) -> dict[str, list[bytes]]:
    sent = encode_all(grid, batches)
    return {rid: [p for r, s, p in sent if r == rid and s in seqs] for rid in batches}


def test_a_streamed_snapshot_and_region_equal_the_servers_own(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=3)
    with (
        running_server(mission, tmp_path / "store", SMALL_CHUNKS) as (server, endpoint),
        client_session(endpoint) as session,
    ):
        pubs = publishers(session, mission.mission, batches)
        client = MapClient(session, mission.mission, endpoint=endpoint)
        resend_until_acked(client, pubs, _payloads(grid, batches, range(1, 4)))
        seen: list[tuple[int, int]] = []
        snap = client.snapshot(progress=lambda got, of: seen.append((got, of)))
        lo, hi = np.array([0.4, 0.3, 0.1]), np.array([2.2, 1.7, 0.8])
        region = client.region(lo, hi)
        with server._lock:
            own, own_region = server.team.snapshot(), server.team.region(lo, hi)
        stats = client.stats()["streams"]
    assert seen[-1] == (10, 10) and len(seen) == 10
    assert snap.lam.tobytes() == own.lam.tobytes() and snap.eta.tobytes() == own.eta.tobytes()
    assert snap.acks == own.acks == {rid: {EPOCH: 3} for rid in batches} and snap.above == own.above
    assert len(region) == len(own_region) > 600  # more than one chunk of the region's
    for name in ("idx", "mu", "sigma", "expected_coverage", "entropy"):
        assert getattr(region, name).tobytes() == getattr(own_region, name).tobytes(), name
    assert stats["started"] >= 2 and stats["held"] >= 1


def test_deltas_merged_between_chunk_queries_do_not_tear_the_snapshot(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=6)
    first = {rid: deltas[:3] for rid, deltas in batches.items()}
    with (
        running_server(mission, tmp_path / "store", SMALL_CHUNKS) as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        pubs = publishers(session, mission.mission, batches)
        client = MapClient(session, mission.mission, endpoint=endpoint)
        resend_until_acked(client, pubs, _payloads(grid, batches, range(1, 4)))
        client.window = 1  # one chunk a query: the rest of the map is merged into meanwhile
        merged_meanwhile: list[int] = []

        def merge_the_rest(got: int, _of: int) -> None:
            if got == 1:
                resend_until_acked(client, pubs, _payloads(grid, batches, range(1, 7)))
                merged_meanwhile.append(got)

        snap = client.snapshot(progress=merge_the_rest)
        later = client.snapshot()
    assert merged_meanwhile == [1]
    assert snap.acks == {rid: {EPOCH: 3} for rid in batches}
    assert_maps_equal(snap.lam, snap.eta, central_fusion(grid, sensor, first))
    assert later.acks == {rid: {EPOCH: 6} for rid in batches}
    assert_maps_equal(later.lam, later.eta, central_fusion(grid, sensor, batches))


def test_a_stream_expired_mid_answer_is_started_again_cleanly(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=2)
    options = ServerOptions(chunk_bytes=SMALL_CHUNKS.chunk_bytes, stream_idle_s=0.3)
    with (
        running_server(mission, tmp_path / "store", options) as (server, endpoint),
        client_session(endpoint) as session,
    ):
        pubs = publishers(session, mission.mission, batches)
        client = MapClient(session, mission.mission, endpoint=endpoint)
        resend_until_acked(client, pubs, _payloads(grid, batches, range(1, 3)))
        client.window = 3
        paused: list[int] = []

        def pause_once(got: int, _of: int) -> None:
            if got == 3 and not paused:
                paused.append(got)
                time.sleep(0.8)  # the server drops the stream meanwhile

        snap = client.snapshot(progress=pause_once)
        with server._lock:
            own = server.team.snapshot()
        stats = server.streams.cache.stats()
    assert paused == [3]
    assert stats["expired"] >= 1 and stats["started"] >= 2
    assert snap.lam.tobytes() == own.lam.tobytes() and snap.eta.tobytes() == own.eta.tobytes()
    assert snap.acks == own.acks == {rid: {EPOCH: 2} for rid in batches}


@pytest.mark.parametrize("part", ["snapshot", "region"])
def test_hostile_stream_parameters_get_an_error_reply_and_the_server_goes_on(tmp_path: Path, part: str):
    mission = small_mission()
    box = "lo=0,0,0;hi=3,2,1;" if part == "region" else ""
    with (
        running_server(mission, tmp_path / "store", SMALL_CHUNKS) as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        key = bus.key(mission.mission, "map", part)
        started = ask_all(session, f"{key}?{box}count=1", 5.0)
        assert started is not None and started.error is None and len(started.ok) == 1
        kind = SNAPSHOT_KIND if part == "snapshot" else "region_chunk"
        head = Chunk.decode(started.ok[0], kind)
        held = f"stream={head.stream}"
        hostile = {
            f"{held};cursor=-1": "bad query",
            f"{held};cursor={head.chunks}": "bad query",
            f"{held};cursor=99999999999999999999": "bad query",
            f"{held};cursor=1e3": "bad query",
            f"{held};count=0": "bad query",
            f"{held};count=100000": "bad query",
            f"{held};count=-3": "bad query",
            "stream=0123456789abcdef;cursor=1": EXPIRED.strip(": "),
            "stream=0123456789ABCDEF": "bad query",
            "stream=../../etc/passwd": "bad query",
            "stream=" + "a" * 5000: "bad query",
            "cursor=4": "bad query",  # a stream starts at cursor 0
            "\x00\xff;;;==;cursor": "bad query",
        }
        if part == "region":
            hostile |= {
                "lo=nan,0,0;hi=1,1,1": "map/region",
                "lo=0,0;hi=1,1,1": "map/region",
                "": "map/region",
            }
        for params, said in hostile.items():
            selector = f"{key}?{params}" if params else key
            answer = ask_all(session, selector, 5.0)
            assert answer is not None and not answer.ok, params
            assert answer.error is not None and said in answer.error, (params, answer.error)
            assert len(answer.error) < 400, params  # no echo of a long parameter
        rest = ask_all(session, f"{key}?{held};cursor=1;count=64", 5.0)  # the stream is still held
        assert rest is not None and rest.error is None and len(rest.ok) == head.chunks - 1
        client = MapClient(session, mission.mission, endpoint=endpoint)
        if part == "snapshot":
            assert client.snapshot().grid.matches(mission.workspace.grid())
        else:
            assert len(client.region([0, 0, 0], [3, 2, 1])) == mission.workspace.grid().size
        assert client.stats()["deltas_applied"] == 0


# -- the cache of held streams, without Zenoh ----------------------------------------------------


def _held(name: str, nbytes: int = 10) -> HeldStream:
    return HeldStream(name * 16, SNAPSHOT_KIND, 1, lambda _i: b"", nbytes)


def test_the_stream_cache_bounds_each_requester_all_streams_their_bytes_and_their_idle_time():
    now = [0.0]
    cache = StreamCache(max_streams=4, per_requester=2, max_bytes=100, idle_s=5.0, clock=lambda: now[0])
    for name in "abc":
        cache.hold(_held(name), "zid1")  # a's dropped: zid1 holds 2 at most
    assert cache.find("a" * 16) is None and cache.find("b" * 16) is not None
    for name in "def":
        cache.hold(_held(name), None)  # no stated id: only the overall bound of 4 holds
    assert cache.stats()["held"] == 4 and cache.find("c" * 16) is None  # the least recently asked
    assert cache.find("b" * 16) is not None  # asked for after c: kept
    cache.hold(_held("0", 75), None)  # 75 + 3 * 10 > 100 bytes: the least recently asked go
    assert cache.stats()["held_bytes"] <= 100 and cache.find("0" * 16) is not None
    now[0] = 6.0
    assert cache.find("0" * 16) is None and cache.stats()["held"] == 0 and cache.stats()["expired"] >= 1


@pytest.mark.parametrize(
    "params",
    [
        {"cursor": "-1", "stream": "a" * 16},
        {"cursor": "1234567890", "stream": "a" * 16},
        {"cursor": "٣", "stream": "a" * 16},  # a non-ASCII digit
        {"count": "0"},
        {"count": "65"},
        {"cursor": "2"},  # without stream
        {"stream": "a" * 15},
        {"stream": "A" * 16},
    ],
)
def test_bad_stream_parameters_are_value_errors_that_echo_little(params: dict):
    with pytest.raises(ValueError) as raised:
        parse_stream_parameters(params)
    assert len(str(raised.value)) < 200


def test_stream_parameters_default_to_a_new_stream_of_one_window():
    assert parse_stream_parameters({}) == StreamAsk(None, 0, 16)
    assert parse_stream_parameters({"stream": "ab" * 8, "cursor": "7", "count": "64"}) == StreamAsk(
        "ab" * 8, 7, 64
    )
