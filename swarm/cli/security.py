"""``swarm security init``: certificates and per-identity Zenoh configs for a mission's team."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "security",
        help="mutual TLS and access control for a team: certificates and Zenoh configs",
        description="Security of a mission's bus (docs/security.md).",
    )
    ssub = p.add_subparsers(dest="security_command", required=True, metavar="COMMAND")
    init = ssub.add_parser(
        "init",
        help="write a CA, one certificate and one Zenoh config per identity of the team",
    )
    init.defer(_init_arguments)


def _init_arguments(init: argparse.ArgumentParser) -> None:
    from swarm.security import command

    command.add_init_arguments(init)
    init.set_defaults(run=command.run_init)
