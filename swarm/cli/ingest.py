"""``swarm ingest``: fuse a point cloud seen from one sensor position into a coverage map."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from swarm.cli.common import fail


# -- swarm ingest -------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
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
        "--discretize",
        action="store_true",
        help="one measurement per end voxel: the mean end point of the rays ending there (OctoMap's option)",
    )
    p.add_argument(
        "--no-hit-precedence",
        action="store_true",
        help="let rays clear voxels that hold another ray's return (the paper's text; default: they do not)",
    )
    p.add_argument(
        "--bounds",
        type=float,
        nargs=6,
        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
        help="workspace box in metres (default: fits the origin and the rays up to max range, corners on "
        "multiples of --voxel, as OctoMap's voxels)",
    )
    p.add_argument(
        "--repeat",
        type=int,
        default=1,
        metavar="N",
        help="fuse the cloud N times, each into a fresh map, and report the best time as "
        "fusion_seconds, as 'swarm bench fusion --repeat N' does (default 1; the map is the same)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object with the figures")
    p.set_defaults(run=_run_ingest)


def _run_ingest(args: argparse.Namespace) -> int:
    from swarm.formats.map_file import save_map
    from swarm.formats.point_cloud_file import read_point_cloud
    from swarm.map.ingest import ingest_cloud
    from swarm.map.sensor_model import SensorModel

    if args.repeat < 1:
        return fail(f"--repeat must be at least 1, got {args.repeat}")
    if not (args.voxel > 0 and np.isfinite(args.voxel)):
        return fail(f"--voxel must be a positive number, got {args.voxel}")
    try:
        sensor = SensorModel(
            args.sigma_min,
            args.zeta,
            args.tau,
            args.max_range,
            hit_precedence=not args.no_hit_precedence,
            discretize=args.discretize,
        )
        points = read_point_cloud(args.cloud)
        bounds = None
        if args.bounds is not None:
            bounds = (np.array(args.bounds[:3]), np.array(args.bounds[3:]))
            if not np.all(bounds[1] > bounds[0]):
                return fail(f"--bounds: each max must exceed its min, got {args.bounds}")
        cells = np.prod(np.ceil((bounds[1] - bounds[0]) / args.voxel)) if bounds else 0
        if cells > 400e6:
            return fail(f"--bounds at --voxel {args.voxel} make {cells:.3g} voxels (limit 4e8)")
        cmap, report = ingest_cloud(points, np.array(args.origin), sensor, args.voxel, bounds, args.repeat)
    except ValueError as exc:
        return fail(str(exc))
    save_map(args.out, cmap)
    if args.json:
        print(json.dumps(report.to_dict()))
    else:
        r = report
        print(
            f"fused {r.rays:,} rays of {r.points:,} points into {r.voxels:,} voxels {tuple(r.shape)} "
            f"in {r.fusion_seconds:.3f} s ({r.voxel_updates:,} voxel updates)"
            + (
                f"; best of {r.fusion_repeats}, the first {r.first_fusion_seconds:.3f} s"
                if r.fusion_repeats > 1
                else ""
            )
        )
        print(
            f"skipped: {r.skipped_nonfinite} NaN/inf, {r.skipped_outside} outside the box, "
            f"{r.skipped_degenerate} zero-length; cut: {r.truncated_at_max_range} at max range, "
            f"{r.clipped_at_box} at the box (free space up to it)"
        )
        print(f"entropy: {r.initial_entropy_bits:,.0f} -> {r.final_entropy_bits:,.0f} bits")
        print(f"wrote {args.out}")
    return 0
