"""``swarm view``: follow a mission over Zenoh as any client would, and draw it with rerun.

The view subscribes to ``<mission>/merged`` (every delta the map server merged) and
``<mission>/robot/*/status``, then starts from ``map/snapshot`` (deltas the snapshot already
holds are skipped, as an agent does). Zenoh callbacks only queue payloads; one worker
thread applies every merged delta to its replica of the team map (information form, eq.
24-25) and logs the entropy after each one, and draws the map and the robots at most once
per ``period`` seconds of wall time. A slow viewer thus draws fewer frames; it never drops
a delta and never makes the mission wait (the view publishes nothing).
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

from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table
from swarm.protocol import bus
from swarm.protocol.applied_deltas import AppliedDeltas
from swarm.protocol.map_client import MapClient, MapQueryError, MapServerUnavailable, sensor_from_stats
from swarm.protocol.wire import DeltaMessage, WireError, status_on_key
from swarm.view.scene import RobotTrack, log_map, log_robot, require_rerun

log = logging.getLogger("swarm.view")

TIMELINE = "sim_time"


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
        self.cmap: CoverageMap | None = None
        self.entropy: EntropyCache | None = None
        self.applied = AppliedDeltas()
        self.tracks: dict[str, RobotTrack] = {}
        self.sim_time = 0.0
        self.frames = 0
        self.deltas = 0
        self.rejected = 0
        self._inbox: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._subs = [
            bus.subscribe(session, bus.key(mission, "merged"), lambda _k, p: self._inbox.put(("delta", p))),
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
                    raise ConnectionError(
                        f"no map server of mission {self.mission!r} answered: {exc}"
                    ) from exc
                time.sleep(0.5)
        self.cmap = CoverageMap(snap.grid, sensor, snap.lam, snap.eta)
        self.entropy = EntropyCache.from_information(self.cmap.lam, self.cmap.eta, table=default_table())
        self.applied.cover(snap.acks, snap.above)
        self._set_time(0.0)
        self.rec.log("plots/entropy", require_rerun().Scalars(float(self.entropy.total)))

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

    def drain(self) -> int:
        """Handle every queued message; returns how many."""
        handled = 0
        while True:
            try:
                kind, payload = self._inbox.get_nowait()
            except queue.Empty:
                return handled
            handled += 1
            try:
                if kind == "delta":
                    self._on_delta(payload)
                else:
                    self._on_status(payload)
            except (WireError, ValueError) as exc:
                self.rejected += 1
                if self.rejected <= 10:
                    log.warning("view: ignored a %s message: %s", kind, exc)

    def _on_delta(self, payload) -> None:
        msg = DeltaMessage.decode(payload)
        if self.cmap is None or not self.cmap.grid.matches(msg.grid):
            raise WireError("merged delta on another grid than the snapshot's")
        if not self.applied.add(msg.robot, msg.epoch, msg.seq):
            return
        self.cmap.apply_received(Delta(msg.idx, msg.dlam, msg.deta))
        idx = msg.idx.astype(np.int64)
        self.entropy.update_information(idx, self.cmap.lam[idx], self.cmap.eta[idx])
        self.deltas += 1
        self.sim_time = max(self.sim_time, float(msg.t))
        self._set_time(msg.t)
        self.rec.log("plots/entropy", require_rerun().Scalars(float(self.entropy.total)))

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
