"""``swarm bench ros2 latency``: image stamp to delta sent, our protocol and the ROS 2 path side by side.

Two agents (``swarm agent`` processes) at 640 x 480, each robot r1 of a one-robot mission of its
own (the same explorer; no teammate in the way): one takes ``robot/r1/frame``, the other the ROS 2
topics of a simulated robot (``sim2d.ros2_robots``: images, CameraInfo, tf chain
map -> odom -> base_link -> camera_link -> optical frame). The benchmark renders views of the
office once, then sends them alternately to the two agents (each first every other time), each
stamped with the wall clock just before it is serialised and put, and waits for the agent's
delta carrying that stamp (``share_min_bits`` 0: every frame's delta goes out at once).

The latency is the delta's arrival (wall clock, this machine) minus the stamp: the frame's
serialisation and transport, the agent's decoding (for r2: CDR, pairing, tf lookup, the
CameraInfo's calibration), stereo, fusion, decision and delta. With ``--raw`` r2's CameraInfo
carries a distortion, so its agent rectifies each pair too (our protocol's frames are rectified
by the driver, as it asks).

Stereo and fusion take most of that time and vary most from frame to frame on a busy machine,
and they are the same code on both paths. So first, in this process and without the agents, the
part that differs is timed alone: stamp to the frame in the agent's hands (our protocol:
``robot/r1/frame`` put, received and decoded; ROS 2: the images, CameraInfo and tf put, received,
deserialised, paired, posed from tf and made a frame), through a router session as in a mission.
"""

from __future__ import annotations

import math
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from sim2d.render import Renderer, camera_pose
from sim2d.robot_link import WireRobots
from sim2d.ros2_robots import Ros2Robots
from swarm.config import load_mission
from swarm.mission.role_processes import start_role, stop_roles
from swarm.protocol import bus
from swarm.protocol.wire import DeltaMessage, Frame, WireError

WARM_UP = 5  # frames of each path not counted (the kernels' first calls)


PATHS = ("swarm", "ros2")


def _mission_file(config: Path, folder: Path, width: int, height: int, path: str) -> Path:
    """The mission ``bench<path>``: the config's first robot alone, the rig at ``width`` x ``height``."""
    data = yaml.safe_load(config.read_text())
    data["mission"] = f"bench{path}"
    data["floor_plan"] = str((config.parent / data["floor_plan"]).resolve())
    data["robots"] = data["robots"][:1]
    data["rig"] = {**data.get("rig", {}), "width": width, "height": height}
    data["sharing"] = {"share_min_bits": 0.0}
    out = folder / f"bench-{path}.yaml"
    out.write_text(yaml.safe_dump(data))
    return out


class _Deltas:
    """Arrival times (wall clock) of each mission's deltas, by the frame time they carry."""

    def __init__(self) -> None:
        self.arrivals: dict[str, list[tuple[float, float]]] = {path: [] for path in PATHS}
        self._cond = threading.Condition()

    def on_delta(self, key: str, payload: bytes) -> None:
        now = time.time()
        try:
            msg = DeltaMessage.decode(payload)
        except WireError:
            return
        path = key.split("/")[1].removeprefix("bench")
        with self._cond:
            self.arrivals.setdefault(path, []).append((msg.t, now))
            self._cond.notify_all()

    def wait(self, path: str, t: float, timeout: float = 30.0) -> float | None:
        """Seconds from ``t`` to the arrival of the delta of ``path``'s frame stamped ``t``."""

        def found() -> float | None:
            return next((at - t for when, at in self.arrivals[path] if abs(when - t) < 1e-6), None)

        with self._cond:
            self._cond.wait_for(lambda: found() is not None, timeout)
            return found()


def frame_paths(missions: dict, camera, views, frames: int, raw: bool) -> dict[str, list[float]]:
    """Stamp to the frame in an agent's hands (ms), both paths alternately, in this process:
    ``sim2d``'s publishers on one session, the agents' links on another, a router between."""
    from robot_agent.frame_inbox import FrameInbox
    from robot_agent.frame_link import WireLink
    from robot_agent.ros2_link import Ros2Link

    endpoint = bus.tcp_endpoint(bus.free_port())
    sessions = [bus.open_session(listen=[endpoint], timestamping=True)]
    sessions += [bus.open_session(connect=[endpoint], timestamping=True) for _ in range(2)]
    wire, ros2 = WireRobots(sessions[1], missions["swarm"]), Ros2Robots(sessions[1], missions["ros2"])
    if raw:
        _distort(ros2)
    inboxes = {"swarm": FrameInbox(), "ros2": FrameInbox()}
    own = WireLink(sessions[2], missions["swarm"].mission, "r1")
    link = Ros2Link.open(missions["ros2"], "r1", sessions[2])
    own.start(inboxes["swarm"])
    link.frames.start(inboxes["ros2"])
    out: dict[str, list[float]] = {"swarm": [], "ros2": []}
    try:
        while wire.missing() or ros2.missing():
            time.sleep(0.05)
        time.sleep(0.5)
        for k in range(frames + WARM_UP):
            pose, left, right = views[k % len(views)]
            paths = [("swarm", wire), ("ros2", ros2)]
            for name, robots in paths if k % 2 == 0 else paths[::-1]:
                t = time.time()
                robots.publish({"r1": Frame("r1", k + 1, t, pose, camera, "raw8", left=left, right=right)}, t)
                item = inboxes[name].take(10.0)
                frame = Frame.decode(item) if name == "swarm" else item.frame()
                if frame is None:
                    raise RuntimeError(f"the ROS 2 frame was not made: {link.frames.all_counters()}")
                if k >= WARM_UP:
                    out[name].append((time.time() - t) * 1e3)
    finally:
        own.close()
        link.close()
        wire.close()
        ros2.close()
        for session in sessions[::-1]:
            session.close()
    return out


def run(config: Path, frames: int = 60, width: int = 640, height: int = 480, raw: bool = False) -> dict:
    """Measure both paths; returns their latencies (ms) and prints the tables."""
    with tempfile.TemporaryDirectory(prefix="swarm-bench-ros2-") as tmp:
        folder = Path(tmp)
        files = {path: _mission_file(config, folder, width, height, path) for path in PATHS}
        missions = {path: load_mission(file) for path, file in files.items()}
        mission = missions["ros2"]
        rig = mission.rig_for("r1")
        start = mission.start_of("r1")
        renderer = Renderer(mission.load_floor_plan(), rig.camera(), seed=0)
        views = []
        for yaw in start.yaw + np.linspace(0, 2 * math.pi, 12, endpoint=False):
            pose = camera_pose(start.x, start.y, yaw, rig.camera_height)
            views.append((pose, *renderer.stereo_pair(pose, rig.noise_std, np.random.default_rng(0))))
        in_hands = frame_paths(missions, rig.camera(), views, max(frames, 100), raw)
        in_hands = _report(
            in_hands, width, height, raw, "stamp to the frame in the agent's hands (this process)"
        )
        endpoint = bus.tcp_endpoint(bus.free_port())
        session = bus.open_session(listen=[endpoint], timestamping=True)
        deltas = _Deltas()
        sub = bus.subscribe(session, "swarm/*/delta/*", deltas.on_delta)
        robots = {
            "swarm": WireRobots(session, missions["swarm"]),
            "ros2": Ros2Robots(session, missions["ros2"]),
        }
        if raw:
            _distort(robots["ros2"])
        agents = [
            start_role(
                [
                    "agent",
                    "--id",
                    "r1",
                    "--config",
                    str(files[path]),
                    "--connect",
                    endpoint,
                    "--coordination",
                    "none",
                    *(["--ros2"] if path == "ros2" else []),
                ],
                folder / f"agent-{path}.log",
            )  # fmt: skip
            for path in PATHS
        ]
        latency: dict[str, list[float]] = {"swarm": [], "ros2": []}
        try:
            deadline = time.monotonic() + 180
            while any(link.missing() for link in robots.values()):
                if time.monotonic() > deadline or any(a.poll() is not None for a in agents):
                    logs = "\n".join((folder / f"agent-{path}.log").read_text()[-1500:] for path in PATHS)
                    raise RuntimeError(f"the agents did not start:\n{logs}")
                time.sleep(0.1)
            time.sleep(3.0)  # they load the team map (none here) and listen
            for k in range(frames + WARM_UP):
                pose, left, right = views[k % len(views)]
                for name in PATHS if k % 2 == 0 else PATHS[::-1]:  # neither always first
                    t = time.time()
                    frame = Frame("r1", k + 1, t, pose, rig.camera(), "raw8", left=left, right=right)
                    robots[name].publish({"r1": frame}, t)
                    seconds = deltas.wait(name, t)
                    if seconds is None:
                        raise RuntimeError(f"{name}: no delta for frame {k + 1} (see agent-{name}.log)")
                    if k >= WARM_UP:
                        latency[name].append(seconds * 1e3)
                    robots[name].take(0.0)  # the command: not waited for
        finally:
            stop_roles(agents)
            sub.undeclare()
            for link in robots.values():
                link.close()
            session.close()
        return {
            "frame_path": in_hands,
            **_report(latency, width, height, raw, "image stamp to delta sent (agents)"),
        }


def _distort(ros2: Ros2Robots) -> None:
    """Make the simulated robot's CameraInfo claim a radial distortion (its agent then remaps)."""
    for robot in ros2.robots.values():
        robot.distortion = np.array([-0.28, 0.07, 0.0002, 0.00002, 0.0])


def _report(latency: dict[str, list[float]], width: int, height: int, raw: bool, what: str) -> dict:
    out = {}
    print(f"{what}, {width}x{height}, {len(latency['swarm'])} frames each, alternating:")
    for name, values in latency.items():
        p50, p99 = np.percentile(values, [50, 99])
        out[name] = {"p50_ms": float(p50), "p99_ms": float(p99), "mean_ms": float(np.mean(values))}
        rectified = ", raw images rectified by the agent)" if raw else ")"
        path = (
            f"ROS 2 path (rmw_zenoh topics{rectified}" if name == "ros2" else "our protocol (robot/r1/frame)"
        )
        print(f"  {path:<58} p50 {p50:7.1f} ms  p99 {p99:7.1f} ms  mean {np.mean(values):7.1f} ms")
    added = out["ros2"]["p50_ms"] - out["swarm"]["p50_ms"]
    print(f"  the ROS 2 path adds {added:+.1f} ms at the median, "
          f"{out['ros2']['p99_ms'] - out['swarm']['p99_ms']:+.1f} ms at p99")  # fmt: skip
    out["added_p50_ms"] = added
    return out
