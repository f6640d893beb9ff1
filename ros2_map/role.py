"""The team map as ROS 2 topics over rmw_zenoh: a client of the mission's bus, like ``swarm view``.

:class:`TeamMapTopics` subscribes to ``<mission>/merged`` and starts from ``map/snapshot`` (the
deltas the snapshot holds count as applied), so it never slows the map server: it reads only
what every replica reads, and the server never waits for it. On the ROS side it is one node
(default ``/swarm_team_map``) with three publishers (``swarm.ros2.node``: liveliness tokens, CDR,
attachments):

* ``map`` (``nav_msgs/OccupancyGrid``), latched (reliable, TRANSIENT_LOCAL, keep last 1: the QoS
  of Nav2's map_server, so a late joiner gets the latest grid);
* ``map_updates`` (``map_msgs/OccupancyGridUpdate``), reliable, volatile, keep last 10 (what
  RViz's map display and Nav2's static layer subscribe to beside the grid);
* ``team_map_cloud`` (``sensor_msgs/PointCloud2`` of the occupied voxels), latched.

What goes out when is :mod:`ros2_map.outputs`. Zenoh's callbacks only queue merged payloads
(at most ``max_queued_bytes`` waiting, larger ones than a whole-map delta refused at once); one
worker thread applies them (:class:`ros2_map.replica.FollowedMap` refuses bad ones, counted),
and publishes what is due. When the queue is full a payload is dropped, or when the numbers of
the merged stream skip one (``swarm.protocol.merged_stream``: the server drops samples for a
subscriber that does not keep up), the replica misses a delta: the worker starts again from a
fresh snapshot (at most one per ``RESYNC_INTERVAL_S``: each costs the server a whole-map query).
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import Counter

import zenoh

from ros2_map.options import Ros2MapOptions
from ros2_map.outputs import MapOutputs
from ros2_map.replica import FollowedMap
from swarm.log_limit import LogLimiter
from swarm.protocol import bus
from swarm.protocol.byte_budget import MAX_QUEUED_MERGED_BYTES, ByteBudget
from swarm.protocol.map_client import MapClient, MapQueryError, MapServerUnavailable, sensor_from_stats
from swarm.protocol.merged_stream import StreamPosition
from swarm.protocol.message_size import delta_bytes
from swarm.protocol.sharded_client import unsharded_only
from swarm.protocol.wire import WireError
from swarm.ros2.graph import LATCHED_QOS, Qos
from swarm.ros2.map_messages import OCCUPANCY_GRID, OCCUPANCY_GRID_UPDATE, POINT_CLOUD2, register_map_msgs
from swarm.ros2.node import Ros2Context, Ros2Publisher

log = logging.getLogger("ros2_map")

#: map_updates: rclcpp's default (reliable, volatile, keep last 10)
UPDATES_QOS = Qos()
#: The message type of each kind of output, and the name it is counted under.
TYPES = {"full": OCCUPANCY_GRID, "update": OCCUPANCY_GRID_UPDATE, "cloud": POINT_CLOUD2}
COUNTED = {"full": "grids_full", "update": "grid_updates", "cloud": "clouds"}
#: Seconds at least between two fresh snapshots after dropped deltas (each costs the server a
#: whole-map query), and at most spent applying queued deltas before the topics' turn.
RESYNC_INTERVAL_S = 10.0
DRAIN_S = 0.25
#: Seconds to wait for the map server's first snapshot.
SNAPSHOT_TIMEOUT_S = 30.0


class TeamMapTopics:
    """The team map of ``mission`` (read on ``session``) published on ``ros_session`` (default
    the same session; it must timestamp its samples: ``swarm.ros2.session``) as ROS 2 topics:
    ``start()``, then ``stop()``.

    ``counts``: merged deltas (``merged_*``, as :class:`FollowedMap` counts them, plus
    ``merged_dropped``, ``merged_too_large``), messages sent (``grids_full``, ``grid_updates``,
    ``clouds``) and their bytes (``*_bytes``), ``resyncs``; ``last_ms``: the time the worker spent
    building and publishing the last message of each kind.
    """

    def __init__(
        self,
        session: zenoh.Session,
        mission: str,
        options: Ros2MapOptions | None = None,
        ros_session: zenoh.Session | None = None,
        *,
        snapshot_timeout: float = SNAPSHOT_TIMEOUT_S,
        max_queued_bytes: int = MAX_QUEUED_MERGED_BYTES,
    ) -> None:
        self.session = session
        self.mission = mission
        self.options = options or Ros2MapOptions()
        self.context = Ros2Context(ros_session or session, self.options.domain_id, self.options.distro)
        self.snapshot_timeout = snapshot_timeout
        self.budget = ByteBudget(max_queued_bytes)
        self.counts: Counter[str] = Counter()
        self.last_ms: dict[str, float] = {}
        self.outputs: MapOutputs | None = None
        self.publishers: dict[str, Ros2Publisher] = {}  # by kind: "full", "update", "cloud"
        self._max_payload = 0  # set from the snapshot's grid
        self._last_snapshot = -math.inf
        self._inbox: queue.Queue = queue.Queue()
        self._resync = threading.Event()
        self.stream = StreamPosition()  # where this subscriber is in the numbered merged stream
        self._stop = threading.Event()
        self._worker: threading.Thread | None = None
        self._subscriber = None
        self._node = None
        self._peer_log = LogLimiter(log)

    # -- life cycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Subscribe, declare the node and its publishers, load the snapshot, start the worker.

        Raises ConnectionError when no map server of the mission answers within
        ``snapshot_timeout``; ValueError when the options' band misses every map layer, or when
        the ROS 2 session does not timestamp its samples.
        """
        # subscribe before the snapshot so that no merged delta falls between the two
        self._subscriber = self.session.declare_subscriber(bus.key(self.mission, "merged"), self._on_sample)
        options, types = self.options, self.context.types
        self._node = node = self.context.node(options.node_name, options.namespace)
        try:
            if options.grid:
                register_map_msgs(types)
                self.publishers["full"] = node.publisher(options.map_topic, OCCUPANCY_GRID, LATCHED_QOS)
                self.publishers["update"] = node.publisher(
                    options.updates, OCCUPANCY_GRID_UPDATE, UPDATES_QOS
                )
            if options.cloud:
                self.publishers["cloud"] = node.publisher(options.cloud_topic, POINT_CLOUD2, LATCHED_QOS)
        except zenoh.ZError as exc:
            self.stop()
            if "timestamping" not in str(exc):
                raise
            raise ValueError(
                "the ROS 2 session must timestamp its samples for latched topics: open it with "
                "swarm.protocol.bus.open_session(..., timestamping=True)"
            ) from exc
        try:
            self._catch_up(self.snapshot_timeout)
        except Exception:
            self.stop()
            raise
        self._worker = threading.Thread(target=self._run, name="ros2-map", daemon=True)
        self._worker.start()

    def stop(self) -> None:
        self._stop.set()
        if self._worker is not None:
            self._worker.join(timeout=30.0)
        if self._subscriber is not None:
            self._subscriber.undeclare()
            self._subscriber = None
        if self._node is not None:
            self._node.close()
            self._node = None

    @property
    def fmap(self) -> FollowedMap | None:
        return None if self.outputs is None else self.outputs.fmap

    def caught_up(self) -> bool:
        """Whether every merged delta received is applied and every message due for it sent."""
        outputs = self.outputs
        return (
            outputs is not None
            and self.budget.taken == 0  # given back once applied
            and not self._resync.is_set()
            and outputs.idle()
        )

    def topics(self) -> dict[str, str]:
        """Each publisher's kind -> its fully qualified topic."""
        return {kind: pub.topic for kind, pub in self.publishers.items()}

    # -- the team map -----------------------------------------------------------------------------
    def _catch_up(self, timeout: float) -> None:
        """Start (again) from the server's snapshot; ConnectionError when none answers in time."""
        client = MapClient(self.session, self.mission, timeout=min(timeout, 5.0))
        deadline = time.monotonic() + timeout
        while True:
            try:
                snapshot = client.snapshot()
                sensor = sensor_from_stats(client.stats())
                break
            except (MapServerUnavailable, MapQueryError) as exc:
                if time.monotonic() >= deadline:
                    raise ConnectionError(unsharded_only(self.session, self.mission, exc)) from exc
                time.sleep(0.5)
        fmap = FollowedMap(snapshot, sensor)
        outputs = MapOutputs(fmap, self.options, self.context.types)
        if self.outputs is not None:
            fmap.counts.update(self.outputs.fmap.counts)  # the counts go on across snapshots
            outputs.carry_rates(self.outputs)
        self.outputs = outputs
        self._max_payload = delta_bytes(fmap.grid)
        self._last_snapshot = time.monotonic()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh's callback: note the sample's number (a skipped one makes a fresh snapshot due),
        then :meth:`_on_merged` its payload; never raises."""
        try:
            attachment = None if sample.attachment is None else sample.attachment.to_bytes()
            if self.stream.observe(attachment) is not None:
                self.counts["merged_missed"] += 1
                self._resync.set()
            self._on_merged(str(sample.key_expr), sample.payload.to_bytes())
        except Exception:  # noqa: BLE001 (a callback must never raise into Zenoh)
            self._peer_log.exception("callback", "merged callback failed")

    def _on_merged(self, _key: str, payload: bytes) -> None:
        """Queue the payload within the budget (module doc); never raises."""
        if self._max_payload and len(payload) > self._max_payload:
            self.counts["merged_too_large"] += 1
            return
        if self.budget.take(len(payload)):
            self._inbox.put(payload)
            return
        self.counts["merged_dropped"] += 1
        self._resync.set()
        self._peer_log.warning(
            "dropped", "merged delta dropped: %s bytes are waiting", f"{self.budget.taken:,}"
        )

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                payload = self._inbox.get(timeout=0.05)
            except queue.Empty:
                payload = None
            if payload is not None:
                self._apply(payload)
                self._drain()
            if self._resync.is_set() and time.monotonic() - self._last_snapshot >= RESYNC_INTERVAL_S:
                self._start_again()
            self._publish_due()

    def _drain(self) -> None:
        """Apply what is queued, for at most DRAIN_S: a flood must not hold the topics back."""
        deadline = time.monotonic() + DRAIN_S
        while time.monotonic() < deadline:
            try:
                payload = self._inbox.get_nowait()
            except queue.Empty:
                return
            self._apply(payload)

    def _apply(self, payload: bytes) -> None:
        try:
            self.fmap.apply_payload(payload)
        except WireError as exc:
            self._peer_log.warning(f"rejected:{exc.kind}", "refused a merged delta: %s", exc)
        except Exception:  # never die of one message
            self.counts["worker_errors"] += 1
            self._peer_log.exception("failed", "error applying a merged delta")
        finally:
            self.budget.give(len(payload))

    def _start_again(self) -> None:
        """After a dropped delta: a fresh snapshot (the deltas queued meanwhile are then applied
        once, as after the first one). On failure the old map stays and it is tried again."""
        self._resync.clear()
        try:
            self._catch_up(timeout=5.0)
            self.counts["resyncs"] += 1
        except ConnectionError as exc:
            self._resync.set()
            self._peer_log.warning("resync", "cannot start again from a snapshot: %s", exc)

    # -- the topics ---------------------------------------------------------------------------------
    def _publish_due(self) -> None:
        for kind, message, build_s in self.outputs.due(time.monotonic(), time.time()):
            started = time.perf_counter()
            payload = self.context.types.serialize(message, TYPES[kind])
            self.publishers[kind].publish_cdr(payload)
            name = COUNTED[kind]
            self.counts[name] += 1
            self.counts[f"{name}_bytes"] += len(payload)
            self.last_ms[kind] = (build_s + time.perf_counter() - started) * 1e3

    def progress_line(self) -> str:
        """One line of what was followed and sent."""
        c, m = self.counts, (self.fmap.counts if self.fmap is not None else Counter())
        cloud = self.outputs.cloud if self.outputs is not None else None
        cloud = f", {cloud.points:,} occupied voxels" if cloud is not None else ""
        return (
            f"ros2 map: {m['applied']} merged deltas applied, {m['rejected']} refused, "
            f"{c['merged_dropped']} dropped ({c['resyncs']} resyncs); sent {c['grids_full']} grids "
            f"+ {c['grid_updates']} updates ({c['grids_full_bytes'] + c['grid_updates_bytes']:,} B), "
            f"{c['clouds']} clouds ({c['clouds_bytes']:,} B){cloud}"
        )
