"""``swarm map``: inspect coverage map files and query a running map server."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from swarm.cli import ros2_map
from swarm.cli.common import fail
from swarm.protocol import bus


# -- swarm map info -----------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
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
        help="a running map server's figures: a summary, or the map/stats JSON",
        description="Ask a running map server (swarm server) for map/stats and print a summary: the "
        "mission and its grid, the known fraction, the entropy beside the initial one and H_th (and "
        "whether the mission is done), the deltas applied and refused, and per robot its deltas and "
        "acks. --json prints the whole map/stats object (docs/protocol.md, Queries).",
    )
    _add_map_query_arguments(stats)
    stats.add_argument("--json", action="store_true", help="print the whole map/stats JSON object")
    stats.set_defaults(run=_run_map_stats)
    picture = msub.add_parser(
        "picture",
        help="the pictures of a map (top view, 3-D, slices) from a map file or a running server",
        description="Write the picture set every run writes (top_view.png, map_3d.png and slices/ of "
        "E[C] and entropy per height band, one palette, colour bars in their units) into --out, from "
        "a map file (map.npz, a store's snapshot.npz) or from the running map server at --connect. "
        "A run folder's map.npz brings its config.yaml (floor plan, the robots' band) and "
        "trajectories.json (paths) along.",
    )
    _add_map_query_arguments(picture)
    picture.defer(_picture_arguments)
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
        help="write the team map (from a running server or a map.npz) as .npz, .ply or OctoMap .bt",
        description="Write --out from a running map server's map/snapshot, or from the map file "
        "--from. By its suffix: .npz a map file (as swarm map info reads); .ply the voxels with "
        "E[C] > --threshold, with mu, sigma, entropy (bits) and expected_coverage per vertex "
        "(--cubes: as cubes); .bt an OctoMap binary tree at the map's resolution: voxels with "
        "sigma > --max-sigma unknown, the others occupied when E[C] > 0.5, else free. OctoMap "
        "anchors voxels at the world origin: a map whose origin is not a multiple of its voxel "
        "size is refused unless --align shift moves it (less than half a voxel per axis).",
    )
    _add_map_query_arguments(export)
    export.add_argument(
        "--from", dest="source", type=Path, metavar="MAP.npz", help="read this map file, no server"
    )
    export.add_argument("--out", type=Path, required=True, help="output file: *.npz, *.ply or *.bt")
    export.add_argument("--threshold", type=float, default=0.5, help="PLY: E[C] above this (default 0.5)")
    export.add_argument("--cubes", action="store_true", help="PLY: each voxel a cube (8 vertices, 6 faces)")
    export.add_argument(
        "--max-sigma",
        type=float,
        default=0.5,
        help=".bt: voxels with a larger sigma are unknown (default 0.5)",
    )
    export.add_argument(
        "--align",
        choices=("refuse", "shift"),
        default="refuse",
        help=".bt: an origin off OctoMap's lattice is refused (default) or shifted onto it",
    )
    export.set_defaults(run=_run_map_export)
    imp = msub.add_parser(
        "import",
        help="turn an OctoMap .bt or .ot into a map.npz a mission can start from (prior_map:)",
        description="Read an OctoMap binary tree (.bt) and write a coverage map file at the tree's "
        "resolution over the box of its known nodes, pruned nodes expanded: occupied voxels get "
        "the belief N(1, --sigma), free voxels N(0, --sigma), unknown voxels the uninformative "
        "prior N(0.5, 10 sigma_s(max range)). Name the result as prior_map: in a mission file.",
    )
    imp.add_argument("bt", type=Path, help="OctoMap .bt or .ot file")
    imp.add_argument("--out", type=Path, required=True, help="output map file (*.npz)")
    imp.add_argument(
        "--sigma",
        type=float,
        default=0.1,
        help="belief standard deviation of known voxels, coverage units (default 0.1)",
    )
    imp.set_defaults(run=_run_map_import)
    ros2_map.register(msub, _add_map_query_arguments, _open_client)


def _picture_arguments(p: argparse.ArgumentParser) -> None:
    from swarm.cli import map_picture

    map_picture.add_arguments(p)
    p.set_defaults(run=lambda args: map_picture.run(args, _open_client))


def _add_map_query_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint of the map server (default tcp/127.0.0.1:7447); repeatable",
    )
    bus.add_zenoh_config_argument(p)
    p.add_argument(
        "--mission",
        help="mission name, the key prefix (default: --config's mission, else the only mission whose "
        "server answers; a server of another mission is an error naming both)",
    )
    p.add_argument(
        "--config",
        type=Path,
        help="mission YAML file: take the mission name from it (swarm map picture: its floor plan too)",
    )
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for an answer (default 5)")


def _open_client(args: argparse.Namespace):
    """A MapClient on the mission to query (see ``resolve_mission`` for the rule)."""
    from swarm.config import load_mission
    from swarm.protocol.map_client import MapClient, resolve_mission
    from swarm.protocol.sharded_client import ShardedMapClient, discover_layout

    wanted, origin = args.mission, "--mission"
    if wanted is None and args.config is not None:
        wanted, origin = load_mission(args.config).mission, f"{args.config}: mission"
    client = MapClient.connect(args.connect, wanted or "default", args.timeout, args.zenoh_config)
    try:
        client.mission = resolve_mission(client.session, wanted, args.timeout, client.endpoint, origin)
        # a sharded map service: one client per shard, answers fanned in (docs/sharding.md)
        layout = discover_layout(client.session, client.mission, args.timeout, once=True)
    except BaseException:
        client.close()
        raise
    if layout is None:
        return client
    return ShardedMapClient(
        client.session, client.mission, layout, args.timeout, client.endpoint, owns_session=True
    )


def _run_map_info(args: argparse.Namespace) -> int:
    from swarm.formats.map_file import MapFileError, is_store_snapshot, load_map
    from swarm.map.summary import summarize

    try:
        summary = summarize(load_map(args.map))
    except (MapFileError, FileNotFoundError) as exc:
        return fail(str(exc))
    if is_store_snapshot(args.map):
        summary["note"] = (
            "a map server's store snapshot: the team map at its last compaction, without the "
            "deltas logged after it (swarm map export gets the live map)"
        )
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:>22}: {value}")
    return 0


def _run_map_stats(args: argparse.Namespace) -> int:
    from swarm.cli.map_stats import stats_summary
    from swarm.protocol.map_client import MapQueryError

    try:
        with _open_client(args) as client:
            stats = client.stats()
    except (ConnectionError, MapQueryError, ValueError) as exc:
        return fail(_explained(exc, args))
    print(json.dumps(stats, indent=1) if args.json else "\n".join(stats_summary(stats)))
    return 0


def _run_map_get(args: argparse.Namespace) -> int:
    from swarm.protocol.map_client import MapQueryError, format_region, region_rows

    try:
        values = [float(v) for v in (args.point or args.box).split(",")]
    except ValueError:
        values = []
    if len(values) != (3 if args.point else 6):
        return fail(f"--point takes X,Y,Z and --box X0,Y0,Z0,X1,Y1,Z1, got {args.point or args.box!r}")
    option = "--point" if args.point else "--box"
    if not all(math.isfinite(v) for v in values):
        return fail(f"{option} {args.point or args.box}: coordinates must be finite numbers")
    try:
        with _open_client(args) as client:
            region = client.point(values) if args.point else client.region(values[:3], values[3:])
    except (ConnectionError, MapQueryError, ValueError) as exc:
        return fail(_explained(exc, args))
    if len(region) == 0:
        lo, hi = region.grid.lo, region.grid.hi
        box = ", ".join(f"{a:g}..{b:g}" for a, b in zip(lo, hi, strict=True))
        return fail(f"{option} {args.point or args.box}: outside the map's workspace (x, y, z in {box} m)")
    print(json.dumps(region_rows(region)) if args.json else format_region(region))
    return 0


def _run_map_export(args: argparse.Namespace) -> int:
    from swarm.formats.map_export import export_coverage_map
    from swarm.formats.map_file import MapFileError, load_map
    from swarm.protocol.map_client import MapQueryError, export_map

    options = {"cubes": args.cubes, "max_sigma": args.max_sigma, "align": args.align}
    try:
        if args.source is not None:
            print(export_coverage_map(args.out, load_map(args.source), args.threshold, **options))
            return 0
        with _open_client(args) as client:
            print(export_map(client, args.out, args.threshold, **options))
    except (ConnectionError, MapQueryError, MapFileError, ValueError, OSError) as exc:
        return fail(_explained(exc, args))
    return 0


def _run_map_import(args: argparse.Namespace) -> int:
    from swarm.formats.octomap_file import OctomapFileError
    from swarm.formats.octomap_map import import_bt

    if args.out.suffix.lower() != ".npz":
        return fail(f"{args.out}: the output must end in .npz")
    try:
        print(f"reading {args.bt} ...", flush=True)
        print("wrote " + import_bt(args.bt, args.out, args.sigma))
    except (OctomapFileError, ValueError, OSError) as exc:
        return fail(str(exc))
    return 0


def _explained(exc: Exception, args: argparse.Namespace) -> str:
    """The error's text; over TLS, a server that does not answer may be one that refuses our
    certificate (it looks the same from here), so the text says to check them (docs/security.md)."""
    text = str(exc)
    if not isinstance(exc, ConnectionError) or "certificate" in text:
        return text
    config = bus.config_path(getattr(args, "zenoh_config", None))
    if config is not None:
        text += f" (over TLS a refused certificate looks like this: check that {config} names "
        text += "this mission's CA and an identity allowed to query)"
    elif any(str(e).startswith("tls/") for e in getattr(args, "connect", None) or ()):
        text += " (a tls/ endpoint needs --zenoh-config with the mission's CA and a certificate, e.g. "
        text += "<run>/security/tool/zenoh.json5 of swarm sim --secure; docs/security.md)"
    return text
