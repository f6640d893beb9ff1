"""``swarm bench server``, ``soak``, ``durability``, ``slowloris`` and ``stall``: the map server
measured under load, attack and power cuts (merge throughput and ack latency, a TLS team for
minutes, acked deltas lost to SIGKILL and power cuts, idle connections, a stalled subscriber).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swarm.cli.common import at_least, bundled, fail


def register(bsub: argparse._SubParsersAction) -> None:
    """Add the map server's benchmarks to ``swarm bench``'s subcommands ``bsub``."""
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
    shards = bsub.add_parser(
        "shards",
        help="one map server beside two shards: throughput and publish-to-acked latency",
        description="The same deltas, split by owner, to one swarm server and then to a map service of "
        "two shards (docs/sharding.md) on loopback: voxel updates merged per second with --agents "
        "publishers, and the time from a paced publish until every shard's map/acks covers it (p50, "
        "p99). On one host the shards share its cores.",
    )
    shards.add_argument("--agents", type=int, default=16, help="publisher sessions (default 16)")
    shards.add_argument("--deltas", type=int, default=20, help="deltas per publisher (default 20)")
    shards.add_argument(
        "--period", type=float, default=0.5, help="seconds between a publisher's paced deltas (default 0.5)"
    )
    shards.set_defaults(run=_run_bench_shards)
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
        default=bundled(Path("configs") / "office.yaml"),
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


def _run_bench_shards(args: argparse.Namespace) -> int:
    from swarm.bench import shards

    if args.agents < 1 or args.deltas < 1 or args.period <= 0:
        return fail("--agents, --deltas and --period must be positive")
    figures = shards.run(args.agents, args.deltas, period_s=args.period)
    print(shards.format_table(figures))
    return 0


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
