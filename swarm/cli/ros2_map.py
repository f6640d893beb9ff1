"""``swarm map ros2``: the running mission's team map as ROS 2 topics over rmw_zenoh (docs/ros2.md)."""

from __future__ import annotations

import argparse
import os
import signal
import threading
import time
from pathlib import Path

from swarm.cli.common import endpoint_problem, fail

#: option of each Ros2MapOptions field, for error lines
_FLAGS = {  # fmt: skip
    "domain_id": "--domain-id",
    "distro": "--distro",
    "namespace": "--namespace",
    "node_name": "--node-name",
    "map_topic": "--map-topic",
    "updates_topic": "--updates-topic",
    "cloud_topic": "--cloud-topic",
    "frame_id": "--frame-id",
    "band": "--band",
    "threshold": "--threshold",
    "free_rule": "--free-if",
    "period_s": "--period",
    "cloud_period_s": "--cloud-period",
    "cloud_bytes_per_s": "--cloud-rate",
    "full_period_s": "--full-period",
    "incremental_above": "--incremental-above",
}


def register(msub: argparse._SubParsersAction, add_query_arguments, open_client) -> None:
    """Add ``ros2`` to the ``swarm map`` commands: ``add_query_arguments`` adds --connect,
    --mission, --config...; ``open_client(args)`` is the MapClient on the mission they name."""
    p = msub.add_parser(
        "ros2",
        help="publish the running team map as ROS 2 topics (OccupancyGrid, PointCloud2) over rmw_zenoh",
        description="Follow a running mission's team map (its merged deltas, from map/snapshot on, as "
        "any client does) and publish it as a ROS 2 node over Zenoh, as rmw_zenoh_cpp does, no ROS "
        "install needed: the 2-D projection of the robots' height band as nav_msgs/OccupancyGrid on "
        "'map' (latched) with map_msgs/OccupancyGridUpdate on 'map_updates' for large grids, and the "
        "occupied voxels with mu, sigma and entropy as sensor_msgs/PointCloud2 on 'team_map_cloud' "
        "(latched), each rate-limited. ROS 2 robots, RViz, Foxglove and Nav2 see them with "
        "RMW_IMPLEMENTATION=rmw_zenoh_cpp (docs/ros2.md, 'Team map').",
    )
    add_query_arguments(p)
    p.add_argument(
        "--ros-connect",
        action="append",
        metavar="ENDPOINT",
        help="publish to the robots' rmw_zenohd router here (e.g. tcp/192.168.1.10:7447) "
        "instead of the team's router (--connect); repeatable",
    )
    p.add_argument(
        "--ros-zenoh-config",
        type=Path,
        metavar="FILE",
        help="Zenoh JSON5 config of the robots' side (e.g. rmw_zenoh's TLS, its endpoints unless "
        "--ros-connect); default with --ros-connect: $ZENOH_CONFIG",
    )
    p.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else 0)")
    p.add_argument(
        "--distro", default="jazzy", help="ROS 2 distribution: humble, jazzy (default), kilted, ..."
    )
    p.add_argument("--namespace", default="/", help="the node's namespace, e.g. /team (default /)")
    p.add_argument("--node-name", default="swarm_team_map", help="node name (default swarm_team_map)")
    p.add_argument("--frame-id", default="map", help="frame of every message (default map)")
    p.add_argument("--map-topic", default="map", help="OccupancyGrid topic (default map)")
    p.add_argument("--updates-topic", help="OccupancyGridUpdate topic (default <map topic>_updates)")
    p.add_argument(
        "--cloud-topic", default="team_map_cloud", help="PointCloud2 topic (default team_map_cloud)"
    )
    p.add_argument(
        "--band",
        nargs=2,
        type=float,
        metavar=("Z_LO", "Z_HI"),
        help="height band (m) of the 2-D map (default 0.1 and 0.1 m above --config's camera "
        "height, at least 0.3; without --config 0.1 0.5)",
    )
    p.add_argument("--threshold", type=float, default=0.5, help="E[C] above this is occupied (default 0.5)")
    p.add_argument(
        "--free-if",
        dest="free_rule",
        choices=("all", "any"),
        default="all",
        help="a column is free when all (default) or any of its band voxels are known",
    )
    p.add_argument("--period", type=float, default=1.0, help="seconds between grids at most (default 1)")
    p.add_argument(
        "--cloud-period", type=float, default=2.0, help="seconds between clouds at most (default 2)"
    )
    p.add_argument(
        "--cloud-rate", type=float, default=2.0, help="MB/s of clouds at most on average (default 2)"
    )
    p.add_argument(
        "--full-period",
        type=float,
        default=10.0,
        help="large grids: seconds between whole grids (default 10)",
    )
    p.add_argument(
        "--incremental-above",
        type=int,
        default=250_000,
        help="grids of more cells send the box of changed cells between whole grids (default 250000)",
    )
    p.add_argument("--no-grid", action="store_true", help="publish no OccupancyGrid")
    p.add_argument("--no-cloud", action="store_true", help="publish no PointCloud2")
    p.add_argument(
        "--duration", type=float, help="stop after this many seconds (default: at Ctrl-C / SIGTERM)"
    )
    p.add_argument(
        "--progress-every", type=float, default=10.0, help="seconds between progress lines (default 10)"
    )
    p.set_defaults(run=_run, open_client=open_client)


def _options(args: argparse.Namespace, camera_height: float | None):
    """The validated options, or a ValueError whose lines name the options."""
    from pydantic import ValidationError

    from ros2_map.options import DEFAULT_BAND, Ros2MapOptions
    from swarm.navigation.traversability import FLOOR_CLEARANCE, robot_band_top

    band = args.band
    if band is None:
        band = DEFAULT_BAND if camera_height is None else (FLOOR_CLEARANCE, robot_band_top(camera_height))
    domain = args.domain_id
    if domain is None:
        text = os.environ.get("ROS_DOMAIN_ID", "").strip() or "0"
        if not text.isdigit():
            raise ValueError(f"ROS_DOMAIN_ID: must be an integer 0..232 (got {text!r})")
        domain = int(text)
    values = dict(
        domain_id=domain,
        distro=args.distro,
        namespace=args.namespace,
        node_name=args.node_name,
        map_topic=args.map_topic,
        updates_topic=args.updates_topic,
        cloud_topic=args.cloud_topic,
        frame_id=args.frame_id,
        band=tuple(band),
        threshold=args.threshold,
        free_rule=args.free_rule,
        grid=not args.no_grid,
        cloud=not args.no_cloud,
        period_s=args.period,
        cloud_period_s=args.cloud_period,
        cloud_bytes_per_s=args.cloud_rate * 1e6,
        full_period_s=args.full_period,
        incremental_above=args.incremental_above,
    )
    try:
        return Ros2MapOptions(**values)
    except ValidationError as exc:
        lines = []
        for error in exc.errors():
            field = str(error["loc"][0]) if error["loc"] else ""
            message = str(error.get("ctx", {}).get("error", error["msg"]))
            lines.append(f"{_FLAGS.get(field, '--' + field.replace('_', '-'))}: {message}")
        raise ValueError("\n".join(lines)) from None


def _run(args: argparse.Namespace) -> int:
    from ros2_map.role import TeamMapTopics
    from swarm.config import load_mission
    from swarm.protocol import bus

    for endpoint in args.ros_connect or []:
        problem = endpoint_problem(endpoint)
        if problem:
            return fail(f"--ros-connect {endpoint}: {problem}")
    if args.no_grid and args.no_cloud:
        return fail("--no-grid and --no-cloud: nothing left to publish")
    if not args.progress_every > 0:
        return fail(f"--progress-every must be > 0, got {args.progress_every}")
    camera_height = None if args.config is None else load_mission(args.config).rig.camera_height
    try:
        options = _options(args, camera_height)
    except ValueError as exc:
        return fail(str(exc))
    try:
        client = args.open_client(args)
    except ConnectionError as exc:
        return fail(str(exc))
    ros_session = None
    try:  # the ROS side on a session of its own (timestamped: latched topics need it)
        if args.ros_connect or args.ros_zenoh_config:
            ros_session = bus.open_session(
                connect=args.ros_connect, config_file=args.ros_zenoh_config, timestamping=True
            )
        else:
            ros_session = bus.open_session(
                connect=args.connect, config_file=args.zenoh_config, timestamping=True
            )
        topics = TeamMapTopics(client.session, client.mission, options, ros_session)
        topics.start()
    except (ConnectionError, ValueError) as exc:
        client.close()
        if ros_session is not None:
            ros_session.close()
        return fail(str(exc))
    return _follow(topics, args, client, ros_session)


def _follow(topics, args: argparse.Namespace, client, ros_session) -> int:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    from ros2_map.role import TYPES

    shown = ", ".join(f"{name} ({TYPES[kind]})" for kind, name in topics.topics().items())
    print(
        f"ros2 map: mission {client.mission!r} as ROS 2 domain {topics.options.domain_id} "
        f"({topics.options.distro}): {shown}",
        flush=True,
    )
    deadline = None if args.duration is None else time.monotonic() + args.duration
    next_line = time.monotonic() + args.progress_every
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            stop.wait(0.2)
            if time.monotonic() >= next_line:
                next_line += args.progress_every
                print(topics.progress_line(), flush=True)
    finally:
        topics.stop()
        print(topics.progress_line(), flush=True)
        if ros_session is not None:
            ros_session.close()
        client.close()
    return 0
