"""``swarm study`` and ``python -m swarm.mission.study``: arguments to a :class:`StudySpec`, and the run."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pydantic import ValidationError

from swarm.mission.study.grid import COORDINATIONS, OPTION_OF, StudyError, StudySpec
from swarm.navigation.strategies import STRATEGIES

# -- command line ----------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm study``."""
    parser.description = (
        "Run a grid of simulated missions and compare them. The grid crosses every mission "
        "(CONFIG files and --map ROS maps) with --robots, --strategies, --coordination and --seeds; "
        "each cell is one 'swarm sim run' subprocess writing DIR/runs/<name> "
        "(<config>-<N>r-<strategy>-<coordination>-s<seed>) and DIR/logs/<name>.log. Coordination "
        "only matters for entropy teams of 2+ robots, so other cells run once as coordination none; "
        "a robot count larger than a mission places is reported and skipped. Outputs in DIR: "
        "results.csv (one row per run), summary.csv and summary.md (one row per config, robots, "
        "strategy and coordination, over seeds: runs reached H_th, mean ± std time to H_th, final "
        "entropy, overlap, F1, distance, speed-up over one robot), time_to_threshold.png and "
        "speedup.png. A run that did not reach H_th counts with its sim time as a lower bound, "
        "marked '>='. Exit code 0, 1 when some run failed, 2 for a bad option, 130 when interrupted. "
        "See docs/study.md."
    )
    parser.epilog = (
        "Example: swarm study configs/office.yaml --robots 1 2 4 --seeds 0 1 2 --out runs/study-office "
        "(Ctrl-C stops it cleanly; run the same command with --resume to finish it)."
    )
    parser.add_argument(
        "configs",
        nargs="*",
        type=Path,
        metavar="CONFIG",
        help="mission YAML file(s), given before the options",
    )
    parser.add_argument(
        "--map",
        dest="maps",
        action="append",
        nargs="+",
        type=Path,
        metavar="MAP.yaml",
        help="ROS map_server map(s) to explore, robots placed automatically; repeatable",
    )
    parser.add_argument(
        "--robots", nargs="+", type=int, default=[1, 2, 4], metavar="N", help="robot counts (default: 1 2 4)"
    )
    parser.add_argument(
        "--strategies",
        nargs="+",
        choices=STRATEGIES,
        default=["entropy"],
        metavar="STRATEGY",
        help=f"exploration strategies, of {', '.join(STRATEGIES)} (default: entropy)",
    )
    parser.add_argument(
        "--coordination",
        nargs="+",
        choices=COORDINATIONS,
        default=["coordinator", "none"],
        metavar="MODE",
        help="coordination modes, of coordinator, none (default: both); used for entropy teams of 2+ robots",
    )
    parser.add_argument(
        "--seeds", nargs="+", type=int, default=[0, 1, 2], metavar="S", help="seeds (default: 0 1 2)"
    )
    parser.add_argument(
        "--max-time",
        type=float,
        metavar="T",
        help="simulated seconds at most per run (default: each mission's)",
    )
    parser.add_argument(
        "--observable-threshold",
        type=float,
        metavar="F",
        help="every run's H_th = entropy no sensor can ever observe + F x the observable prior "
        "(swarm sim --observable-threshold; --map missions use F = 0.16 anyway)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="J",
        help="missions run at once (default 1: each mission already runs several processes)",
    )
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="study folder")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="read the cells whose run folder already holds a metrics.json instead of running them",
    )


def spec_from_args(args: argparse.Namespace) -> StudySpec:
    """The validated study of parsed arguments; StudyError names the bad option."""
    try:
        return StudySpec(
            configs=tuple(args.configs),
            maps=tuple(p for group in args.maps or [] for p in group),
            robots=tuple(args.robots),
            strategies=tuple(args.strategies),
            coordination=tuple(args.coordination),
            seeds=tuple(args.seeds),
            max_time_s=args.max_time,
            observable_threshold=args.observable_threshold,
            jobs=args.jobs,
            out=args.out,
            resume=args.resume,
        )
    except ValidationError as exc:
        raise StudyError(describe_spec_error(exc)) from exc


def describe_spec_error(err: ValidationError) -> str:
    """One line per problem, each starting with the option it is about."""
    lines = []
    for e in err.errors():
        option = OPTION_OF.get(str(e["loc"][0]), str(e["loc"][0])) + ": " if e["loc"] else ""
        msg = str(e.get("ctx", {}).get("error", e["msg"])) if e["type"] == "value_error" else e["msg"]
        if e["type"] != "value_error":
            msg += f" (got {e.get('input')!r})"
        line = f"{option}{msg}"
        if line not in lines:
            lines.append(line)
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """``swarm study``: validate the options, run the study, write its outputs."""
    from swarm.mission.study.orchestration import run_study

    try:
        spec = spec_from_args(args)
        return run_study(spec)
    except StudyError as exc:
        for line in str(exc).splitlines():
            print(f"swarm study: error: {line}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm.mission.study``: the same as ``swarm study``."""
    parser = argparse.ArgumentParser(prog="swarm study")
    add_arguments(parser)
    return run(parser.parse_args(argv))
