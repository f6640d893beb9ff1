"""Malformed deltas are refused whole, each counted under its kind in map/stats, while the
server keeps answering queries and applying good deltas; bad queries get error replies."""

from __future__ import annotations

from pathlib import Path

import msgpack
import numpy as np
import pytest

from map_server.ledger import REJECT_KINDS, Rejected, validate_delta
from swarm.map.grid import Grid
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient, MapQueryError
from tests.support.malformed_deltas import good, tamper
from tests.support.map_server_mission import (
    EPOCH,
    client_session,
    publishers,
    running_server,
    small_mission,
    wait_until,
)


def bad_payloads(grid: Grid) -> list[tuple[str, str, bytes]]:
    """(kind, key robot, payload) of one malformed delta per way of being wrong."""
    ok = good(grid)
    f32 = np.float32
    other = Grid(grid.origin, grid.voxel, (grid.shape[0] + 1, *grid.shape[1:]))
    return [
        ("malformed", "r1", b"\x00\xffnot msgpack at all"),
        ("malformed", "r1", msgpack.packb([1, 2, 3])),
        ("malformed", "r1", tamper(ok, seq=None)),
        ("malformed", "r1", tamper(ok, dlam=np.ones(2, f32).tobytes())),  # 3 idx, 2 dlam
        ("unsupported_version", "r1", tamper(ok, v=1)),  # v1: ask map/epoch
        ("wrong_grid", "r1", good(other)),
        ("wrong_grid", "r1", tamper(ok, grid={**grid.to_dict(), "voxel": 0.2})),
        ("robot_mismatch", "r2", ok),
        ("out_of_grid", "r1", tamper(ok, idx=np.array([1, 2, grid.size], np.uint32).tobytes())),
        ("non_finite", "r1", tamper(ok, dlam=np.array([1, np.nan, 1], f32).tobytes())),
        ("non_finite", "r1", tamper(ok, deta=np.array([1, 1, np.inf], f32).tobytes())),
        ("negative_information", "r1", tamper(ok, dlam=np.array([1, -1, 1], f32).tobytes())),
        ("duplicate_idx", "r1", tamper(ok, idx=np.array([7, 9, 7], np.uint32).tobytes())),
    ]


def test_validate_delta_names_each_kind():
    grid = small_mission().workspace.grid()
    assert validate_delta(good(grid), grid, "r1").seq == 1
    for kind, robot, payload in bad_payloads(grid):
        with pytest.raises(Rejected) as info:
            validate_delta(payload, grid, robot)
        assert info.value.kind == kind, (kind, str(info.value))
        assert kind in REJECT_KINDS


def test_server_counts_each_rejection_and_keeps_serving(tmp_path: Path):
    mission = small_mission()
    grid = mission.workspace.grid()
    with (
        running_server(mission, tmp_path / "store") as (_server, endpoint),
        client_session(endpoint) as session,
    ):
        client = MapClient(session, mission.mission, timeout=5.0, endpoint=endpoint)
        pubs = publishers(session, mission.mission, ["r1", "r2"])
        expected = dict.fromkeys(REJECT_KINDS, 0)
        seq = 0
        for kind, robot, payload in bad_payloads(grid):
            pubs[robot].put(payload)
            expected[kind] += 1
            seq += 1
            pubs["r1"].put(good(grid, seq=seq, idx=(seq, seq + 100)))  # a good one after each bad one
            wait_until(lambda seq=seq: client.acks().get("r1", {}).get(EPOCH, 0) >= seq, 10, f"good #{seq}")
            stats = client.stats()
            assert stats["rejected"] == expected, kind
            assert stats["deltas_applied"] == seq
        # a duplicate is not an error: counted apart, map unchanged
        before = client.snapshot()
        pubs["r1"].put(good(grid, seq=1, idx=(1, 101)))
        pubs["r1"].put(good(grid, seq=seq + 1, idx=(500,)))
        wait_until(lambda: client.acks()["r1"][EPOCH] == seq + 1, 10, "the last good delta")
        stats = client.stats()
        after = client.snapshot()
        assert stats["duplicates"] == 1 and stats["rejected"] == expected
        changed = np.flatnonzero(after.lam != before.lam)
        assert changed.tolist() == [500]
        # bad region queries get an error reply, not a crash
        for params in ("", "lo=0,0,0", "lo=0,0;hi=1,1,1", "lo=a,b,c;hi=1,1,1", "lo=1,1,1;hi=0,0,0",
                       "lo=0,0,0;hi=nan,1,1", "lo=0,0,0,0;hi=1,1,1"):  # fmt: skip
            with pytest.raises(MapQueryError, match="map/region"):
                client._get("region", params)
        region = client.region([0.0, 0.0, 0.0], [0.05, 0.05, 0.35])
        assert len(region) == 4 and client.stats()["deltas_applied"] == seq + 1
        assert len(client.region([-1e9] * 3, [1e9] * 3)) == grid.size  # clipped to the grid
        # a garbage payload on a deeper key is not ours; the server is still well
        session.put(bus.key(mission.mission, "delta", "r1", "x"), b"junk")
        assert client.stats()["rejected"] == expected
