"""A ROS 2 node on a Zenoh session, speaking rmw_zenoh_cpp's wire: no ROS install needed.

``Ros2Node`` announces itself and each of its publishers and subscriptions with liveliness
tokens (so ``ros2 node list`` and ``ros2 topic list -v`` on an rmw_zenoh robot show them, with
their QoS), publishes CDR messages with the 33-byte attachment on the topic's key, and hands the
messages of a subscription to a callback. QoS as rmw_zenoh maps it (its ``docs/design.md``,
"Quality of Service"): TRANSIENT_LOCAL publishers are Zenoh advanced publishers with a cache of
``depth`` samples (late joiners get them), TRANSIENT_LOCAL subscriptions advanced subscribers that
ask for that history; congestion control is DROP except RELIABLE + KEEP_ALL (BLOCK).

A subscription never raises into Zenoh's thread: a payload that does not deserialize, lacks the
attachment or is larger than ``max_bytes`` is counted by reason in ``Ros2Subscription.refused``,
as is a callback that raised (the message names the first such error in ``last_error``).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import xxhash
import zenoh
import zenoh.ext

from swarm.ros2.attachment import Attachment, AttachmentError
from swarm.ros2.graph import (
    Durability,
    EntityKind,
    GraphEntity,
    History,
    Qos,
    Reliability,
    check_namespace,
    check_node_name,
    qualified_name,
)
from swarm.ros2.types import DEFAULT_DISTRO, MessageError, Ros2Types

#: the QoS of rclcpp's default profile (reliable, volatile, keep last 10)
DEFAULT_ENDPOINT_QOS = Qos()
#: the largest message a subscription takes by default (a 4K RGB image is 25 MB)
DEFAULT_MAX_BYTES = 64 * 1024 * 1024


def entity_gid(token: str) -> bytes:
    """The 16-byte GID of an entity: XXH3-128 of its liveliness token, low 64 bits first (as
    rmw_zenoh computes it), so our attachments carry the GID ROS 2 tools show for our publishers."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")


@dataclass(frozen=True)
class MessageInfo:
    """What came with a message: its attachment (None if the sender sent none) and arrival time."""

    attachment: Attachment | None
    received_s: float  # time.time() at arrival
    key: str


class Ros2Context:
    """One Zenoh session seen as one ROS 2 context: domain, distribution, entity ids.

    ``session`` is any open Zenoh session (client mode to the robot's ``rmw_zenohd``, or a peer of
    ours); ``domain_id`` is ROS_DOMAIN_ID (0..232 as ROS allows); ``distro`` one of
    ``swarm.ros2.types.DISTROS``. Raises ValueError for a bad domain or distro.
    """

    def __init__(self, session: zenoh.Session, domain_id: int = 0, distro: str = DEFAULT_DISTRO) -> None:
        if not 0 <= int(domain_id) <= 232:
            raise ValueError(f"ROS domain id must be 0..232, got {domain_id}")
        self.session = session
        self.domain_id = int(domain_id)
        self.types = Ros2Types(distro)
        self.session_id = str(session.info.zid())
        self._ids = itertools.count()
        self._lock = threading.Lock()

    def next_id(self) -> int:
        with self._lock:
            return next(self._ids)

    def node(self, name: str, namespace: str = "/", enclave: str = "/") -> Ros2Node:
        return Ros2Node(self, name, namespace, enclave)


class Ros2Publisher:
    """A publisher of ``type_name`` on one topic; ``publish(message)`` or ``publish_cdr(bytes)``."""

    def __init__(self, node: Ros2Node, topic: str, type_name: str, qos: Qos) -> None:
        ctx = node.context
        self.type_name = type_name
        self.types = ctx.types
        self.entity = node.entity(EntityKind.PUBLISHER, topic, type_name, qos)
        self.topic = self.entity.topic
        self.gid = entity_gid(self.entity.token())
        self._seq = itertools.count(1)
        self._lock = threading.Lock()
        keep_all = qos.reliability == Reliability.RELIABLE and qos.history == History.KEEP_ALL
        options = dict(
            congestion_control=zenoh.CongestionControl.BLOCK if keep_all else zenoh.CongestionControl.DROP,
            reliability=zenoh.Reliability.BEST_EFFORT
            if qos.reliability == Reliability.BEST_EFFORT
            else zenoh.Reliability.RELIABLE,
        )
        if qos.durability == Durability.TRANSIENT_LOCAL:
            self._publisher = zenoh.ext.declare_advanced_publisher(
                ctx.session,
                self.entity.key,
                cache=zenoh.ext.CacheConfig(qos.effective_depth),
                publisher_detection=True,
                **options,
            )
        else:
            self._publisher = ctx.session.declare_publisher(self.entity.key, **options)
        self._token = ctx.session.liveliness().declare_token(self.entity.token())
        self.published = 0

    def has_subscribers(self) -> bool:
        """Whether a subscription matches this topic now (a TRANSIENT_LOCAL publisher's Zenoh
        advanced publisher tells nothing: True, its late joiners get the cache anyway)."""
        status = getattr(self._publisher, "matching_status", None)
        return True if status is None else bool(getattr(status, "matching", status))

    def publish(self, message: Any) -> None:
        """Serialise ``message`` (of this publisher's type) and put it with its attachment."""
        self.publish_cdr(self.types.serialize(message, self.type_name))

    def publish_cdr(self, payload: bytes) -> None:
        """Put an already serialised CDR message."""
        with self._lock:
            attachment = Attachment(next(self._seq), time.time_ns(), self.gid)
            self._publisher.put(payload, attachment=attachment.encode())
            self.published += 1

    def close(self) -> None:
        """Undeclare the publisher and its token (once; again does nothing)."""
        if self._token is not None:
            self._token.undeclare()
            self._publisher.undeclare()
            self._token = None


class Ros2Subscription:
    """A subscription: each message of ``type_name`` on ``topic`` goes to ``callback(msg, info)``.

    ``require_attachment`` refuses samples without rmw_zenoh's attachment (a ROS 2 publisher always
    sends one); ``max_bytes`` refuses larger payloads before they are deserialised.
    """

    def __init__(
        self,
        node: Ros2Node,
        topic: str,
        type_name: str,
        callback: Callable[[Any, MessageInfo], None],
        qos: Qos,
        *,
        max_bytes: int = DEFAULT_MAX_BYTES,
        require_attachment: bool = True,
    ) -> None:
        ctx = node.context
        self.type_name = type_name
        self.types = ctx.types
        self.callback = callback
        self.max_bytes = int(max_bytes)
        self.require_attachment = require_attachment
        self.entity = node.entity(EntityKind.SUBSCRIPTION, topic, type_name, qos)
        self.topic = self.entity.topic
        self.received = 0
        self.refused: Counter[str] = Counter()
        self.last_error = ""
        self._lock = threading.Lock()
        if qos.durability == Durability.TRANSIENT_LOCAL:
            history = zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=qos.effective_depth)
            self._subscriber = zenoh.ext.declare_advanced_subscriber(
                ctx.session, self.entity.key, self._on_sample, history=history
            )
        else:
            self._subscriber = ctx.session.declare_subscriber(self.entity.key, self._on_sample)
        self._token = ctx.session.liveliness().declare_token(self.entity.token())

    def _refuse(self, reason: str, detail: str) -> None:
        with self._lock:
            self.refused[reason] += 1
            self.last_error = f"{self.topic}: {detail}"

    def _on_sample(self, sample: zenoh.Sample) -> None:
        payload = sample.payload
        if len(payload) > self.max_bytes:
            self._refuse("too large", f"{len(payload)} bytes, more than the {self.max_bytes} taken")
            return
        attachment = None
        if sample.attachment is not None:
            try:
                attachment = Attachment.decode(sample.attachment.to_bytes())
            except AttachmentError as exc:
                self._refuse("bad attachment", str(exc))
                return
        elif self.require_attachment:
            self._refuse("no attachment", "a sample without rmw_zenoh's attachment")
            return
        try:
            message = self.types.deserialize(payload.to_bytes(), self.type_name)
        except MessageError as exc:
            self._refuse("malformed", str(exc))
            return
        with self._lock:
            self.received += 1
        try:
            self.callback(message, MessageInfo(attachment, time.time(), str(sample.key_expr)))
        except Exception as exc:  # a callback's fault must not reach Zenoh's thread
            self._refuse("callback raised", f"{type(exc).__name__}: {exc}")

    def close(self) -> None:
        """Undeclare the subscription and its token (once; again does nothing)."""
        if self._token is not None:
            self._token.undeclare()
            self._subscriber.undeclare()
            self._token = None


class Ros2Node:
    """A ROS 2 node: its liveliness token, and the publishers and subscriptions made from it.

    ``name`` is the node name, ``namespace`` e.g. ``/r1`` (topics without a leading '/' go under
    it), ``enclave`` the SROS enclave ('/' for none). ValueError for names ROS would refuse.
    """

    def __init__(self, context: Ros2Context, name: str, namespace: str = "/", enclave: str = "/") -> None:
        self.context = context
        self.name = check_node_name(name)
        self.namespace = check_namespace(namespace)
        self.enclave = enclave or "/"
        self.node_id = context.next_id()
        self._entities: list[Ros2Publisher | Ros2Subscription] = []
        node = GraphEntity(
            context.domain_id,
            context.session_id,
            self.node_id,
            self.node_id,
            EntityKind.NODE,
            self.enclave,
            self.namespace,
            self.name,
        )
        self._token = context.session.liveliness().declare_token(node.token())

    def resolve(self, topic: str) -> str:
        """The fully qualified name of ``topic`` in this node's namespace."""
        return qualified_name(topic, self.namespace, self.name)

    def entity(self, kind: str, topic: str, type_name: str, qos: Qos) -> GraphEntity:
        ctx = self.context
        return GraphEntity(
            ctx.domain_id,
            ctx.session_id,
            self.node_id,
            ctx.next_id(),
            kind,
            self.enclave,
            self.namespace,
            self.name,
            self.resolve(topic),
            type_name,
            ctx.types.type_hash(type_name),
            qos,
        )

    def publisher(self, topic: str, type_name: str, qos: Qos = DEFAULT_ENDPOINT_QOS) -> Ros2Publisher:
        pub = Ros2Publisher(self, topic, type_name, qos)
        self._entities.append(pub)
        return pub

    def subscription(
        self,
        topic: str,
        type_name: str,
        callback: Callable[[Any, MessageInfo], None],
        qos: Qos = DEFAULT_ENDPOINT_QOS,
        **options: Any,
    ) -> Ros2Subscription:
        sub = Ros2Subscription(self, topic, type_name, callback, qos, **options)
        self._entities.append(sub)
        return sub

    def close(self) -> None:
        """Undeclare every publisher, subscription and the node's token."""
        for entity in self._entities:
            entity.close()
        self._entities.clear()
        self._token.undeclare()
