"""``swarm bench``: the benchmarks (fusion, OctoMap files, entropy, agent frame, server, ROS 2 map,
sparse map)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swarm.cli import bench_ros2
from swarm.cli.common import fail


def _bundled(relative: Path) -> Path:
    """A file shipped in the repository, from the project folder or beside an editable install
    (``relative`` itself when neither has it: the benchmark then says it is missing)."""
    beside_install = Path(__file__).resolve().parents[2] / relative
    return next((p for p in (relative, beside_install) if p.exists()), relative)


DEFAULT_SCAN = _bundled(Path("data") / "octomap" / "scan.dat.bz2")
# The replay tests' four EuRoC V1_01 pairs; their first is the first pair of the whole sequence.
DEFAULT_EUROC = _bundled(Path("tests") / "data" / "euroc_mini")
DEFAULT_BT = _bundled(Path("data") / "octomap" / "geb079.bt")


#: swarm.bench.entropy.SAMPLE, the voxels the entropy benchmark samples (kept here: --help stays light).
ENTROPY_SAMPLE = 20_000


def at_least(lowest: int):
    """An argparse type: an integer of at least ``lowest`` (else argparse's one-line error)."""

    def parse(text: str) -> int:
        value = int(text)
        if value < lowest:
            raise argparse.ArgumentTypeError(f"must be at least {lowest:,} (got {value})")
        return value

    parse.__name__ = "integer"  # argparse's word for a value it cannot parse
    return parse


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
    server = bsub.add_parser(
        "server",
        help="map server: voxel updates merged per second, publish-to-acked latency",
        description="Voxel updates merged per second by the map server's merge path (apply alone, "
        "with decoding, with the write-ahead log fsynced), then a swarm server process with "
        "--agents sessions publishing deltas on loopback: throughput and the latency from "
        "publish until map/acks shows the delta.",
    )
    server.add_argument("--agents", type=int, default=8, help="agent sessions (default 8)")
    server.add_argument("--deltas", type=int, default=25, help="deltas per agent (default 25)")
    server.add_argument("--min-voxels", type=int, default=2000, help="smallest delta (default 2000)")
    server.add_argument("--max-voxels", type=int, default=20000, help="largest delta (default 20000)")
    server.add_argument(
        "--period",
        type=float,
        default=0.25,
        help="paced latency: seconds between an agent's deltas (default 0.25)",
    )
    server.add_argument(
        "--flood",
        type=float,
        metavar="SECONDS",
        help="instead: --agents publishers with no pause for SECONDS, then their resends; prints the "
        "server's peak memory, the inbox's high-water mark and refusals, and whether every delta "
        "was applied exactly once (deltas of --min-voxels to --max-voxels; try 200 and 2000)",
    )
    server.set_defaults(run=_run_bench_server)
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
        default=_bundled(Path("configs") / "office.yaml"),
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
    soak = bsub.add_parser(
        "soak",
        help="map server over mutual TLS and access control under a steady team load for minutes",
        description="A swarm server over TLS with the access rules, --agents sessions each with its own "
        "certificate publishing one delta every --period seconds for --minutes; prints per minute the "
        "server's memory (RSS), CPU and the publish-to-ack latency p50/p99. Nothing is asserted.",
    )
    soak.add_argument("--agents", type=int, default=16, help="agent sessions (default 16)")
    soak.add_argument("--minutes", type=float, default=10.0, help="duration (default 10)")
    soak.add_argument(
        "--period", type=float, default=1.0, help="seconds between an agent's deltas (default 1)"
    )
    soak.add_argument("--voxels", type=int, default=2000, help="voxels per delta, at least (default 2000)")
    soak.set_defaults(run=_run_bench_soak)
    durable = bsub.add_parser(
        "durability",
        help="acked deltas lost by the map server's store under SIGKILL and simulated power cuts",
        description="Power cuts: the store's file operations recorded while a map server merges and "
        "compacts, and for every instant of the recording every disk state a cut may leave (unsynced "
        "data and folder names dropped, torn or zeroed tails) opened by a new server: acked deltas "
        "lost, and deltas applied twice. SIGKILL: --kills kills of a swarm server process mid-stream "
        "on loopback, restarted on the same store each time. Exit status 1 if anything acked was lost.",
    )
    durable.add_argument("--kills", type=at_least(1), default=15, help="SIGKILL rounds (default 15)")
    durable.add_argument(
        "--deltas", type=at_least(2), default=8, help="deltas per robot of the power-cut run (default 8)"
    )
    durable.set_defaults(run=_run_bench_durability)
    slow = bsub.add_parser(
        "slowloris",
        help="new sessions and acks while a stranger holds hundreds of idle connections to the server",
        description="A swarm server on loopback over TCP, then over mutual TLS; a stranger holds "
        "--connections idle or stalled-handshake connections for --seconds, reopening each one closed. "
        "Prints how long a new robot session takes to open before, during and right after, and the "
        "longest gap between an honest robot's acks (docs/security.md, Transport limits).",
    )
    slow.add_argument("--connections", type=at_least(1), default=300, help="idle connections (default 300)")
    slow.add_argument("--seconds", type=float, default=20.0, help="attack length (default 20)")
    slow.set_defaults(run=_run_bench_slowloris)
    stall = bsub.add_parser(
        "stall",
        help="robots' ack p99 and H_th with a stalled merged subscriber and 300 idle connections",
        description="Run a swarm sim mission twice, alone and attacked: a Zenoh session on the map "
        "server's endpoint behind a relay that stops reading (a subscriber of merged that does not "
        "drain) and --connections idle TCP connections to the same endpoint. Prints the robots' ack "
        "latency (p50/p99/max, from a delta's arrival to the first map/acks covering it, polled every "
        "20 ms) and whether each mission reached H_th, side by side (swarm.bench.stall). Exit status 1 "
        "when the attacked p99 is over --target-ms or the attacked mission misses H_th.",
    )
    stall.add_argument(
        "--config",
        type=Path,
        default=_bundled(Path("configs") / "office.yaml"),
        help="the mission (default configs/office.yaml, 4 robots)",
    )
    stall.add_argument(
        "--out",
        type=Path,
        default=Path("runs") / "bench-stall",
        help="run folders (default: runs/bench-stall)",
    )
    stall.add_argument("--connections", type=at_least(0), default=300, help="idle connections (default 300)")
    stall.add_argument("--seed", type=int, default=0, help="the missions' seed (default 0)")
    stall.add_argument("--target-ms", type=float, default=200.0, help="ack p99 target (default 200)")
    stall.add_argument(
        "--runs",
        default="alone,attacked",
        help="runs in order, comma-separated, of: alone, stall (the stalled subscriber only), idle "
        "(the idle connections only), attacked (both); default alone,attacked",
    )
    stall.set_defaults(run=_run_bench_stall)
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
        default=_bundled(Path("configs") / "office.yaml"),
        help="the mission whose floor plan is the map (default configs/office.yaml)",
    )
    ros2.add_argument("--tiles", type=at_least(2), default=4, help="large map: office x N x N (default 4)")
    ros2.add_argument("--rate", type=float, default=20.0, help="merged deltas per simulated s (default 20)")
    ros2.set_defaults(run=_run_bench_ros2_map)
    bench_ros2.register(bsub)


def _run_bench_slowloris(args: argparse.Namespace) -> int:
    from swarm.bench import slowloris

    return slowloris.run(args.connections, args.seconds)


def _run_bench_stall(args: argparse.Namespace) -> int:
    from swarm.bench import stall

    runs = tuple(r.strip() for r in args.runs.split(",") if r.strip())
    unknown = [r for r in runs if r not in stall.RUNS]
    if unknown or not runs:
        return fail(f"--runs {args.runs!r}: expected some of {', '.join(stall.RUNS)}")
    return stall.run(args.config, args.out, args.connections, args.seed, args.target_ms, runs)


def _run_bench_durability(args: argparse.Namespace) -> int:
    from swarm.bench import durability

    return durability.run(args.kills, args.deltas)


def _run_bench_soak(args: argparse.Namespace) -> int:
    from swarm.bench import soak

    if args.agents < 1 or args.minutes <= 0 or args.period <= 0 or args.voxels < 1:
        print("swarm: error: --agents, --minutes, --period and --voxels must be positive", file=sys.stderr)
        return 2
    soak.run(args.agents, args.minutes, args.period, args.voxels)
    return 0


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


def _run_bench_agent(args: argparse.Namespace) -> int:
    from swarm.bench import agent_frame

    try:
        sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes]
    except ValueError:
        return fail(f"--sizes takes WxH values like 160x120, got {args.sizes}")
    print(agent_frame.format_table(agent_frame.run(args.config, sizes, args.repeat)))
    return 0


def _run_bench_server(args: argparse.Namespace) -> int:
    from swarm.bench import server, server_flood

    if args.agents < 1 or args.deltas < 1 or not 1 <= args.min_voxels <= args.max_voxels or args.period <= 0:
        return fail("--agents, --deltas, --period must be positive, and --min-voxels <= --max-voxels")
    if args.flood is not None:
        if not args.flood > 0:
            return fail("--flood takes a positive number of seconds")
        figures = server_flood.run_flood(args.agents, args.flood, args.min_voxels, args.max_voxels)
        print(server_flood.format_flood(figures))
        return 0
    figures = server.run(args.agents, args.deltas, args.min_voxels, args.max_voxels, args.period)
    print(server.format_table(figures))
    return 0
