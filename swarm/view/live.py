"""``swarm view``: follow a mission over Zenoh as any client would, and draw it with rerun.

The view subscribes to ``<mission>/merged`` (every delta the map server merged) and
``<mission>/robot/*/status``, then starts from ``map/snapshot`` (deltas the snapshot already
holds are skipped, as an agent does). Zenoh callbacks only queue payloads; one worker
thread applies every merged delta to its replica of the team map
(:class:`swarm.protocol.team_replica.TeamReplica`, information form, eq. 24-25) and logs the
entropy after each one, and draws the map and the robots at most once per ``period`` seconds
of wall time. A slow viewer thus draws fewer frames; a merged sample it misses makes it catch
up from a fresh snapshot, and it never makes the mission wait (the view publishes nothing).
"""

from __future__ import annotations

import logging
import os
import queue
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from swarm.log_limit import LogLimiter
from swarm.map.coverage_map import CoverageMap
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient, MapQueryError, MapServerUnavailable, sensor_from_stats
from swarm.protocol.sharded_client import unsharded_only
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import DeltaMessage, WireError, status_on_key
from swarm.view.scene import RobotTrack, log_map, log_robot, require_rerun

log = logging.getLogger("swarm.view")

TIMELINE = "sim_time"
#: Merged samples kept while the first snapshot is on its way (more: a catch-up after it).
MAX_EARLY_SAMPLES = 10_000


def missing_display() -> str | None:
    """Why a rerun viewer window cannot open here, or None when it can (or may).

    On Linux and the BSDs a window needs an X or Wayland display: ``DISPLAY``,
    ``WAYLAND_DISPLAY`` or ``WAYLAND_SOCKET`` set in the environment (an ssh session without
    X forwarding, a container or a CI runner has none). macOS and Windows always may.
    """
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return None
    if any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")):
        return None
    return "no display to open a viewer window on (DISPLAY and WAYLAND_DISPLAY are unset)"


def open_recording(mission: str, save: str | Path | None = None, spawn: bool = False):
    """A rerun recording that streams to ``save`` (an .rrd file) and/or a spawned viewer."""
    rr = require_rerun()
    rec = rr.RecordingStream(f"swarm-{mission}")
    if save is not None:
        Path(save).parent.mkdir(parents=True, exist_ok=True)
        rec.save(str(save))
    if spawn:
        rec.spawn()
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


class TeamView:
    """The live view of one mission (see the module doc)."""

    def __init__(
        self, session: zenoh.Session, mission: str, rec, period: float = 1.0, max_points: int = 60_000
    ) -> None:
        self.session = session
        self.mission = mission
        self.rec = rec
        self.period = period
        self.max_points = max_points
        self.team: TeamReplica | None = None  # from the first snapshot on
        self.tracks: dict[str, RobotTrack] = {}
        self.sim_time = 0.0
        self.frames = 0
        self.deltas = 0
        self.rejected_statuses = 0
        self._inbox: queue.Queue = queue.Queue()
        self._early: list[zenoh.Sample] = []  # merged samples before the first snapshot
        self._early_lock = threading.Lock()
        self._early_dropped = False
        self._stop = threading.Event()
        self._subs = [
            session.declare_subscriber(bus.key(mission, "merged"), self._on_merged),
            bus.subscribe(
                session,
                bus.key_pattern(mission, "robot", "*", "status"),
                lambda k, p: self._inbox.put(("status", (k, p))),
            ),
        ]
        self._worker: threading.Thread | None = None

    # -- life cycle ------------------------------------------------------------------------
    def catch_up(self, timeout: float = 30.0) -> None:
        """Start from the server's snapshot; raises ConnectionError when none answers in time."""
        client = MapClient(self.session, self.mission, timeout=2.0)
        deadline = time.monotonic() + timeout
        while True:
            try:
                snap = client.snapshot()
                sensor = sensor_from_stats(client.stats())
                break
            except (MapServerUnavailable, MapQueryError) as exc:
                if time.monotonic() >= deadline:
                    raise ConnectionError(unsharded_only(self.session, self.mission, exc)) from exc
                time.sleep(0.5)
        team = TeamReplica(
            snap.grid,
            sensor,
            fetch=client.snapshot,
            on_applied=self._on_delta,
            peer_log=LogLimiter(log),
            name="view",
        )
        team.load_snapshot(snap)
        with self._early_lock:
            self.team = team
            early, self._early = self._early, []
        for sample in early:
            team.on_sample(sample)
        if self._early_dropped:  # some merged samples before the snapshot were not kept
            team.resync(force=True)
        self._set_time(0.0)
        self.rec.log("plots/entropy", require_rerun().Scalars(team.entropy_bits))

    def start(self) -> None:
        self._worker = threading.Thread(target=self._run, name="view", daemon=True)
        self._worker.start()

    def stop(self) -> None:
        """Draw a last frame, stop the worker and flush the recording."""
        self._stop.set()
        if self._worker is not None:
            self._worker.join(timeout=30.0)
        for sub in self._subs:
            sub.undeclare()
        self.rec.flush()

    # -- work --------------------------------------------------------------------------------
    def _set_time(self, t: float) -> None:
        self.rec.set_time(TIMELINE, duration=float(t))

    def _run(self) -> None:
        last_frame = 0.0
        while True:
            stopping = self._stop.is_set()
            self.drain()
            now = time.monotonic()
            if stopping or now - last_frame >= self.period:
                last_frame = now
                self.draw()
            if stopping:
                return
            time.sleep(0.05)

    @property
    def cmap(self) -> CoverageMap | None:
        """The replica's map (None before the first snapshot)."""
        return None if self.team is None else self.team.map

    @property
    def rejected(self) -> int:
        return self.rejected_statuses + (0 if self.team is None else self.team.counts["rejected"])

    def _on_merged(self, sample: zenoh.Sample) -> None:
        with self._early_lock:
            team = self.team
            if team is None and len(self._early) < MAX_EARLY_SAMPLES:
                self._early.append(sample)
            elif team is None:
                self._early_dropped = True
        if team is not None:
            team.on_sample(sample)

    def drain(self) -> int:
        """Apply the merged deltas waiting and handle every queued status; returns how many."""
        handled = 0 if self.team is None else self.team.drain()
        while True:
            try:
                kind, payload = self._inbox.get_nowait()
            except queue.Empty:
                return handled
            handled += 1
            try:
                self._on_status(payload)
            except (WireError, ValueError) as exc:
                self.rejected_statuses += 1
                if self.rejected_statuses <= 10:
                    log.warning("view: ignored a %s message: %s", kind, exc)

    def _on_delta(self, msg: DeltaMessage, _idx: np.ndarray, _size: int) -> None:
        """After each merged delta applied: the sim time and the entropy curve."""
        self.deltas += 1
        self.sim_time = max(self.sim_time, float(msg.t))
        self._set_time(msg.t)
        self.rec.log("plots/entropy", require_rerun().Scalars(self.team.entropy_bits))

    def _on_status(self, sample: tuple[str, bytes]) -> None:
        status = status_on_key(*sample)
        track = self.tracks.setdefault(status.robot, RobotTrack())
        track.path.append(tuple(float(v) for v in status.pose.xyz))
        track.yaw = float(status.pose.ypr[0])
        track.target = status.target
        track.state = status.state
        self.sim_time = max(self.sim_time, float(status.t))

    def draw(self) -> None:
        """Log the map and the robots at the latest sim time."""
        if self.cmap is None:
            return
        self._set_time(self.sim_time)
        log_map(self.rec, self.cmap, self.max_points)
        for robot, track in self.tracks.items():
            log_robot(self.rec, robot, track)
        self.frames += 1


def run_view(
    connect: list[str] | None,
    mission: str,
    save: str | Path | None = None,
    spawn: bool = True,
    period: float = 1.0,
    duration: float | None = None,
    stop: threading.Event | None = None,
    zenoh_config: str | Path | None = None,
) -> TeamView:
    """Open a session, follow ``mission`` until ``duration`` seconds pass or ``stop`` is set."""
    session = bus.open_session(connect=connect or None, config_file=zenoh_config)
    try:
        rec = open_recording(mission, save, spawn)
        view = TeamView(session, mission, rec, period)
        view.catch_up()
        view.start()
        deadline = None if duration is None else time.monotonic() + duration
        stop = stop or threading.Event()
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            stop.wait(0.2)
        view.stop()
        return view
    finally:
        session.close()
