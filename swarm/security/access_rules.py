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
"""

from __future__ import annotations

from dataclasses import dataclass

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


def team_identities(robots: list[str]) -> list[Identity]:
    """Every identity of a team: the services, then per robot its agent and its frame source."""
    team = [
        Identity(SERVER, "map server (the mission's Zenoh router)", listens=True),
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


def access_control(mission: str, robots: list[str]) -> dict:
    """Zenoh's ``access_control`` block for the router of ``mission`` with ``robots``."""
    p = f"swarm/{mission}"
    rules = [
        # the server answers a query on swarm/*/map/stats on that very key: it must go out too
        _rule("team-receives", RECEIVED, "egress", [f"{p}/**", STATS_OF_ANY_MISSION]),
        _rule("team-reads", ["declare_subscriber"], "ingress", [f"{p}/**"]),
        _rule(
            "team-queries-map",
            ["query"],
            "ingress",
            [*(f"{p}/map/{q}" for q in MAP_QUERIES), f"{p}/coord/stats", STATS_OF_ANY_MISSION],
        ),
        _rule("server-answers", ["declare_queryable", "reply"], "ingress", [f"{p}/map/**"]),
        _rule("server-puts", ["put"], "ingress", [f"{p}/merged", f"{p}/mission/done"]),
        _rule("coordinator-answers", ["declare_queryable", "reply"], "ingress", [f"{p}/coord/**"]),
        _rule("world-puts", ["put"], "ingress", [f"{p}/robot/*/frame", f"{p}/sim/truth"]),
        _rule("operator-puts", ["put"], "ingress", [f"{p}/{PRIOR_DELTA}"]),
        _rule("operator-asks", ["query"], "ingress", [f"{p}/map/epoch/prior"]),
    ]
    subjects = [
        {"id": "team", "cert_common_names": [i.name for i in team_identities(robots)]},
        {"id": SERVER, "cert_common_names": [SERVER]},
        {"id": COORDINATOR, "cert_common_names": [COORDINATOR]},
        {"id": WORLD, "cert_common_names": [WORLD]},
        {"id": OPERATOR, "cert_common_names": [OPERATOR]},
    ]
    policies = [
        {"id": "team", "rules": ["team-receives", "team-reads", "team-queries-map"], "subjects": ["team"]},
        {"id": SERVER, "rules": ["server-answers", "server-puts"], "subjects": [SERVER]},
        {"id": COORDINATOR, "rules": ["coordinator-answers"], "subjects": [COORDINATOR]},
        {"id": WORLD, "rules": ["world-puts"], "subjects": [WORLD]},
        {"id": OPERATOR, "rules": ["operator-puts", "operator-asks"], "subjects": [OPERATOR]},
    ]
    for rid in robots:
        agent, source = agent_name(rid), source_name(rid)
        rules.append(
            _rule(f"{agent}-puts", ["put"], "ingress", [f"{p}/{k}" for k in _agent_keys(rid)]),
        )
        asks = [f"{p}/coord/assign/{rid}", f"{p}/map/epoch/{rid}"]
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


def _agent_keys(rid: str) -> list[str]:
    return [f"delta/{rid}", f"robot/{rid}/cmd", f"robot/{rid}/status"]
