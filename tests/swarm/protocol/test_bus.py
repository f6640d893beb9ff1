"""Zenoh helpers over a real loopback session: explicit endpoints, scouting off, reliable BLOCK."""

from __future__ import annotations

import json
import queue

import pytest
import zenoh

from swarm.protocol import bus


def test_keys():
    assert bus.key("default", "robot", "r1", "frame") == "swarm/default/robot/r1/frame"
    assert bus.key("lab", "delta/r2") == "swarm/lab/delta/r2"
    assert bus.key_pattern("lab", "robot", "*", "cmd") == "swarm/lab/robot/*/cmd"
    for bad in ("*", "a/**", "", "/x", "a//b", "x$"):
        with pytest.raises(ValueError):
            bus.key("lab", bad)


def test_config_has_explicit_endpoints_and_no_multicast():
    conf = bus.make_config(listen=["tcp/127.0.0.1:7999"], connect=["tcp/127.0.0.1:7998"])
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7999"]
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7998"]


@pytest.fixture
def sessions():
    endpoint = bus.tcp_endpoint(bus.free_port())
    server = bus.open_session(listen=[endpoint])
    client = bus.open_session(connect=[endpoint])
    yield server, client
    client.close()
    server.close()


def test_reliable_publisher_delivers_everything_in_order(sessions):
    server, client = sessions
    sub, inbox = bus.subscribe_queue(client, bus.key_pattern("t", "delta", "*"))
    pub = bus.reliable_publisher(server, bus.key("t", "delta", "r1"))
    assert pub.congestion_control == zenoh.CongestionControl.BLOCK
    assert bus.wait_for_subscribers([pub], timeout=5.0)
    payload = bytes(range(256)) * 64  # 16 KiB
    for i in range(200):
        pub.put(i.to_bytes(4, "little") + payload)
    got = []
    while len(got) < 200:
        key_expr, data = inbox.get(timeout=5.0)
        assert key_expr == "swarm/t/delta/r1"
        got.append(int.from_bytes(data[:4], "little"))
        assert data[4:] == payload
    assert got == list(range(200))
    sub.undeclare()


def test_wait_for_subscribers_times_out_without_one(sessions):
    server, _ = sessions
    pub = bus.reliable_publisher(server, bus.key("t", "nobody"))
    assert not bus.has_subscribers(pub)
    assert not bus.wait_for_subscribers([pub], timeout=0.1)


def test_callback_subscriber(sessions):
    server, client = sessions
    inbox: queue.Queue = queue.Queue()
    sub = bus.subscribe(client, bus.key("t", "cmd"), lambda k, p: inbox.put((k, p)))
    pub = bus.reliable_publisher(server, bus.key("t", "cmd"))
    assert bus.wait_for_subscribers([pub], timeout=5.0)
    pub.put(b"hello")
    assert inbox.get(timeout=5.0) == ("swarm/t/cmd", b"hello")
    sub.undeclare()
