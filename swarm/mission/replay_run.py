"""``swarm replay asl|bag``: a recording through the real map server and agent processes.

The runner is the Zenoh router on loopback (or joins one with ``connect``); it starts ``swarm
server`` and ``swarm agent`` as processes, publishes the recording's rectified frames on
``robot/<id>/frame`` in lockstep with the agent's answers (``replay.publisher``), watches
``delta/*`` for the entropy, and writes the run folder: config.yaml, map.npz, the picture set
of every run (top_view.png, map_3d.png, slices/; :mod:`swarm.mission.map_pictures`, with the
camera's path), entropy.png, occupied.ply, frames.csv (per frame: round trip, stereo valid
fraction, map entropy), metrics.json, and the processes' logs.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import threading
import time
from collections.abc import Iterator
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from replay.publisher import FramePublisher
from replay.ros2_player import Ros2Player
from robot_agent.kernels import load_kernels
from robot_agent.stereo import matcher_for_rig
from swarm.config import Mission, mission_from_dict
from swarm.formats.map_file import save_map
from swarm.formats.point_cloud_file import write_ply_points
from swarm.formats.shown_numbers import shown
from swarm.formats.stereo_calibration import StereoCalibration
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.mission.interrupts import Interrupts
from swarm.mission.map_pictures import write_map_pictures
from swarm.mission.picture_style import pyplot
from swarm.mission.role_failure import RoleError
from swarm.mission.role_processes import (
    final_server_map,
    start_role,
    stop_roles,
    wait_for_server,
)
from swarm.mission.team_monitor import TeamMonitor
from swarm.protocol import bus, codec
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import Frame
from swarm.streams.frames import RecordedPair, make_frame, rectified_camera
from swarm.streams.matching import Matched

OCCUPIED = 0.5  # E[C] above which a known voxel is drawn as a surface
AGENT_START_S = 120.0  # wait this long for the agent to subscribe to its frames
AGENT_STOP_S = 30.0  # and this long for it to exit after SIGTERM before killing it


class Recording(Protocol):
    """What the runner needs of a recording (``replay.asl.AslRecording``, ``replay.bag.BagRecording``)."""

    calibration: StereoCalibration
    matched: Matched

    def __len__(self) -> int: ...
    def positions(self) -> np.ndarray: ...
    def pairs(self, start: int = 0, count: int | None = None) -> Iterator[RecordedPair]: ...


class FrameEntropy:
    """The team map's entropy after each frame of the replayed robot, as the bus shows it.

    The agent's deltas carry the time of the frame they follow (``t``) and may arrive after the
    next frame left (``--realtime``), or not follow a frame at all (its outbox holds what is not
    worth sending yet): the entropy after the frame at time ``t`` is the one after the last of
    the robot's deltas with a time <= ``t``. Wraps ``monitor.on_delta`` as the ``delta/*``
    subscriber.
    """

    def __init__(self, monitor: TeamMonitor, robot: str) -> None:
        self.monitor = monitor
        self.robot = robot
        self.marks: list[tuple[float, float]] = []  # (t, entropy after) per delta of the robot
        self._lock = threading.Lock()

    def on_delta(self, key: str, payload: bytes) -> None:
        with self._lock:
            self.monitor.on_delta(key, payload)
            try:
                header = codec.unpack(payload, "delta", (codec.DELTA_VERSION,))
                robot, t = header.get("robot"), float(header.get("t"))
            except (codec.WireError, TypeError, ValueError, AttributeError):
                return  # counted as rejected by the monitor
            if robot == self.robot:
                self.marks.append((t, self.monitor.team_entropy))

    def after(self, t: float) -> float:
        """Entropy (bits) after the frame at recording time ``t`` (s); the start's before any delta."""
        with self._lock:
            found = [bits for when, bits in self.marks if when <= t]
        return found[-1] if found else self.monitor.curve[0][1]

    def latest(self) -> float | None:
        """Recording time of the latest frame whose delta has arrived (None: none yet)."""
        with self._lock:
            return max((when for when, _ in self.marks), default=None)


def default_mission(
    recording: Recording, robot: str = "r1", margin: float = 3.0, voxel: float = 0.1
) -> Mission:
    """A mission around the recording: a box ``margin`` m around the trajectory (1.5 m below and
    above it), its corners on the lattice of ``voxel`` (multiples of the voxel edge, as OctoMap
    anchors its voxels: ``swarm map export --out map.bt`` takes the map as it is), the rectified rig."""
    pos = recording.positions()
    lo, hi = pos.min(axis=0) - margin, pos.max(axis=0) + margin
    lo[2], hi[2] = pos[:, 2].min() - 1.5, pos[:, 2].max() + 1.5
    lo, hi = lattice_box(lo, hi, voxel)
    cam = rectified_camera(recording.calibration)
    hfov = math.degrees(2 * math.atan(cam.width / 2 / cam.fx))
    data = {
        "mission": "replay",
        "workspace": {"lo": lo, "hi": hi, "voxel": voxel},
        "robots": [{"id": robot, "start": {"x": float(pos[0, 0]), "y": float(pos[0, 1])}}],
        "rig": {
            "width": cam.width,
            "height": cam.height,
            "hfov_deg": round(hfov, 4),
            "baseline": cam.baseline,
            "camera_height": float(max(pos[0, 2], 0.05)),
        },
        # Real stereo: rays grazing the floor would clear the voxels their neighbours hit
        # (docs/map-core.md, hit precedence); missions in the simulator keep it off.
        "sensor": {"hit_precedence": True},
    }
    return mission_from_dict(data)


def lattice_box(lo: np.ndarray, hi: np.ndarray, voxel: float) -> tuple[list[float], list[float]]:
    """The smallest box holding [lo, hi] whose corners are whole numbers of voxel edges from the
    world origin (m), as plain floats without negative zeros (they go into config.yaml)."""
    first = np.floor(np.asarray(lo, dtype=np.float64) / voxel + 1e-9)
    last = np.ceil(np.asarray(hi, dtype=np.float64) / voxel - 1e-9)
    digits = max(0, -math.floor(math.log10(voxel))) + 3
    return [shown(k * voxel, digits) for k in first], [shown(k * voxel, digits) for k in last]


@dataclass
class ReplayOptions:
    out: Path
    robot: str = "r1"
    start: int = 0
    count: int | None = None
    realtime: bool = False
    connect: str | None = None
    quiet: bool = False
    zenoh_config: Path | None = None  # the replay's own session (the frame source), with connect
    agent_zenoh_config: Path | None = None  # the agent's, with connect (docs/security.md)
    ros2: bool = False  # the recording as a ROS 2 robot's topics, the agent on its ROS 2 path


def _frames(recording: Recording, options: ReplayOptions) -> Iterator[Frame]:
    for _pair, frame in _pairs(recording, options):
        yield frame


def _pairs(recording: Recording, options: ReplayOptions) -> Iterator[tuple[RecordedPair, Frame]]:
    camera = rectified_camera(recording.calibration)
    for seq, pair in enumerate(recording.pairs(options.start, options.count)):
        yield pair, make_frame(options.robot, seq, pair, recording.calibration, camera)


def run_replay(
    recording: Recording, mission: Mission, options: ReplayOptions, interrupts: Interrupts | None = None
) -> dict:
    """Replay ``recording`` through a map server and an agent; write the run folder; return metrics.

    A Ctrl-C (``interrupts``: the command's) stops the roles and raises KeyboardInterrupt."""
    out = options.out
    out.mkdir(parents=True, exist_ok=True)
    config_path = out / "config.yaml"
    config_path.write_text(mission.to_yaml())
    # Compile the fusion and point kernels here (a no-op load when Numba's cache is warm), so that
    # the agent loads them from the cache: on a fresh clone it would compile them at start, which
    # on a busy machine outlasted the wait for its subscription below.
    load_kernels(None if options.quiet else lambda line: print(line, flush=True), "replay")
    endpoint = options.connect or bus.tcp_endpoint(bus.free_port())
    if options.connect:
        session = bus.open_session(connect=[endpoint], config_file=options.zenoh_config)
    else:
        session = bus.open_session(listen=[endpoint])  # the runner is the router
    monitor = TeamMonitor(mission)
    entropy = FrameEntropy(monitor, options.robot)
    name = mission.mission
    sub = bus.subscribe(session, bus.key_pattern(name, "delta", "*"), entropy.on_delta)
    client = MapClient(session, name, timeout=2.0)
    camera = rectified_camera(recording.calibration)
    matcher = matcher_for_rig(mission.rig_for(options.robot))  # the agent's matcher
    procs = []
    rows: list[dict] = []
    publisher = None
    server_map = None
    try:
        if options.connect is None:
            store = out / "server-store"
            if store.exists():
                shutil.rmtree(store)
            listen = bus.tcp_endpoint(bus.free_port())  # not the default 7447: it may be taken
            server_args = ["server", "--config", str(config_path), "--store", str(store)]
            server_args += ["--connect", endpoint, "--listen", listen]
            server = start_role(server_args, out / "server.log")
            procs.append(server)
            wait_for_server(client, server)
        agent = start_role(
            ["agent", "--id", options.robot, "--connect", endpoint, "--config", str(config_path),
             "--coordination", "none", "--on-mission-done", "continue", *(["--ros2"] if options.ros2 else []),
             *(["--zenoh-config", str(options.agent_zenoh_config)] if options.agent_zenoh_config else [])],
            out / f"agent-{options.robot}.log",
        )  # fmt: skip
        procs.append(agent)  # stopped below however the replay ends
        if options.ros2:
            publisher = Ros2Player(session, mission, options.robot, recording.calibration)
        else:
            publisher = FramePublisher(session, name, options.robot)
        if not publisher.wait_for_agent(AGENT_START_S):
            raise RoleError(
                f"the agent did not subscribe to its frames within {AGENT_START_S:g} s "
                f"(see {out}/agent-*.log)"
            )

        def stereo_valid(frame: Frame) -> float:
            return float(np.isfinite(matcher.disparity(frame.left, frame.right)).mean())

        sent_t: list[float] = []  # recording times of the frames sent so far

        def after_each(frame: Frame, rtt: float | None) -> None:
            # In realtime nothing may hold the next frame back: the stereo valid fraction is
            # computed after the run, the round trips come from the answers' arrival times, and
            # each frame's entropy from the deltas' times (FrameEntropy) once all are in.
            valid = None if options.realtime else stereo_valid(frame)
            if not options.realtime:
                time.sleep(0.05)  # let the agent's delta of this frame arrive
            sent_t.append(frame.t)
            rows.append(
                {"seq": frame.seq, "t": frame.t, "round_trip_ms": None if rtt is None else rtt * 1e3,
                 "stereo_valid": valid, "entropy_bits": None}
            )  # fmt: skip
            if not options.quiet:
                ms = "no answer" if rtt is None else f"{rtt * 1e3:6.0f} ms"
                shown = "" if valid is None else f"  stereo valid {valid:4.0%}"
                if options.realtime:  # this frame's delta is not in yet: say which frame H is after
                    latest = entropy.latest()
                    done = 0 if latest is None else sum(t <= latest for t in sent_t)
                    ms, after = "sent", f" after frame {done}" if done else " at the start"
                    h = entropy.after(sent_t[done - 1]) if done else monitor.curve[0][1]
                else:
                    after, h = "", entropy.after(frame.t)
                print(f"frame {frame.seq + 1:4d}/{len(recording)}  {ms}{shown}  "
                      f"H={h:,.0f} bits{after}", flush=True)  # fmt: skip

        items = _pairs(recording, options) if options.ros2 else _frames(recording, options)
        log = publisher.run(items, options.realtime, after_each=after_each)
        for row, (_seq, _t, rtt), sent in zip(rows, log.rows, log.sent_s, strict=True):
            row["round_trip_ms"] = None if rtt is None else rtt * 1e3
            row["sent_s"] = sent
        if options.realtime:
            for row, frame in zip(rows, _frames(recording, options), strict=False):
                row["stereo_valid"] = stereo_valid(frame)
        stop_roles([agent], AGENT_STOP_S)  # the agent flushes its outbox on SIGTERM, waits for the acks
        procs_agent = agent.returncode
        for row in rows:  # every delta is in: the entropy after each frame, by the deltas' times
            row["entropy_bits"] = entropy.after(row["t"])
        if options.connect is None:
            server_map = final_server_map(client, monitor)
    finally:
        with interrupts.held() if interrupts is not None else nullcontext():
            if publisher is not None:
                publisher.close()
            stop_roles([p for p in procs if p.poll() is None])
            sub.undeclare()
            session.close()
    cmap = server_map if server_map is not None else monitor.cmap
    return _write_outputs(
        out, cmap, options.robot, rows, log.unanswered, recording, monitor, camera, procs_agent
    )


def occupied_points(cmap: CoverageMap, threshold: float = OCCUPIED) -> tuple[np.ndarray, np.ndarray]:
    """Centres (N, 3) and E[C] of the known voxels whose expected coverage is above ``threshold``."""
    known = cmap.known_mask()
    lam = cmap.lam.astype(np.float64)
    cover = np.zeros(cmap.grid.size)
    cover[known] = expected_coverage(cmap.eta[known] / lam[known], 1.0 / np.sqrt(lam[known]))
    idx = np.flatnonzero(known & (cover >= threshold))
    ijk = np.stack(np.unravel_index(idx, cmap.grid.shape), axis=1)
    return cmap.grid.lo + (ijk + 0.5) * cmap.grid.voxel, cover[idx]


def _write_outputs(out, cmap, robot, rows, unanswered, recording, monitor, camera, agent_code) -> dict:
    save_map(out / "map.npz", cmap)
    with (out / "frames.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, ["seq", "t", "sent_s", "round_trip_ms", "stereo_valid", "entropy_bits"])
        writer.writeheader()
        writer.writerows(rows)
    points, cover = occupied_points(cmap)
    write_ply_points(out / "occupied.ply", points, cover)
    rtts = [r["round_trip_ms"] for r in rows if r["round_trip_ms"] is not None]
    metrics = {
        "frames": len(rows),
        "unanswered": unanswered,
        "image_size": [camera.width, camera.height],
        "matching": recording.matched.describe(),
        "round_trip_ms_median": float(np.median(rtts)) if rtts else None,
        "stereo_valid_median": float(np.median([r["stereo_valid"] for r in rows])) if rows else None,
        "entropy_start_bits": monitor.curve[0][1],
        "entropy_end_bits": monitor.team_entropy,
        "occupied_voxels": len(points),
        "agent_exit_code": agent_code,
    }
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    start, final = metrics["entropy_start_bits"], metrics["entropy_end_bits"]
    _plots(out, cmap, robot, rows, recording, start, final)
    return metrics


def _plots(out: Path, cmap: CoverageMap, robot: str, rows, recording, start_bits, final_bits) -> None:
    """The picture set of every run (top_view.png, map_3d.png, slices/: the camera's path on
    them) and the replay's entropy.png (the entropy after each frame)."""
    import matplotlib.ticker

    write_map_pictures(out, cmap, {robot: recording.positions()})
    if not rows:
        return
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4), dpi=110, layout="constrained")
    frames = [r["seq"] + 1 for r in rows]
    shared = [r["entropy_bits"] for r in rows]
    ax.plot(frames, shared, "b.-", label="after each frame (the deltas shared so far)")
    ax.axhline(final_bits, color="k", ls="--", lw=1, label="final map (after the agent's shutdown flush)")
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax.set(xlabel="frame", ylabel="map entropy (bits)", title=entropy_title(start_bits, final_bits))
    ax.legend(loc="upper right")
    fig.savefig(out / "entropy.png")
    plt.close(fig)


def entropy_title(start_bits: float, final_bits: float) -> str:
    """The title of ``entropy.png``: the map's entropy before the first frame (the prior, or
    the map the server held) and the final map's, both as ``metrics.json`` gives them (bits)."""
    return f"Map entropy: {start_bits:,.0f} -> {final_bits:,.0f} bits (start -> final map)"
