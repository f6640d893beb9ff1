"""``swarm bench ros2 ...``: the ROS 2 path (docs/ros2.md) measured beside our own protocol."""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm.cli.common import fail

DEFAULT_MISSION = Path("configs") / "office.yaml"
DEFAULT_EUROC = Path("tests") / "data" / "euroc_mini"


def register(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser(
        "ros2",
        help="the ROS 2 path beside our protocol: latency, a recording's map, a whole mission",
        description="The agent's ROS 2 path (rmw_zenoh topics in, cmd_vel out) measured beside our own "
        "protocol (robot/<id>/frame and cmd) in the same run.",
    )
    sub = p.add_subparsers(dest="ros2_bench", required=True, metavar="COMMAND")
    latency = sub.add_parser(
        "latency",
        help="image stamp to delta sent, p50/p99, both paths alternately",
        description="Two agents of one mission at --width x --height: r1 on robot/r1/frame, r2 on a "
        "simulated robot's ROS 2 topics; rendered office views go to each in turn, stamped with the wall "
        "clock; the latency is the stamp to the arrival of the agent's delta of that frame.",
    )
    latency.add_argument(
        "--config", type=Path, default=DEFAULT_MISSION, help="mission (default configs/office.yaml)"
    )
    latency.add_argument(
        "--frames", type=int, default=60, help="frames per path, after 5 warm-up ones (default 60)"
    )
    latency.add_argument("--width", type=int, default=640, help="image width (default 640)")
    latency.add_argument("--height", type=int, default=480, help="image height (default 480)")
    latency.add_argument(
        "--raw",
        action="store_true",
        help="the ROS 2 CameraInfo claims a distortion: the agent rectifies each pair",
    )
    latency.set_defaults(run=_run_latency)
    euroc = sub.add_parser(
        "euroc",
        help="a recording's map through swarm replay asl and asl --ros2: max relative difference",
        description="Replay an ASL/EuRoC folder twice through a map server and an agent: as "
        "robot/<id>/frame (swarm replay asl) and as a ROS 2 robot's raw images, CameraInfo (from "
        "sensor.yaml) and tf (from the ground truth) (swarm replay asl --ros2); print both maps' "
        "maximum relative difference of the information (lam, eta) and whether they know the same voxels.",
    )
    euroc.add_argument(
        "--euroc", type=Path, default=DEFAULT_EUROC, help="ASL folder (default tests/data/euroc_mini)"
    )
    euroc.add_argument("--frames", type=int, help="pairs to replay (default: all)")
    euroc.add_argument(
        "--out",
        type=Path,
        default=Path("runs") / "bench-ros2-euroc",
        help="parent of the run folders (default runs/bench-ros2-euroc)",
    )
    euroc.set_defaults(run=_run_euroc)
    mission = sub.add_parser(
        "mission",
        help="a whole simulated mission on our protocol and on the ROS 2 path, and its speed-up",
        description="swarm sim of the mission with --robots and with one robot, each on our protocol and "
        "with --ros2 (4 runs, same seed); prints time to H_th, speed-up, surface accuracy and "
        "completeness of each, and the ROS 2 runs' difference.",
    )
    mission.add_argument(
        "config", nargs="?", type=Path, default=DEFAULT_MISSION, help="mission (default office)"
    )
    mission.add_argument("--robots", type=int, help="team size (default: the mission's)")
    mission.add_argument("--seed", type=int, default=0, help="seed of every run (default 0)")
    mission.add_argument("--max-time", type=float, help="simulated seconds at most per run")
    mission.add_argument("--no-single", action="store_true", help="skip the one-robot runs (no speed-up)")
    mission.add_argument(
        "--out",
        type=Path,
        default=Path("runs") / "bench-ros2-mission",
        help="parent of the run folders (default runs/bench-ros2-mission)",
    )
    mission.set_defaults(run=_run_mission)


def _run_latency(args: argparse.Namespace) -> int:
    from swarm.bench import ros2_latency

    if args.frames < 1 or args.width < 8 or args.height < 8:
        return fail("--frames must be >= 1, --width and --height >= 8")
    if not args.config.is_file():
        return fail(f"{args.config}: no such mission file")
    ros2_latency.run(args.config, args.frames, args.width, args.height, args.raw)
    return 0


def _run_euroc(args: argparse.Namespace) -> int:
    from swarm.bench import ros2_runs

    if not (args.euroc / "mav0").is_dir():
        return fail(f"{args.euroc}: not an ASL folder (no mav0/)")
    return ros2_runs.euroc(args.euroc, args.out, args.frames)


def _run_mission(args: argparse.Namespace) -> int:
    from swarm.bench import ros2_runs

    if not args.config.is_file():
        return fail(f"{args.config}: no such mission file")
    return ros2_runs.mission(args.config, args.out, args.robots, args.seed, args.max_time, not args.no_single)
