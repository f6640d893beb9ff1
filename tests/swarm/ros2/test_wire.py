"""ROS 2 over Zenoh as rmw_zenoh_cpp writes it (``swarm.ros2``): key expressions, liveliness
tokens, QoS strings, the 33-byte attachment, and a node's publishers and subscriptions on real
loopback Zenoh sessions. Expected strings are rmw_zenoh ``docs/design.md``'s own examples."""

from __future__ import annotations

import queue
import struct
import time

import numpy as np
import pytest
import zenoh

from swarm.protocol import bus
from swarm.ros2.attachment import SIZE, Attachment, AttachmentError
from swarm.ros2.graph import (
    DEFAULT_QOS,
    LATCHED_QOS,
    Durability,
    EntityKind,
    GraphEntity,
    History,
    Qos,
    Reliability,
    dds_type_name,
    node_token_pattern,
    parse_token,
    qualified_name,
    topic_key,
)
from swarm.ros2.node import Ros2Context, entity_gid
from swarm.ros2.types import NO_TYPE_HASH, MessageError, Ros2Types, header

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_topic_keys_are_rmw_zenohs_design_examples():
    types = Ros2Types("jazzy")
    assert types.type_hash("std_msgs/msg/String") == STRING_HASH
    assert topic_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == (
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    )
    fq = qualified_name("chatter", "/robot1")
    assert topic_key(0, fq, "std_msgs/msg/String", STRING_HASH) == (
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    )
    assert Ros2Types("humble").type_hash("std_msgs/msg/String") == NO_TYPE_HASH


def test_liveliness_tokens_are_rmw_zenohs_design_examples():
    zid = "8b20917502ee955ac4476e0266340d5c"
    talker = GraphEntity(2, zid, 0, 10, EntityKind.PUBLISHER, "/", "/", "talker", "/chatter",
                         "std_msgs/msg/String", STRING_HASH, Qos(depth=7))  # fmt: skip
    assert talker.token() == (
        f"@ros2_lv/2/{zid}/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,"
    )
    node = GraphEntity(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 0, EntityKind.NODE, "/", "/", "listener")
    assert node.token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert parse_token(talker.token()) == talker
    assert parse_token(node.token()) == node


def test_qos_strings_leave_rmw_zenohs_defaults_empty_and_parse_back():
    assert DEFAULT_QOS.token() == "::,:,:,:,,"
    assert Qos(depth=0).token() == "::,:,:,:,,"  # depth 0 is rmw_zenoh's 42
    latched = LATCHED_QOS.token()
    assert latched == ":1:,1:,:,:,,"
    sensor = Qos(Reliability.BEST_EFFORT, Durability.VOLATILE, History.KEEP_LAST, 5)
    assert sensor.token() == "2::,5:,:,:,,"
    for qos in (LATCHED_QOS, sensor, Qos(history=History.KEEP_ALL, depth=3)):
        assert Qos.from_token(qos.token()) == qos
    for bad in ("1:2", "9::,1:,:,:,,", "::x,1:,:,:,,"):
        with pytest.raises(ValueError):
            Qos.from_token(bad)


@pytest.mark.parametrize(
    "name, namespace, expected",
    [
        ("cmd_vel", "/r1", "/r1/cmd_vel"),
        ("/tf", "/r1", "/tf"),
        ("a/b", "", "/a/b"),
        ("~/x", "/r1", "/r1/n/x"),
    ],
)
def test_qualified_names(name, namespace, expected):
    assert qualified_name(name, namespace, "n") == expected


@pytest.mark.parametrize("name", ["", "a//b", "a/", "1abc", "a-b", "a/*"])
def test_names_ros_refuses_are_refused(name):
    with pytest.raises(ValueError):
        qualified_name(name, "/")


def test_attachment_is_33_little_endian_bytes():
    gid = bytes(range(16))
    raw = Attachment(7, 1_700_000_000_123_456_789, gid).encode()
    assert len(raw) == SIZE == 33
    assert struct.unpack("<q", raw[:8])[0] == 7
    assert struct.unpack("<q", raw[8:16])[0] == 1_700_000_000_123_456_789
    assert raw[16] == 16 and raw[17:] == gid
    assert Attachment.decode(raw) == Attachment(7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(AttachmentError):
        Attachment.decode(raw[:-1])
    with pytest.raises(AttachmentError):
        Attachment.decode(raw[:16] + bytes([8]) + raw[17:])


def test_cdr_round_trip_and_malformed_payloads_refused():
    types = Ros2Types("jazzy")
    msg = types.new("std_msgs/msg/String", data="hello")
    raw = types.serialize(msg, "std_msgs/msg/String")
    assert raw[:2] == b"\x00\x01"  # CDR little-endian encapsulation
    assert types.deserialize(raw, "std_msgs/msg/String").data == "hello"
    for bad in (b"", b"\x00\x01", b"\x07\x07\x00\x00abc", raw[:6]):
        with pytest.raises(MessageError):
            types.deserialize(bad, "std_msgs/msg/String")
    with pytest.raises(ValueError, match="not in ROS 2"):
        types.new("no_msgs/msg/Nothing")


@pytest.fixture
def contexts():
    endpoint = bus.tcp_endpoint(bus.free_port())
    a = bus.open_session(listen=[endpoint])
    b = bus.open_session(connect=[endpoint])
    yield Ros2Context(a, domain_id=3), Ros2Context(b, domain_id=3)
    b.close()
    a.close()


def _wait(predicate, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def test_publisher_and_subscription_exchange_messages_with_attachments(contexts):
    pub_ctx, sub_ctx = contexts
    talker = pub_ctx.node("talker", "/r1")
    listener = sub_ctx.node("listener", "/r1")
    got: queue.Queue = queue.Queue()
    sub = listener.subscription("chatter", "std_msgs/msg/String", lambda m, i: got.put((m, i)))
    pub = talker.publisher("chatter", "std_msgs/msg/String")
    assert pub.entity.key == sub.entity.key == (f"3/r1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    time.sleep(0.3)
    for text in ("a", "b", "c"):
        pub.publish(pub_ctx.types.new("std_msgs/msg/String", data=text))
    received = [got.get(timeout=5) for _ in range(3)]
    assert [m.data for m, _ in received] == ["a", "b", "c"]
    assert [i.attachment.sequence_number for _, i in received] == [1, 2, 3]
    assert all(i.attachment.gid == entity_gid(pub.entity.token()) for _, i in received)
    assert all(abs(i.attachment.source_timestamp_ns / 1e9 - time.time()) < 10 for _, i in received)


@pytest.mark.slow
def test_liveliness_tokens_announce_the_node_and_its_endpoints(contexts):
    pub_ctx, sub_ctx = contexts
    node = pub_ctx.node("mapper", "/team")
    node.publisher("map", "nav_msgs/msg/OccupancyGrid", LATCHED_QOS)
    time.sleep(0.3)
    tokens = [str(r.ok.key_expr) for r in sub_ctx.session.liveliness().get(node_token_pattern(3), timeout=3)]
    entities = [parse_token(t) for t in tokens]
    kinds = sorted((e.kind, e.topic) for e in entities if e.node_name == "mapper")
    assert kinds == [("MP", "/team/map"), ("NN", None)]
    pub = next(e for e in entities if e.kind == "MP")
    assert pub.session_id == str(pub_ctx.session.info.zid()) and pub.namespace == "/team"
    assert pub.qos == LATCHED_QOS and pub.type_hash == pub_ctx.types.type_hash("nav_msgs/msg/OccupancyGrid")
    node.close()
    time.sleep(0.3)
    left = [str(r.ok.key_expr) for r in sub_ctx.session.liveliness().get(node_token_pattern(3), timeout=3)]
    assert not [t for t in left if "/mapper" in t]


def test_transient_local_late_subscriber_gets_the_cached_samples(contexts):
    pub_ctx, sub_ctx = contexts
    latched = Qos(durability=Durability.TRANSIENT_LOCAL, depth=2)
    pub = pub_ctx.node("latched").publisher("/state", "std_msgs/msg/String", latched)
    for text in ("one", "two", "three"):
        pub.publish(pub_ctx.types.new("std_msgs/msg/String", data=text))
    time.sleep(0.2)
    got: list = []
    sub_ctx.node("late").subscription(
        "/state", "std_msgs/msg/String", lambda m, i: got.append(m.data), latched
    )
    assert _wait(lambda: len(got) >= 2)
    assert got[:2] == ["two", "three"]


def test_a_subscription_counts_bad_samples_and_keeps_going(contexts):
    pub_ctx, sub_ctx = contexts
    got: list = []

    def callback(message, info):
        if message.data == "boom":
            raise RuntimeError("callback fault")
        got.append(message.data)

    sub = sub_ctx.node("listener").subscription("/x", "std_msgs/msg/String", callback, max_bytes=1000)
    key = sub.entity.key
    types = pub_ctx.types
    good = types.serialize(types.new("std_msgs/msg/String", data="ok"), "std_msgs/msg/String")
    boom = types.serialize(types.new("std_msgs/msg/String", data="boom"), "std_msgs/msg/String")
    att = Attachment(1, time.time_ns(), bytes(16)).encode()
    time.sleep(0.3)
    session = pub_ctx.session
    session.put(key, b"\x00\x01\x00\x00\xff\xff\xff\x7f", attachment=att)  # a 2 GB string claim
    session.put(key, good)  # no attachment
    session.put(key, good, attachment=b"short")
    session.put(key, bytes(np.zeros(2000, np.uint8)), attachment=att)
    session.put(key, boom, attachment=att)
    session.put(key, good, attachment=att)
    assert _wait(lambda: got == ["ok"])
    assert _wait(lambda: sum(sub.refused.values()) == 5)
    assert sub.refused == {"malformed": 1, "no attachment": 1, "bad attachment": 1, "too large": 1,
                           "callback raised": 1}  # fmt: skip


def test_header_stamps_round_trip():
    types = Ros2Types()
    h = header(types, 12.25, "cam")
    assert (h.stamp.sec, h.stamp.nanosec, h.frame_id) == (12, 250_000_000, "cam")
    with pytest.raises(ValueError):
        header(types, float("nan"), "cam")


def test_zenoh_session_id_is_what_tokens_carry(contexts):
    ctx, _ = contexts
    assert ctx.session_id == str(ctx.session.info.zid())
    assert isinstance(ctx.session, zenoh.Session)
    assert dds_type_name("sensor_msgs/msg/Image") == "sensor_msgs::msg::dds_::Image_"
