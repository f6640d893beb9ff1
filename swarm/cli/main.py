"""The ``swarm`` command line: a thin shell over the roles and the map core.

Each command group's arguments sit in its own module beside this one (``ingest``, ``maps``,
``bench``, ``sim``, ``roles``, ``study``, ``stereo``, ``replay``, ``view``); this module only assembles them.
"""

from __future__ import annotations

import argparse
import math
import sys

from swarm import __version__
from swarm.cli import bench, ingest, maps, replay, roles, security, sim, stereo, study, view
from swarm.cli.common import LazyParser, complete, endpoint_problem, fail, zenoh_message
from swarm.formats.errors import InputError
from swarm.mission.role_failure import RoleError


def build_parser(lazy: bool = False) -> argparse.ArgumentParser:
    """The whole ``swarm`` command line; with ``lazy``, the arguments of subcommands that need
    heavy imports are added only when their subcommand parses (:class:`LazyParser`)."""
    parser = LazyParser(
        prog="swarm",
        description="Multi-robot probabilistic volumetric mapping (Rocha, Dias and Carvalho 2005) "
        "over Zenoh: fuse ranges into Gaussian coverage maps, simulate, benchmark.",
    )
    parser.add_argument("--version", action="version", version=f"swarm {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    ingest.register(sub)
    maps.register(sub)
    bench.register(sub)
    roles.register_agent(sub)
    roles.register_server(sub)
    roles.register_coordinator(sub)
    study.register(sub)
    stereo.register(sub)
    replay.register(sub)
    sim.register(sub)
    view.register(sub)
    security.register(sub)
    return parser if lazy else complete(parser)


def _infinite_defaults(parser: argparse.ArgumentParser) -> set[str]:
    """Destinations of options, in every sub-command, whose default is an infinity."""
    found = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= _infinite_defaults(sub)
        elif isinstance(action.default, float) and math.isinf(action.default):
            found.add(action.dest)
    return found


def main(argv: list[str] | None = None) -> int:
    """Run one ``swarm`` command; user-input errors print ``swarm: error: FILE: FIELD: what``, exit 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "sim" and (len(argv) == 1 or argv[1] not in sim.SIM_COMMANDS):
        argv.insert(1, "run")  # 'swarm sim [CONFIG]' means 'swarm sim run [CONFIG]'
    parser = build_parser(lazy=True)
    args = parser.parse_args(argv)
    unlimited = _infinite_defaults(parser)  # e.g. stereo --max-depth: inf means "no limit"
    for dest, value in vars(args).items():
        values = value if isinstance(value, list | tuple) else [value]
        floats = [v for v in values if isinstance(v, float)]
        if any(math.isnan(v) for v in floats) or (
            dest not in unlimited and any(math.isinf(v) for v in floats)
        ):
            shown = " ".join(str(v) for v in values)
            return fail(f"--{dest.replace('_', '-')} {shown}: must be finite numbers")
    problems = endpoint_problems(vars(args))
    if problems:
        return fail(problems[0])
    try:
        return int(args.run(args) or 0)
    except InputError as exc:  # a user's file or value: FILE: FIELD: what, never a traceback
        return fail(str(exc))
    except RoleError as exc:  # a role process of a mission or replay failed: say which and why
        return fail(str(exc))
    except OSError as exc:  # a path the user gave that cannot be used (--out an existing file, ...)
        if exc.filename is None:
            raise
        return fail(f"{exc.filename}: {exc.strerror}")
    except Exception as exc:
        if type(exc).__module__.startswith("zenoh"):  # e.g. a port in use: no Rust traceback
            return fail(f"Zenoh: {zenoh_message(exc)}")
        raise


def endpoint_problems(options: dict) -> list[str]:
    """``--listen``/``--connect OPTION: why`` for each malformed endpoint among ``options`` (the
    parsed arguments): one endpoint (``swarm replay --connect``) or a list (repeatable options)."""
    problems = []
    for option in ("listen", "connect"):
        given = options.get(option) or []
        for endpoint in [given] if isinstance(given, str) else given:
            problem = endpoint_problem(endpoint)
            if problem:
                problems.append(f"--{option} {endpoint}: {problem}")
    return problems


if __name__ == "__main__":
    sys.exit(main())
