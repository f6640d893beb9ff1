"""ROS 2 names on Zenoh, as rmw_zenoh_cpp maps them: topic key expressions, QoS strings and the
liveliness tokens of the ROS graph.

Source: rmw_zenoh's ``docs/design.md`` (ros2/rmw_zenoh), sections "Topic and Service name mapping
to Zenoh key expressions" and "Graph Cache", and its ``qos_to_keyexpr``:

* a topic's data key is ``<domain_id>/<fully qualified name without its leading '/'>/<DDS type
  name>/<type hash>``, e.g. ``0/r1/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45...``;
* a node announces ``@ros2_lv/<domain>/<session id>/<node id>/<node id>/NN/<enclave>/<namespace>/
  <node name>`` and each of its publishers (``MP``) and subscriptions (``MS``) ``@ros2_lv/<domain>/
  <session id>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node name>/<topic>/<type>/
  <hash>/<qos>``, names *mangled* (every ``/`` written ``%``; an empty namespace is ``%``);
* QoS is ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
  <liveliness>,<lease s>,<ns>``, each field left empty when it equals rmw_zenoh's default (reliable,
  volatile, keep last 42, infinite durations, automatic liveliness); the numbers are rmw's enums.

Pure functions over strings; no Zenoh session here (``swarm.ros2.node`` declares them).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import IntEnum

ADMIN_SPACE = "@ros2_lv"
#: rmw_duration_t RMW_DURATION_INFINITE as (sec, nsec)
INFINITE = (9223372036, 854775807)


class Reliability(IntEnum):
    """rmw_qos_reliability_policy_e."""

    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(IntEnum):
    """rmw_qos_durability_policy_e."""

    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class History(IntEnum):
    """rmw_qos_history_policy_e."""

    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2


class EntityKind:
    """The entity kinds of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


@dataclass(frozen=True)
class Qos:
    """The QoS of a publisher or subscription (what rmw_zenoh honours: the rest stays default).

    ``depth`` is the history depth (samples kept: the publication cache of a TRANSIENT_LOCAL
    publisher, the queue of a subscription); 0 means rmw_zenoh's default of 42.
    """

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    history: History = History.KEEP_LAST
    depth: int = 10

    def __post_init__(self) -> None:
        if not 0 <= int(self.depth) < 2**31:
            raise ValueError(f"QoS depth must be 0..2^31-1, got {self.depth}")

    @property
    def effective_depth(self) -> int:
        return int(self.depth) or DEFAULT_QOS.depth

    def token(self) -> str:
        """The compact QoS string of a liveliness token (defaults left empty)."""
        d = DEFAULT_QOS

        def field(value: int, default: int) -> str:
            return "" if int(value) == int(default) else str(int(value))

        # deadline, lifespan and liveliness lease are never set here: infinite, i.e. default
        return (
            f"{field(self.reliability, d.reliability)}:{field(self.durability, d.durability)}:"
            f"{field(self.history, d.history)},{field(self.effective_depth, d.depth)}:,:,:,,"
        )

    @classmethod
    def from_token(cls, text: str) -> Qos:
        """Parse a QoS string of a liveliness token; ValueError if it is not one."""
        parts = text.split(":")
        if len(parts) != 6:
            raise ValueError(f"QoS {text!r}: expected 6 ':'-separated fields, got {len(parts)}")
        history = parts[2].split(",")
        if len(history) != 2:
            raise ValueError(f"QoS {text!r}: history must be '<kind>,<depth>'")
        d = DEFAULT_QOS
        try:
            return cls(
                Reliability(int(parts[0])) if parts[0] else d.reliability,
                Durability(int(parts[1])) if parts[1] else d.durability,
                History(int(history[0])) if history[0] else d.history,
                int(history[1]) if history[1] else d.depth,
            )
        except ValueError as exc:
            raise ValueError(f"QoS {text!r}: {exc}") from None


#: rmw_zenoh's default QoS: the values a token leaves empty
DEFAULT_QOS = Qos(Reliability.RELIABLE, Durability.VOLATILE, History.KEEP_LAST, 42)
#: sensor data (rclcpp's SensorDataQoS): best effort, keep last 5
SENSOR_QOS = Qos(Reliability.BEST_EFFORT, Durability.VOLATILE, History.KEEP_LAST, 5)
#: latched: late joiners get the last ``depth`` samples (tf_static, maps)
LATCHED_QOS = Qos(Reliability.RELIABLE, Durability.TRANSIENT_LOCAL, History.KEEP_LAST, 1)

_NAME_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def check_node_name(name: str) -> str:
    """A valid ROS node name (letters, digits and '_', not starting with a digit) or ValueError."""
    if not _NAME_TOKEN.match(name or ""):
        raise ValueError(f"node name {name!r}: letters, digits and '_' only, not starting with a digit")
    return name


def check_namespace(namespace: str) -> str:
    """A namespace as ROS writes it: '' or '/' for none, else '/a/b' (tokens as in node names).

    Returns the normalised form ('/' or '/a/b'); ValueError names what is wrong.
    """
    text = (namespace or "/").strip()
    if not text.startswith("/"):
        text = "/" + text
    text = text.rstrip("/") or "/"
    if text != "/":
        for token in text[1:].split("/"):
            if not _NAME_TOKEN.match(token):
                raise ValueError(
                    f"namespace {namespace!r}: token {token!r} must be letters, digits and '_', "
                    "not starting with a digit"
                )
    return text


def qualified_name(name: str, namespace: str = "/", node: str | None = None) -> str:
    """The fully qualified name of a topic: absolute names stay, relative ones go under
    ``namespace``, ``~/x`` under ``namespace/node`` (ROS 2's topic and service names design).

    ValueError for an empty name, ``//``, a trailing ``/``, or a token that is not a ROS name.
    """
    text = (name or "").strip()
    if not text:
        raise ValueError("empty topic name")
    ns = check_namespace(namespace)
    if text == "~" or text.startswith("~/"):
        if node is None:
            raise ValueError(f"topic {name!r}: a private name needs the node's name")
        text = (ns.rstrip("/") + "/" + check_node_name(node) + text[1:]).rstrip("/")
    elif not text.startswith("/"):
        text = ns.rstrip("/") + "/" + text
    if "//" in text or text.endswith("/"):
        raise ValueError(f"topic {name!r}: no empty tokens ('//' or a trailing '/')")
    for token in text[1:].split("/"):
        if not re.match(r"^[A-Za-z0-9_]+$", token) or token[0].isdigit():
            raise ValueError(
                f"topic {name!r}: token {token!r} must be letters, digits and '_', not starting with a digit"
            )
    return text


def dds_type_name(type_name: str) -> str:
    """``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_`` (the CDR type name)."""
    parts = type_name.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"type {type_name!r}: expected 'package/msg/Name'")
    package, kind, short = parts
    return f"{package}::{kind}::dds_::{short}_"


def ros_type_name(dds_name: str) -> str:
    """The inverse of ``dds_type_name``; ValueError for a name not of that shape."""
    match = re.fullmatch(r"([A-Za-z0-9_]+)::([a-z]+)::dds_::([A-Za-z0-9_]+)_", dds_name)
    if not match:
        raise ValueError(f"{dds_name!r} is not a DDS type name 'pkg::msg::dds_::Name_'")
    return "/".join(match.groups())


def mangle(name: str) -> str:
    """A name inside a liveliness token: each '/' written '%'."""
    return name.replace("/", "%")


def demangle(name: str) -> str:
    return name.replace("%", "/")


def topic_key(domain_id: int, fq_name: str, type_name: str, type_hash: str) -> str:
    """The data key of a topic: ``<domain>/<name without leading '/'>/<DDS type>/<hash>``."""
    return f"{int(domain_id)}/{fq_name.strip('/')}/{dds_type_name(type_name)}/{type_hash}"


@dataclass(frozen=True)
class GraphEntity:
    """One liveliness token of the ROS graph, parsed (``parse_token``) or to declare (``token``)."""

    domain_id: int
    session_id: str
    node_id: int
    entity_id: int
    kind: str
    enclave: str
    namespace: str
    node_name: str
    topic: str | None = None
    type_name: str | None = None  # ROS form, package/msg/Name
    type_hash: str | None = None
    qos: Qos | None = None

    def token(self) -> str:
        """The liveliness key expression announcing this entity."""
        head = (
            f"{ADMIN_SPACE}/{int(self.domain_id)}/{self.session_id}/{int(self.node_id)}/"
            f"{int(self.entity_id)}/{self.kind}/{mangle(self.enclave)}/{mangle(self.namespace)}/"
            f"{self.node_name}"
        )
        if self.kind == EntityKind.NODE:
            return head
        if self.topic is None or self.type_name is None or self.type_hash is None or self.qos is None:
            raise ValueError(f"a {self.kind} token needs its topic, type, type hash and QoS")
        return (
            f"{head}/{mangle(self.topic)}/{dds_type_name(self.type_name)}/{self.type_hash}/{self.qos.token()}"
        )

    @property
    def key(self) -> str:
        """The data key of this entity's topic (publishers and subscriptions)."""
        if self.topic is None or self.type_name is None or self.type_hash is None:
            raise ValueError("a node has no data key")
        return topic_key(self.domain_id, self.topic, self.type_name, self.type_hash)


def node_token_pattern(domain_id: int) -> str:
    """The key expression matching every liveliness token of a domain."""
    return f"{ADMIN_SPACE}/{int(domain_id)}/**"


def parse_token(key: str) -> GraphEntity:
    """A liveliness token of rmw_zenoh's graph; ValueError naming the part that does not parse."""
    parts = str(key).split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE:
        raise ValueError(f"{key!r}: not a ROS 2 liveliness token ('{ADMIN_SPACE}/<domain>/...', 9+ parts)")
    kind = parts[5]
    if kind not in (EntityKind.NODE, EntityKind.PUBLISHER, EntityKind.SUBSCRIPTION, "SS", "SC"):
        raise ValueError(f"{key!r}: unknown entity kind {kind!r}")
    try:
        domain, node_id, entity_id = int(parts[1]), int(parts[3]), int(parts[4])
    except ValueError:
        raise ValueError(f"{key!r}: domain, node and entity ids must be integers") from None
    common = dict(
        domain_id=domain,
        session_id=parts[2],
        node_id=node_id,
        entity_id=entity_id,
        kind=kind,
        enclave=demangle(parts[6]),
        namespace=demangle(parts[7]),
        node_name=parts[8],
    )
    if kind == EntityKind.NODE:
        if len(parts) != 9:
            raise ValueError(f"{key!r}: a node token has 9 parts, this one {len(parts)}")
        return GraphEntity(**common)
    if len(parts) != 13:
        raise ValueError(f"{key!r}: an endpoint token has 13 parts, this one {len(parts)}")
    return GraphEntity(
        **common,
        topic=demangle(parts[9]),
        type_name=ros_type_name(parts[10]),
        type_hash=parts[11],
        qos=Qos.from_token(parts[12]),
    )
