"""``swarm security init``: write a mission's certificates and per-identity Zenoh configs."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from swarm.protocol import bus
from swarm.security.access_rules import team_identities
from swarm.security.certificates import DEFAULT_DAYS
from swarm.security.team_setup import DEFAULT_HOSTS, DEFAULT_PORT, init_team


def add_init_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm security init``."""
    parser.description = (
        "Write a certificate authority for the mission, one certificate per identity (map server, "
        "coordinator, simulated world, read-only tools, and per robot its agent and its frame source) "
        "and one Zenoh config per identity: mutual TLS, and on the map server (the mission's router) "
        "access-control rules keyed on the certificates' common names. Give each machine ca.pem and "
        "its identities' folders; keep ca-key.pem offline. See docs/security.md."
    )
    parser.add_argument("--mission", required=True, metavar="NAME", help="mission name (the key prefix)")
    parser.add_argument("--robots", required=True, nargs="+", metavar="ID", help="robot ids, e.g. r1 r2 r3")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    parser.add_argument(
        "--server-host",
        action="append",
        metavar="HOST",
        help="address or DNS name the others reach the map server at, written into the server's "
        "certificate; the first goes into the others' configs; repeatable "
        f"(default {' and '.join(DEFAULT_HOSTS)})",
    )
    parser.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"the server's TLS port (default {DEFAULT_PORT})"
    )
    parser.add_argument(
        "--days", type=int, default=DEFAULT_DAYS, help=f"certificate lifetime (default {DEFAULT_DAYS})"
    )
    parser.add_argument(
        "--shards",
        type=int,
        default=1,
        metavar="N",
        help="servers of the map service (the mission's map_service.shards; default 1): shard 0 is "
        "'server', the mission's router; shard K > 0 gets 'server-shard-K', allowed only its own "
        "swarm/<mission>/shard/K/ keys (docs/sharding.md)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite a team already in --out")


def run_init(args: argparse.Namespace) -> int:
    """``swarm security init``: 0 on success, 2 on bad arguments."""
    try:
        if args.days < 1:
            raise ValueError(f"--days {args.days}: must be at least 1")
        if not 1 <= args.shards <= bus.MAX_SHARDS:
            most = bus.MAX_SHARDS
            raise ValueError(f"--shards {args.shards}: must be in 1..{most} (as map_service.shards)")
        _check_names(args)
        team = init_team(
            args.mission,
            args.robots,
            args.out,
            args.server_host,
            args.port,
            args.days,
            args.force,
            shards=args.shards,
        )
    except (ValueError, OSError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote the team of mission {args.mission!r} to {team.out}:")
    print(f"  {'ca.pem':<24} the mission's certificate authority (every machine)")
    print(f"  {'ca-key.pem':<24} its private key: keep it offline")
    for identity in team_identities(args.robots, args.shards):
        print(f"  {identity.name + '/':<24} {identity.role}")
    if args.shards > 1:
        print(
            f"start shard 0 (swarm server --shard 0) with --zenoh-config {team.configs['server']}, "
            "shard K with server-shard-K/zenoh.json5, every other role with its own"
        )
    else:
        server = team.configs["server"]
        print(f"start the map server with --zenoh-config {server}, every other role with its own")
    return 0


def _check_names(args: argparse.Namespace) -> None:
    """The mission and robot ids as a mission file takes them (letters, digits, _ and -), and a
    server host a certificate can name; ValueError naming the option otherwise."""
    name = re.compile(r"^[A-Za-z0-9_-]+$")  # the ids a mission file takes (swarm.config's NAME_PATTERN)
    if not name.match(args.mission):
        raise ValueError(f"--mission {args.mission!r}: only letters, digits, _ and - (as in a mission file)")
    bad = [r for r in args.robots if not name.match(r)]
    if bad:
        raise ValueError(f"--robots {' '.join(map(repr, bad))}: only letters, digits, _ and - (as robot ids)")
    for host in args.server_host or []:
        if not re.fullmatch(r"[A-Za-z0-9.:_-]+", host):
            raise ValueError(f"--server-host {host!r}: not a host name or IP address")
