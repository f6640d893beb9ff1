"""The ``swarm`` command line: a thin shell over the roles and the map core."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

BUNDLED_SCAN = Path("data") / "octomap" / "scan.dat.bz2"
# The bundled scan, from the project folder or beside an editable install.
DEFAULT_SCAN = next(
    (p for p in (BUNDLED_SCAN, Path(__file__).resolve().parent.parent / BUNDLED_SCAN) if p.exists()),
    BUNDLED_SCAN,
)


def _fail(message: str) -> int:
    print(f"swarm: error: {message}", file=sys.stderr)
    return 2


# -- swarm ingest -------------------------------------------------------------------------
def _add_ingest(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ingest",
        help="fuse a point cloud seen from one sensor position into a coverage map",
        description=(
            "Fuse a point cloud (one batch seen from --origin) into a new Gaussian coverage map "
            "and write it as map.npz. Reads .npy/.npz (N x 3), ASCII 'x y z' lines (plain, .gz or "
            ".bz2) and PLY. NaN/inf points and rays that leave --bounds are skipped and counted; "
            "rays longer than --max-range update free space up to it and mark no hit."
        ),
    )
    p.add_argument("cloud", type=Path, help="point cloud file")
    p.add_argument("--out", type=Path, required=True, help="map file to write (map.npz)")
    p.add_argument(
        "--origin",
        type=float,
        nargs=3,
        default=(0.0, 0.0, 0.0),
        metavar=("X", "Y", "Z"),
        help="sensor position in the cloud's frame (default: 0 0 0)",
    )
    p.add_argument("--voxel", type=float, default=0.1, help="voxel edge in metres (default: 0.1)")
    p.add_argument(
        "--max-range",
        type=float,
        default=5.0,
        help="sensor max range in metres (default: 5, the rig default)",
    )
    p.add_argument("--sigma-min", type=float, default=0.06, help="sensor model sigma_min (default 0.06)")
    p.add_argument("--zeta", type=float, default=0.0375, help="sensor model zeta per metre (default 0.0375)")
    p.add_argument("--tau", type=float, default=2.0, help="sensor model damping tau in metres (default 2)")
    p.add_argument(
        "--bounds",
        type=float,
        nargs=6,
        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
        help="workspace box (default: fits the origin and the rays up to max range)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object with the figures")
    p.set_defaults(run=_run_ingest)


def _run_ingest(args: argparse.Namespace) -> int:
    from swarm.formats.map_file import save_map
    from swarm.formats.point_cloud_file import read_point_cloud
    from swarm.map.ingest import ingest_cloud
    from swarm.map.sensor_model import SensorModel

    if not (args.voxel > 0 and np.isfinite(args.voxel)):
        return _fail(f"--voxel must be a positive number, got {args.voxel}")
    try:
        sensor = SensorModel(args.sigma_min, args.zeta, args.tau, args.max_range)
        points = read_point_cloud(args.cloud)
        bounds = None
        if args.bounds is not None:
            bounds = (np.array(args.bounds[:3]), np.array(args.bounds[3:]))
            if not np.all(bounds[1] > bounds[0]):
                return _fail(f"--bounds: each max must exceed its min, got {args.bounds}")
        cells = np.prod(np.ceil((bounds[1] - bounds[0]) / args.voxel)) if bounds else 0
        if cells > 400e6:
            return _fail(f"--bounds at --voxel {args.voxel} make {cells:.3g} voxels (limit 4e8)")
        cmap, report = ingest_cloud(points, np.array(args.origin), sensor, args.voxel, bounds)
    except ValueError as exc:
        return _fail(str(exc))
    save_map(args.out, cmap)
    if args.json:
        print(json.dumps(report.to_dict()))
    else:
        r = report
        print(
            f"fused {r.rays:,} rays of {r.points:,} points into {r.voxels:,} voxels {tuple(r.shape)} "
            f"in {r.fusion_seconds:.3f} s ({r.voxel_updates:,} voxel updates)"
        )
        print(
            f"skipped: {r.skipped_nonfinite} NaN/inf, {r.skipped_outside} outside the box, "
            f"{r.skipped_degenerate} zero-length; cut: {r.truncated_at_max_range} at max range, "
            f"{r.clipped_at_box} at the box (free space up to it)"
        )
        print(f"entropy: {r.initial_entropy_bits:,.0f} -> {r.final_entropy_bits:,.0f} bits")
        print(f"wrote {args.out}")
    return 0


# -- swarm map info -----------------------------------------------------------------------
def _add_map(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("map", help="inspect coverage maps", description="Inspect coverage maps.")
    msub = p.add_subparsers(dest="map_command", required=True, metavar="COMMAND")
    info = msub.add_parser(
        "info",
        help="summary of a map.npz",
        description="Print a summary of a map.npz: shape, voxel size, known "
        "fraction, entropy and occupied voxels (E[C] > 0.5).",
    )
    info.add_argument("map", type=Path, help="map.npz file")
    info.add_argument("--json", action="store_true", help="print JSON")
    info.set_defaults(run=_run_map_info)
    stats = msub.add_parser(
        "stats",
        help="a running map server's figures (map/stats JSON)",
        description="Ask a running map server (swarm server) for map/stats and print the JSON: "
        "entropy, known fraction, deltas applied per robot, rejected and duplicate counts, log size.",
    )
    _add_map_query_arguments(stats)
    stats.set_defaults(run=_run_map_stats)
    get = msub.add_parser(
        "get",
        help="beliefs of a point's voxel or of a box, from a running map server",
        description="Ask a running map server (map/region) for the beliefs of the voxel holding "
        "--point, or of every voxel that the box --box touches: index, centre, mu, sigma, E[C] "
        "and entropy in bits.",
    )
    _add_map_query_arguments(get)
    where = get.add_mutually_exclusive_group(required=True)
    where.add_argument("--point", metavar="X,Y,Z", help="world point in metres")
    where.add_argument("--box", metavar="X0,Y0,Z0,X1,Y1,Z1", help="world box in metres (min and max corners)")
    get.add_argument("--json", action="store_true", help="print JSON, one object per voxel")
    get.set_defaults(run=_run_map_get)
    export = msub.add_parser(
        "export",
        help="fetch the team map from a running map server and write map.npz or a PLY",
        description="Fetch map/snapshot from a running map server and write --out: a .npz map file "
        "(as swarm map info reads) or a .ply of the centres of voxels with E[C] > --threshold.",
    )
    _add_map_query_arguments(export)
    export.add_argument("--out", type=Path, required=True, help="output file: *.npz or *.ply")
    export.add_argument("--threshold", type=float, default=0.5, help="PLY: E[C] above this (default 0.5)")
    export.set_defaults(run=_run_map_export)


def _add_map_query_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint of the map server (default tcp/127.0.0.1:7447); repeatable",
    )
    p.add_argument("--mission", default="default", help="mission name, the key prefix (default: default)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for an answer (default 5)")


def _run_map_info(args: argparse.Namespace) -> int:
    from swarm.formats.map_file import MapFileError, load_map
    from swarm.map.summary import summarize

    try:
        summary = summarize(load_map(args.map))
    except (MapFileError, FileNotFoundError) as exc:
        return _fail(str(exc))
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:>22}: {value}")
    return 0


def _run_map_stats(args: argparse.Namespace) -> int:
    from swarm.protocol.map_client import MapClient, MapQueryError

    try:
        with MapClient.connect(args.connect, args.mission, args.timeout) as client:
            print(json.dumps(client.stats(), indent=1))
    except (ConnectionError, MapQueryError) as exc:
        return _fail(str(exc))
    return 0


def _run_map_get(args: argparse.Namespace) -> int:
    from swarm.protocol.map_client import MapClient, MapQueryError, format_region, region_rows

    try:
        values = [float(v) for v in (args.point or args.box).split(",")]
    except ValueError:
        values = []
    if len(values) != (3 if args.point else 6):
        return _fail(f"--point takes X,Y,Z and --box X0,Y0,Z0,X1,Y1,Z1, got {args.point or args.box!r}")
    try:
        with MapClient.connect(args.connect, args.mission, args.timeout) as client:
            region = client.point(values) if args.point else client.region(values[:3], values[3:])
    except (ConnectionError, MapQueryError) as exc:
        return _fail(str(exc))
    print(json.dumps(region_rows(region)) if args.json else format_region(region))
    return 0


def _run_map_export(args: argparse.Namespace) -> int:
    from swarm.protocol.map_client import MapClient, MapQueryError, export_map

    try:
        with MapClient.connect(args.connect, args.mission, args.timeout) as client:
            print(export_map(client, args.out, args.threshold))
    except (ConnectionError, MapQueryError, ValueError, OSError) as exc:
        return _fail(str(exc))
    return 0


# -- swarm bench --------------------------------------------------------------------------
def _add_bench(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks that print their figures",
        description="Benchmarks that print their figures.",
    )
    bsub = p.add_subparsers(dest="bench_command", required=True, metavar="COMMAND")
    fusion = bsub.add_parser(
        "fusion",
        help="rays/s of our fusion beside OctoMap's insertPointCloud",
        description="Rays/s and voxel updates/s of our fusion on the real OctoMap scan and a "
        "synthetic 160x120 frame, with OctoMap's insertPointCloud (octomap-python, "
        "pip install '.[bench]') on the same clouds, resolution and max range, single-threaded.",
    )
    fusion.add_argument(
        "--scan",
        type=Path,
        default=DEFAULT_SCAN,
        help=f"real scan to use (default: {DEFAULT_SCAN})",
    )
    fusion.add_argument("--voxel", type=float, default=0.1, help="voxel edge (default 0.1 m)")
    fusion.add_argument("--repeat", type=int, default=3, help="take the best of N runs (default 3)")
    fusion.set_defaults(run=_run_bench_fusion)
    entropy = bsub.add_parser(
        "entropy",
        help="entropy of a 1,000,000-voxel map",
        description="Time the lookup-table entropy of a 1,000,000-voxel map, "
        "the exact formula on a sample, and an incremental update.",
    )
    entropy.add_argument("--voxels", type=int, default=1_000_000)
    entropy.add_argument("--repeat", type=int, default=5)
    entropy.set_defaults(run=_run_bench_entropy)
    agent = bsub.add_parser(
        "agent",
        help="time per frame of stereo, fusion and planning",
        description="Time per frame of the agent's stages (stereo: SGBM + depth + points; fusion; "
        "planning: traversability + Dijkstra + one path) on frames rendered from a mission, at "
        "160x120 and 640x480 by default.",
    )
    agent.add_argument("--config", type=Path, default=Path("configs/office.yaml"), help="mission to render")
    agent.add_argument("--sizes", nargs="+", default=["160x120", "640x480"], help="image sizes WxH")
    agent.add_argument("--repeat", type=int, default=5)
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
        "--period", type=float, default=0.25, help="paced latency: seconds between an agent's deltas"
    )
    server.set_defaults(run=_run_bench_server)


def _run_bench_fusion(args: argparse.Namespace) -> int:
    from swarm.bench import fusion

    if not args.scan.exists():
        print(f"note: {args.scan} not found; measuring the synthetic frame only", file=sys.stderr)
    figures = fusion.run(args.scan, args.voxel, args.repeat)
    print(fusion.format_table(figures))
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
        return _fail(f"--sizes takes WxH values like 160x120, got {args.sizes}")
    print(agent_frame.format_table(agent_frame.run(args.config, sizes, args.repeat)))
    return 0


def _run_bench_server(args: argparse.Namespace) -> int:
    from swarm.bench import server

    if args.agents < 1 or args.deltas < 1 or not 1 <= args.min_voxels <= args.max_voxels or args.period <= 0:
        return _fail("--agents, --deltas, --period must be positive, and --min-voxels <= --max-voxels")
    figures = server.run(args.agents, args.deltas, args.min_voxels, args.max_voxels, args.period)
    print(server.format_table(figures))
    return 0


# -- swarm sim ----------------------------------------------------------------------------
SIM_COMMANDS = {"run", "render", "world", "-h", "--help"}
DEFAULT_MISSION = "configs/office.yaml"


def _add_sim(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim",
        help="simulated missions: run one, render a view, or run the world alone",
        description="Simulated missions. 'swarm sim [CONFIG]' is short for 'swarm sim run [CONFIG]'.",
    )
    ssub = p.add_subparsers(dest="sim_command", required=True, metavar="COMMAND")
    run = ssub.add_parser(
        "run",
        help="run a whole mission: world, map server, coordinator and one agent per robot over Zenoh",
        description="Run a mission on this machine: the simulated world, the map server, the "
        "coordinator and one agent per robot, each a separate process talking Zenoh over loopback. "
        "Shows progress, stops at the entropy threshold H_th or --max-time, and writes the run "
        "folder (metrics.json, map.npz, server_map.npz, entropy.png, top_view.png, config.yaml, "
        f"logs). Default mission: {DEFAULT_MISSION} (4 robots).",
    )
    run.add_argument("config", nargs="?", type=Path, help=f"mission YAML (default {DEFAULT_MISSION})")
    run.add_argument("--map", type=Path, help="a ROS map_server map.yaml to explore instead of a mission")
    run.add_argument("--robots", type=int, help="number of robots (default: the mission's, 1 with --map)")
    run.add_argument("--out", type=Path, help="run folder (default runs/<mission>-<strategy>-s<seed>)")
    run.add_argument("--strategy", choices=["entropy", "frontier", "random"], default="entropy")
    run.add_argument("--seed", type=int, default=0, help="random seed of the world and agents (default 0)")
    run.add_argument("--max-time", type=float, help="simulated seconds at most (default: the mission's)")
    run.add_argument(
        "--coordination",
        choices=["coordinator", "none"],
        default="coordinator",
        help="coordinator (default): targets from swarm coordinator; none: each robot chooses alone "
        "(eq. 35 on the shared map)",
    )
    run.add_argument(
        "--share-min-bits",
        type=float,
        help="override sharing.share_min_bits (0 shares every voxel: the utility filter off)",
    )
    run.add_argument(
        "--kill-coordinator-at",
        type=float,
        metavar="SIM_S",
        help="fault injection: SIGKILL the coordinator at this sim time (agents must carry on alone)",
    )
    run.add_argument("--quiet", action="store_true", help="no progress lines")
    run.set_defaults(run=_run_sim_mission)
    render = ssub.add_parser(
        "render",
        help="write what a robot sees (left/right images, true depth) as PNGs",
        description="Render robot ROBOT's first view of a mission config (or of a ROS map with "
        "--map) and write left.png, right.png, depth.png and depth.npy to --out.",
    )
    world = ssub.add_parser(
        "world",
        help="run the simulated world alone: frames out, commands in, over Zenoh",
        description="Run the lockstep pymunk world of a mission: publish every robot's frames on "
        "swarm/<mission>/robot/<rid>/frame and advance when every live agent has answered with a "
        "cmd. Agents (swarm agent) are started separately and connect to --listen.",
    )
    from sim2d.commands import add_render_arguments, add_run_arguments, run_render, run_sim

    add_render_arguments(render)
    render.set_defaults(run=run_render)
    add_run_arguments(world)
    world.set_defaults(run=run_sim)


# -- swarm agent --------------------------------------------------------------------------
def _add_agent(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "agent",
        help="run one robot's agent: stereo -> map -> exploration, over Zenoh",
        description="Run one robot's agent: take its frames (robot/<id>/frame), fuse them into a "
        "local coverage map, share voxel deltas (delta/<id>), choose targets and send velocity "
        "commands (robot/<id>/cmd). Stops on SIGINT/SIGTERM after flushing its pending deltas.",
    )
    p.add_argument("--id", required=True, dest="robot_id", help="robot id, as in the mission config")
    p.add_argument("--config", required=True, type=Path, help="mission YAML file")
    p.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (default tcp/127.0.0.1:7447); repeatable",
    )
    p.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on as well; repeatable",
    )
    p.add_argument(
        "--strategy",
        choices=["entropy", "frontier", "random"],
        default="entropy",
        help="exploration: entropy gradient (the paper, default), nearest frontier, or random",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--coordination",
        choices=["auto", "none"],
        default="auto",
        help="auto (default): ask the coordinator (coord/assign) for targets and choose alone when it "
        "does not answer; none: always choose alone (eq. 35 on the shared map)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    p.set_defaults(run=_run_agent)


def _run_agent(args: argparse.Namespace) -> int:
    import logging
    import signal

    from robot_agent.agent import Agent
    from swarm.config import ConfigError, load_mission
    from swarm.protocol import bus

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s: %(message)s"
    )
    try:
        mission = load_mission(args.config)
        session = bus.open_session(args.listen, args.connect)
        coordinated = args.coordination == "auto"
        agent = Agent(mission, args.robot_id, session, args.strategy, args.seed, coordination=coordinated)
    except (ConfigError, ValueError, ConnectionError) as exc:
        return _fail(str(exc))
    signal.signal(signal.SIGTERM, lambda *_: agent.stop())
    signal.signal(signal.SIGINT, lambda *_: agent.stop())
    try:
        agent.run()
    finally:
        stats = agent.outbox.stats
        print(
            f"{args.robot_id}: {stats.deltas_sent} deltas, {stats.voxels_sent} voxels, "
            f"{stats.bytes_sent} bytes sent, {stats.resent} resent; "
            f"merged {dict(agent.merged_counts)}; coordinator {dict(agent.coordinator_counts)}; "
            f"map entropy {agent.explorer.map_entropy:,.0f} bits",
            flush=True,
        )
        session.close()
    return 0


# -- swarm study --------------------------------------------------------------------------
def _add_study(sub: argparse._SubParsersAction) -> None:
    from swarm.mission import study

    p = sub.add_parser(
        "study",
        help="run a grid of missions (robots x strategies x coordination x seeds) and tabulate them",
        description="Run a grid of simulated missions as swarm sim subprocesses, with progress, "
        "then write results.csv, summary.csv/.md (means over seeds, speed-up over one robot) and "
        "plots of time to threshold and speed-up. See docs/study.md.",
    )
    study.add_arguments(p)
    p.set_defaults(run=study.run)


# -- swarm coordinator --------------------------------------------------------------------
def _add_coordinator(sub: argparse._SubParsersAction) -> None:
    from coordinator import command as coordinator

    p = sub.add_parser(
        "coordinator",
        help="run the coordinator: eq. 35 targets for the robots, spread apart (Burgard et al.)",
        description="Run the coordinator of a mission: keep a replica of the team map from merged, "
        "answer coord/assign with the eq. 35 target that maximises utility minus path cost, lowering "
        "the utility of targets near those other robots hold. See docs/coordinator.md.",
    )
    coordinator.add_arguments(p)
    p.set_defaults(run=coordinator.run)


# -- swarm server -------------------------------------------------------------------------
def _add_server(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "server",
        help="run the map server: merge every robot's deltas, persist, answer queries",
        description="Run the map server of a mission: listen on --listen (agents and tools connect "
        "there), apply each delta/<rid> exactly once, log it durably in --store before acking it, "
        "republish it on merged, and answer map/stats, map/acks, map/snapshot and map/region. "
        "On start it recovers the map and acks from the store; SIGINT/SIGTERM compact it and exit.",
    )
    p.add_argument("--config", required=True, type=Path, help="mission YAML file (grid, sensor model)")
    p.add_argument("--store", required=True, type=Path, help="store folder (snapshot + write-ahead log)")
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on (default tcp/127.0.0.1:7447); repeatable",
    )
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="also connect here")
    p.add_argument("--mission", help="mission name, the key prefix (default: the config's mission)")
    p.add_argument("--compact-mb", type=float, default=256, help="compact when the log reaches this (MB)")
    p.add_argument("--compact-records", type=int, default=20000, help="... or this many deltas")
    p.add_argument("--log-every", type=float, default=10.0, help="seconds between progress lines")
    p.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    p.set_defaults(run=_run_server)


def _run_server(args: argparse.Namespace) -> int:
    import logging

    from map_server.server import ServerOptions, serve
    from map_server.store import StoreError
    from swarm.config import ConfigError, load_mission
    from swarm.protocol import bus

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s: %(message)s"
    )
    if args.compact_mb <= 0 or args.compact_records < 1 or args.log_every <= 0:
        return _fail("--compact-mb, --compact-records and --log-every must be positive")
    options = ServerOptions(int(args.compact_mb * 2**20), args.compact_records, log_every_s=args.log_every)
    try:
        mission = load_mission(args.config)
        serve(mission, args.listen or [bus.DEFAULT_ENDPOINT], args.store, args.mission, options, args.connect)
    except (ConfigError, StoreError, ValueError, OSError) as exc:
        return _fail(str(exc))
    return 0


# -- swarm stereo -------------------------------------------------------------------------
def _add_stereo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "stereo",
        help="stereo tools for checking a rig",
        description="Stereo tools for checking a rig on real images.",
    )
    ssub = p.add_subparsers(dest="stereo_command", required=True, metavar="COMMAND")
    depth = ssub.add_parser(
        "depth",
        help="depth in metres from a rectified or calibrated stereo pair",
        description="Match LEFT and RIGHT with OpenCV SGBM and write depth in metres (NaN where "
        "unknown, same size as the input) to --out, and optionally a colour PNG.",
    )
    from robot_agent.stereo_command import add_arguments

    add_arguments(depth)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarm",
        description="Multi-robot probabilistic volumetric mapping (Rocha, Dias and Carvalho 2005) "
        "over Zenoh: fuse ranges into Gaussian coverage maps, simulate, benchmark.",
    )
    from swarm import __version__

    parser.add_argument("--version", action="version", version=f"swarm {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_ingest(sub)
    _add_map(sub)
    _add_bench(sub)
    _add_agent(sub)
    _add_server(sub)
    _add_coordinator(sub)
    _add_study(sub)
    _add_stereo(sub)
    _add_sim(sub)
    return parser


def _run_sim_mission(args: argparse.Namespace) -> int:
    from swarm.mission.simulated_mission import run_sim_mission

    return run_sim_mission(args, DEFAULT_MISSION)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "sim" and (len(argv) == 1 or argv[1] not in SIM_COMMANDS):
        argv.insert(1, "run")  # 'swarm sim [CONFIG]' means 'swarm sim run [CONFIG]'
    args = build_parser().parse_args(argv)
    return int(args.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
