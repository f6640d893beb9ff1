"""``swarm security init``: a mission's CA, one certificate and one Zenoh config per identity.

Layout of the output folder (docs/security.md)::

    ca.pem                  the mission's certificate authority (give to every machine)
    ca-key.pem              its private key: keep it offline; it signs new identities
    <identity>/cert.pem     the identity's certificate (CN = the identity's name)
    <identity>/key.pem      its private key (mode 0600)
    <identity>/zenoh.json5  its Zenoh config: mutual TLS; the server's also the access rules

Paths inside each ``zenoh.json5`` are relative to the file's folder (``swarm`` resolves them
so; for other Zenoh programs, run them from that folder or make the paths absolute).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from swarm.protocol import bus
from swarm.protocol.transport_limits import max_sessions_for, team_limits, with_handshake_timeout
from swarm.security.access_rules import Identity, access_control, team_identities
from swarm.security.certificates import DEFAULT_DAYS, issue, make_ca

DEFAULT_PORT = 7447
DEFAULT_HOSTS = ("127.0.0.1", "localhost")


@dataclass(frozen=True)
class TeamFiles:
    """What ``init_team`` wrote: the folder, the CA, and the config of each identity."""

    out: Path
    ca: Path
    configs: dict[str, Path]


def zenoh_config(
    identity: Identity, mission: str, robots: list[str], hosts: list[str], port: int, shards: int = 1
) -> dict:
    """The Zenoh config of ``identity``: mTLS with the mission's CA, the team's transport limits
    (``swarm.protocol.transport_limits``); the router gets the rules (for a map service of
    ``shards`` servers: shard 0 is the router, the other shards connect to it as clients)."""
    tls = {
        "root_ca_certificate": "../ca.pem",
        "enable_mtls": True,
        "verify_name_on_connect": True,
        "connect_certificate": "cert.pem",
        "connect_private_key": "key.pem",
    }
    conf: dict = {"scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}}
    if identity.listens:
        tls.update(listen_certificate="cert.pem", listen_private_key="key.pem")
        conf["mode"] = "router"
        conf["listen"] = {"endpoints": [with_handshake_timeout(f"tls/0.0.0.0:{port}")]}
        conf["access_control"] = access_control(mission, robots, shards)
    else:
        conf["mode"] = "client"
        conf["connect"] = {"endpoints": [f"tls/{_host_part(hosts[0])}:{port}"]}
    # the router also keeps a session per further shard
    limits = team_limits(max_sessions_for(len(robots)) + shards - 1)
    conf["transport"] = {
        "unicast": {
            key.rsplit("/", 1)[1]: v for key, v in limits.items() if key.startswith("transport/unicast/")
        },
        "link": {"tx": {"lease": limits["transport/link/tx/lease"]}, "tls": tls},
    }
    return conf


def _host_part(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def init_team(
    mission: str,
    robots: list[str],
    out: Path,
    hosts: list[str] | None = None,
    port: int = DEFAULT_PORT,
    days: int = DEFAULT_DAYS,
    overwrite: bool = False,
    shards: int = 1,
) -> TeamFiles:
    """Write the CA, every identity's certificate and Zenoh config under ``out``.

    ``hosts``: the map server's addresses or DNS names, as the others will connect to it
    (the first is the one written in their configs). ``shards``: the map service's servers
    (``map_service.shards``); with more than one, shard 0 is ``server`` (the router, with the
    rules) and shard k > 0 gets ``server-shard-<k>`` (a client of the router, allowed only its own
    shard's keys). Raises ``ValueError`` for a bad mission or robot name, duplicate robots, a
    shard count outside 1..64, or an ``out`` that already holds a CA (unless ``overwrite``).
    """
    hosts = list(hosts or DEFAULT_HOSTS)
    bus.key(mission)  # the mission and robot ids are key parts: no wildcards, no empty names
    for rid in robots:
        bus.key(mission, rid)
        if "/" in rid:
            raise ValueError(f"robot id {rid!r}: must not contain '/'")
    if len(set(robots)) != len(robots):
        raise ValueError(f"robot ids must be distinct: {robots}")
    if not 1 <= shards <= bus.MAX_SHARDS:
        raise ValueError(f"shards {shards}: must be in 1..{bus.MAX_SHARDS} (as map_service.shards)")
    if not 0 < port < 65536:
        raise ValueError(f"port {port}: must be in 1..65535")
    out = Path(out)
    if (out / "ca.pem").exists() and not overwrite:
        raise ValueError(f"{out}: already holds a team (ca.pem); choose another --out or pass --force")
    out.mkdir(parents=True, exist_ok=True)
    ca = make_ca(mission, days)
    ca.write(out / "ca.pem", out / "ca-key.pem")
    configs: dict[str, Path] = {}
    for identity in team_identities(robots, shards):
        folder = out / identity.name
        folder.mkdir(exist_ok=True)
        names = hosts if identity.listens else []
        issue(ca, identity.name, names, mission, days).write(folder / "cert.pem", folder / "key.pem")
        conf = zenoh_config(identity, mission, robots, hosts, port, shards)
        header = f"// Zenoh config of {identity.name!r}: {identity.role}; mission {mission!r}\n"
        (folder / "zenoh.json5").write_text(header + json.dumps(conf, indent=2) + "\n")
        configs[identity.name] = folder / "zenoh.json5"
    return TeamFiles(out, out / "ca.pem", configs)
