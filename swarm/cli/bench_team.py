"""``swarm bench team``: whole missions of several team sizes, every role process measured."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swarm.cli.common import at_least, bundled, fail

DEFAULT_TEAM_CONFIG = bundled(Path("configs") / "campus_floor.yaml")


def register(bsub: argparse._SubParsersAction) -> None:
    """Add ``team`` to ``swarm bench``'s subcommands ``bsub``."""
    team = bsub.add_parser(
        "team",
        help="whole missions of 16 and 4 robots: real-time factor, coordinator p95, memory per role",
        description="Run `swarm sim CONFIG --robots N --max-time T` for each team size, one after the "
        "other, sampling every role process once a second from /proc (CPU time, peak RSS, peak PSS: "
        "shared library pages split among the processes that map them). Prints per team: the "
        "simulated time over the world's wall time once every agent was there (the real-time "
        "factor), the entropy removed, the coordinator's answer times, and per role (agent, server, "
        "coordinator, world, runner) its CPU time and the largest peak memory of its processes; then "
        "the speed-up of the largest team over the smallest (entropy removed in the same simulated "
        "time). Linux only. The run folders are kept under --out.",
    )
    team.add_argument(
        "config",
        nargs="?",
        type=Path,
        default=DEFAULT_TEAM_CONFIG,
        help=f"mission (default {DEFAULT_TEAM_CONFIG})",
    )
    team.add_argument(
        "--robots", type=at_least(1), nargs="+", default=[16, 4], help="team sizes (default 16 4)"
    )
    team.add_argument("--max-time", type=float, default=120.0, help="simulated seconds per run (default 120)")
    team.add_argument(
        "--out", type=Path, default=Path("runs") / "bench-team", help="run folders (default runs/bench-team)"
    )
    team.set_defaults(run=_run_bench_team)


def _run_bench_team(args: argparse.Namespace) -> int:
    from swarm.bench import team_scale

    if not args.max_time > 0:
        return fail("--max-time must be > 0")
    if not args.config.is_file():
        return fail(f"{args.config}: no such mission file")
    if not Path("/proc/self/smaps_rollup").exists():
        return fail("swarm bench team reads /proc (Linux only)")
    runs = []
    for robots in args.robots:
        print(f"running {args.config} with {robots} robots for {args.max_time:g} s simulated ...", flush=True)
        try:
            run = team_scale.run_team(args.config, robots, args.max_time, args.out / f"robots-{robots}")
        except RuntimeError as exc:
            print(f"swarm bench team: {exc}", file=sys.stderr)
            return 1
        print(team_scale.format_run(run), flush=True)
        runs.append(run)
    if len(runs) > 1:
        big, small = max(runs, key=lambda r: r.robots), min(runs, key=lambda r: r.robots)
        print(
            f"speed-up of {big.robots} over {small.robots} robots (entropy removed in "
            f"{args.max_time:g} s simulated): {team_scale.speed_up(big, small):.2f}x",
            flush=True,
        )
    return 0
