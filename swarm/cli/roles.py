"""``swarm agent``, ``swarm coordinator``, ``swarm server``: each role on its own, as on real robots."""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm.cli import ros2_options
from swarm.cli.common import fail
from swarm.navigation.strategies import STRATEGIES
from swarm.protocol import bus


# -- swarm agent --------------------------------------------------------------------------
def register_agent(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "agent",
        help="run one robot's agent: stereo -> map -> exploration, over Zenoh",
        description="Run one robot's agent: take its frames (robot/<id>/frame), fuse them into a "
        "local coverage map, share voxel deltas (delta/<id>), choose targets and send velocity "
        "commands (robot/<id>/cmd). Stops on SIGINT/SIGTERM, and when the map server announces the "
        "end of the mission (mission/done), after flushing its pending deltas; then prints its "
        "final figures.",
    )
    p.add_argument("--id", required=True, dest="robot_id", help="robot id, as in the mission config")
    p.add_argument("--config", required=True, type=Path, help="mission YAML file")
    bus.add_client_arguments(p)
    p.add_argument(
        "--strategy",
        choices=STRATEGIES,
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
    p.add_argument(
        "--progress-every",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds between progress lines: frames fused, deltas sent and acked, map entropy (default 10)",
    )
    p.add_argument(
        "--on-mission-done",
        choices=["stop", "continue"],
        default="stop",
        help="when the map server announces the end of the mission (mission/done): stop (default), or "
        "continue taking frames (a replay: the recording decides when it ends)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    ros2_options.add_arguments(p)
    p.set_defaults(run=_run_agent)


def _run_agent(args: argparse.Namespace) -> int:
    import logging
    import signal

    from robot_agent.agent import Agent
    from swarm.child_command import stop_signals
    from swarm.config import ConfigError, load_mission
    from swarm.protocol.map_client import MissionMismatch
    from swarm.protocol.mission_listener import MissionDoneListener

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s: %(message)s"
    )
    if args.progress_every <= 0:
        return fail(f"--progress-every {args.progress_every}: must be positive")
    log = logging.getLogger("swarm.agent")
    try:
        mission = load_mission(args.config)
        if args.robot_id not in mission.robot_ids:
            known = ", ".join(mission.robot_ids)
            raise ValueError(f"{args.config}: robots: no robot {args.robot_id!r} (robots: {known})")
        ros2 = ros2_options.ros2_config(mission, args.robot_id, args)
        log.info("%s: %s", args.robot_id, bus.describe_connection(args.listen, args.connect))
        session = bus.open_session(
            args.listen, args.connect, config_file=args.zenoh_config, timestamping=ros2 is not None
        )
        log.info("%s: connected; mission %r (from %s)", args.robot_id, mission.mission, args.config)
        coordinated = args.coordination == "auto"
        link = None
        if ros2 is not None:
            from robot_agent.ros2_link import Ros2Link

            link = Ros2Link.open(mission, args.robot_id, session, ros2)
        agent = Agent(mission, args.robot_id, session, args.strategy, args.seed, coordinated, link)
        agent.progress_every_s = args.progress_every
    except (ConfigError, ValueError, ConnectionError) as exc:
        return fail(str(exc))
    for sig in stop_signals():  # SIGTERM, and SIGINT unless a runner started it (swarm.child_command)
        signal.signal(sig, lambda *_: agent.stop())

    def on_done(done) -> None:  # the map server's end of the mission: stop as on SIGTERM
        if args.on_mission_done == "continue":
            log.info("%s: mission done (%s): taking frames on (--on-mission-done continue)",
                     args.robot_id, done.describe())  # fmt: skip
            return
        log.info("%s: mission done (%s): stopping", args.robot_id, done.describe())
        agent.stop()

    ending = MissionDoneListener(session, mission.mission, on_done)
    mismatch = None
    try:
        agent.run()
    except MissionMismatch as exc:
        mismatch = exc
    finally:
        ending.close()
        if mismatch is None:  # after the shutdown flush: the final figures
            stats = agent.sharing.stats
            print(
                f"{args.robot_id}: final, after the shutdown flush: {agent.frames_fused:,} frames fused, "
                f"{stats.deltas_sent:,} deltas ({stats.voxels_sent:,} voxels, {stats.bytes_sent:,} bytes) "
                f"sent ({stats.released_held:,} voxels of them under share_min_bits, past max_held_bits), "
                f"{agent.acked:,} acked, {stats.resent:,} resent; merged {dict(agent.merged_counts)}; "
                f"coordinator {dict(agent.coordinator_counts)}; targets {dict(agent.explorer.target_kinds)}; "
                f"drives given up {dict(agent.explorer.give_ups)}; "
                f"coordinator targets declined (near one it gave up) {agent.explorer.declined_assignments}; "
                f"map entropy {agent.explorer.map_entropy:,.0f} bits",
                flush=True,
            )
            if link is not None:
                frames, commands = link.frames, link.commands
                dropped = frames.all_counters()
                print(f"{args.robot_id}: ROS 2: {frames.pairs_made} pairs taken; dropped {dropped}; "
                      f"commands {dict(commands.counters)}", flush=True)  # fmt: skip
        session.close()
    return fail(f"{args.config}: mission: {mismatch}") if mismatch else 0


# -- swarm coordinator --------------------------------------------------------------------
def register_coordinator(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "coordinator",
        help="run the coordinator: eq. 35 targets for the robots, spread apart (Burgard et al.)",
        description="Run the coordinator of a mission: keep a replica of the team map from merged, "
        "answer coord/assign with the eq. 35 target that maximises utility minus path cost, lowering "
        "the utility of targets near those other robots hold. See docs/coordinator.md.",
    )
    p.defer(_coordinator_arguments)


def _coordinator_arguments(p: argparse.ArgumentParser) -> None:
    from coordinator import command as coordinator

    coordinator.add_arguments(p)
    p.set_defaults(run=coordinator.run)


# -- swarm server -------------------------------------------------------------------------
def register_server(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "server",
        help="run the map server: merge every robot's deltas, persist, answer queries",
        description="Run the map server of a mission: listen on --listen (agents and tools connect "
        "there), apply each delta/<rid> exactly once, log it durably in --store before acking it, "
        "republish it on merged, and answer map/stats, map/acks, map/snapshot and map/region. "
        "On start it recovers the map and acks from the store; SIGINT/SIGTERM compact it and exit. "
        "When the team map's entropy reaches the mission's H_th, or every robot heard from has nothing "
        "left, it announces the end of the mission on mission/done (agents and the world stop) and "
        "goes on answering queries.",
    )
    p.add_argument("--config", required=True, type=Path, help="mission YAML file (grid, sensor model)")
    p.add_argument("--store", required=True, type=Path, help="store folder (snapshot + write-ahead log)")
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on (default: the --zenoh-config file's, else tcp/127.0.0.1:7447); "
        "repeatable",
    )
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="also connect here")
    bus.add_zenoh_config_argument(p)
    p.add_argument("--mission", help="mission name, the key prefix (default: the config's mission)")
    p.add_argument(
        "--shard",
        type=int,
        metavar="K",
        help="which slab of the mission's map_service layout this process serves (0..shards-1; keys "
        "under <mission>/shard/K; docs/sharding.md); needed when map_service.shards > 1",
    )
    p.add_argument(
        "--compact-mb",
        type=float,
        default=256,
        help="compact the store when its log reaches this many MB (default 256)",
    )
    p.add_argument(
        "--compact-records", type=int, default=20000, help="... or this many deltas (default 20000)"
    )
    p.add_argument(
        "--log-every", type=float, default=10.0, help="seconds between progress lines (default 10)"
    )
    p.add_argument(
        "--max-payload-mb",
        type=float,
        help="refuse a delta payload larger than this, before decoding it "
        "(default: 12 bytes per voxel of the grid + 64 KiB, the largest honest delta)",
    )
    p.add_argument(
        "--inbox", type=int, default=256, help="deltas queued per robot at most; more are refused and "
        "counted, and their agents resend them (default 256)"
    )  # fmt: skip
    p.add_argument(
        "--robots",
        help="comma-separated robot ids whose deltas are taken (default: the mission's robots)",
    )
    p.add_argument("--robot-pattern", help="also take robot ids that fully match this regular expression")
    p.add_argument(
        "--no-information-bound",
        action="store_true",
        help="do not refuse deltas carrying more information than the robot's rig can gather "
        "(docs/protocol.md, Limits)",
    )
    p.add_argument(
        "--information-burst", type=float, default=300.0, metavar="S",
        help="seconds of a rig's maximum information rate a robot may send at once (default 300)",
    )  # fmt: skip
    p.add_argument(
        "--quarantine-after", type=int, default=3, metavar="N",
        help="quarantine a robot after N deltas over its information budget (default 3; 0: never)",
    )  # fmt: skip
    p.add_argument(
        "--quarantine",
        action="append",
        default=[],
        metavar="ROBOT",
        help="refuse this robot's deltas and take its past ones out of the map (repeatable; at run "
        "time: list ids in STORE/quarantine, one a line, and send the server SIGHUP)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    p.set_defaults(run=_run_server)


def _run_server(args: argparse.Namespace) -> int:
    import logging
    import re

    from map_server.options import ServerOptions
    from map_server.process import serve
    from map_server.store import StoreError
    from swarm.config import ConfigError, load_mission

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s: %(message)s"
    )
    if args.compact_mb <= 0 or args.compact_records < 1 or args.log_every <= 0 or args.inbox < 1:
        return fail("--compact-mb, --compact-records, --log-every and --inbox must be positive")
    if args.max_payload_mb is not None and not args.max_payload_mb > 0:
        return fail("--max-payload-mb must be positive")
    if not args.information_burst > 0 or args.quarantine_after < 0:
        return fail("--information-burst must be positive and --quarantine-after at least 0")
    robots = tuple(r.strip() for r in args.robots.split(",") if r.strip()) if args.robots else None
    try:
        if args.robot_pattern:
            re.compile(args.robot_pattern)
    except re.error as exc:
        return fail(f"--robot-pattern: not a regular expression: {exc}")
    options = ServerOptions(
        int(args.compact_mb * 2**20),
        args.compact_records,
        log_every_s=args.log_every,
        max_payload_bytes=None if args.max_payload_mb is None else int(args.max_payload_mb * 2**20),
        inbox_messages=args.inbox,
        robots=robots,
        robot_pattern=args.robot_pattern,
        information_bound=not args.no_information_bound,
        burst_s=args.information_burst,
        quarantine_after=args.quarantine_after,
        quarantine=tuple(args.quarantine),
    )
    try:
        mission = load_mission(args.config)
        listen = args.listen or ([] if bus.config_path(args.zenoh_config) else [bus.DEFAULT_ENDPOINT])
        config = args.zenoh_config
        serve(
            mission,
            listen,
            args.store,
            args.mission,
            options,
            args.connect,
            zenoh_config=config,
            shard=args.shard,
        )
    except (ConfigError, StoreError, ValueError, OSError) as exc:  # ConnectionError is an OSError
        return fail(str(exc))
    return 0
