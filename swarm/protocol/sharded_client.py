"""Queries to a sharded map service: one :class:`MapClient` per shard, answers fanned in
(docs/sharding.md).

Shard ``k`` answers under ``bus.shard_mission(mission, k, N)`` about its slab of the grid
(``swarm.map.shard_layout``). Slabs are contiguous flat ranges in shard order, so the team
map's ``lam``/``eta`` are the shards' side by side; the team's entropy, deltas and updates are
sums; a region is each shard's part of the box, in the team grid's indices. Every query asks
every shard and raises when one does not answer (``MapServerUnavailable`` naming it): a team map
with a slab missing is not the team map. :func:`map_client_for` gives the client a mission
needs, a plain :class:`MapClient` when it has one server.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from swarm.map.grid import Grid
from swarm.map.shard_layout import ShardLayout
from swarm.protocol import bus
from swarm.protocol.map_client import DEFAULT_TIMEOUT_S, MapClient
from swarm.protocol.map_stream import Progress
from swarm.protocol.wire import Region, Snapshot

#: ``map/stats`` fields that add up over the shards (each shard counts its own slab's)
SUMMED = (
    "voxels",
    "entropy_bits",
    "initial_entropy_bits",
    "deltas_applied",
    "updates_merged",
    "duplicates",
    "wal_records",
    "wal_bytes",
    "queued",
    "epochs_issued",
)


@dataclass
class ShardedSnapshot:
    """Every shard's snapshot (``shards[k]`` over shard k's slab, with its own acks) and the
    team map they make (``team``: the mission grid, lam/eta side by side; its acks are empty,
    as acks are per shard)."""

    shards: list[Snapshot]
    team: Snapshot


class ShardedMapClient:
    """The map queries of ``MapClient`` over the shards of ``layout`` (mission ``mission``)."""

    def __init__(
        self,
        session: zenoh.Session,
        mission: str,
        layout: ShardLayout,
        timeout: float = DEFAULT_TIMEOUT_S,
        endpoint: str = "the Zenoh network",
        owns_session: bool = False,
    ) -> None:
        self.session = session
        self.endpoint = endpoint
        self._owns = owns_session
        self.mission = mission
        self.layout = layout
        self.timeout = float(timeout)
        #: one client per shard, in shard order
        self.clients = [
            MapClient(session, bus.shard_mission(mission, k, layout.count), timeout, endpoint)
            for k in range(layout.count)
        ]

    def close(self) -> None:
        """Close the session when this client opened it (else it is borrowed: left open)."""
        if self._owns:
            self.session.close()

    def __enter__(self) -> ShardedMapClient:
        return self

    def __exit__(self, *_exc) -> None:
        self.close()

    # -- queries -------------------------------------------------------------------------
    def stats(self) -> dict:
        """The team's ``map/stats``: shard 0's object with the team grid, the :data:`SUMMED`
        fields summed, ``known_fraction`` over the team grid, ``rejected`` summed per kind,
        ``robots`` per robot with ``deltas`` summed and, per shard, ``shards``: each shard's own
        ``map/stats`` object. Raises as ``MapClient.stats`` does, for the first shard that fails."""
        return team_stats(self.layout, [client.stats() for client in self.clients])

    def acks(self) -> list[dict[str, dict[int, int]]]:
        """Each shard's ``map/acks`` (a robot's epochs and seqs are per shard), in shard order."""
        return [client.acks() for client in self.clients]

    def snapshot(self, progress: Progress | None = None) -> ShardedSnapshot:
        """Every shard's snapshot, one after the other, and the team map they make. Each is
        one consistent state of its shard; together they are not one instant of the team."""
        shards = [client.snapshot(progress) for client in self.clients]
        lam = np.concatenate([np.asarray(s.lam, np.float32).reshape(-1) for s in shards])
        eta = np.concatenate([np.asarray(s.eta, np.float32).reshape(-1) for s in shards])
        return ShardedSnapshot(shards, Snapshot(self.layout.grid, lam, eta))

    def team_snapshot(self, progress: Progress | None = None) -> Snapshot:
        """The team map they make (mission grid, slabs side by side, no acks)."""
        return self.snapshot(progress).team

    def region(self, lo, hi, progress: Progress | None = None) -> Region:
        """The beliefs of the voxels the box [lo, hi] (world metres) touches, from the shards
        whose slabs it crosses, in the team grid's indices (ascending)."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        parts = []
        for k, client in enumerate(self.clients):
            slab = self.layout.grid_of(k)
            if hi[0] < slab.lo[0] or lo[0] > slab.hi[0]:
                continue
            part = client.region(lo, hi, progress)
            parts.append((self.layout.to_global(k, part.idx), part))
        return _joined(self.layout, parts)

    def point(self, p) -> Region:
        """The belief of the voxel holding point ``p`` (empty outside the grid)."""
        return self.region(p, p)


def team_stats(layout: ShardLayout, shards: list[dict]) -> dict:
    """The team's ``map/stats`` from each shard's (see :meth:`ShardedMapClient.stats`)."""
    first = shards[0]
    team = dict(first)
    grid = layout.grid
    team |= {"shape": list(grid.shape), "origin": list(grid.origin)}
    for name in SUMMED:
        if all(isinstance(s.get(name), int | float) for s in shards):
            team[name] = sum(s[name] for s in shards)
    known = sum(float(s.get("known_fraction", 0.0)) * int(s.get("voxels", 0)) for s in shards)
    team["known_fraction"] = known / max(grid.size, 1)
    kinds = {kind for s in shards for kind in s.get("rejected", {})}
    team["rejected"] = {k: sum(int(s.get("rejected", {}).get(k, 0)) for s in shards) for k in sorted(kinds)}
    robots: dict[str, dict] = {}
    for s in shards:
        for robot, entry in s.get("robots", {}).items():
            mine = robots.setdefault(robot, {"deltas": 0, "voxel_updates": 0, "acked_seq": 0, "last_seq": 0})
            # seqs are per shard: the latest run's acked and applied seqs add up to its deltas
            for name in ("deltas", "voxel_updates", "acked_seq", "last_seq"):
                mine[name] += int(entry.get(name, 0))
    team["robots"] = robots
    team["quarantined"] = sorted({r for s in shards for r in s.get("quarantined", [])})
    team["mission"] = first.get("shard", {}).get("mission", first.get("mission"))
    team["shards"] = shards
    return team


def _joined(layout: ShardLayout, parts: list[tuple[np.ndarray, Region]]) -> Region:
    """One region of the team grid from the shards' parts (``(global idx, region)``)."""
    if not parts:
        empty = np.zeros(0, np.float32)
        return Region(layout.grid, np.zeros(0, np.uint32), empty, empty, empty, empty)
    idx = np.concatenate([g for g, _ in parts])
    order = np.argsort(idx, kind="stable")
    values = {name: np.concatenate([getattr(r, name) for _, r in parts])[order] for name in Region._VALUES}
    return Region(layout.grid, idx[order].astype(np.uint32), **values)


def discover_layout(
    session: zenoh.Session, mission: str, timeout: float = DEFAULT_TIMEOUT_S, once: bool = False
) -> ShardLayout | None:
    """The ``ShardLayout`` of ``mission``'s sharded map service, as its shards describe it in
    ``map/stats`` (``shard``: count, x cuts and the mission grid), or None when no shard of it
    answers within ``timeout`` s (an unsharded mission, or none running). ``once``: ask one
    time only (a session that has seen the servers answer already knows their queryables)."""
    pattern = bus.key_pattern(mission, "shard", "*", "map", "stats")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for reply in session.get(pattern, timeout=max(deadline - time.monotonic(), 0.05)):
            if reply.ok is None:
                continue
            try:
                shard = json.loads(reply.ok.payload.to_bytes())["shard"]
                whole = shard["mission_grid"]
                grid = Grid(tuple(whole["origin"]), float(whole["voxel_size"]), tuple(whole["shape"]))
                return ShardLayout(grid, tuple(int(b) for b in shard["bounds"]))
            except (ValueError, KeyError, TypeError):
                continue  # not a shard's stats: another may answer
        if once:
            break
        time.sleep(0.05)
    return None


def unsharded_only(session: zenoh.Session, mission: str, exc: Exception) -> str:
    """Why a role that follows one map server found none for ``mission``: the error ``exc``,
    or that the mission's map service is sharded, which the role does not follow yet."""
    layout = discover_layout(session, mission, 1.0, once=True)
    if layout is None:
        return f"no map server of mission {mission!r} answered: {exc}"
    return (
        f"mission {mission!r} has a sharded map service ({layout.count} shards); this role follows "
        "an unsharded one only for now (docs/sharding.md, 'Limits'); swarm map stats/get/export "
        "work on a sharded one"
    )


def map_client_for(
    session: zenoh.Session,
    mission: str,
    layout: ShardLayout | None,
    timeout: float = DEFAULT_TIMEOUT_S,
    endpoint: str = "the Zenoh network",
) -> MapClient | ShardedMapClient:
    """The client of ``mission``'s map service: a ``MapClient`` when ``layout`` is None or one
    shard, else a ``ShardedMapClient``."""
    if layout is None or layout.count == 1:
        return MapClient(session, mission, timeout, endpoint)
    return ShardedMapClient(session, mission, layout, timeout, endpoint)
