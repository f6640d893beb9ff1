"""The secured bus of a sharded map service (docs/security.md, docs/sharding.md): the identities
and rules `swarm security init --shards 2` writes, and real sessions over loopback mutual TLS with
shard 0 as the mission's router and shard 1 connected to it with its own certificate.

What must hold: robot r1's agent may put deltas on every shard, but only as r1; a session holding
shard 1's certificate can neither answer shard 0's queries nor put shard 0's merged stream or the
mission's end; every team member may still query every shard (a tool finds the shards itself).
"""

from __future__ import annotations

import json
import queue
import time

import pytest
import zenoh

from swarm.cli.main import main
from swarm.protocol import bus
from swarm.protocol.epochs import ask_epoch, wait_for_epoch
from swarm.protocol.map_client import MapClient
from swarm.security.access_rules import access_control, agent_name, shard_server_name, team_identities
from swarm.security.certificates import common_name
from swarm.security.team_setup import init_team
from tests.support.map_server_mission import EPOCH, wait_until
from tests.support.secure_team import ROBOTS, secure_shards, session_as, slab_delta

MISSION = "srvtest"
SHARDS = 2


@pytest.fixture(scope="module")
def team(tmp_path_factory):
    return init_team(MISSION, ROBOTS, tmp_path_factory.mktemp("team"), shards=SHARDS)


def prefix(shard: int) -> str:
    return bus.shard_mission(MISSION, shard, SHARDS)


def allowed_to(acl: dict, message: str, key: str) -> set[str]:
    """The CNs Zenoh's rules let send ``message`` on ``key`` at the router (ingress): those of a
    policy with a rule of that message whose key expressions include ``key`` (as Zenoh matches)."""
    rules = {r["id"]: r for r in acl["rules"]}
    names = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    target = zenoh.KeyExpr(key)
    return {
        cn
        for policy in acl["policies"]
        for rule in map(rules.get, policy["rules"])
        if message in rule["messages"]
        and rule["flows"] == ["ingress"]
        and any(zenoh.KeyExpr(k).includes(target) for k in rule["key_exprs"])
        for subject in policy["subjects"]
        for cn in names[subject]
    }


# -- what init writes -------------------------------------------------------------------------------


def test_each_shard_has_its_identity_and_the_others_connect_to_shard_0(team):
    shard_names = [shard_server_name(k) for k in range(SHARDS)]
    assert shard_names == ["server", "server-shard-1"]
    assert [i.name for i in team_identities(ROBOTS, SHARDS)][:3] == [
        "server",
        "server-shard-1",
        "coordinator",
    ]
    for name in shard_names:
        assert common_name(team.configs[name].parent / "cert.pem") == name
    _conf, listen, connect = bus.session_config(config_file=team.configs["server-shard-1"])
    assert listen == [] and connect == ["tls/127.0.0.1:7447"]  # a client of the router
    conf, listen, _ = bus.session_config(config_file=team.configs["server"])
    assert listen == ["tls/0.0.0.0:7447#tls_handshake_timeout_ms=60000"]
    written = json.loads(team.configs["server"].read_text().split("\n", 1)[1])  # after the header
    assert written["access_control"] == access_control(MISSION, ROBOTS, SHARDS)
    unsharded = init_team(MISSION, ROBOTS, team.out / "unsharded")
    sessions = json.loads(
        bus.session_config(config_file=unsharded.configs["server"])[0].get_json("transport")
    )
    assert json.loads(conf.get_json("transport"))["unicast"]["max_sessions"] == (
        sessions["unicast"]["max_sessions"] + SHARDS - 1
    )
    assert "server-shard-1" not in unsharded.configs


def test_only_robot_rn_may_put_its_deltas_on_any_shard_in_the_rules():
    acl = access_control("m", ROBOTS, SHARDS)
    for k in range(SHARDS):
        for rid in ROBOTS:
            assert allowed_to(acl, "put", f"swarm/m/shard/{k}/delta/{rid}") == {agent_name(rid)}
            assert allowed_to(acl, "query", f"swarm/m/shard/{k}/map/epoch/{rid}") == {agent_name(rid)}
        assert allowed_to(acl, "put", f"swarm/m/shard/{k}/delta/prior") == {"operator"}
    assert allowed_to(acl, "put", "swarm/m/delta/r1") == set()  # no unsharded server to take it
    assert allowed_to(acl, "put", "swarm/m/shard/2/delta/r1") == set()  # no such shard


def test_each_shard_may_answer_and_put_only_its_own_keys_in_the_rules():
    acl = access_control("m", ROBOTS, SHARDS)
    for k in range(SHARDS):
        own = shard_server_name(k)
        for query in ("stats", "acks", "snapshot", "region", "epoch/r1"):
            for message in ("declare_queryable", "reply"):
                assert allowed_to(acl, message, f"swarm/m/shard/{k}/map/{query}") == {own}
        assert allowed_to(acl, "put", f"swarm/m/shard/{k}/merged") == {own}
        # every member may ask every shard
        assert allowed_to(acl, "query", f"swarm/m/shard/{k}/map/snapshot") == {
            i.name for i in team_identities(ROBOTS, SHARDS)
        }
    assert allowed_to(acl, "put", "swarm/m/mission/done") == {"server"}  # shard 0 alone
    assert allowed_to(acl, "reply", "swarm/m/map/stats") == set()
    assert allowed_to(acl, "reply", "swarm/m/shard/*/map/stats") == set()  # no one answers for all


def test_security_init_takes_the_shard_count(tmp_path, capsys):
    args = ["security", "init", "--mission", "m", "--robots", "r1", "--shards", "3"]
    assert main([*args, "--out", str(tmp_path / "team")]) == 0
    out = capsys.readouterr().out
    assert "server-shard-1/" in out and "server-shard-2/" in out and "server-shard-3/" not in out
    assert (tmp_path / "team" / "server-shard-2" / "zenoh.json5").is_file()
    assert main([*args[:-1], "0", "--out", str(tmp_path / "bad")]) == 2
    assert "--shards 0: must be in 1..64" in capsys.readouterr().err


# -- real sessions over TLS ------------------------------------------------------------------------


def watch(session: zenoh.Session) -> tuple[queue.Queue, object]:
    seen: queue.Queue = queue.Queue()
    return seen, session.declare_subscriber(
        bus.key_pattern(MISSION, "**"), lambda s: seen.put(str(s.key_expr))
    )


def keys_seen(seen: queue.Queue) -> list[str]:
    return [seen.get_nowait() for _ in range(seen.qsize())]


def test_an_agent_cannot_put_on_another_robots_shard_delta_key(team, tmp_path):
    with secure_shards(team, tmp_path / "store", SHARDS) as (servers, endpoint):
        with session_as(team, "agent-r1", endpoint) as r1, session_as(team, "tool", endpoint) as tool:
            seen, subscriber = watch(tool)
            time.sleep(0.3)
            assert ask_epoch(r1, prefix(1), "r2", 1.0) is None  # r2's epoch key is r2's agent's
            for k in range(SHARDS):
                r1.put(bus.key(prefix(k), "delta", "r2"), slab_delta("r2", k))
            grants = {k: wait_for_epoch(r1, prefix(k), "r1", 10.0) for k in range(SHARDS)}
            for k, grant in grants.items():  # after the others, same link
                payload = slab_delta("r1", k)
                r1.put(bus.key(prefix(k), "delta", "r1"), payload, attachment=grant.sign(payload))
            clients = [MapClient(tool, prefix(k), timeout=5.0) for k in range(SHARDS)]
            for client in clients:
                wait_until(lambda c=client: c.acks().get("r1", {}).get(EPOCH) == 1, 10.0, "r1's delta")
            time.sleep(0.3)
            deltas = sorted(k for k in keys_seen(seen) if "/delta/" in k)
            subscriber.undeclare()
            assert [c.acks() for c in clients] == [{"r1": {EPOCH: 1}}] * SHARDS
    assert deltas == [bus.key(prefix(k), "delta", "r1") for k in range(SHARDS)], deltas
    assert [s.stats()["deltas_applied"] for s in servers] == [1, 1]


def test_a_shard_cannot_answer_or_put_as_another_shard(team, tmp_path):
    forged_acks = json.dumps({"r1": {str(EPOCH): 10**9}}).encode()
    with secure_shards(team, tmp_path / "store", SHARDS) as (servers, endpoint):
        with (
            session_as(team, "server-shard-1", endpoint) as shard1,
            session_as(team, "tool", endpoint) as tool,
        ):
            seen, subscriber = watch(tool)
            forged = [
                shard1.declare_queryable(
                    bus.key(prefix(0), "map", q), lambda q: q.reply(q.key_expr, forged_acks)
                )
                for q in ("acks", "stats")
            ]
            time.sleep(0.3)
            shard1.put(bus.key(prefix(0), "merged"), b"forged")
            shard1.put(bus.key(MISSION, "mission", "done"), b"forged")
            shard1.put(bus.key(prefix(1), "merged"), b"its own")  # after the others, same link
            wait_until(lambda: not seen.empty(), 10.0, "shard 1's own merged")
            time.sleep(0.3)
            keys = keys_seen(seen)
            shard0 = MapClient(tool, prefix(0), timeout=5.0)
            for _ in range(3):  # the forged queryables never passed the router: no conflict either
                assert shard0.acks() == {}
                assert shard0.stats()["shard"]["index"] == 0
            assert MapClient(tool, prefix(1), timeout=5.0).stats()["shard"]["index"] == 1
            for q in forged:
                q.undeclare()
            subscriber.undeclare()
    assert keys == [bus.key(prefix(1), "merged")], keys


def test_swarm_map_stats_as_a_tool_finds_the_shards_over_the_rules(team, tmp_path, capsys):
    with secure_shards(team, tmp_path / "store", SHARDS) as (_servers, endpoint):
        tool = ["--zenoh-config", str(team.configs["tool"]), "--connect", endpoint, "--timeout", "10"]
        for mission in (["--mission", MISSION], []):  # named, or found via swarm/*/shard/*/map/stats
            assert main(["map", "stats", "--json", *tool, *mission]) == 0
            stats = json.loads(capsys.readouterr().out)
            assert stats["mission"] == MISSION and len(stats["shards"]) == SHARDS, stats
