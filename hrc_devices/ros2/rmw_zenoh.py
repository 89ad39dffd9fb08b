"""ROS 2's wire format over Zenoh (rmw_zenoh), in pure Python: key expressions, attachments, liveliness tokens.

What a ROS 2 node using ``rmw_zenoh_cpp`` puts on Zenoh, as its design document (ros2/rmw_zenoh,
``docs/design.md``) states it:

- a topic's data on ``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>``, e.g.
  ``0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_df66…``; the payload is CDR with its 4-byte
  encapsulation header. Humble has no type hashes: its key ends in the literal ``TypeHashNotSupported``;
  Jazzy and later in ``RIHS01_<sha256>`` (REP-2016), which :mod:`rosbags` computes from the message definitions;
- with every sample an attachment of 33 bytes: the sequence number (int64, little-endian), the source timestamp
  (int64 ns since the epoch, little-endian), the GID's length (one byte, 16) and the publisher's GID (16 bytes).
  A subscription drops a sample without one;
- one liveliness token per node and per endpoint, which ``ros2 node list`` / ``ros2 topic list`` read:
  ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<node_id>/NN/<mangled_enclave>/<mangled_namespace>/<node_name>``
  and, for a publisher (``MP``) or a subscription (``MS``),
  ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/MP/<mangled_enclave>/<mangled_namespace>/<node_name>/
  <mangled_qualified_name>/<type_name>/<type_hash>/<qos>``; a mangled name has each ``/`` replaced by ``%``.

The pure functions build and check those; :class:`Ros2Node` is the thin I/O class over a ``zenoh.Session``.
The GID is 16 bytes of BLAKE2b over the endpoint's liveliness key (rmw_zenoh hashes the same key with XXH3-128;
the design document leaves the GID opaque, and ROS tools only compare it).
"""

from __future__ import annotations

import functools
import logging
import re
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from hashlib import blake2b
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, NamedTuple, get_args

import numpy as np
import zenoh
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from hrc_contract.config import ConfigError, Ros2Distro
from hrc_contract.errors import HrcError

log = logging.getLogger("hrc.rmw_zenoh")

Distro = Ros2Distro
DISTROS: tuple[Distro, ...] = get_args(Distro)
_STORES: dict[Distro, Stores] = {
    "humble": Stores.ROS2_HUMBLE,
    "jazzy": Stores.ROS2_JAZZY,
    "kilted": Stores.ROS2_KILTED,
}

VENDORED_MSG_DIR = Path(__file__).parent / "ros2_msgs"
"""Definitions the standard stores lack (``<pkg>/msg/<Type>.msg``: zed_msgs, hri_msgs; sources in its README)."""

ADMIN_SPACE = "@ros2_lv"
"""The hermetic prefix of rmw_zenoh's liveliness tokens (``*`` and ``**`` never match it)."""
HUMBLE_TYPE_HASH = "TypeHashNotSupported"
GID_SIZE = 16
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
MAX_PAYLOAD_BYTES = 1_000_000
"""A sample larger than this is dropped before it is decoded (the contract's limit for native messages)."""

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAME = re.compile(_TOKEN)
_PATH = re.compile(rf"/?(?:{_TOKEN})(?:/{_TOKEN})*")

DropReason = Literal[
    "too_large", "no_attachment", "attachment_malformed", "wrong_type", "wrong_type_hash", "callback_error"
]
"""Why a :class:`Ros2Subscription` dropped a sample (counted in :attr:`Ros2Subscription.dropped`)."""
DROP_REASONS: tuple[DropReason, ...] = get_args(DropReason)


class AttachmentError(HrcError):
    """An attachment rmw_zenoh would drop, or one that lies (negative sequence or stamp). One line."""


# --------------------------------------------------------------------------------------------------------- types


@functools.cache
def typestore(distro: Distro) -> Typestore:
    """The message definitions of ``distro`` (rosbags' store with the vendored ones registered), shared and
    read-only.

    Raises:
        ConfigError: an unknown distro; the message lists the allowed ones.
    """
    if distro not in _STORES:
        raise ConfigError(f"unknown ROS 2 distro {distro!r}; allowed: {', '.join(DISTROS)}")
    store = get_typestore(_STORES[distro])
    types: dict[str, Any] = {}
    for path in sorted(VENDORED_MSG_DIR.glob("*/msg/*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{path.parts[-3]}/msg/{path.stem}"))
    store.register(types)
    return store


class TopicType(NamedTuple):
    """A message type as rmw_zenoh names it on the wire.

    Attributes:
        msgtype: the ROS name, ``std_msgs/msg/Float64``.
        dds_name: the DDS name in keys and tokens, ``std_msgs::msg::dds_::Float64_``.
        type_hash: ``TypeHashNotSupported`` (Humble) or ``RIHS01_<sha256 hex>`` (Jazzy and later).
    """

    msgtype: str
    dds_name: str
    type_hash: str


def dds_type_name(msgtype: str) -> str:
    """``std_msgs/msg/Float64`` → ``std_msgs::msg::dds_::Float64_`` (the name CDR type support declares).

    Raises:
        ConfigError: not ``<package>/msg/<Type>``.
    """
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg" or not all(_NAME.fullmatch(p) for p in parts):
        raise ConfigError(f"message type {msgtype!r} is not <package>/msg/<Type>")
    return f"{parts[0]}::msg::dds_::{parts[2]}_"


@functools.cache
def topic_type(distro: Distro, msgtype: str) -> TopicType:
    """The wire names of ``msgtype`` in ``distro``; the hash is rosbags' RIHS01 of that distro's definition.

    Raises:
        ConfigError: an unknown distro, or a type its store does not have.
    """
    store = typestore(distro)
    if msgtype not in store.fielddefs:
        raise ConfigError(f"message type {msgtype!r} is not in the {distro} definitions")
    type_hash = HUMBLE_TYPE_HASH if distro == "humble" else store.hash_rihs01(msgtype)
    return TopicType(msgtype, dds_type_name(msgtype), type_hash)


# ---------------------------------------------------------------------------------------------------------- names


def fully_qualified_name(namespace: str, name: str) -> str:
    """The absolute ROS name of ``name`` in ``namespace``: ``("/cell", "speed")`` → ``/cell/speed``.

    A ``name`` starting with ``/`` is absolute already. Tokens are ``[A-Za-z_][A-Za-z0-9_]*``.

    Raises:
        ConfigError: a namespace or name that is not made of such tokens.
    """
    if namespace not in ("", "/") and not _PATH.fullmatch(namespace):
        raise ConfigError(f"ROS namespace {namespace!r} is not /token/token… (tokens [A-Za-z_][A-Za-z0-9_]*)")
    if not _PATH.fullmatch(name):
        raise ConfigError(f"ROS name {name!r} is not token/token… (tokens [A-Za-z_][A-Za-z0-9_]*)")
    if name.startswith("/"):
        return name
    return f"/{namespace.strip('/')}/{name}" if namespace.strip("/") else f"/{name}"


def normalized_namespace(namespace: str) -> str:
    """``""`` and ``/`` → ``/``; ``cell`` → ``/cell``: the namespace as rcl hands it to the RMW.

    Raises:
        ConfigError: not ``/token/token…``.
    """
    if namespace in ("", "/"):
        return "/"
    if not _PATH.fullmatch(namespace):
        raise ConfigError(f"ROS namespace {namespace!r} is not /token/token… (tokens [A-Za-z_][A-Za-z0-9_]*)")
    return "/" + namespace.strip("/")


def mangle(name: str) -> str:
    """A name inside a liveliness token: each ``/`` replaced by ``%`` (``/`` → ``%``, ``/a/b`` → ``%a%b``)."""
    return name.replace("/", "%")


def topic_key(domain_id: int, fq_name: str, wire: TopicType) -> str:
    """``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>`` (the name without its leading ``/``)."""
    return f"{domain_id}/{fq_name.strip('/')}/{wire.dds_name}/{wire.type_hash}"


class Qos(NamedTuple):
    """The QoS an endpoint announces. Defaults: what the gateway's publishers are (reliable, volatile, keep last).

    Values are rmw's enums: reliability 1 RELIABLE, 2 BEST_EFFORT; durability 1 TRANSIENT_LOCAL, 2 VOLATILE;
    history 1 KEEP_LAST, 2 KEEP_ALL.
    """

    reliability: int = 1
    durability: int = 2
    history: int = 1
    depth: int = 10


DEFAULT_QOS = Qos()


def qos_key(qos: Qos) -> str:
    """rmw_zenoh's compact QoS chunk, every policy written out (``1:2:1,10:,:,:,,``); deadline, lifespan and
    liveliness left at their defaults (empty), as ``qos_to_keyexpr`` writes them."""
    return f"{qos.reliability}:{qos.durability}:{qos.history},{qos.depth}:,:,:,,"


def node_token(
    domain_id: int, session_id: str, node_id: int, namespace: str, node_name: str, enclave: str = "/"
) -> str:
    """The liveliness key of a node (entity kind ``NN``)."""
    ns = mangle(normalized_namespace(namespace))
    return f"{ADMIN_SPACE}/{domain_id}/{session_id}/{node_id}/{node_id}/NN/{mangle(enclave)}/{ns}/{node_name}"


def endpoint_token(
    kind: Literal["MP", "MS"],
    domain_id: int,
    session_id: str,
    node_id: int,
    entity_id: int,
    namespace: str,
    node_name: str,
    fq_name: str,
    wire: TopicType,
    qos: Qos = DEFAULT_QOS,
    enclave: str = "/",
) -> str:
    """The liveliness key of a publisher (``MP``) or a subscription (``MS``) of a node."""
    ns = mangle(normalized_namespace(namespace))
    head = f"{ADMIN_SPACE}/{domain_id}/{session_id}/{node_id}/{entity_id}/{kind}/{mangle(enclave)}/{ns}/{node_name}"
    return f"{head}/{mangle(fq_name)}/{wire.dds_name}/{wire.type_hash}/{qos_key(qos)}"


def gid_of(token: str) -> bytes:
    """An endpoint's 16-byte GID: BLAKE2b-128 of its liveliness key (unique per endpoint, stable across restarts)."""
    return blake2b(token.encode(), digest_size=GID_SIZE).digest()


# ---------------------------------------------------------------------------------------------------- attachments


class Attachment(NamedTuple):
    """What rmw_zenoh attaches to every sample.

    Attributes:
        sequence_number: the publisher's count of samples, from 1.
        source_timestamp_ns: when it was published [ns since the epoch].
        source_gid: the publisher's GID (16 bytes).
    """

    sequence_number: int
    source_timestamp_ns: int
    source_gid: bytes


_HEAD = struct.Struct("<qqB")


def encode_attachment(attachment: Attachment) -> bytes:
    """The 33 bytes: int64 LE sequence, int64 LE timestamp, GID length 16, GID.

    Raises:
        AttachmentError: a GID that is not 16 bytes.
    """
    if len(attachment.source_gid) != GID_SIZE:
        raise AttachmentError(f"source GID of {len(attachment.source_gid)} bytes; allowed: {GID_SIZE}")
    return _HEAD.pack(attachment.sequence_number, attachment.source_timestamp_ns, GID_SIZE) + attachment.source_gid


def decode_attachment(data: bytes) -> Attachment:
    """Parse an attachment as rmw_zenoh does, and stricter: exactly 33 bytes, GID length 16, sequence ≥ 0, stamp ≥ 0.

    Raises:
        AttachmentError: anything else (the message says what was found).
    """
    if len(data) != ATTACHMENT_SIZE:
        raise AttachmentError(f"attachment of {len(data)} bytes; allowed: {ATTACHMENT_SIZE}")
    sequence, stamp_ns, gid_length = _HEAD.unpack_from(data)
    if gid_length != GID_SIZE:
        raise AttachmentError(f"GID length {gid_length}; allowed: {GID_SIZE}")
    if sequence < 0 or stamp_ns < 0:
        raise AttachmentError(f"sequence {sequence}, source timestamp {stamp_ns} ns; allowed: ≥ 0")
    return Attachment(sequence, stamp_ns, bytes(data[_HEAD.size :]))


# ------------------------------------------------------------------------------------------------------- messages


def new_message(distro: Distro, msgtype: str, **fields: Any) -> Any:
    """A message of ``distro``'s ``msgtype``: the given fields, every other field at its zero value (recursively).

    The definitions differ between distros (fields added); this builds what the distro's CDR expects. The zero
    values are built once per type and shared between messages: treat messages as read-only.

    Raises:
        ConfigError: an unknown distro or type; TypeError: a field the type does not have.
    """
    defaults = _defaults(distro, msgtype)
    if not fields.keys() <= defaults.keys():
        unknown = ", ".join(sorted(set(fields) - set(defaults)))
        raise TypeError(f"{msgtype} has no field {unknown}; it has {', '.join(defaults)}")
    return typestore(distro).types[msgtype](**(defaults | fields))


@functools.cache
def _defaults(distro: Distro, msgtype: str) -> dict[str, Any]:
    store = typestore(distro)
    if msgtype not in store.fielddefs:
        raise ConfigError(f"message type {msgtype!r} is not in the {distro} definitions")
    return {name: _zero(distro, desc) for name, desc in store.fielddefs[msgtype][1]}


_NUMPY_TYPES = {"byte": "uint8", "char": "uint8", "bool": "bool"}


def _zero(distro: Distro, desc: Any) -> Any:
    nodetype, detail = desc
    if nodetype == Nodetype.BASE:
        base = detail[0]
        return "" if base == "string" else False if base == "bool" else 0.0 if base.startswith("float") else 0
    if nodetype == Nodetype.NAME:
        return typestore(distro).types[detail](**_defaults(distro, detail))
    element, length = detail
    count = length if nodetype == Nodetype.ARRAY else 0
    if element[0] == Nodetype.BASE and element[1][0] != "string":
        return np.zeros(count, dtype=_NUMPY_TYPES.get(element[1][0], element[1][0]))
    return [_zero(distro, element) for _ in range(count)]


def serialize(distro: Distro, message: Any) -> bytes:
    """CDR (little-endian, with its encapsulation header) of a message of ``distro``'s store."""
    return bytes(typestore(distro).serialize_cdr(message, message.__msgtype__))


def deserialize(distro: Distro, payload: bytes, msgtype: str) -> Any:
    """The message of ``msgtype`` in CDR ``payload`` (rosbags; raises what rosbags raises on malformed data)."""
    return typestore(distro).deserialize_cdr(payload, msgtype)


# ------------------------------------------------------------------------------------------------------------ I/O


class Ros2Publisher:
    """A ROS 2 publisher of a :class:`Ros2Node`: a declared Zenoh publisher, its ``MP`` token and its sequence.

    :meth:`put` is called from one thread (the sequence is not locked).
    """

    def __init__(self, node: Ros2Node, entity_id: int, topic: str, msgtype: str, qos: Qos) -> None:
        self.fq_name = fully_qualified_name(node.namespace, topic)
        self.wire = topic_type(node.distro, msgtype)
        self.key = topic_key(node.domain_id, self.fq_name, self.wire)
        self.token_key = endpoint_token(
            "MP", node.domain_id, node.session_id, node.node_id, entity_id, node.namespace, node.name,
            self.fq_name, self.wire, qos,
        )  # fmt: skip
        self.gid = gid_of(self.token_key)
        self.sequence_number = 0
        self._distro = node.distro
        self._publisher: Any = node.session.declare_publisher(self.key, congestion_control=zenoh.CongestionControl.DROP)
        self._token: Any = node.session.liveliness().declare_token(self.token_key)

    def put(self, payload: bytes, stamp_ns: int | None = None) -> None:
        """Publish CDR bytes with the next sequence number and ``stamp_ns`` (default now) in the attachment."""
        self.sequence_number += 1
        stamp = time.time_ns() if stamp_ns is None else stamp_ns
        attachment = encode_attachment(Attachment(self.sequence_number, stamp, self.gid))
        self._publisher.put(payload, attachment=attachment)

    def publish(self, message: Any, stamp_ns: int | None = None) -> None:
        """Serialise ``message`` (of this topic's type, from :func:`new_message`) and :meth:`put` it."""
        self.put(serialize(self._distro, message), stamp_ns)

    def close(self) -> None:
        self._token.undeclare()
        self._publisher.undeclare()


SampleCallback = Callable[[bytes, Attachment], None]


@dataclass
class Ros2Subscription:
    """A ROS 2 subscription of a :class:`Ros2Node`: hands each valid sample's (CDR payload, attachment) on.

    It listens on the topic for every type and hash (``<domain>/<topic>/*/*``), so that a publisher of another type
    or another distro's hash is seen and counted (``wrong_type``, ``wrong_type_hash``) rather than silently
    unmatched. Samples larger than ``max_payload_bytes``, without an attachment or with a malformed one are dropped
    and counted by reason (:data:`DROP_REASONS`); an exception of the callback is logged and counted
    (``callback_error``), never raised into Zenoh. The callback runs on Zenoh's thread: it should only validate
    and store.
    """

    key: str
    token_key: str
    wire: TopicType
    callback: SampleCallback
    max_payload_bytes: int = MAX_PAYLOAD_BYTES
    received: int = 0
    dropped: Counter[str] = field(default_factory=Counter)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _handles: list[Any] = field(default_factory=list)

    def on_sample(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        """Judge one sample (what the Zenoh callback calls; public so that tests can feed it)."""
        reason = self._judge(key, len(payload), attachment)
        if reason is None and attachment is not None:
            try:
                decoded = decode_attachment(attachment)
            except AttachmentError:
                reason = "attachment_malformed"
            else:
                try:
                    self.callback(payload, decoded)
                except Exception:  # a hostile sample must never take the subscriber down
                    log.exception("error while handling a ROS 2 sample on %s", key)
                    reason = "callback_error"
        with self._lock:
            if reason is None:
                self.received += 1
            else:
                self.dropped[reason] += 1

    def _judge(self, key: str, size: int, attachment: bytes | None) -> DropReason | None:
        head, _, type_hash = key.rpartition("/")
        dds_name = head.rpartition("/")[2]
        if size > self.max_payload_bytes:
            return "too_large"
        if dds_name != self.wire.dds_name:
            return "wrong_type"
        if type_hash != self.wire.type_hash:
            return "wrong_type_hash"
        if attachment is None:
            return "no_attachment"
        return None

    def counts(self) -> tuple[int, dict[str, int]]:
        """``(received, dropped by reason)`` now (a copy; safe from any thread)."""
        with self._lock:
            return self.received, dict(self.dropped)

    def close(self) -> None:
        for handle in self._handles:
            handle.undeclare()
        self._handles.clear()


class Ros2Node:
    """A ROS 2 node as rmw_zenoh shows it, over an open ``zenoh.Session``: its ``NN`` token, publishers and
    subscriptions with theirs. Close it (or use it as a context manager) before the session closes.

    Args:
        session: an open Zenoh session (the caller owns it).
        name: the node's name (``[A-Za-z_][A-Za-z0-9_]*``).
        namespace: its namespace (``""`` or ``/`` for none).
        domain_id: ``ROS_DOMAIN_ID`` [0, 232].
        distro: whose key form and definitions to use.
        node_id: the node's id within its session (rmw_zenoh counts nodes of a context from 0).

    Raises:
        ConfigError: a bad name, namespace, domain or distro.
    """

    def __init__(
        self,
        session: zenoh.Session,
        name: str,
        namespace: str = "",
        domain_id: int = 0,
        distro: Distro = "jazzy",
        node_id: int = 0,
    ) -> None:
        if not _NAME.fullmatch(name):
            raise ConfigError(f"ROS node name {name!r}; allowed: [A-Za-z_][A-Za-z0-9_]*")
        if not 0 <= domain_id <= 232:
            raise ConfigError(f"ROS domain id {domain_id}; allowed: 0..232")
        typestore(distro)
        self.session = session
        self.name = name
        self.namespace = normalized_namespace(namespace)
        self.domain_id = domain_id
        self.distro: Distro = distro
        self.node_id = node_id
        self.session_id = str(session.zid())
        self.token_key = node_token(domain_id, self.session_id, node_id, self.namespace, name)
        self._token: Any = session.liveliness().declare_token(self.token_key)
        self._next_entity_id = node_id + 1
        self.publishers: list[Ros2Publisher] = []
        self.subscriptions: list[Ros2Subscription] = []

    def _entity_id(self) -> int:
        entity_id = self._next_entity_id
        self._next_entity_id += 1
        return entity_id

    def create_publisher(self, topic: str, msgtype: str, qos: Qos = DEFAULT_QOS) -> Ros2Publisher:
        """A publisher of ``msgtype`` on ``topic`` (relative to the node's namespace unless absolute)."""
        publisher = Ros2Publisher(self, self._entity_id(), topic, msgtype, qos)
        self.publishers.append(publisher)
        return publisher

    def create_subscription(
        self,
        topic: str,
        msgtype: str,
        callback: SampleCallback,
        qos: Qos = DEFAULT_QOS,
        max_payload_bytes: int = MAX_PAYLOAD_BYTES,
    ) -> Ros2Subscription:
        """A subscription handing each valid sample's (payload, attachment) to ``callback`` (see the class)."""
        fq_name = fully_qualified_name(self.namespace, topic)
        wire = topic_type(self.distro, msgtype)
        token_key = endpoint_token(
            "MS", self.domain_id, self.session_id, self.node_id, self._entity_id(), self.namespace, self.name,
            fq_name, wire, qos,
        )  # fmt: skip
        listen_key = f"{self.domain_id}/{fq_name.strip('/')}/*/*"
        subscription = Ros2Subscription(listen_key, token_key, wire, callback, max_payload_bytes)

        def on_sample(sample: zenoh.Sample) -> None:
            attachment = sample.attachment
            subscription.on_sample(
                str(sample.key_expr), sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes()
            )

        subscription._handles.append(self.session.declare_subscriber(listen_key, on_sample))
        subscription._handles.append(self.session.liveliness().declare_token(token_key))
        self.subscriptions.append(subscription)
        return subscription

    def close(self) -> None:
        """Undeclare every endpoint and the node's token (idempotent)."""
        for publisher in self.publishers:
            publisher.close()
        for subscription in self.subscriptions:
            subscription.close()
        self.publishers.clear()
        self.subscriptions.clear()
        if self._token is not None:
            self._token.undeclare()
            self._token = None

    def __enter__(self) -> Ros2Node:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def liveliness_keys(session: zenoh.Session, domain_id: int, timeout_s: float = 2.0) -> list[str]:
    """Every rmw_zenoh liveliness token of ``domain_id`` alive now, as a ROS 2 context gets them at start-up."""
    replies = session.liveliness().get(f"{ADMIN_SPACE}/{domain_id}/**", timeout=timeout_s)
    return sorted(str(reply.ok.key_expr) for reply in replies if reply.ok is not None)


def parse_endpoint_token(token: str) -> Mapping[str, str]:
    """The parts of an endpoint token (``kind``, ``namespace``, ``node``, ``topic``, ``type``, ``hash``, ``qos``),
    names demangled; a node token has no topic parts.

    Raises:
        ValueError: not an rmw_zenoh liveliness key.
    """
    parts = token.split("/")
    if parts[0] != ADMIN_SPACE or len(parts) not in (9, 13):
        raise ValueError(f"{token!r} is not an rmw_zenoh liveliness key")
    fields = {"domain": parts[1], "session": parts[2], "node_id": parts[3], "entity_id": parts[4], "kind": parts[5]}
    fields |= {"enclave": parts[6].replace("%", "/"), "namespace": parts[7].replace("%", "/"), "node": parts[8]}
    if len(parts) == 13:
        fields |= {"topic": parts[9].replace("%", "/"), "type": parts[10], "hash": parts[11], "qos": parts[12]}
    return fields
