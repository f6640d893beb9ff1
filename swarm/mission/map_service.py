"""The mission's map service as ``swarm sim`` runs it: one ``swarm server`` per shard (docs/sharding.md).

Unsharded (``map_service.shards`` 1, the default), one server with its store in
``<run>/server-store`` and its log in ``server.log``, as always. Sharded, shard ``k`` is a
``swarm server --shard k`` process with its own store ``<run>/server-store/shard-<k>``, its own
log ``server-shard-<k>.log``; on the open loopback bus it has its own listening port and connects to
the runner's router; with ``--secure`` shard 0 is the mission's TLS router (as an unsharded server
is) and shard k > 0 connects to it with its own certificate (``server-shard-<k>``). Each owns a
slab of the grid (``swarm.map.shard_layout``). :class:`MapService` builds the commands,
subscribes the monitor to every shard's deltas, sends a previous map split over the shards,
and reads the team map from the stores once the servers have stopped.
"""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarm.config import Mission
from swarm.formats.map_file import MapFileError, load_map
from swarm.map.coverage_map import CoverageMap
from swarm.map.shard_layout import ShardLayout
from swarm.mission.prior_map import PRIOR_SOURCE, chunks, load_previous_map, prior_delta
from swarm.mission.role_failure import RoleError
from swarm.mission.team_monitor import TeamMonitor
from swarm.protocol import bus
from swarm.protocol.epochs import EpochRefused, put_delta, wait_for_epoch
from swarm.protocol.map_client import MapClient
from swarm.protocol.sharded_client import ShardedMapClient, map_client_for
from swarm.protocol.wire import DeltaMessage


@dataclass
class MapService:
    """The servers of ``mission``'s map service in run folder ``out`` (see the module doc).

    ``bus_args(k)``: the bus arguments (``--listen``, ``--connect``, ``--zenoh-config``) of
    shard ``k``'s server (``k`` 0 only when unsharded); called once per shard.
    """

    mission: Mission
    out: Path
    config_path: Path
    bus_args: Callable[[int], list[str]]

    def __post_init__(self) -> None:
        self.layout: ShardLayout = self.mission.shard_layout()

    @property
    def count(self) -> int:
        return self.layout.count

    @property
    def sharded(self) -> bool:
        return self.count > 1

    @property
    def store(self) -> Path:
        """The run's server store folder (holding one folder per shard when sharded)."""
        return self.out / "server-store"

    def store_of(self, shard: int) -> Path:
        return self.store / f"shard-{shard}" if self.sharded else self.store

    def log_of(self, shard: int) -> Path:
        return self.out / (f"server-shard-{shard}.log" if self.sharded else "server.log")

    def prefix(self, shard: int) -> str:
        """Shard ``shard``'s key prefix (the mission's name when unsharded)."""
        return bus.shard_mission(self.mission.mission, shard, self.count)

    def clear_stores(self) -> None:
        """Remove an earlier run's stores: the servers must not recover an old map."""
        if self.store.exists():
            shutil.rmtree(self.store)

    def commands(self) -> list[list[str]]:
        """The ``swarm`` arguments of each server process, in shard order."""
        base = ["server", "--config", str(self.config_path)]
        if not self.sharded:
            return [[*base, "--store", str(self.store), *self.bus_args(0)]]
        return [
            [*base, "--store", str(self.store_of(k)), "--shard", str(k), *self.bus_args(k)]
            for k in range(self.count)
        ]

    # -- as a client -------------------------------------------------------------------------
    def client(self, session, timeout: float = 2.0) -> MapClient | ShardedMapClient:
        """The team map's client: a ``MapClient``, or a ``ShardedMapClient`` over every shard."""
        return map_client_for(session, self.mission.mission, self.layout, timeout)

    def shard_client(self, session, shard: int, timeout: float = 2.0) -> MapClient:
        """Shard ``shard``'s own server (the only one when unsharded)."""
        return MapClient(session, self.prefix(shard), timeout)

    def watch_deltas(self, session, monitor: TeamMonitor) -> list:
        """Subscribe ``monitor`` to every shard's ``delta/*``: the subscribers."""
        return [
            bus.subscribe(
                session,
                bus.key_pattern(self.prefix(k), "delta", "*"),
                lambda key, payload, k=k: monitor.on_delta(key, payload, k),
            )
            for k in range(self.count)
        ]

    def publish_prior(self, session, monitor: TeamMonitor) -> int:
        """Send the previous map as ``delta/prior``, each shard its slab's part, and wait until
        the servers and the monitor hold it all; returns its voxels. Raises RoleError."""
        mission = self.mission
        grid, sensor = mission.workspace.grid(), mission.sensor.model()
        delta = prior_delta(grid, sensor, load_previous_map(mission.prior_map_path(), sensor))
        parts = self.layout.split(delta) if self.sharded else {0: delta}
        sent = 0
        for k, part in parts.items():
            prefix, slab = self.prefix(k), self.layout.grid_of(k)
            publisher = bus.reliable_publisher(session, bus.key(prefix, "delta", PRIOR_SOURCE))
            try:
                grant = wait_for_epoch(session, prefix, PRIOR_SOURCE, timeout=60.0)
            except (TimeoutError, EpochRefused) as exc:
                raise RoleError(
                    f"the map server {prefix} issued no epoch for the previous map: {exc}"
                ) from exc
            pieces = chunks(part)
            for seq, piece in enumerate(pieces, start=1):
                msg = DeltaMessage(
                    PRIOR_SOURCE, grant.epoch, seq, 0.0, slab, piece.idx, piece.dlam, piece.deta
                )
                put_delta(publisher, grant, msg.encode())
            sent += len(pieces)
            publisher.undeclare()
        client = self.client(session)
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            applied = int(client.stats().get("deltas_applied", 0))
            if applied >= sent and monitor.applied >= sent:
                return len(delta)
            time.sleep(0.1)
        raise RoleError("the map server did not take the previous map within 60 s (see its log)")

    def store_map(self, monitor: TeamMonitor) -> CoverageMap | None:
        """The team map the stopped servers left in their stores (each ``snapshot.npz``, written
        at its stop; slabs side by side), or None when one is missing or does not read."""
        lam, eta = [], []
        for k in range(self.count):
            path = self.store_of(k) / "snapshot.npz"
            if not path.is_file():
                return None
            try:
                cmap = load_map(path)
            except MapFileError as exc:
                print(f"runner: {exc}", file=sys.stderr, flush=True)
                return None
            if not cmap.grid.matches(self.layout.grid_of(k)):
                return None
            lam.append(cmap.lam)
            eta.append(cmap.eta)
        grid = self.layout.grid
        return CoverageMap(grid, monitor.cmap.sensor, np.concatenate(lam), np.concatenate(eta))
