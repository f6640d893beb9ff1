"""Who may do what on a mission's bus: the identities and Zenoh's ``access_control`` block.

Each identity is a certificate common name (CN). The map server's session is the mission's
Zenoh router; it applies these rules to every message arriving from (``ingress``) or leaving
for (``egress``) a connected session, keyed on the CN of that session's TLS certificate
(Zenoh 1.x access control, ``subjects`` with ``cert_common_names``). Everything not allowed
is denied (``default_permission: deny``). Keys are under ``swarm/<mission>/``:

| identity (CN) | may put | may answer |
|---|---|---|
| ``agent-<rid>`` (robot rid's agent) | ``delta/<rid>``, ``robot/<rid>/cmd``, ``robot/<rid>/status`` | - |
| ``source-<rid>`` (robot rid's driver or replay) | ``robot/<rid>/frame`` | - |
| ``world`` (the simulator, for all its robots) | ``robot/*/frame``, ``sim/truth`` | - |
| ``server`` (map server) | ``merged``, ``mission/done`` | ``map/**`` |
| ``coordinator`` | - | ``coord/**`` |
| ``tool`` (viewer, ``swarm map``, monitors) | - | - |
| ``operator`` (``swarm sim``'s runner) | ``delta/prior`` (a previous map) | - |

Every identity may subscribe to the mission's keys and query ``map/stats``, ``map/acks``,
``map/snapshot``, ``map/region`` and ``coord/stats`` (and ``swarm/*/map/stats``, which tools ask
to find the mission whose server answers). Robot rid's agent alone may query
``coord/assign/<rid>`` (the key tells the coordinator who asks) and ``map/epoch/<rid>`` (the
epoch and MAC key of its deltas); the operator alone ``map/epoch/prior``.
Every identity receives what it subscribed to (egress is open within the mission's keys).

A sharded map service (``shards`` N > 1, docs/sharding.md) has a server per shard: shard 0 is
``server`` (the router, and alone puts ``mission/done``), shard k > 0 ``server-shard-<k>``. Each
may answer only ``shard/<k>/map/**`` and put only ``shard/<k>/merged``; the map keys above
(``delta/<rid>``, ``map/...``, ``delta/prior``) are then those of every shard
(``shard/<k>/delta/<rid>`` for every k, and so on), and every identity may also ask
``shard/*/map/stats`` (and ``swarm/*/shard/*/map/stats``), where clients find the shards.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarm.protocol import bus

SERVER = "server"
COORDINATOR = "coordinator"
WORLD = "world"
TOOL = "tool"
OPERATOR = "operator"
SERVICES = (SERVER, COORDINATOR, WORLD, TOOL, OPERATOR)
# the key a mission's previous map arrives on (swarm/mission/prior_map.py, PRIOR_SOURCE "prior")
PRIOR_DELTA = "delta/prior"
# what tools ask to find the mission whose server answers (swarm.protocol.map_client.missions_answering)
STATS_OF_ANY_MISSION = "swarm/*/map/stats"
# ... and the shards of sharded missions (the same function; docs/sharding.md)
STATS_OF_ANY_SHARD = "swarm/*/shard/*/map/stats"
#: The map server's queries every identity may ask (``map/epoch/<rid>`` only robot rid's agent,
#: ``map/epoch/prior`` only the operator: an epoch's key is that robot's)
MAP_QUERIES = ("stats", "acks", "snapshot", "region")

RECEIVED = ["put", "declare_subscriber", "declare_queryable", "query", "reply"]


def agent_name(robot: str) -> str:
    """The CN of robot ``robot``'s agent."""
    return f"agent-{robot}"


def source_name(robot: str) -> str:
    """The CN of robot ``robot``'s frame source (its driver or a replay)."""
    return f"source-{robot}"


@dataclass(frozen=True)
class Identity:
    """One certificate: its common name, what it is, and whether its session listens (router)."""

    name: str
    role: str
    listens: bool = False


def shard_server_name(shard: int) -> str:
    """The CN of map server shard ``shard``: ``server`` for shard 0 (the mission's router, as
    an unsharded server is), ``server-shard-<k>`` for the others."""
    if shard < 0:
        raise ValueError(f"no shard {shard}")
    return SERVER if shard == 0 else f"{SERVER}-shard-{shard}"


def team_identities(robots: list[str], shards: int = 1) -> list[Identity]:
    """Every identity of a team: the services (with ``shards`` > 1, shard 0's server, then one
    ``server-shard-<k>`` per further shard), then per robot its agent and its frame source."""
    if shards < 1:
        raise ValueError(f"shards {shards}: must be at least 1")
    router = "map server (the mission's Zenoh router)"
    if shards > 1:
        router = f"map server shard 0 of {shards} (the mission's Zenoh router; announces mission/done)"
    team = [Identity(SERVER, router, listens=True)]
    for k in range(1, shards):
        team.append(Identity(shard_server_name(k), f"map server shard {k} of {shards}"))
    team += [
        Identity(COORDINATOR, "coordinator"),
        Identity(WORLD, "simulated world (frame source of every simulated robot)"),
        Identity(TOOL, "read-only tools: viewer, swarm map, monitors"),
        Identity(OPERATOR, "mission operator (swarm sim's runner): may load a previous map"),
    ]
    for rid in robots:
        team.append(Identity(agent_name(rid), f"robot {rid}'s agent"))
        team.append(Identity(source_name(rid), f"robot {rid}'s frame source (driver or replay)"))
    return team


def _rule(rule_id: str, messages: list[str], flow: str, keys: list[str]) -> dict:
    return {"id": rule_id, "messages": messages, "flows": [flow], "permission": "allow", "key_exprs": keys}


def map_prefixes(mission: str, shards: int = 1) -> list[str]:
    """The key prefixes of the map servers: ``swarm/<mission>``, or ``swarm/<mission>/shard/<k>``
    for each of ``shards`` > 1 (``swarm.protocol.bus.shard_mission``)."""
    return [f"swarm/{bus.shard_mission(mission, k, shards)}" for k in range(shards)]


def access_control(mission: str, robots: list[str], shards: int = 1) -> dict:
    """Zenoh's ``access_control`` block for the router of ``mission`` with ``robots`` and a map
    service of ``shards`` servers (1: the unsharded keys; see the module doc)."""
    p = f"swarm/{mission}"
    maps = map_prefixes(mission, shards)
    # a sharded mission's shards are found on swarm/<mission>/shard/*/map/stats (and tools
    # looking for any mission ask swarm/*/shard/*/map/stats): docs/sharding.md
    found_on = [] if shards == 1 else [f"{p}/shard/*/map/stats", STATS_OF_ANY_SHARD]
    queries = [f"{m}/map/{q}" for m in maps for q in MAP_QUERIES]
    rules = [
        # the server answers a query on swarm/*/map/stats on that very key: it must go out too
        _rule("team-receives", RECEIVED, "egress", [f"{p}/**", STATS_OF_ANY_MISSION, *found_on[1:]]),
        _rule("team-reads", ["declare_subscriber"], "ingress", [f"{p}/**"]),
        _rule(
            "team-queries-map",
            ["query"],
            "ingress",
            [*queries, f"{p}/coord/stats", STATS_OF_ANY_MISSION, *found_on],
        ),
    ]
    subjects = [{"id": "team", "cert_common_names": [i.name for i in team_identities(robots, shards)]}]
    team_rules = ["team-receives", "team-reads", "team-queries-map"]
    policies = [{"id": "team", "rules": team_rules, "subjects": ["team"]}]
    for k, m in enumerate(maps):
        name = shard_server_name(k)
        puts = [f"{m}/merged", *([f"{p}/mission/done"] if k == 0 else [])]  # shard 0 alone announces
        rules.append(_rule(f"{name}-answers", ["declare_queryable", "reply"], "ingress", [f"{m}/map/**"]))
        rules.append(_rule(f"{name}-puts", ["put"], "ingress", puts))
        subjects.append({"id": name, "cert_common_names": [name]})
        policies.append({"id": name, "rules": [f"{name}-answers", f"{name}-puts"], "subjects": [name]})
    rules += [
        _rule("coordinator-answers", ["declare_queryable", "reply"], "ingress", [f"{p}/coord/**"]),
        _rule("world-puts", ["put"], "ingress", [f"{p}/robot/*/frame", f"{p}/sim/truth"]),
        _rule("operator-puts", ["put"], "ingress", [f"{m}/{PRIOR_DELTA}" for m in maps]),
        _rule("operator-asks", ["query"], "ingress", [f"{m}/map/epoch/prior" for m in maps]),
    ]
    subjects += [
        {"id": COORDINATOR, "cert_common_names": [COORDINATOR]},
        {"id": WORLD, "cert_common_names": [WORLD]},
        {"id": OPERATOR, "cert_common_names": [OPERATOR]},
    ]
    policies += [
        {"id": COORDINATOR, "rules": ["coordinator-answers"], "subjects": [COORDINATOR]},
        {"id": WORLD, "rules": ["world-puts"], "subjects": [WORLD]},
        {"id": OPERATOR, "rules": ["operator-puts", "operator-asks"], "subjects": [OPERATOR]},
    ]
    for rid in robots:
        agent, source = agent_name(rid), source_name(rid)
        puts = [f"{m}/delta/{rid}" for m in maps] + [f"{p}/robot/{rid}/{k}" for k in ("cmd", "status")]
        rules.append(_rule(f"{agent}-puts", ["put"], "ingress", puts))
        asks = [f"{p}/coord/assign/{rid}", *(f"{m}/map/epoch/{rid}" for m in maps)]
        rules.append(_rule(f"{agent}-asks", ["query"], "ingress", asks))
        rules.append(_rule(f"{source}-puts", ["put"], "ingress", [f"{p}/robot/{rid}/frame"]))
        subjects.append({"id": agent, "cert_common_names": [agent]})
        subjects.append({"id": source, "cert_common_names": [source]})
        policies.append({"id": agent, "rules": [f"{agent}-puts", f"{agent}-asks"], "subjects": [agent]})
        policies.append({"id": source, "rules": [f"{source}-puts"], "subjects": [source]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
