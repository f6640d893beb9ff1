"""``swarm bench``: the benchmarks (fusion, OctoMap files, entropy, agent frame, sparse map, ROS 2
map); the map server's are swarm.cli.bench_server's, the ROS 2 path's swarm.cli.bench_ros2's,
the coordinator's swarm.cli.bench_coordinator's, whole missions' swarm.cli.bench_team's."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swarm.cli import bench_coordinator, bench_ros2, bench_server, bench_team
from swarm.cli.common import at_least, bundled, fail

DEFAULT_SCAN = bundled(Path("data") / "octomap" / "scan.dat.bz2")
# The replay tests' four EuRoC V1_01 pairs; their first is the first pair of the whole sequence.
DEFAULT_EUROC = bundled(Path("tests") / "data" / "euroc_mini")
DEFAULT_BT = bundled(Path("data") / "octomap" / "geb079.bt")


#: swarm.bench.entropy.SAMPLE, the voxels the entropy benchmark samples (kept here: --help stays light).
ENTROPY_SAMPLE = 20_000


# -- swarm bench --------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks that print their figures",
        description="Benchmarks that print their figures.",
    )
    bsub = p.add_subparsers(dest="bench_command", required=True, metavar="COMMAND")
    fusion = bsub.add_parser(
        "fusion",
        help="rays/s of our fusion beside OctoMap's insertPointCloud",
        description="Time, rays/s and voxel updates/s of our fusion on the real OctoMap scan (at 5 m "
        "max range and over its whole beam) and on a dense stereo cloud from one real EuRoC frame, "
        "with OctoMap's insertPointCloud (octomap-python, pip install '.[bench]') on the same "
        "clouds, resolution and max range, single-threaded, timed alternately with ours; one "
        "measurement per ray, then discretize on both sides. Also surface precision and recall "
        "of both maps against the cloud.",
    )
    fusion.add_argument(
        "--scan",
        type=Path,
        default=DEFAULT_SCAN,
        help=f"real scan to use (default: {DEFAULT_SCAN})",
    )
    fusion.add_argument(
        "--euroc",
        type=Path,
        default=DEFAULT_EUROC,
        help=f"EuRoC folder (ASL layout); its first pair is the dense cloud (default {DEFAULT_EUROC})",
    )
    fusion.add_argument("--voxel", type=float, default=0.1, help="voxel edge (default 0.1 m)")
    fusion.add_argument("--repeat", type=at_least(1), default=3, help="take the best of N runs (default 3)")
    fusion.set_defaults(run=_run_bench_fusion)
    octo = bsub.add_parser(
        "octomap",
        help="read and write OctoMap .bt files, ours beside OctoMap's own",
        description="Time reading a .bt (default: the bundled geb079.bt) and writing its voxels "
        "back, with our own code and with OctoMap (octomap-python, pip install '.[bench]').",
    )
    octo.add_argument("--bt", type=Path, default=DEFAULT_BT, help=f"OctoMap file (default: {DEFAULT_BT})")
    octo.add_argument("--repeat", type=at_least(1), default=3, help="take the best of N runs (default 3)")
    octo.set_defaults(run=_run_bench_octomap)
    entropy = bsub.add_parser(
        "entropy",
        help="entropy of a 1,000,000-voxel map",
        description="Time the lookup-table entropy of a 1,000,000-voxel map, "
        "the exact formula on a sample, and an incremental update.",
    )
    entropy.add_argument(
        "--voxels",
        type=at_least(ENTROPY_SAMPLE),
        default=1_000_000,
        help=f"map size in voxels (default 1,000,000; at least {ENTROPY_SAMPLE:,}, the exact one's sample)",
    )
    entropy.add_argument("--repeat", type=at_least(1), default=5, help="take the best of N runs (default 5)")
    entropy.set_defaults(run=_run_bench_entropy)
    agent = bsub.add_parser(
        "agent",
        help="time per frame of stereo, fusion and planning",
        description="Time per frame of the agent's stages (stereo: SGBM + depth + points; fusion; "
        "planning: traversability + Dijkstra + one path) on frames rendered from a mission, at "
        "160x120, 640x480 and 752x480 by default; fusion with one measurement per ray and with "
        "weighted (one per end voxel carrying its rays' information) and discretize (one per end voxel).",
    )
    agent.add_argument(
        "--config",
        type=Path,
        default=Path("configs/office.yaml"),
        help="mission to render (default configs/office.yaml)",
    )
    agent.add_argument(
        "--sizes",
        nargs="+",
        default=["160x120", "640x480", "752x480"],
        help="image sizes WxH (default 160x120 640x480 752x480)",
    )
    agent.add_argument(
        "--repeat", type=at_least(1), default=5, help="time N runs of each stage: best and median (default 5)"
    )
    agent.set_defaults(run=_run_bench_agent)
    memory = bsub.add_parser(
        "agent-memory",
        help="one agent's RSS and PSS step by step on a mission's grid, and the arrays it holds",
        description="Build one robot agent of a mission (default configs/campus_floor.yaml) on a "
        "loopback Zenoh session of its own, feed it --frames frames rendered by sim2d while a pymunk "
        "world drives its robot, and print after each step the process's RSS, peak RSS within the step "
        "(VmHWM), PSS, private and shared pages (MB); --arrays: the largest numpy arrays the agent "
        "holds; --trace: tracemalloc's peak per step and top allocation sites (slow). Linux only.",
    )
    memory.add_argument(
        "--config",
        type=Path,
        default=Path("configs/campus_floor.yaml"),
        help="mission (default configs/campus_floor.yaml)",
    )
    memory.add_argument("--robot", default=None, help="robot id (default: the mission's first)")
    memory.add_argument("--frames", type=at_least(1), default=30, help="frames to feed (default 30)")
    memory.add_argument("--arrays", action="store_true", help="list the largest arrays held at the end")
    memory.add_argument("--trace", action="store_true", help="also run tracemalloc (slow)")
    memory.add_argument(
        "--server",
        action="store_true",
        help="against a map server of the mission (its own process, a fresh store): catch-up, "
        "sharing, a resync at the end",
    )
    memory.set_defaults(run=_run_bench_agent_memory)
    sparse = bsub.add_parser(
        "sparse",
        help="the block-sparse map beside the dense one: same map, fusion time, memory",
        description="The block-sparse map (swarm.map.block_map) beside the dense map on the same "
        "ray streams: range frames over a mission's floor (--config), the EuRoC stereo frames "
        "(--euroc) and the real OctoMap scan (--scan): the largest relative difference of the two "
        "maps, the time to fuse each stream (best of --repeat rounds, alternating), memory; then "
        "--robots robots on the streets of a 200 m x 100 m x 5 m campus at 0.1 m (1e8 voxels): the "
        "block map's memory as the explored volume grows. Prints the load average.",
    )
    sparse.add_argument(
        "--config",
        type=Path,
        default=bundled(Path("configs") / "office.yaml"),
        help="mission whose floor and rig give the frames (default configs/office.yaml)",
    )
    sparse.add_argument("--scan", type=Path, default=DEFAULT_SCAN, help=f"real scan (default {DEFAULT_SCAN})")
    sparse.add_argument(
        "--euroc",
        type=Path,
        default=DEFAULT_EUROC,
        help=f"EuRoC folder (ASL layout; default {DEFAULT_EUROC})",
    )
    sparse.add_argument("--repeat", type=at_least(1), default=3, help="take the best of N rounds (default 3)")
    sparse.add_argument("--robots", type=at_least(1), default=16, help="robots on the campus (default 16)")
    sparse.add_argument(
        "--block-bits",
        type=at_least(1),
        nargs="+",
        default=[4, 3],
        help="blocks of 2^N voxels a side of the campus maps, 1 to 5 (default 4 3: 16^3 and 8^3)",
    )
    sparse.add_argument("--no-site", action="store_true", help="skip the campus")
    sparse.set_defaults(run=_run_bench_sparse)
    bench_server.register(bsub)
    bench_coordinator.register(bsub)
    bench_team.register(bsub)
    ros2 = bsub.add_parser(
        "ros2-map",
        help="cost and bytes of the team map's ROS 2 topics (swarm map ros2), office and large map",
        description="Replay the exploration of the office map and of the office repeated --tiles x "
        "--tiles times as merged deltas (one per 1 m tile, --rate per simulated second) through "
        "swarm map ros2's code with its default options, and print per kind of message (whole grid, "
        "grid update, cloud) how many went out, the wall ms to build, serialise and put each, their "
        "bytes as a subscriber received them, and the bytes per simulated second (swarm.bench.ros2_map).",
    )
    ros2.add_argument(
        "--config",
        type=Path,
        default=bundled(Path("configs") / "office.yaml"),
        help="the mission whose floor plan is the map (default configs/office.yaml)",
    )
    ros2.add_argument("--tiles", type=at_least(2), default=4, help="large map: office x N x N (default 4)")
    ros2.add_argument("--rate", type=float, default=20.0, help="merged deltas per simulated s (default 20)")
    ros2.set_defaults(run=_run_bench_ros2_map)
    bench_ros2.register(bsub)


def _run_bench_ros2_map(args: argparse.Namespace) -> int:
    from swarm.bench import ros2_map

    if not args.rate > 0:
        return fail(f"--rate {args.rate:g}: must be > 0")
    print(ros2_map.format_figures(ros2_map.run(args.config, args.tiles, args.rate)))
    return 0


def _run_bench_octomap(args: argparse.Namespace) -> int:
    from swarm.bench import octomap_io
    from swarm.formats.octomap_file import OctomapFileError

    try:
        print(octomap_io.format_table(octomap_io.run(args.bt, args.repeat)))
    except (OctomapFileError, OSError) as exc:
        return fail(str(exc))
    return 0


def _run_bench_fusion(args: argparse.Namespace) -> int:
    from swarm.bench import fusion

    missing = [path for path in (args.scan, args.euroc / "mav0") if not path.exists()]
    if len(missing) == 2:  # the defaults are relative to the project folder
        return fail(
            f"nothing to measure: no {missing[0]} and no {missing[1]} (run from the project folder, "
            "or give --scan FILE and/or --euroc DIR)"
        )
    for path, what in ((args.scan, "scan"), (args.euroc / "mav0", "EuRoC stereo cloud")):
        if path in missing:
            print(f"note: {path} not found; skipping the {what}", file=sys.stderr)
    if not args.voxel > 0:  # --repeat is checked by its argparse type (at_least)
        return fail(f"--voxel {args.voxel:g}: must be > 0")

    def progress(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    figures = fusion.run(args.scan, args.euroc, args.voxel, args.repeat, progress)
    print(fusion.format_table(figures))
    return 0


def _run_bench_sparse(args: argparse.Namespace) -> int:
    from swarm.bench import block_map

    if not args.config.exists():
        return fail(f"{args.config}: no such mission file")
    if max(args.block_bits) > 5:
        return fail(f"--block-bits {max(args.block_bits)}: at most 5 (blocks of 32^3 voxels)")
    scan = args.scan if args.scan.exists() else None
    euroc = args.euroc if (args.euroc / "mav0").exists() else None
    for path, found in ((args.scan, scan), (args.euroc / "mav0", euroc)):
        if found is None:
            print(f"note: {path} not found; skipping it", file=sys.stderr)

    def progress(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    print(
        block_map.run(
            args.config, scan, euroc, args.repeat, not args.no_site, args.robots, args.block_bits, progress
        )
    )
    return 0


def _run_bench_entropy(args: argparse.Namespace) -> int:
    from swarm.bench import entropy

    print(entropy.format_figures(entropy.run(args.voxels, args.repeat)))
    return 0


def _run_bench_agent_memory(args: argparse.Namespace) -> int:
    from swarm.bench import agent_memory

    if not args.config.exists():
        return fail(f"{args.config}: no such mission file")
    if not Path("/proc/self/smaps_rollup").exists():
        return fail("swarm bench agent-memory reads /proc/self/smaps_rollup: Linux only")
    agent_memory.run(args.config, args.robot, args.frames, args.arrays, args.trace, server=args.server)
    return 0


def _run_bench_agent(args: argparse.Namespace) -> int:
    from swarm.bench import agent_frame

    try:
        sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes]
    except ValueError:
        return fail(f"--sizes takes WxH values like 160x120, got {args.sizes}")
    print(agent_frame.format_table(agent_frame.run(args.config, sizes, args.repeat)))
    return 0
