"""The ``swarm`` command line: a thin shell over the roles and the map core.

Each command group's arguments sit in its own module beside this one (``ingest``, ``maps``,
``bench``, ``sim``, ``roles``, ``study``, ``stereo``); this module only assembles them.
"""

from __future__ import annotations

import argparse
import sys

from swarm import __version__
from swarm.cli import bench, ingest, maps, roles, sim, stereo, study
from swarm.cli.common import endpoint_problem, fail, zenoh_message
from swarm.formats.errors import InputError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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
    sim.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one ``swarm`` command; user-input errors print ``swarm: error: FILE: FIELD: what``, exit 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "sim" and (len(argv) == 1 or argv[1] not in sim.SIM_COMMANDS):
        argv.insert(1, "run")  # 'swarm sim [CONFIG]' means 'swarm sim run [CONFIG]'
    args = build_parser().parse_args(argv)
    for option in ("listen", "connect"):
        for endpoint in getattr(args, option, None) or []:
            problem = endpoint_problem(endpoint)
            if problem:
                return fail(f"--{option} {endpoint}: {problem}")
    try:
        return int(args.run(args) or 0)
    except InputError as exc:  # a user's file or value: FILE: FIELD: what, never a traceback
        return fail(str(exc))
    except Exception as exc:
        if type(exc).__module__.startswith("zenoh"):  # e.g. a port in use: no Rust traceback
            return fail(f"Zenoh: {zenoh_message(exc)}")
        raise


if __name__ == "__main__":
    sys.exit(main())
