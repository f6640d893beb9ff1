"""The map server role over Zenoh (``swarm server``; DESIGN.md sections 4-5, docs/protocol.md).

Subscribes ``swarm/<mission>/delta/*``. Zenoh callbacks only enqueue; one worker thread
validates each payload, drops duplicates, appends the new ones to the write-ahead log and
fsyncs (a group commit per batch), applies them to the team map exactly once, and
republishes each payload unchanged on ``swarm/<mission>/merged``. The acks of
``map/acks`` therefore only ever cover durable deltas. Queryables ``map/stats``,
``map/acks``, ``map/snapshot`` and ``map/region`` read the map under a lock, so they never
see a half-applied delta. The worker compacts the store when its log grows past the
configured size, and :meth:`MapServer.stop` drains the queue and compacts once more.
"""

from __future__ import annotations

import json
import logging
import queue
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import zenoh

from map_server.ledger import Ledger, Rejected, describe_grid, validate_delta
from map_server.store import Store, StoreError, StoreIdentity
from map_server.team_map import TeamMap, parse_vector
from swarm.config import Mission
from swarm.protocol import bus
from swarm.protocol.wire import DeltaMessage

log = logging.getLogger("swarm.server")


@dataclass(frozen=True)
class ServerOptions:
    """Tuning of the server: compaction thresholds, group-commit size, progress interval."""

    compact_bytes: int = 256 << 20
    compact_records: int = 20_000
    max_batch: int = 64
    log_every_s: float = 10.0
    fsync: bool = True


class MapServer:
    """Merges deltas into the team map on a Zenoh session; :meth:`start`, then :meth:`stop`."""

    def __init__(
        self,
        mission: Mission,
        store_dir: str | Path,
        mission_name: str | None = None,
        options: ServerOptions | None = None,
    ) -> None:
        """Open the store and recover the map from it (snapshot, then the log); no Zenoh yet."""
        self.name = mission_name or mission.mission
        self.options = options or ServerOptions()
        self.session: zenoh.Session | None = None
        grid, sensor = mission.workspace.grid(), mission.sensor.model()
        self.store, recovered = Store.open(
            store_dir, StoreIdentity(self.name, grid, sensor), fsync=self.options.fsync
        )
        ledger = Ledger.from_json(recovered.ledger_json)
        self.team = TeamMap(grid, sensor, recovered.lam, recovered.eta, ledger)
        self.team.updates.update(recovered.counters.get("updates", {}))
        from_snapshot = len(self.team.ledger)
        for payload in recovered.wal_payloads:
            try:
                msg = validate_delta(payload, grid)
            except Rejected as exc:
                log.warning("WAL record refused on replay (%s): %s", exc.kind, exc)
                continue
            if self.team.admit(msg):
                self.team.apply(msg)
        self.team.duplicates = 0
        self.recovered = (from_snapshot, len(self.team.ledger) - from_snapshot, recovered.torn_bytes)
        self._lock = threading.Lock()
        self._inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self._stopping = threading.Event()
        self._worker = threading.Thread(target=self._work, name="map-server-worker", daemon=True)
        self._declared: list = []
        self._delta_sub = None
        self._merged_pub = None
        self.wal_errors = 0
        self._started = time.monotonic()
        self._last_log = (time.monotonic(), len(self.team.ledger))

    # -- lifecycle -----------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> None:
        """Declare the merged publisher, the queryables and the delta subscriber on ``session``;
        start the worker."""
        self.session = session
        key = self.key
        self._merged_pub = bus.reliable_publisher(self.session, key("merged"))
        handlers = {
            "stats": self._on_stats,
            "acks": self._on_acks,
            "snapshot": self._on_snapshot,
            "region": self._on_region,
        }
        for part, handler in handlers.items():
            self._declared.append(self.session.declare_queryable(key("map", part), _guarded(handler)))
        self._worker.start()
        self._delta_sub = bus.subscribe(
            self.session, bus.key_pattern(self.name, "delta", "*"), self._on_delta
        )
        applied, replayed, torn = self.recovered
        log.info(
            "map server for mission %r: grid %s, store %s: %d deltas from the snapshot, %d replayed "
            "from the log%s; H = %s bits",
            self.name,
            describe_grid(self.team.grid),
            self.store.path,
            applied,
            replayed,
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
        if self.store.wal_records:
            self._compact()
        for entity in self._declared:
            entity.undeclare()
        self._declared.clear()
        if self._merged_pub is not None:
            self._merged_pub.undeclare()
            self._merged_pub = None
        self.store.close()
        self._log_progress(force=True)

    def key(self, *parts: str) -> str:
        return bus.key(self.name, *parts)

    # -- deltas --------------------------------------------------------------------------
    def _on_delta(self, key_expr: str, payload: bytes) -> None:
        self._inbox.put((key_expr.rsplit("/", 1)[-1], payload))

    def _work(self) -> None:
        while True:
            try:
                first = self._inbox.get(timeout=0.1)
            except queue.Empty:
                if self._stopping.is_set():
                    break
                self._log_progress()
                continue
            batch = [first]
            while len(batch) < self.options.max_batch:
                try:
                    batch.append(self._inbox.get_nowait())
                except queue.Empty:
                    break
            try:
                self.merge(batch)
            except Exception:  # noqa: BLE001 (the worker must survive any one bad batch)
                log.exception("merging a batch of %d deltas failed", len(batch))
            self._log_progress()

    def merge(self, batch: list[tuple[str, bytes]]) -> int:
        """Validate, log durably, apply and republish a batch of (robot, payload); returns how many
        were new. Called by the worker thread only."""
        admitted: list[tuple[DeltaMessage, bytes]] = []
        for robot, payload in batch:
            try:
                msg = validate_delta(payload, self.team.grid, robot)
            except Rejected as exc:
                with self._lock:
                    count = self.team.count_rejected(exc.kind)
                if count <= 10 or count % 1000 == 0:
                    log.warning("rejected delta on delta/%s (%s, #%d): %s", robot, exc.kind, count, exc)
                continue
            with self._lock:
                new = self.team.admit(msg)
            if new:
                admitted.append((msg, payload))
        if not admitted:
            return 0
        try:
            self.store.append([payload for _, payload in admitted])
        except (OSError, StoreError) as exc:
            self.wal_errors += 1
            log.error(
                "write-ahead log append failed, %d deltas not applied (their senders will resend): %s",
                len(admitted),
                exc,
            )
            with self._lock:
                for msg, _ in admitted:
                    self.team.release(msg)
            return 0
        with self._lock:
            for msg, _ in admitted:
                self.team.apply(msg)
        for _, payload in admitted:
            self._merged_pub.put(payload)
        if self.store.should_compact(self.options.compact_bytes, self.options.compact_records):
            self._compact()
        return len(admitted)

    def _compact(self) -> None:
        t0 = time.perf_counter()
        team = self.team  # only this thread (or stop(), after it) changes the map: no lock needed
        self.store.compact(
            team.grid, team.cmap.lam, team.cmap.eta, team.ledger.to_json(), {"updates": dict(team.updates)}
        )
        log.info(
            "compacted the store: snapshot of %d deltas in %.0f ms, log generation %d",
            len(team.ledger),
            (time.perf_counter() - t0) * 1e3,
            self.store.generation,
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
            "queued": self._inbox.qsize(),
            "uptime_s": round(time.monotonic() - self._started, 3),
        }
        return stats

    def _on_stats(self, query: zenoh.Query) -> None:
        _reply_json(query, self.stats())

    def _on_acks(self, query: zenoh.Query) -> None:
        with self._lock:
            acks = self.team.acks()
        _reply_json(query, {r: {str(e): s for e, s in by_epoch.items()} for r, by_epoch in acks.items()})

    def _on_snapshot(self, query: zenoh.Query) -> None:
        with self._lock:
            snap = self.team.snapshot()
        query.reply(query.key_expr, snap.encode())

    def _on_region(self, query: zenoh.Query) -> None:
        params = query.parameters
        try:
            lo = parse_vector(params.get("lo"), "lo")
            hi = parse_vector(params.get("hi"), "hi")
            with self._lock:
                region = self.team.region(lo, hi)
        except ValueError as exc:
            query.reply_err(f"map/region: {exc}".encode())
            return
        query.reply(query.key_expr, region.encode())

    # -- progress ------------------------------------------------------------------------
    def _log_progress(self, force: bool = False) -> None:
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


def _guarded(handler):
    """A queryable callback that answers an error instead of raising into Zenoh."""

    def callback(query: zenoh.Query) -> None:
        try:
            handler(query)
        except Exception as exc:  # noqa: BLE001 (one bad query must not take the server down)
            log.exception("query %s failed", query.selector)
            try:
                query.reply_err(f"{query.key_expr}: server error: {exc}".encode())
            except zenoh.ZError:
                pass

    return callback


def _reply_json(query: zenoh.Query, obj: dict) -> None:
    query.reply(query.key_expr, json.dumps(obj).encode(), encoding=zenoh.Encoding.APPLICATION_JSON)


# -- the process ---------------------------------------------------------------------------


def serve(
    mission: Mission,
    listen: list[str],
    store_dir: Path,
    mission_name: str | None = None,
    options: ServerOptions | None = None,
    connect: list[str] | None = None,
) -> None:
    """Run the server until SIGTERM/SIGINT: recover the store, listen, merge; compact on exit."""
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        server = MapServer(mission, store_dir, mission_name, options)
        try:
            session = bus.open_session(listen=listen, connect=connect or [])
        except BaseException:
            server.store.close()
            raise
        try:
            server.start(session)
            log.info("listening on %s", ", ".join(listen))
            while not stop.wait(0.5):
                pass
            log.info("stopping: applying queued deltas and compacting the store")
        finally:
            server.stop()
            session.close()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
