"""The map server role over Zenoh (``swarm server``; docs/protocol.md), of the whole map or of one
shard's slab (``<mission>`` is then ``<mission>/shard/<k>``: docs/sharding.md, map_server.shard_role).
Subscribes ``swarm/<mission>/delta/*`` and answers ``map/epoch/<rid>`` with the epochs it
issues (map_server.admission, map_server.epochs). Zenoh callbacks only enqueue
(map_server.intake refuses what it can before reading it); one worker thread admits each
payload (epoch, MAC, next seq, information budget), drops duplicates, appends the new ones to
the write-ahead log and fsyncs (a group commit per batch), applies them to the team map exactly
once, and republishes each payload unchanged on ``swarm/<mission>/merged``, numbered
(``swarm.protocol.merged_stream``) and with congestion control DROP: a subscriber that does not
drain loses samples (and catches up from the snapshot) instead of holding the worker. Acks
(``map/acks``) only cover durable deltas. ``map/stats``, ``map/acks``, ``map/snapshot`` and
``map/region`` (streamed: map_server.snapshot_stream) read the map under a lock. The worker
compacts the store past the configured log size; :meth:`MapServer.stop` once more.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import zenoh

from map_server.admission import Admission
from map_server.disk_pause import DiskPause
from map_server.inbox import Inbox
from map_server.intake import DeltaIntake
from map_server.ledger import Rejected, describe_grid
from map_server.limits import mission_bounds
from map_server.options import ServerOptions, max_payload_for
from map_server.query_gate import QueryGate
from map_server.recovery import recover
from map_server.replies import guarded, reply_json
from map_server.shard_role import ShardRole
from map_server.snapshot_stream import HeldStream, MapStreams, StreamCache, held_region, held_snapshot
from map_server.store import Store, StoreError, StoreIdentity
from map_server.store_files import OS_FILES, StoreFiles
from map_server.team_map import merge_kernels, parse_vector, region_of, warm_up_merge
from swarm.compile_progress import compile_progress
from swarm.config import Mission
from swarm.log_limit import LogLimiter
from swarm.protocol import bus
from swarm.protocol.codec import short
from swarm.protocol.merged_stream import MergedNumbering
from swarm.protocol.wire import DeltaMessage

log = logging.getLogger("swarm.server")


class MapServer:
    """Merges deltas into the team map on a Zenoh session; :meth:`start`, then :meth:`stop`."""

    def __init__(
        self,
        mission: Mission,
        store_dir: str | Path,
        mission_name: str | None = None,
        options: ServerOptions | None = None,
        files: StoreFiles = OS_FILES,
        shard: int = 0,
    ) -> None:
        """Open the store and recover the map from it (snapshot, then the log); no Zenoh yet.
        ``files``: the store's file layer (map_server.store_files; a recording one in tests).
        ``shard``: the slab served, its grid and default prefix (map_server.shard_role; ConfigError)."""
        self.role = ShardRole.of(mission, shard)  # which shard of the map service (1: the whole map)
        self.name = mission_name or self.role.prefix
        self.options = options or ServerOptions()
        self.session: zenoh.Session | None = None
        grid, sensor = self.role.grid, mission.sensor.model()
        self.store, recovered = Store.open(
            store_dir, StoreIdentity(self.name, grid, sensor), self.options.fsync, files
        )
        self.store.log_reserve_bytes = self.options.log_reserve_bytes
        #: acks paused while the store cannot write, resumed when it can (map_server.disk_pause)
        self._disk = DiskPause(log)
        try:
            self.team, registry, self.recovered = recover(
                self.store, recovered, grid, sensor, self.options.max_epochs, files
            )
        except StoreError:
            self.store.close()
            raise
        self.bounds = mission_bounds(mission, self.options.burst_s) if self.options.information_bound else {}
        self.max_payload = self.options.max_payload_bytes or max_payload_for(grid)
        self._lock = threading.Lock()
        #: held by a compaction while it writes the map to disk, and by a quarantine while it
        #: rebuilds the map: the one change to the map that does not come from the worker (the
        #: compacting thread), so a compaction needs no more, and queries go on meanwhile
        self._rebuild_lock = threading.Lock()
        self._snapshot_due = threading.Event()  # set by a quarantine: the worker compacts soon
        for robot in self.options.quarantine:
            self.quarantine(robot)
        self._inbox = Inbox(
            self.options.inbox_messages, self.options.inbox_bytes or max(2 * self.max_payload, 16 << 20)
        )
        self._queries = QueryGate(
            self.options.max_queries, self.options.max_queries_per_requester, self.options.query_workers
        )
        #: the streamed map/snapshot and map/region answers held (map_server.snapshot_stream)
        o = self.options
        self.streams = MapStreams(
            StreamCache(
                o.max_streams,
                o.max_streams_per_requester,
                o.max_stream_bytes or max(4 * 8 * grid.size, 64 << 20),
                o.stream_idle_s,
            ),
            o.chunk_bytes,
        )
        #: what a remote peer makes the server log: one line per reason per 10 s, with counts
        self._peer_log = LogLimiter(log)
        #: which deltas are taken (epochs, MACs, seqs, budgets) and the map/epoch answers
        self.admission = Admission(
            self.team,
            self._lock,
            registry,
            robots=frozenset(self.options.robots or mission.robot_ids),
            # a mission with a previous map takes it on delta/prior (no rig: no information bound)
            takes_prior=mission.prior_map is not None,
            robot_pattern=self.options.robot_pattern,
            max_pattern_robots=self.options.max_pattern_robots,
            bounds=self.bounds,
            quarantine_after=self.options.quarantine_after,
            quarantine=self.quarantine,
            peer_log=self._peer_log,
        )
        #: the refusals before the inbox, the queueing and the admission (map_server.intake)
        self.intake = DeltaIntake(
            self.team, self._lock, self.admission, self._inbox, self.max_payload, self._peer_log
        )
        self._stopping = threading.Event()
        self._worker = threading.Thread(target=self._work, name="map-server-worker", daemon=True)
        self._declared: list = []
        self._delta_sub = self._merged_pub = None
        #: the run id and sample numbers of merged (the attachment of every sample)
        self.merged_numbers = MergedNumbering()
        self.merged_put_max_s = 0.0  # the longest a put on merged took (DROP: never a subscriber's wait)
        self.wal_errors, self._started = 0, time.monotonic()
        self._last_log = (self._started, len(self.team.ledger))
        #: map/stats' H_th and end of the mission, as map_server.mission_end decides them
        self.threshold_bits: float | None = None
        self.mission_done: dict | None = None

    # -- lifecycle -----------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> None:
        """Declare the merged publisher, the queryables and the delta subscriber on ``session``;
        start the worker. The merge's compiled kernels are loaded first (said while they compile)."""
        with compile_progress(merge_kernels(), log.info):
            warm_up_merge(self.team.sensor)
        self.session = session
        key = self.key
        self._merged_pub = bus.dropping_publisher(self.session, key("merged"))
        handlers = {
            "stats": guarded(self._on_stats),
            "acks": guarded(self._on_acks),
            # the whole-map answers (16 bytes per voxel each) go through the gate
            "snapshot": self._queries.wrap("snapshot", self._on_snapshot),
            "region": self._queries.wrap("region", self._on_region),
        }
        self._declared += [self.session.declare_queryable(key("map", p), h) for p, h in handlers.items()]
        epochs = bus.key_pattern(self.name, "map", "epoch", "*")
        self._declared.append(self.session.declare_queryable(epochs, guarded(self.admission.on_epoch_query)))
        self._worker.start()
        self._delta_sub = self.session.declare_subscriber(
            bus.key_pattern(self.name, "delta", "*"), self.intake.on_sample
        )
        applied, replayed, torn = self.recovered
        log.info(
            "map server for mission %r: grid %s, store %s: %d deltas from the snapshot, %d replayed "
            "from the log%s; H = %s bits",
            *(self.name, describe_grid(self.team.grid), self.store.path, applied, replayed),
            f", {torn} torn bytes cut" if torn else "",
            f"{self.team.entropy.total:,.0f}",
        )

    def stop(self) -> None:
        """Stop taking deltas, apply what is queued, compact the store and undeclare everything."""
        if self._delta_sub is not None:
            self._delta_sub.undeclare()
            self._delta_sub = None
        self._stopping.set()
        if self._worker.is_alive():
            self._worker.join()
        if self.store.wal_records or self._snapshot_due.is_set():
            self._compact()
        for entity in self._declared:
            entity.undeclare()
        self._declared.clear()
        self._queries.close()
        if self._merged_pub is not None:
            self._merged_pub.undeclare()
            self._merged_pub = None
        self.store.close()
        self._log_progress(force=True)

    def key(self, *parts: str) -> str:
        return bus.key(self.name, *parts)

    # -- deltas --------------------------------------------------------------------------
    def accepts_robot(self, robot: str) -> bool:
        """Whether ``delta/<robot>`` is taken (map_server.admission.Admission.accepts_robot)."""
        return self.admission.accepts_robot(robot)

    def _work(self) -> None:
        while True:
            self._disk.wait_for_retry(self._stopping)
            batch = self._inbox.take(self.options.max_batch, timeout=0.1)
            if self._snapshot_due.is_set() and self._disk.compaction_due():
                self._compact()
            if not batch:
                if self._stopping.is_set():
                    break
                self._log_progress()
                continue
            try:
                self.merge(batch)
            except Exception:  # noqa: BLE001 (the worker must survive anything; merge isolates each delta)
                log.exception("merging a batch of %d deltas failed", len(batch))
            self._log_progress()

    def merge(self, batch: list[tuple[str, bytes, bytes | None]]) -> int:
        """Validate, log durably, apply and republish a batch of (robot, payload, MAC attached);
        returns how many were applied. Each payload is decoded once; a refused one is counted and
        touches nothing else. Called by the worker thread only."""
        admitted: list[tuple[DeltaMessage, bytes]] = []
        for robot, payload, mac in batch:
            msg = self.intake.admit(robot, payload, mac)
            if msg is not None:
                admitted.append((msg, payload))
        if not admitted:
            return 0
        try:
            self.store.append([payload for _, payload in admitted])
        except (OSError, StoreError) as exc:
            self.wal_errors += 1
            self._disk.failed(exc, len(admitted))  # "disk full: acks paused", then a line per 10 s
            with self._lock:
                for msg, _ in admitted:
                    self.admission.release(msg)
            return 0
        self._disk.succeeded()
        applied = []
        for msg, payload in admitted:
            try:
                with self._lock:
                    self.team.apply(msg)
                    self.admission.applied(msg)
                applied.append(payload)
            except Exception as exc:  # noqa: BLE001 (e.g. map_overflow: this delta alone is refused)
                with self._lock:
                    self.admission.release(msg)
                kind = exc.kind if isinstance(exc, Rejected) else "internal_error"
                self.intake.reject(msg.robot, msg, Rejected(kind, str(exc)))
        for payload in applied if self._merged_pub is not None else ():
            try:
                started = time.perf_counter()
                self._merged_pub.put(payload, attachment=self.merged_numbers.next())
                self.merged_put_max_s = max(self.merged_put_max_s, time.perf_counter() - started)
            except Exception:  # noqa: BLE001 (agents also start from the snapshot; keep merging)
                log.exception("republishing a merged delta failed")
        if self.store.should_compact(self.options.compact_bytes, self.options.compact_records) and (
            self._disk.compaction_due()
        ):
            self._compact()
        return len(applied)

    def _compact(self) -> None:
        """Write the snapshot and start the next log: called by the worker, or by :meth:`stop`
        once the worker has ended, so only a quarantine can change the map meanwhile."""
        due = self._snapshot_due.is_set()
        self._snapshot_due.clear()
        t0 = time.perf_counter()
        team = self.team
        with self._rebuild_lock:  # not the query lock: acks and stats answer during the write
            counters = {"updates": dict(team.updates), "ledger": team.ledger.compaction_json()}
            with self._lock:
                counters["epochs"] = self.admission.registry.counters()
            counters["quarantined"] = sorted(team.quarantined)
            try:
                lam, eta, arrays = team.cmap.lam, team.cmap.eta, team.contributions.to_arrays()
                self.store.compact(team.grid, lam, eta, team.ledger.to_json(), counters, arrays)
            except OSError as exc:  # disk full: the old snapshot and log stay in force
                if due:
                    self._snapshot_due.set()
                self._disk.compaction_failed(exc)
                return
        log.info(
            "compacted the store: snapshot of %d deltas in %.0f ms, log generation %d",
            len(team.ledger),
            (time.perf_counter() - t0) * 1e3,
            self.store.generation,
        )

    def quarantine(self, robot: str) -> None:
        """Refuse ``robot``'s further deltas and take its past ones out of the map (thread-safe;
        docs/protocol.md, "Quarantine"). The next compaction makes it durable."""
        with self._rebuild_lock, self._lock:
            if robot in self.team.quarantined and robot not in self.team.contributions.by_robot:
                return
            h_before = self.team.entropy.total
            changed = self.team.quarantine(robot)
            h_after = self.team.entropy.total
        self._snapshot_due.set()  # durable at the worker's next round (or at stop)
        log.warning(
            "quarantined %s: its further deltas are refused%s",
            short(robot, 40),
            f"; its past ones left the map (H {h_before:,.0f} -> {h_after:,.0f} bits)" if changed else "",
        )

    # -- queries -------------------------------------------------------------------------
    def stats(self) -> dict:
        """The ``map/stats`` object (docs/protocol.md)."""
        with self._lock:
            stats = self.team.stats()
        stats |= {
            "mission": self.name,
            "wal_records": self.store.wal_records,
            "wal_bytes": self.store.wal_bytes,
            "wal_generation": self.store.generation,
            "snapshots_written": self.store.snapshots_written,
            "acks_paused": self._disk.paused,
            "store_errors": self._disk.errors,
            "queued": len(self._inbox),
            "inbox": self._inbox.stats(),
            "queries": self._queries.stats(),
            "streams": self.streams.cache.stats(),
            "max_payload_bytes": self.max_payload,
            "uptime_s": round(time.monotonic() - self._started, 3),
            "epochs_issued": self.admission.epochs_issued,
            "breaches": dict(self.admission.breaches),
            "threshold_bits": self.threshold_bits,
            "mission_done": self.mission_done,
            **self.role.stats_fields(),
            "merged": {
                "run": f"{self.merged_numbers.run:016x}",
                "published": self.merged_numbers.number,
                "longest_put_ms": round(self.merged_put_max_s * 1e3, 3),
            },
        }
        return stats

    def _on_stats(self, query: zenoh.Query) -> None:
        # on the server's own key, also to a wildcard query (swarm/*/map/stats, .../shard/*/...):
        # the access rules let a shard reply only under its own prefix (docs/security.md)
        reply_json(query, self.stats(), self.key("map", "stats"))

    def _on_acks(self, query: zenoh.Query) -> None:
        with self._lock:
            acks = self.admission.acks()
        reply_json(query, {r: {str(e): s for e, s in by_epoch.items()} for r, by_epoch in acks.items()})

    def _on_snapshot(self, query: zenoh.Query) -> None:
        self.streams.answer(query, self._snapshot_stream)

    def _snapshot_stream(self, _query: zenoh.Query) -> HeldStream:
        """The stream of a new ``map/snapshot`` answer: a copy of the map, its acks and seqs at
        one point of the ledger (or the held copy of the same map version)."""
        with self._lock:
            version = self.team.version
            held = self.streams.cache.current_snapshot(version)
            if held is not None:
                return held
            snap, deltas = self.team.snapshot(), len(self.team.ledger)
        return held_snapshot(snap, deltas, version, self.streams.chunk_bytes)

    def _on_region(self, query: zenoh.Query) -> None:
        self.streams.answer(query, self._region_stream)

    def _region_stream(self, query: zenoh.Query) -> HeldStream:
        """The stream of a new ``map/region`` answer; ValueError for a bad box."""
        params = query.parameters
        lo = parse_vector(params.get("lo"), "lo")
        hi = parse_vector(params.get("hi"), "hi")
        idx = self.team.region_indices(lo, hi)
        with self._lock:  # only the gather: a flood of large regions cannot hold the worker back
            values = self.team.gather(idx)
        return held_region(region_of(self.team.grid, idx, *values), self.streams.chunk_bytes)

    def _log_progress(self, force: bool = False) -> None:
        """One progress line in the log every ``log_every_s`` when deltas came (always: ``force``)."""
        now = time.monotonic()
        last_t, last_n = self._last_log
        if not force and now - last_t < self.options.log_every_s:
            return
        with self._lock:
            n = len(self.team.ledger)
            if n == last_n and not force:
                self._last_log = (now, n)
                return
            team = self.team
            h, h0 = team.entropy.total, team.initial_entropy_bits
            msg = (
                f"{n} deltas applied (+{(n - last_n) / max(now - last_t, 1e-9):.1f}/s), "
                f"{sum(team.updates.values()):,} voxel updates, H = {h:,.0f} bits ({100 * h / h0:.1f}% of "
                f"the prior), known {team.known / team.grid.size:.1%}, {team.duplicates} duplicates, "
                f"{sum(team.rejected.values())} rejected, log {self.store.wal_records} records"
            )
        self._last_log = (now, n)
        log.info(msg)
