"""``swarm coordinator``: its arguments and its run."""

from __future__ import annotations

import argparse
import logging
import signal
from pathlib import Path

from coordinator.role import SNAPSHOT_TIMEOUT_S, Coordinator
from swarm.protocol import bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm coordinator``."""
    parser.description = (
        "Run the coordinator: keep a replica of the team map from swarm/<mission>/merged (starting "
        "from map/snapshot when a map server answers), follow robot/*/status, and answer "
        "coord/assign with entropy-gradient targets spread out over the team (Burgard et al. 2005). "
        "Stops on SIGINT/SIGTERM."
    )
    parser.add_argument("--config", required=True, type=Path, help="mission YAML file")
    parser.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (default tcp/127.0.0.1:7447); repeatable",
    )
    parser.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on as well; repeatable",
    )
    parser.add_argument(
        "--mission", metavar="NAME", help="mission name in the keys (default: the config's `mission`)"
    )
    parser.add_argument(
        "--snapshot-timeout",
        type=float,
        default=SNAPSHOT_TIMEOUT_S,
        metavar="S",
        help=f"seconds to wait for a map server's snapshot at start (default {SNAPSHOT_TIMEOUT_S:g})",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log at debug level")


def run(args: argparse.Namespace) -> int:
    """``swarm coordinator``: run until SIGINT/SIGTERM; 0 on a clean stop, 2 on bad arguments."""
    import sys

    from swarm.config import ConfigError, load_mission

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s: %(message)s"
    )
    try:
        mission = load_mission(args.config)
        if args.mission is not None:
            bus.key(args.mission)  # a valid key part
        session = bus.open_session(args.listen, args.connect)
    except (ConfigError, ValueError, ConnectionError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 2
    coordinator = Coordinator(
        mission, session, mission_name=args.mission, snapshot_timeout=args.snapshot_timeout
    )
    signal.signal(signal.SIGTERM, lambda *_: coordinator.request_stop())
    signal.signal(signal.SIGINT, lambda *_: coordinator.request_stop())
    try:
        coordinator.start()
        coordinator.wait()
    finally:
        coordinator.stop()
        counts = coordinator.counts
        print(
            "coordinator: "
            + ", ".join(f"{k} {counts[k]}" for k in sorted(counts))
            + f"; team map {coordinator.state.team.entropy_bits:,.0f} bits",
            flush=True,
        )
        session.close()
    return 0
