"""``swarm coordinator``: its arguments and its run."""

from __future__ import annotations

import argparse
import logging
import signal
import time
from pathlib import Path

from coordinator.defaults import SNAPSHOT_TIMEOUT_S
from swarm.child_command import stop_signals
from swarm.protocol import bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm coordinator``."""
    parser.description = (
        "Run the coordinator: keep a replica of the team map from swarm/<mission>/merged (starting "
        "from map/snapshot when a map server answers), follow robot/*/status, and answer "
        "coord/assign/<rid> with entropy-gradient targets spread out over the team (Burgard et al. 2005). "
        "Stops on SIGINT/SIGTERM."
    )
    parser.add_argument("--config", required=True, type=Path, help="mission YAML file")
    bus.add_client_arguments(parser)
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
    parser.add_argument(
        "--progress-every",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds between progress lines: requests answered, merged deltas, team map entropy "
        "(default 10)",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log at debug level")


def message_limit_of(mission) -> int:
    """The largest message (bytes) the coordinator's Zenoh session takes from a link: twice the
    largest it must take (a merged delta of the default maximum size, or the map server's
    snapshot with the ledger of every robot it may accept), at least 64 MiB
    (docs/protocol.md, "Message sizes")."""
    from swarm.protocol.message_size import PATTERN_ROBOTS, delta_bytes, message_limit, snapshot_bytes

    grid = mission.workspace.grid()
    robots = len(mission.robot_ids) + PATTERN_ROBOTS
    return message_limit(delta_bytes(grid), snapshot_bytes(grid, robots))


def run(args: argparse.Namespace) -> int:
    """``swarm coordinator``: run until SIGINT/SIGTERM; 0 on a clean stop, 2 on bad arguments."""
    import sys
    import threading

    from coordinator.role import Coordinator
    from swarm.config import ConfigError, load_mission
    from swarm.protocol.map_client import missions_answering
    from swarm.protocol.mission_listener import MissionDoneListener

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s: %(message)s"
    )
    log = logging.getLogger("coordinator")
    try:
        if not args.progress_every > 0:
            raise ValueError(f"--progress-every {args.progress_every}: must be positive")
        mission = load_mission(args.config)
        if args.mission is not None:
            bus.key(args.mission)  # a valid key part
        log.info(bus.describe_connection(args.listen, args.connect))
        session = bus.open_session(
            args.listen,
            args.connect,
            config_file=args.zenoh_config,
            max_message_bytes=message_limit_of(mission),
        )
        log.info(
            "connected; mission %r (from %s): loading the planner's kernels and the team map",
            args.mission or mission.mission,
            args.config,
        )
    except (ConfigError, ValueError, ConnectionError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 2
    coordinator = Coordinator(
        mission, session, mission_name=args.mission, snapshot_timeout=args.snapshot_timeout
    )
    stopping = threading.Event()

    def on_signal(*_) -> None:
        coordinator.request_stop()
        stopping.set()

    for sig in stop_signals():  # SIGTERM, and SIGINT unless a runner started it (swarm.child_command)
        signal.signal(sig, on_signal)
    name = coordinator.name

    def on_done(done) -> None:  # the coordinator is a service: it says so and goes on answering
        counts = coordinator.counts
        log.info(
            "mission done (%s): %d assign requests answered, %d merged deltas applied; answering "
            "(nothing left) until stopped",
            done.describe(),
            counts["requests"],
            counts["merged_applied"],
        )

    ending = MissionDoneListener(session, name, on_done)
    try:
        coordinator.start()
        others = [] if coordinator.started_from_snapshot else missions_answering(session, 0.5)
        if others and name not in others:
            origin = "--mission" if args.mission else f"{args.config}: mission"
            serves = ", ".join(repr(m) for m in others)
            print(
                f"swarm: error: {origin}: mission {name!r}, but the map server on this network serves "
                f"mission {serves}",
                file=sys.stderr,
            )
            return 2
        log.info(
            "waiting for requests on %s, robot statuses on %s and the team map on %s",
            bus.key_pattern(name, "coord", "assign", "*"),
            bus.key_pattern(name, "robot", "*", "status"),
            bus.key(name, "merged"),
        )
        last = (time.monotonic(), 0)
        while not stopping.wait(args.progress_every):
            now, counts = time.monotonic(), coordinator.counts
            answered = counts["requests"]
            log.info(
                "%d assign requests answered (%.1f/s; with an error: %d malformed or on another robot's key, "
                "%d superseded, %d busy), %d merged deltas applied, team map %s bits",
                answered,
                (answered - last[1]) / max(now - last[0], 1e-9),
                counts["requests_rejected"],
                counts["requests_superseded"],
                counts["requests_busy"],
                counts["merged_applied"],
                f"{coordinator.state.team.entropy_bits:,.0f}",
            )
            last = (now, answered)
    finally:
        ending.close()
        coordinator.stop()
        counts = coordinator.counts
        print(
            "coordinator: final: "
            + ", ".join(f"{k} {counts[k]}" for k in sorted(counts))
            + f"; team map {coordinator.state.team.entropy_bits:,.0f} bits",
            flush=True,
        )
        session.close()
    return 0
