"""``swarm map picture``: the picture set of every run (``top_view.png``, ``map_3d.png``,
``slices/``; :mod:`swarm.mission.map_pictures`) from a map file or a running map server."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from swarm.cli.common import fail


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "map",
        nargs="?",
        type=Path,
        help="map file: a map.npz (swarm map export, a run folder's) or a map server store's "
        "snapshot.npz; without it, the map of the running map server at --connect",
    )
    p.add_argument("--out", type=Path, required=True, help="folder to write the pictures into")
    p.add_argument(
        "--band",
        metavar="Z0,Z1",
        help="height band of the top view, metres (default: the robots' band of --config's mission, "
        "else the whole height)",
    )
    p.add_argument(
        "--trajectories",
        type=Path,
        metavar="FILE",
        help="robot paths to draw: a run folder's trajectories.json (robot: [[t, x, y], ...]); "
        "default: the trajectories.json beside MAP, when there is one",
    )


def run(args: argparse.Namespace, open_client) -> int:
    """Read the map, write the pictures, say what was written (``open_client``: ``swarm map``'s
    client of a running server, for no MAP)."""
    from swarm.formats.map_file import MapFileError, is_store_snapshot, load_map
    from swarm.protocol.map_client import MapQueryError, sensor_from_stats

    try:
        band = _band(args.band)
        mission = _mission(args)
        if args.map is not None:
            cmap, source = load_map(args.map), str(args.map)
            if is_store_snapshot(args.map):
                source += " (a store snapshot: the map at the server's last compaction)"
        else:
            from swarm.map.coverage_map import CoverageMap

            with open_client(args) as client:
                snap, stats = client.snapshot(), client.stats()
            cmap = CoverageMap(snap.grid, sensor_from_stats(stats), snap.lam, snap.eta)
            source = f"the map server of mission {client.mission!r} at {client.endpoint}"
        paths = _paths(args)
    except (ConnectionError, MapQueryError, MapFileError, ValueError, OSError) as exc:
        return fail(str(exc))
    from swarm.mission.map_pictures import write_map_pictures

    plan = mission.load_floor_plan() if mission is not None else None
    if band is None and mission is not None:
        band = (0.1, mission.rig.camera_height + 0.1)  # as swarm sim's top view
    written = write_map_pictures(args.out, cmap, paths, plan, band)
    slices = [p for p in written if p.parent.name == "slices"]
    print(f"pictures of {source}:")
    print(f"  {args.out / 'top_view.png'}  top view, largest E[C] per column" + _band_text(band))
    drawn = f", {len(paths)} path(s)" if paths else ""
    print(f"  {args.out / 'map_3d.png'}  occupied voxels in 3-D{drawn}")
    print(f"  {args.out / 'slices'}/  {len(slices)} height bands: E[C] and entropy")
    return 0


def _band(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        z0, z1 = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--band {text}: give Z0,Z1 in metres, e.g. 0.1,0.5") from None
    if not z0 < z1:
        raise ValueError(f"--band {text}: Z0 must be below Z1")
    return z0, z1


def _mission(args: argparse.Namespace):
    """The mission of --config, else of the config.yaml beside MAP (a run folder's), else None."""
    from swarm.config import load_mission

    config = args.config
    if config is None and args.map is not None and (args.map.parent / "config.yaml").is_file():
        config = args.map.parent / "config.yaml"
    return None if config is None else load_mission(config)


def _paths(args: argparse.Namespace) -> dict:
    from swarm.mission.picture_style import paths_from_trajectories

    path = args.trajectories
    if path is None and args.map is not None and (args.map.parent / "trajectories.json").is_file():
        path = args.map.parent / "trajectories.json"
    if path is None:
        return {}
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except ValueError as exc:
        raise ValueError(f"{path}: not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected robot ids to [[t, x, y], ...]")
    return paths_from_trajectories(data)


def _band_text(band: tuple[float, float] | None) -> str:
    return " over the whole height" if band is None else f" of z in [{band[0]:g}, {band[1]:g}] m"
