"""The team bus over Zenoh's mutual TLS and access control, with the configs `swarm security init`
writes: real sessions on loopback TLS endpoints, a real map server behind them.

What must hold: a robot holding r1's certificate cannot get a delta applied as r2; a tool
cannot put; a client without a certificate of the mission's CA cannot connect; a session that
is not the server cannot answer ``map/acks``; and, without any access control at all, a client
refuses disagreeing replies instead of taking the first.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec

from map_server.server import MapServer
from swarm.protocol import bus
from swarm.protocol.coord_client import ask_for_target
from swarm.protocol.epochs import ask_epoch, wait_for_epoch
from swarm.protocol.map_client import ConflictingMapReplies, MapClient
from swarm.protocol.wire import AssignReply, Pose
from swarm.security.access_rules import access_control, agent_name
from swarm.security.certificates import common_name
from swarm.security.team_setup import init_team
from tests.support.map_server_mission import EPOCH, small_mission, wait_until
from tests.support.secure_team import ROBOTS, one_delta, secure_server, session_as


def put_signed(session: zenoh.Session, robot: str, payload: bytes) -> None:
    """Ask the server for ``robot``'s epoch (EPOCH, the first of a fresh store) and put ``payload``
    on ``delta/<robot>`` with its MAC."""
    grant = wait_for_epoch(session, "srvtest", robot, 10.0)
    assert grant.epoch == EPOCH, grant
    session.put(bus.key("srvtest", "delta", robot), payload, attachment=grant.sign(payload))


# -- what init writes -------------------------------------------------------------------------------


def test_every_identity_has_a_certificate_of_the_mission_ca_and_a_config(team):
    ca = x509.load_pem_x509_certificate(team.ca.read_bytes())
    assert set(team.configs) == {"server", "coordinator", "world", "tool", "operator"} | {
        f"{kind}-{r}" for r in ROBOTS for kind in ("agent", "source")
    }
    for name, conf_path in team.configs.items():
        folder = conf_path.parent
        cert = x509.load_pem_x509_certificate((folder / "cert.pem").read_bytes())
        assert common_name(folder / "cert.pem") == name
        ca.public_key().verify(
            cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm)
        )
        assert (folder / "key.pem").stat().st_mode & 0o077 == 0, f"{name}'s key is readable by others"
        conf, listen, connect = bus.session_config(config_file=conf_path)
        tls = json.loads(conf.get_json("transport/link/tls"))
        assert tls["enable_mtls"] is True and Path(tls["connect_certificate"]).is_file()
        acl = json.loads(conf.get_json("access_control"))
        if name == "server":
            assert listen == ["tls/0.0.0.0:7447#tls_handshake_timeout_ms=60000"]
            assert acl["enabled"] and acl["default_permission"] == "deny"
        else:
            assert connect == ["tls/127.0.0.1:7447"] and not listen and not acl["enabled"]


def allowed_in(acl: dict, message: str, key: str) -> set[str]:
    """The CNs the rules let send ``message`` on exactly ``key`` (ingress)."""
    rules = {r["id"]: r for r in acl["rules"]}
    by_subject = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    return {
        cn
        for policy in acl["policies"]
        for rule in policy["rules"]
        if message in rules[rule]["messages"]
        and rules[rule]["flows"] == ["ingress"]
        and key in rules[rule]["key_exprs"]
        for subject in policy["subjects"]
        for cn in by_subject[subject]
    }


def test_only_its_agent_may_put_a_robots_delta_in_the_rules():
    acl = access_control("m", ROBOTS)
    for rid in ROBOTS:
        assert allowed_in(acl, "put", f"swarm/m/delta/{rid}") == {agent_name(rid)}


def test_only_its_agent_may_ask_the_coordinator_for_a_robot_in_the_rules():
    acl = access_control("m", ROBOTS)
    for rid in ROBOTS:
        assert allowed_in(acl, "query", f"swarm/m/coord/assign/{rid}") == {agent_name(rid)}
    assert allowed_in(acl, "query", "swarm/m/coord/assign") == set()  # the old shared key


def test_command_line_endpoints_win_over_the_files(team, monkeypatch):
    _, listen, connect = bus.session_config(connect=["tls/10.0.0.9:9000"], config_file=team.configs["tool"])
    assert connect == ["tls/10.0.0.9:9000"] and listen == []
    monkeypatch.setenv("ZENOH_CONFIG", str(team.configs["server"]))
    conf, listen, _ = bus.session_config(listen=["tls/127.0.0.1:9001"])
    assert listen == ["tls/127.0.0.1:9001"]
    assert json.loads(conf.get_json("access_control"))["enabled"] is True  # from $ZENOH_CONFIG
    monkeypatch.setenv("ZENOH_CONFIG", str(team.out / "missing.json5"))
    with pytest.raises(ValueError, match="missing.json5"):
        bus.session_config()


# -- real sessions over TLS ------------------------------------------------------------------------


def test_r1_cannot_get_a_delta_applied_as_r2_and_a_tool_cannot_put(team, tmp_path):
    with secure_server(team, tmp_path / "store") as (server, endpoint):
        with session_as(team, "agent-r1", endpoint) as r1, session_as(team, "tool", endpoint) as tool:
            tool.put(bus.key("srvtest", "delta", "r3"), one_delta("r3"))
            r1.put(bus.key("srvtest", "delta", "r2"), one_delta("r2"))
            # a tool may not ask for another robot's epoch (its key): no reply reaches it
            assert ask_epoch(tool, "srvtest", "r1", 1.0) is None
            put_signed(r1, "r1", one_delta("r1"))  # after the others, same link
            client = MapClient(r1, "srvtest", timeout=5.0)
            wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10.0, "r1's delta")
            time.sleep(0.3)
            acks = client.acks()
            assert set(acks) == {"r1"}, acks
            assert client.stats()["deltas_applied"] == 1 and client.stats()["epochs_issued"] == 1


@pytest.mark.slow
def test_a_client_without_a_mission_certificate_cannot_connect(team, tmp_path):
    other = init_team("srvtest", ["r1"], tmp_path / "other-team")  # same names, another CA
    with secure_server(team, tmp_path / "store") as (_server, endpoint):
        no_cert = tmp_path / "no-cert.json5"
        no_cert.write_text(
            json.dumps({"transport": {"link": {"tls": {"root_ca_certificate": str(team.ca)}}}})
        )
        for conf in (no_cert, other.configs["agent-r1"]):
            with pytest.raises(ConnectionError, match="TLS"):
                bus.open_session(connect=[endpoint], config_file=conf, wait_s=1.0)
        with pytest.raises(ConnectionError):  # plain TCP to the TLS port
            bus.open_session(connect=[endpoint.replace("tls/", "tcp/")], wait_s=1.0)


def test_a_session_that_is_not_the_server_cannot_answer_map_acks(team, tmp_path):
    with secure_server(team, tmp_path / "store") as (_server, endpoint):
        with (
            session_as(team, "agent-r1", endpoint) as r1,
            session_as(team, "coordinator", endpoint) as forger,
        ):
            forged = json.dumps({"r1": {str(EPOCH): 10**9}}).encode()
            queryable = forger.declare_queryable(
                bus.key("srvtest", "map", "acks"), lambda q: q.reply(q.key_expr, forged)
            )
            put_signed(r1, "r1", one_delta("r1"))
            client = MapClient(r1, "srvtest", timeout=5.0)
            wait_until(lambda: client.acks().get("r1", {}).get(EPOCH) == 1, 10.0, "the true ack")
            for _ in range(5):
                assert client.acks() == {"r1": {EPOCH: 1}}
            queryable.undeclare()


def test_a_session_that_is_not_the_coordinator_cannot_answer_coord_assign(team, tmp_path):
    with secure_server(team, tmp_path / "store") as (_server, endpoint):
        with (
            session_as(team, "agent-r1", endpoint) as r1,
            session_as(team, "tool", endpoint) as forger,
            session_as(team, "coordinator", endpoint) as coordinator,
        ):
            key = bus.key_pattern("srvtest", "coord", "assign", "*")  # as the coordinator declares it
            true = AssignReply((1.0, 2.0, 0.0), (0.0, 1.0, 0.0), 3.0)
            forged = AssignReply((9.0, 9.0, 0.0), (1.0, 0.0, 0.0), 1e9).encode()
            declared = [
                coordinator.declare_queryable(key, lambda q: q.reply(q.key_expr, true.encode())),
                forger.declare_queryable(key, lambda q: q.reply(q.key_expr, forged)),
            ]
            time.sleep(0.3)
            for _ in range(3):  # the forger's declaration never passed the router: no conflict either
                answer = ask_for_target(r1, "srvtest", "r1", Pose((0.0, 0.0, 0.0)), timeout=2.0)
                assert answer is not None and answer.target == true.target
            for q in declared:
                q.undeclare()


def test_swarm_map_stats_as_a_tool_finds_the_mission_over_the_rules(team, tmp_path, capsys):
    from swarm.cli.main import main

    with secure_server(team, tmp_path / "store") as (_server, endpoint):
        tool = ["--zenoh-config", str(team.configs["tool"]), "--connect", endpoint, "--timeout", "10"]
        for mission in (["--mission", "srvtest"], []):  # named, or found via swarm/*/map/stats
            assert main(["map", "stats", "--json", *tool, *mission]) == 0
            assert json.loads(capsys.readouterr().out)["mission"] == "srvtest"


# -- the client's own check, with no access control at all ---------------------------------------------


@pytest.mark.slow
def test_clients_refuse_disagreeing_replies_on_an_open_bus(tmp_path):
    endpoint = bus.tcp_endpoint(bus.free_port())
    server = MapServer(small_mission(), tmp_path / "store")
    router = bus.open_session(listen=[endpoint])
    server.start(router)
    forger = bus.open_session(connect=[endpoint])
    client_session = bus.open_session(connect=[endpoint])
    try:
        client = MapClient(client_session, "srvtest", timeout=3.0)
        assert client.acks() == {}
        forged = json.dumps({"r1": {str(EPOCH): 10**9}}).encode()
        fake = forger.declare_queryable(
            bus.key("srvtest", "map", "acks"), lambda q: q.reply(q.key_expr, forged)
        )
        fake_coord = [
            forger.declare_queryable(
                bus.key_pattern("srvtest", "coord", "assign", "*"),
                lambda q, t=t: q.reply(q.key_expr, AssignReply((t, 0.0, 0.0), (1.0, 0.0, 0.0), t).encode()),
            )
            for t in (1.0, 2.0)
        ]
        time.sleep(0.3)
        for _ in range(3):
            with pytest.raises(ConflictingMapReplies, match="2 different answers"):
                client.acks()
        pose = Pose((0.0, 0.0, 0.0))
        assert ask_for_target(client_session, "srvtest", "r1", pose, timeout=1.0) is None
        fake.undeclare()
        for q in fake_coord:
            q.undeclare()
        time.sleep(0.3)
        assert client.acks() == {}
    finally:
        client_session.close()
        forger.close()
        server.stop()
        router.close()
