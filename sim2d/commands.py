"""Command-line entry points of sim2d, wired into ``swarm sim ...`` by swarm/cli.py.

``swarm sim render [CONFIG | --map MAP.yaml] --robot r1 --out DIR`` writes a robot's first
view: left.png, right.png (the rectified pair), depth.npy (float32 optical-z depth in
metres, NaN = no return; with range noise in range mode) and depth.png (that depth
coloured, near = red, far = blue, 0 to the sensor's max range, with a colour bar in metres;
black = no return).

``swarm sim run CONFIG [--listen EP | --connect EP]`` runs the lockstep simulator.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from swarm.protocol import bus

if TYPE_CHECKING:
    from swarm.config import Mission

# OpenCV, numpy and the mission config are imported where they are used: the arguments of
# these commands are built for `swarm sim ... --help` too, which must stay fast.

#: Seconds ``swarm sim world`` waits for the agents by default (they start slowly on a busy machine).
STARTUP_TIMEOUT_S = 120.0


def _add_mission_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "config",
        nargs="?",
        help="mission YAML file (default: configs/office.yaml, as for swarm sim, unless --map)",
    )
    parser.add_argument("--map", help="a ROS map_server map.yaml to use instead of a mission")
    parser.add_argument(
        "--robots",
        type=int,
        help="robots placed on --map (default 1); with a CONFIG, keep its first N robots (default all)",
    )


def _load(args: argparse.Namespace) -> Mission:
    """The mission of CONFIG, or of --map, or else of ``args.default_config`` (set by the
    ``swarm sim`` command line, as ``swarm sim run`` takes it), with --robots applied.
    ConfigError when a robot has no start pose (naming the file and ``robots[i].start``)."""
    from swarm.config import ConfigError, load_mission, mission_from_map

    if args.config and args.map:
        raise ConfigError("give either a mission CONFIG or --map MAP.yaml, not both")
    if not args.config and not args.map:
        default = getattr(args, "default_config", None)
        if default is None:
            raise ConfigError("give a mission CONFIG or --map MAP.yaml")
        if not Path(default).exists():
            raise ConfigError(
                f"{default}: no such mission file (run from the project folder, or give CONFIG)"
            )
        args.config = default
    if args.robots is not None and args.robots < 1:
        raise ConfigError(f"--robots {args.robots}: must be at least 1")
    if args.map:
        return mission_from_map(args.map, robots=args.robots or 1)
    mission = load_mission(args.config)
    if args.robots is not None:
        if args.robots > len(mission.robots):
            raise ConfigError(
                f"{args.config}: robots: --robots {args.robots} asks for more than the "
                f"{len(mission.robots)} robots the mission places"
            )
        mission = mission.model_copy(update={"robots": mission.robots[: args.robots]})
    mission.start_poses()  # the simulated world places every robot: refuse a robot without start
    return mission


def add_render_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm sim render``."""
    _add_mission_arguments(parser)
    parser.add_argument("--robot", help="robot id (default: the first robot)")
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--width", type=int, help="override the rig's image width")
    parser.add_argument("--height", type=int, help="override the rig's image height")


def run_render(args: argparse.Namespace) -> int:
    """Render a robot's first view to ``args.out``; returns a process exit code."""
    import cv2
    import numpy as np

    from sim2d.render import Renderer, camera_pose
    from swarm.config import ConfigError
    from swarm.formats.depth_picture import depth_picture

    try:
        mission = _load(args)
        robot_id = args.robot or mission.robot_ids[0]
        start = mission.start_of(robot_id)
    except (ConfigError, KeyError) as e:
        print(f"swarm: error: {e}", file=sys.stderr)
        return 2
    rig = mission.rig_for(robot_id)
    overrides = {k: v for k, v in (("width", args.width), ("height", args.height)) if v}
    if overrides:
        rig = rig.model_validate({**rig.model_dump(), **overrides})
    renderer = Renderer(mission.load_floor_plan(), rig.camera(), seed=mission.sim.seed)
    pose = camera_pose(start.x, start.y, start.yaw, rig.camera_height, math.radians(rig.pitch_deg))
    rng = np.random.default_rng(mission.sim.seed)
    left, right = renderer.stereo_pair(pose, rig.noise_std, rng)
    noise = rig.range_noise if rig.mode == "range" else 0.0
    depth = renderer.depth_image(pose, noise, rig.max_range, rng)

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out / "left.png"), left)
    cv2.imwrite(str(out / "right.png"), right)
    np.save(out / "depth.npy", depth)
    cv2.imwrite(str(out / "depth.png"), depth_picture(depth, 0.0, mission.sensor.max_range))
    seen = np.isfinite(depth)
    span = f"{np.nanmin(depth):.2f}-{np.nanmax(depth):.2f} m" if seen.any() else "none"
    print(
        f"robot {robot_id} at ({start.x:g}, {start.y:g}, yaw {start.yaw:g}): "
        f"{rig.width}x{rig.height}, depth {span}, {seen.mean():.0%} of pixels with a return"
    )
    print(f"wrote left.png right.png depth.png depth.npy to {out}")
    return 0


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm sim run``."""
    _add_mission_arguments(parser)
    parser.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on (the world is then the router agents connect to); repeatable",
    )
    parser.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to, e.g. the map server's (default tcp/127.0.0.1:7447); repeatable",
    )
    bus.add_zenoh_config_argument(parser)
    parser.add_argument(
        "--encoding",
        choices=["raw8", "png"],
        default="raw8",
        help="image encoding in the frames: raw8 (default, fastest on loopback) or png (smaller)",
    )
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="each robot as a ROS 2 robot over rmw_zenoh: images, CameraInfo, tf and /clock out, "
        "TwistStamped cmd_vel in, in the namespaces of the mission's ros2 section (docs/ros2.md)",
    )
    parser.add_argument(
        "--ros2-encoding",
        choices=["mono8", "bgr8", "rgb8"],
        default="mono8",
        help="the ROS 2 images' encoding (default mono8; bgr8/rgb8 repeat the gray in 3 channels)",
    )
    parser.add_argument(
        "--max-ticks", type=int, help="stop after this many frames (default: the mission's time)"
    )
    parser.add_argument(
        "--startup-timeout",
        type=float,
        default=STARTUP_TIMEOUT_S,
        metavar="S",
        help="seconds to wait for every robot's agent to subscribe before the first frame; robots whose "
        f"agent has not come by then are declared dead at the first frame (default {STARTUP_TIMEOUT_S:g})",
    )
    parser.add_argument(
        "--progress-every",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds between progress lines: frame, simulated time, rate, live and dead agents (default 10)",
    )


def run_sim(args: argparse.Namespace) -> int:
    """Run the lockstep simulator until the mission's stop condition; returns an exit code."""
    from sim2d.simulator import Simulator
    from swarm.config import ConfigError

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    try:
        mission = _load(args)
    except ConfigError as e:
        print(f"swarm: error: {e}", file=sys.stderr)
        return 2
    if not args.progress_every > 0:
        print(f"swarm: error: --progress-every {args.progress_every}: must be positive", file=sys.stderr)
        return 2

    logging.getLogger(__name__).info(
        "mission %r: %s", mission.mission, bus.describe_connection(args.listen, args.connect)
    )
    try:
        session = bus.open_session(
            args.listen, args.connect, config_file=args.zenoh_config, timestamping=args.ros2
        )
    except (ValueError, ConnectionError) as e:  # a bad --zenoh-config file; no router in time
        print(f"swarm: error: {e}", file=sys.stderr)
        return 2
    link = None
    if args.ros2:
        from sim2d.ros2_robots import Ros2Robots

        try:
            link = Ros2Robots(session, mission, args.ros2_encoding)
        except (ConfigError, ValueError) as e:
            session.close()
            print(f"swarm: error: {e}", file=sys.stderr)
            return 2
    sim = Simulator(mission, session, encoding=args.encoding, link=link)
    sim.progress_every_s = args.progress_every
    import signal

    from swarm.child_command import stop_signals
    from swarm.protocol.mission_listener import MissionDoneListener

    for sig in stop_signals():  # stop cleanly and print the summary (SIGINT: unless a runner started us)
        signal.signal(sig, lambda *_: sim.request_stop())

    def on_done(done) -> None:  # the map server's end of the mission
        logging.getLogger(__name__).info("mission done (%s): stopping", done.describe())
        sim.request_stop(f"mission done ({done.reason})")

    ending = MissionDoneListener(session, mission.mission, on_done)
    try:
        summary = sim.run(max_ticks=args.max_ticks, startup_timeout=args.startup_timeout)
    finally:
        ending.close()
        sim.close()
        session.close()
    if summary.reason == "no_agents":
        key = bus.key(mission.mission, "robot", "<id>", "frame")
        print(
            f"swarm: error: no agent came for any of the robots {', '.join(summary.dead)} within "
            f"{args.startup_timeout:g} s (--startup-timeout): nothing subscribed to {key}; start one "
            f"`swarm agent --id ROBOT --config {args.config or args.map} --connect ENDPOINT` per robot "
            "(a first run compiles their kernels for a minute or two: their logs say so)",
            file=sys.stderr,
        )
        return 1
    print(
        f"{summary.reason}: {summary.ticks} frames, {summary.sim_time_s:.1f} s simulated in "
        f"{summary.wall_time_s:.1f} s (x{summary.real_time_factor:.1f}), dead: "
        f"{', '.join(summary.dead) or 'none'}, rejected commands: {summary.rejected}"
    )
    return 0
