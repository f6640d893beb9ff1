"""The ``swarm`` command line: a thin shell over the roles and the map core."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

DEFAULT_SCAN = Path(__file__).resolve().parent.parent / "data" / "octomap" / "scan.dat.bz2"


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
    from swarm.ingest import ingest_cloud
    from swarm.map.sensor_model import SensorModel
    from swarm.map_file import save_map
    from swarm.point_cloud_file import read_point_cloud

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
            f"skipped: {r.skipped_nonfinite} NaN/inf, {r.skipped_outside} leaving the box, "
            f"{r.skipped_degenerate} zero-length; {r.truncated_at_max_range} cut at max range"
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


def _run_map_info(args: argparse.Namespace) -> int:
    from swarm.map_file import MapFileError, load_map
    from swarm.map_summary import summarize

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


def _run_bench_fusion(args: argparse.Namespace) -> int:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
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


# -- swarm sim ----------------------------------------------------------------------------
def _add_sim(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="the floor-plan simulator", description="The floor-plan simulator.")
    ssub = p.add_subparsers(dest="sim_command", required=True, metavar="COMMAND")
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
    _add_stereo(sub)
    _add_sim(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
