"""The team's entropy across a sharded map service, as shard 0 sees it (docs/sharding.md).

When the map service has ``N > 1`` shards, shard 0 decides the end of the mission
(map_server.mission_end) on the team map's entropy, which is the sum of every shard's
(each holds its own slab; entropy is a sum over voxels, paper eq. 31). :class:`ShardPeers`
asks every other shard's ``map/stats`` (``swarm.protocol.map_client.MapClient`` under the
shard's prefix) at most every ``every_s`` s, from a thread of its own so that a shard that
does not answer never holds the server's loop, and keeps the last answer of each.

A shard whose last ask got no answer (or an answer that is not a shard of this layout: its
``voxels`` differ from the slab's) is *unknown*: :meth:`ShardPeers.team_stats` lists it in
``shards_unknown``, and no threshold end is decided while that list is not empty. Its
entropy in the sum is then its last known one, else its slab's prior entropy (an upper
bound: fusion only takes entropy away), so the figure reported stays finite.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import zenoh

from map_server.shard_role import ShardRole
from swarm.map.coverage_map import prior_entropy_bits
from swarm.map.sensor_model import SensorModel
from swarm.protocol.map_client import MapClient, MapQueryError, MapServerUnavailable

log = logging.getLogger("swarm.server")

#: Seconds between two rounds of asks (the brief's "every check, at most every ~1 s").
EVERY_S = 1.0
#: Seconds one shard has to answer one ask.
ASK_TIMEOUT_S = 1.0


class ShardPeers:
    """The other shards of ``role``'s map service, their last ``map/stats`` (see the module doc)."""

    def __init__(
        self,
        session: zenoh.Session,
        role: ShardRole,
        sensor: SensorModel,
        timeout: float = ASK_TIMEOUT_S,
        every_s: float = EVERY_S,
    ) -> None:
        self.role = role
        self.every_s = float(every_s)
        self.peers = [k for k in range(role.count) if k != role.shard]
        self._clients = {k: MapClient(session, role.prefix_of(k), timeout) for k in self.peers}
        #: each slab's prior entropy (bits): a shard's figure before it ever answered
        self._prior = {k: prior_entropy_bits(role.layout.grid_of(k), sensor) for k in self.peers}
        self._last: dict[int, dict] = {}  # shard -> its last good answer
        self._unknown: set[int] = set(self.peers)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- asking --------------------------------------------------------------------------
    def poll(self) -> list[int]:
        """Ask every other shard's ``map/stats`` once now (blocks up to ``timeout`` per shard
        that does not answer); returns the shards unknown after it."""
        for k in self.peers:
            stats, why = self._ask(k)
            with self._lock:
                was_unknown = k in self._unknown
                if stats is None:
                    self._unknown.add(k)
                else:
                    self._last[k] = stats
                    self._unknown.discard(k)
            if stats is None and not was_unknown:
                log.warning(
                    "shard %d (%s) is unknown: %s; no threshold end until it answers",
                    k,
                    self.role.prefix_of(k),
                    why,
                )
            elif stats is not None and was_unknown:
                log.info(
                    "shard %d (%s) answers: H = %s bits",
                    k,
                    self.role.prefix_of(k),
                    f"{stats['entropy_bits']:,.0f}",
                )
        with self._lock:
            return sorted(self._unknown)

    def _ask(self, k: int) -> tuple[dict | None, str]:
        """(shard ``k``'s stats, "") or (None, why not)."""
        try:
            stats = self._clients[k].stats()
        except (MapServerUnavailable, MapQueryError) as exc:
            return None, str(exc)
        if not isinstance(stats, dict):
            return None, "its map/stats is not an object"
        entropy, voxels = stats.get("entropy_bits"), stats.get("voxels")
        if not isinstance(entropy, int | float) or isinstance(entropy, bool) or not math.isfinite(entropy):
            return None, f"its map/stats has no finite entropy_bits ({str(entropy)[:40]})"
        size = self.role.layout.grid_of(k).size
        if voxels != size:
            return (
                None,
                f"it serves {str(voxels)[:20]} voxels, not the {size:,} of slab {k} (another layout?)",
            )
        return stats, ""

    def start(self) -> None:
        """Ask every ``every_s`` s from a daemon thread until :meth:`close`."""
        if self._thread is None and self.peers:
            self._thread = threading.Thread(target=self._run, name="shard-peers", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            try:
                self.poll()
            except Exception:  # noqa: BLE001 (the asks must go on: a failure leaves shards unknown)
                log.exception("asking the other shards' map/stats failed")
            self._stop.wait(max(self.every_s - (time.monotonic() - started), 0.05))

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    # -- the team ------------------------------------------------------------------------
    def team_stats(self, own: dict) -> dict:
        """The fields :meth:`~map_server.mission_end.MissionEnd.check` reads, for the whole team,
        from this shard's ``map/stats`` ``own`` and the peers' last answers: ``entropy_bits``
        (bits, summed), ``known_fraction`` (over every voxel), ``deltas_applied`` (summed),
        ``shards`` (N) and ``shards_unknown`` (shard numbers whose figures are not current)."""
        with self._lock:
            last, unknown = dict(self._last), sorted(self._unknown)
        entropy = float(own.get("entropy_bits", math.inf))
        voxels = int(own.get("voxels", self.role.grid.size))
        known = float(own.get("known_fraction", 0.0)) * voxels
        deltas = int(own.get("deltas_applied", 0))
        for k in self.peers:
            stats = last.get(k)
            size = self.role.layout.grid_of(k).size
            if stats is None:
                entropy += self._prior[k]
            else:
                entropy += float(stats["entropy_bits"])
                known += float(stats.get("known_fraction", 0.0)) * size
                deltas += int(stats.get("deltas_applied", 0))
            voxels += size
        return {
            "entropy_bits": entropy,
            "known_fraction": known / voxels if voxels else 0.0,
            "deltas_applied": deltas,
            "shards": self.role.count,
            "shards_unknown": unknown,
        }
