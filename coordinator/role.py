"""The coordinator role (``swarm coordinator``): entropy targets for the team, spread out.

It keeps a replica of the team map from the map server's ``merged`` stream (starting from
``map/snapshot`` when a server answers), follows every robot's ``robot/<rid>/status``, and
answers ``coord/assign/<rid>``: the requesting robot gets the eq. 35 target of the team map that
maximises utility minus path cost, with the targets other robots hold discounted and kept
one sensor footprint away, and its teammates' ground lowered (Burgard et al.
2005 and our addition; the rule is in ``coordinator.assignment`` and docs/coordinator.md).
When the only eq. 35 targets are held by others it wanders the robot on its own ground, as
long as anything unknown is in view; when the team map has none at all it answers "nothing
left", and the agent chooses alone (its own eq. 35, then its 3-D frontier views).

Layers: :class:`CoordinatorReplica` (the replica: ``swarm.protocol.team_replica``, plus attribution),
:class:`CoordinatorState` (the replica, who holds what, and the planning of one answer; no
I/O, callable from tests) and :class:`Coordinator` (the Zenoh side: one worker thread applies
merged deltas and statuses in arrival order, one thread answers queries one at a time, the
latest of each robot in turn: a :class:`swarm.protocol.mailbox.Mailbox` of requests). An agent asks with
:func:`swarm.protocol.coord_client.ask_for_target`.
"""

from __future__ import annotations

import functools
import json
import logging
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Callable

import zenoh

from coordinator.answer_report import ANSWER_TIMES_KEPT, answer_time_summary, log_answer
from coordinator.assignment import CoordinationParams
from coordinator.defaults import SNAPSHOT_TIMEOUT_S
from coordinator.state import CoordinatorState
from swarm.compile_progress import compile_progress
from swarm.config import Mission
from swarm.log_limit import LogLimiter
from swarm.navigation import planner
from swarm.protocol import bus, replies
from swarm.protocol.byte_budget import MAX_QUEUED_MERGED_BYTES, ByteBudget
from swarm.protocol.codec import short
from swarm.protocol.mailbox import Mailbox
from swarm.protocol.map_client import MapClient, MapQueryError
from swarm.protocol.wire import AssignRequest, Snapshot, WireError

log = logging.getLogger("coordinator")

#: Robots whose latest request (an older one is refused as superseded), or whose newest status,
#: may wait at once, served in the order they first came; more are refused (busy) or dropped.
MAX_WAITING_ROBOTS = MAX_WAITING_STATUSES = 256

#: The largest ``coord/assign`` payload read (a request is about 100 bytes; up to 256 robots'
#: requests wait at once, each holding its payload).
MAX_REQUEST_BYTES = 64 << 10


# ---------------------------------------------------------------------------------------
# The Zenoh role
# ---------------------------------------------------------------------------------------
class Coordinator:
    """The coordinator on a Zenoh session: ``start()``, then ``stop()`` (or ``wait()``).

    ``mission_name`` overrides the mission's name in the keys (``swarm/<mission>/...``);
    ``clock`` gives seconds (monotonic) for liveness.
    """

    def __init__(
        self,
        mission: Mission,
        session: zenoh.Session,
        params: CoordinationParams | None = None,
        *,
        mission_name: str | None = None,
        snapshot_timeout: float = SNAPSHOT_TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
        max_queued_merged_bytes: int = MAX_QUEUED_MERGED_BYTES,
    ) -> None:
        self.state = CoordinatorState(mission, params)
        self.session = session
        self.name = mission_name or mission.mission
        self.snapshot_timeout = snapshot_timeout
        self.clock = clock
        self.started_from_snapshot = False
        self._inbox: queue.Queue = queue.Queue()
        #: the latest status payload of each status key not handled yet: a status says where a
        #: robot is now, so a newer one replaces it, and a robot publishing statuses in a loop
        #: costs the worker one status per round, not a backlog that holds merged deltas back
        self._statuses: Mailbox[str, bytes] = Mailbox(MAX_WAITING_STATUSES)
        self._refused: Counter[str] = Counter()  # refused stream messages by kind, for the log
        #: what a remote peer makes the coordinator log: one line per reason per 10 s, with counts
        self._peer_log = LogLimiter(log)
        #: the replica queues merged payloads within its byte budget (anyone on an open bus can
        #: put on merged faster than the worker applies) and catches up when it misses one
        team = self.state.team
        team.budget = ByteBudget(max_queued_merged_bytes)
        for feed in team.feeds:  # one per map server shard (docs/sharding.md)
            feed.fetch = functools.partial(self._fetch_snapshot, feed.shard)
        team.peer_log = self._peer_log
        #: waiting coord/assign queries and their requests, the latest of each robot
        self._requests: Mailbox[str, tuple[zenoh.Query, AssignRequest]] = Mailbox(MAX_WAITING_ROBOTS)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._declared: list = []
        #: milliseconds each ``coord/assign`` took, from when the answering thread took it to its reply
        self.answer_ms: deque[float] = deque(maxlen=ANSWER_TIMES_KEPT)
        self._answer_ms_lock = threading.Lock()  # appended by the answering thread, read by coord/stats

    @property
    def counts(self) -> Counter[str]:
        """Every counter: requests, merged deltas (``merged_*``), statuses, releases."""
        out = Counter(self.state.counts)
        out.update({f"merged_{k}": v for k, v in self.state.team.counts.items()})
        out["merged_queued_bytes_high_water"] = self.state.team.budget.high_water
        return out

    def start(self) -> None:
        """Subscribe, load a snapshot if a map server answers, and start answering."""
        name, s = self.name, self.session
        # subscribe before the snapshot so no merged delta falls between the two
        for k in range(self._shards):
            merged = bus.key(bus.shard_mission(name, k, self._shards), "merged")
            self._declared.append(s.declare_subscriber(merged, functools.partial(self._on_merged, shard=k)))
        self._declared.append(
            bus.subscribe(s, bus.key_pattern(name, "robot", "*", "status"), self._on_status)
        )
        self._load_snapshot()
        # Load the compiled navigation kernels (Numba's cache) now: on the first request they
        # took over a second on a loaded machine, past the robots' answer timeout.
        with compile_progress(planner.warm_up_kernels(), log.info):
            planner.warm_up()
        self._threads = [
            threading.Thread(target=self._work, name="coordinator-map", daemon=True),
            threading.Thread(target=self._answer_queries, name="coordinator-assign", daemon=True),
        ]
        for t in self._threads:
            t.start()
        # one key per robot: on a secured bus agent-rN may query only coord/assign/rN
        assign = bus.key_pattern(name, "coord", "assign", "*")
        self._declared.append(s.declare_queryable(assign, self._on_assign))
        self._declared.append(s.declare_queryable(bus.key(name, "coord", "stats"), self._on_stats))
        p = self.state.params
        log.info(
            "coordinator for mission %s: footprint %.2f m, beta %.3f/m, robot timeout %.1f s, map %s",
            name,
            p.footprint_radius,
            p.beta,
            p.robot_timeout_s,
            "from a snapshot" if self.started_from_snapshot else "from the prior",
        )

    @property
    def _shards(self) -> int:
        return len(self.state.team.feeds)

    def _fetch_snapshot(self, shard: int = 0) -> Snapshot:
        """The map server's (shard ``shard``'s) snapshot, streamed in chunks through ``MapClient``
        (which asks again while the server answers "busy" and each window within
        ``snapshot_timeout``). Raises ConnectionError when none answers, ValueError for an error
        reply or a bad snapshot."""
        server = bus.shard_mission(self.name, shard, self._shards)
        client = MapClient(self.session, server, timeout=self.snapshot_timeout)
        try:
            return client.snapshot()
        except MapQueryError as exc:
            raise ValueError(str(exc)) from exc

    def _load_snapshot(self) -> None:
        """Start the replica from the map server's snapshot when one answers (else the prior);
        sharded, each shard's slab from that shard's snapshot."""
        for k in range(self._shards):
            try:
                self.state.team.load_snapshot(self._fetch_snapshot(k), shard=k)
                self.started_from_snapshot = True
            except ConnectionError:
                pass
            except (zenoh.ZError, ValueError, replies.ConflictingReplies) as exc:  # WireError: a ValueError
                log.warning("no usable map snapshot (%s); starting from the prior", exc)

    def _on_merged(self, sample: zenoh.Sample, shard: int = 0) -> None:
        """Zenoh's callback: the replica queues the payload (or drops it, counted
        ``merged_dropped``, and catches up later); the worker is woken to apply it."""
        self.state.team.on_sample(sample, shard)
        self._inbox.put(("merged", None))

    def _on_status(self, key: str, payload: bytes) -> None:
        posted = self._statuses.put(key, payload)
        if posted.replaced is not None:
            self.state.counts["status_superseded"] += 1
        elif not posted.accepted:
            self.state.counts["status_dropped"] += 1
            self._peer_log.warning(
                "status_dropped", "status dropped: %d robots' statuses wait", len(self._statuses)
            )
        if posted.first:  # one wake-up in the inbox for the statuses waiting
            self._inbox.put(("statuses", None))

    def _work(self) -> None:
        """The one thread that changes the replica and the book from the streams, in order
        (the statuses waiting at a wake-up together, the latest of each robot)."""
        last_expiry = self.clock()
        while not self._stop.is_set():
            try:
                kind, payload = self._inbox.get(timeout=0.2)
            except queue.Empty:
                kind = None
            now = self.clock()
            if kind == "merged":
                self._handle("merged", self.state.team.drain)
            elif kind == "statuses":
                for key, status in self._statuses.take_all().items():
                    self._handle("status", self.state.on_status, status, now, key)
            if now - last_expiry >= 0.5:
                last_expiry = now
                self._handle("expiry", self.state.expire, now)

    def _handle(self, kind: str, handler: Callable, *args) -> None:
        """Run one message's ``handler``: a refused message is logged (the first ten of a kind,
        then every thousandth), any other failure counted, and the worker goes on. The targets a
        status or an expiry released are logged."""
        try:
            result = handler(*args)
        except WireError as exc:
            self._refused[kind] += 1
            count = self._refused[kind]
            self._peer_log.warning(f"rejected:{kind}", "rejected %s message (#%d): %s", kind, count, exc)
            return
        except Exception:  # never die of one message
            self.state.counts["worker_errors"] += 1
            self._peer_log.exception(f"failed:{kind}", "error handling a %s message", kind)
            return
        for robot, reason in result if kind != "merged" else ():
            log.info("released the target of %s: %s", robot, reason)

    def _on_assign(self, query: zenoh.Query) -> None:
        """Zenoh's callback: decode the request, refuse at once a malformed one or one whose robot
        is not its key's ``<rid>``, else queue it as its robot's latest (an older one of that
        robot is refused as superseded). Never raises."""
        started = time.perf_counter()
        try:
            size = 0 if query.payload is None else len(query.payload)
            if size > MAX_REQUEST_BYTES:  # refused before it is copied or decoded
                self.state.counts["requests"] += 1
                self.state.counts["requests_rejected"] += 1
                self._refuse(
                    query, started, f"request of {size:,} bytes over the maximum {MAX_REQUEST_BYTES:,}"
                )
                return
            payload = b"" if query.payload is None else query.payload.to_bytes()
            try:
                request = self.state.decode_request(str(query.key_expr), payload)
            except WireError as exc:
                count = self.state.counts["requests_rejected"]
                self._peer_log.warning("assign_rejected", "rejected assign request (#%d): %s", count, exc)
                self._refuse(query, started, str(exc))
                return
            posted = self._requests.put(request.robot, (query, request))
            if posted.replaced is not None:
                self.state.counts["requests_superseded"] += 1
                self._refuse(
                    posted.replaced[0],
                    started,
                    f"superseded by a newer request of {short(request.robot, 40)}",
                )
            if not posted.accepted:
                self.state.counts["requests_busy"] += 1
                waiting = self._requests.max_keys
                self._refuse(query, started, f"busy: {waiting} robots are waiting for an answer; ask again")
        except Exception:  # noqa: BLE001 (a callback must never raise into Zenoh)
            self._peer_log.exception("assign_callback", "coord/assign callback failed")

    def _refuse(self, query: zenoh.Query, started: float, reason: str) -> None:
        """An error reply ``coord/assign: <reason>``, timed like an answer."""
        self._timed(started)
        try:
            query.reply_err(f"coord/assign: {reason}".encode())
        finally:
            query.drop()

    def _answer_queries(self) -> None:
        while not self._stop.is_set():
            waiting = self._requests.take(timeout=0.2)
            if waiting is None:
                continue
            _robot, (query, request) = waiting
            try:
                self._answer(query, request, time.perf_counter())
            finally:
                query.drop()
        for query, _request in self._requests.take_all().values():
            self._refuse(query, time.perf_counter(), "the coordinator is stopping")

    def _timed(self, started: float) -> None:
        """Record one answer's time, before its reply goes out (so coord/stats already counts it)."""
        with self._answer_ms_lock:
            self.answer_ms.append(1e3 * (time.perf_counter() - started))

    def stats(self) -> dict:
        """The ``coord/stats`` object: answer times (ms) and every counter (docs/protocol.md)."""
        with self._answer_ms_lock:
            times = list(self.answer_ms)
        return {"answer_ms": answer_time_summary(times), "counts": dict(self.counts)}

    def _on_stats(self, query: zenoh.Query) -> None:
        try:
            text = json.dumps(self.stats(), allow_nan=False)
            query.reply(query.key_expr, text.encode(), encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as exc:  # never die of one query
            self._peer_log.exception("stats_failed", "coord/stats failed")
            query.reply_err(f"coord/stats: {exc}".encode())

    def _answer(self, query: zenoh.Query, request: AssignRequest, started: float) -> None:
        try:
            answer = self.state.answer_request(request, self.clock())
        except WireError as exc:
            count = self.state.counts["requests_rejected"]
            self._peer_log.warning("assign_rejected", "rejected assign request (#%d): %s", count, exc)
            self._timed(started)
            query.reply_err(f"coord/assign: {exc}".encode())
            return
        except Exception as exc:  # never die of one request
            self.state.counts["requests_failed"] += 1
            self._peer_log.exception("assign_failed", "assign request failed")
            self._timed(started)
            query.reply_err(f"coord/assign: internal error: {short(exc)}".encode())
            return
        reply = answer.reply.encode()
        self._timed(started)
        query.reply(query.key_expr, reply)
        log_answer(answer)

    def stop(self) -> None:
        """Stop answering and join the threads (the session stays open: the caller owns it)."""
        self._stop.set()
        for declared in self._declared:
            try:
                declared.undeclare()
            except zenoh.ZError:
                pass
        self._declared = []
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads = []

    def request_stop(self) -> None:
        """Make ``wait()`` return (safe from a signal handler); ``stop()`` then cleans up."""
        self._stop.set()

    def wait(self) -> None:
        """Block until ``stop()`` or ``request_stop()`` is called."""
        while not self._stop.wait(0.5):
            pass
