"""ROS 2 body trackers as trackers of the cell: rmw_zenoh samples → skeleton capsules → the very same door.

    ROS 2 session thread (Zenoh): a sample on ``<domain>/<topic>/<type>/<hash>``
        ──judge_sample (type, hash, attachment)──▶ SkeletonAdapter.convert: decode (hrc_devices.trackers.ros2_people)
        ──people_capsules (placement, uncertainty, per-person memory)──▶ an ``hrc.humans/1`` frame
        ──door(hrc/<cell>/tracker/<name>/humans, frame, received)──▶ GatewayNode.on_message → InputStore.on_humans
    any refusal ──count_rejection(tracker/<name>, reason, received): counted by reason, the topic faulted (δ = 0)

The frame's ``seq`` is the attachment's sequence number (per publisher, from 1) and its ``stamp_ns`` the message's
``header.stamp``, the capture time; ``received`` is read when the sample arrives, before the conversion, so the age
the loop sees (and the delay budget) includes the conversion. The door then judges the frame as any native one:
parse, plausibility (this tracker's limits: :meth:`hrc_contract.config.CellConfig.tracker_plausibility`), the
stream's order (a stamp in the future or backwards, a sequence number backwards), faults and their hold. People
the tracker marks SEARCHING or TERMINATE are left out of the frame: the gateway's tracks keep them as lost.

Refused before the door, with these reasons: what rmw_zenoh itself drops (``no_attachment``,
``attachment_malformed``, ``too_large``) and a publisher of another type or distro (``wrong_type``,
``wrong_type_hash``); what the decoders refuse (``not_cdr``, ``bad_stamp``, ``non_finite``, ``absurd_keypoint``,
``unknown_body_format`` … of :mod:`hrc_devices.trackers.ros2_people` and :mod:`hrc_devices.trackers.skeletons`); a
message in another frame than configured (``wrong_frame``); anything else that raises (``internal_error``, logged).

ROS4HRI bodies (format ``ros4hri_bodies``, :class:`Ros4hriAdapter`): three streams feed one tracker. The tracked list
(``hri_msgs/IdsList`` on the configured topic, e.g. ``/humans/bodies/tracked``) makes the frames: its sequence number,
and as stamp the oldest capture stamp of what the frame uses. Each body's ``sensor_msgs/JointState`` on
``<the list's namespace>/<id>/joint_states`` and its ``body_<id>`` frame on the TF topic (``tf2_msgs/TFMessage``, in
the configured ``frame_id``) are checked when they arrive and kept (:mod:`hrc_devices.trackers.ros4hri_body`). A
listed body without both, or with either older than ``max_body_age_s`` at the list's stamp (or older than the last
frame's stamp), is left out of the frame: lost, not gone. A refused joint state or TF message faults the tracker as a
refused frame does. Further reasons: ``wrong_topic``, ``joint_count_mismatch``, ``unknown_joint``, ``duplicate_joint``,
``joint_out_of_limits``, ``bad_quaternion``, ``bad_body_id``.

Cost: the conversion runs on the ROS 2 session's receiving thread, never on the safety loop's (which it shares the
interpreter lock with); measured per frame in docs/ros2.md ("ROS 2 trackers").
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import zenoh

from hrc_contract import keys
from hrc_contract.config import CellConfig, ConfigError, Pose, Ros2Config, Ros2TrackerInput
from hrc_contract.messages import MAX_PAYLOAD_BYTES, MessageError
from hrc_devices.robots.model import pose_to_rotation_translation
from hrc_devices.ros2.rmw_zenoh import (
    Attachment,
    AttachmentError,
    Distro,
    Qos,
    Ros2Node,
    TopicType,
    decode_attachment,
    endpoint_token,
    fully_qualified_name,
    topic_type,
    typestore,
)
from hrc_devices.trackers import ros2_people, ros4hri_body
from hrc_devices.trackers.registry import FORMATS
from hrc_devices.trackers.skeletons import BodyCapsules, PersonMemory, PersonUnplacedError
from hrc_runtime.clocks import Clocks, read_clocks
from hrc_runtime.zenoh_session import SecurityError, SessionOptions

log = logging.getLogger("hrc-gateway.ros2-trackers")

JOINT_STATES_TOPIC = "joint_states"
"""A ROS4HRI body's joint states: ``<the tracked list's namespace>/<id>/joint_states``."""

SENSOR_DATA_QOS = Qos(reliability=2, durability=2, history=1, depth=5)
"""What the subscriptions announce: rclcpp's sensor-data profile (best effort, volatile, keep last 5)."""

NODE_ID = 1000
"""The trackers' node id in the ROS 2 session. rmw_zenoh numbers nodes and endpoints of a session from one counter;
the face's node counts from 0, so this node's ids start far above its few endpoints."""


def trackers_node_name(ros2: Ros2Config) -> str:
    """The trackers' node: ``<node_name>_trackers``, beside the face's node on the same session."""
    return f"{ros2.node_name}_trackers"


def tracker_wires(config: CellConfig) -> dict[str, tuple[str, TopicType]]:
    """Each ROS 2 tracker's (fully qualified topic, type on the wire): its configured topic (ROS4HRI: the tracked
    list; :func:`tracker_topics` has all of its topics).

    Raises:
        ConfigError: an unknown distro, a topic that is not a ROS name.
    """
    ros2 = config.ros2
    return {
        name: (
            fully_qualified_name(ros2.namespace, t.ros2.topic),
            topic_type(ros2.distro, FORMATS[t.ros2.format].msgtype),
        )
        for name, t in sorted(config.trackers.items())
        if t.ros2 is not None
    }


class TrackerTopic(NamedTuple):
    """A topic a ROS 2 tracker reads: its fully qualified name (``*``: any one token, a body id), its type on the
    wire, and whether the subscription is announced by a liveliness token (not for a name with ``*``)."""

    fq_name: str
    wire: TopicType
    announced: bool = True


def ros4hri_topics(ros2: Ros2Config, source: Ros2TrackerInput) -> tuple[TrackerTopic, TrackerTopic, TrackerTopic]:
    """A ROS4HRI tracker's topics: the tracked list, every body's joint states, the TF topic.

    Raises:
        ConfigError: an unknown distro, a topic that is not a ROS name.
    """
    tracked = fully_qualified_name(ros2.namespace, source.topic)
    bodies = tracked.rpartition("/")[0]
    return (
        TrackerTopic(tracked, topic_type(ros2.distro, ros2_people.IDS_LIST)),
        TrackerTopic(f"{bodies}/*/{JOINT_STATES_TOPIC}", topic_type(ros2.distro, ros4hri_body.JOINT_STATE), False),
        TrackerTopic(
            fully_qualified_name(ros2.namespace, source.tf_topic), topic_type(ros2.distro, ros4hri_body.TF_MESSAGE)
        ),
    )


def tracker_topics(config: CellConfig) -> dict[str, tuple[TrackerTopic, ...]]:
    """Every topic each ROS 2 tracker reads (what its subscriptions listen to and its publisher must be let put).

    Raises:
        ConfigError: an unknown distro, a topic that is not a ROS name.
    """
    out: dict[str, tuple[TrackerTopic, ...]] = {}
    for name, tracker in sorted(config.trackers.items()):
        if tracker.ros2 is None:
            continue
        if FORMATS[tracker.ros2.format].decode is None:  # several streams: ROS4HRI's
            out[name] = ros4hri_topics(config.ros2, tracker.ros2)
        else:
            fq_name, wire = tracker_wires(config)[name]
            out[name] = (TrackerTopic(fq_name, wire),)
    return out


Door = Callable[[str, bytes, Clocks], None]
"""Where a converted frame goes: (the tracker's cell key, ``hrc.humans/1`` payload, arrival clocks)."""
Rejection = Callable[[str, str, Clocks], None]
"""Where a refusal goes: (``tracker/<name>``, reason, arrival clocks): counted and faulted."""


class Ros2TrackerError(MessageError):
    """A sample refused before the door; ``reason`` is a short key for counting."""


# ---------------------------------------------------------------------------------------------------- the wire


def judge_sample(key: str, size: int, attachment: bytes | None, wire: TopicType) -> Attachment:
    """What rmw_zenoh checks before it hands a sample on (and a wrong type or hash, which it would not match).

    Raises:
        Ros2TrackerError: ``too_large``, ``wrong_type``, ``wrong_type_hash``, ``no_attachment``,
            ``attachment_malformed``.
    """
    head, _, type_hash = key.rpartition("/")
    dds_name = head.rpartition("/")[2]
    if size > MAX_PAYLOAD_BYTES:
        raise Ros2TrackerError("too_large", f"{size} bytes, at most {MAX_PAYLOAD_BYTES} allowed")
    if dds_name != wire.dds_name:
        raise Ros2TrackerError("wrong_type", f"type {dds_name[:80]!r} on the topic; expected {wire.dds_name}")
    if type_hash != wire.type_hash:
        raise Ros2TrackerError("wrong_type_hash", f"type hash {type_hash[:80]!r}; expected {wire.type_hash}")
    if attachment is None:
        raise Ros2TrackerError("no_attachment", "a sample without rmw_zenoh's attachment (rmw_zenoh drops it)")
    try:
        return decode_attachment(attachment)
    except AttachmentError as exc:
        raise Ros2TrackerError("attachment_malformed", str(exc)) from None


# ------------------------------------------------------------------------------------------- conversion (pure)


def placement_of(pose: Pose) -> ros2_people.Placement:
    """The sensor frame's pose in the world (xyz [m], roll-pitch-yaw [rad] as a robot's base pose) as a placement."""
    return ros2_people.Placement(*pose_to_rotation_translation(pose))


def humans_payload(tracker: str, seq: int, stamp_ns: int, people: tuple[tuple[str, BodyCapsules], ...]) -> bytes:
    """The ``hrc.humans/1`` frame of the people's capsules, as JSON bytes for the door (which validates it).

    Raises:
        Ros2TrackerError: ``non_finite`` (a coordinate the JSON cannot carry; never from a checked skeleton).
    """
    humans = []
    for person_id, body in people:
        a, b, r = body.a_m.tolist(), body.b_m.tolist(), body.radius_m.tolist()
        capsules = [{"name": n, "a": a[k], "b": b[k], "radius": r[k]} for k, n in enumerate(body.names)]
        humans.append({"id": person_id, "capsules": capsules})
    doc = {"schema": "hrc.humans/1", "tracker": tracker, "seq": seq, "stamp_ns": stamp_ns, "humans": humans}
    try:
        return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode()
    except ValueError as exc:
        raise Ros2TrackerError("non_finite", str(exc)) from None


@dataclass
class SkeletonAdapter:
    """One ROS 2 tracker's samples → its ``hrc.humans/1`` frames; keeps each person's memory between frames.

    Not thread-safe: one sample at a time (:class:`TrackerSubscription` holds a lock around :meth:`convert`).

    Args:
        tracker: the tracker's name in the cell.
        source: its ROS 2 input (format, frame, placement, uncertainty).
        distro: whose definitions decode the bytes.
    """

    tracker: str
    source: Ros2TrackerInput
    distro: Distro
    placement: ros2_people.Placement = field(init=False)
    memories: dict[str, PersonMemory] = field(default_factory=dict, init=False)

    def __post_init__(self) -> None:
        self.placement = placement_of(self.source.sensor_pose_world)
        self._store = typestore(self.distro)
        decode = FORMATS[self.source.format].decode
        if decode is None:
            raise ConfigError(f"tracker {self.tracker!r}: format {self.source.format!r} is not one of one stream")
        self._decode = decode

    def convert(self, payload: bytes, attachment: Attachment) -> bytes:
        """One sample's frame: seq from the attachment, stamp from the header (the capture time).

        An array of markers without any marker (K4ABT, nobody in view) has no header: it is stamped with the
        attachment's source timestamp (when it was published, after its capture).

        Raises:
            MessageError: see the module docstring (the memories are kept as they were).
        """
        frame = self._decode(payload, self._store)
        empty = not frame.detections and not frame.searching and not frame.frame_id
        if self.source.frame_id is not None and frame.frame_id != self.source.frame_id and not empty:
            raise Ros2TrackerError("wrong_frame", f"frame {frame.frame_id[:80]!r}; expected {self.source.frame_id!r}")
        stamp_ns = attachment.source_timestamp_ns if empty and frame.stamp_ns == 0 else frame.stamp_ns
        people, memories = ros2_people.people_capsules(
            frame, self.memories, self.placement, uncertainty_m=self.source.uncertainty_m
        )
        out = humans_payload(self.tracker, attachment.sequence_number, stamp_ns, people)
        self.memories = memories
        return out


def key_topic(key: str) -> str:
    """The fully qualified topic of an rmw_zenoh data key ``<domain>/<topic…>/<type>/<hash>``."""
    head = key.rsplit("/", 2)[0]
    return "/" + head.partition("/")[2]


@dataclass
class Ros4hriAdapter:
    """A ROS4HRI tracker's three streams → its ``hrc.humans/1`` frames (one per tracked list).

    Not thread-safe: one sample at a time (:class:`TrackerSubscription` holds a lock around :meth:`on_sample`).

    Args:
        tracker: the tracker's name in the cell.
        source: its ROS 2 input (tracked list topic, TF topic, parent frame, placement, height, age limit).
        ros2: the cell's ROS 2 section (namespace, distro).
    """

    tracker: str
    source: Ros2TrackerInput
    ros2: Ros2Config
    placement: ros2_people.Placement = field(init=False)
    memories: dict[str, PersonMemory] = field(default_factory=dict, init=False)
    joints: dict[str, ros4hri_body.BodyJoints] = field(default_factory=dict, init=False)
    poses: dict[str, ros4hri_body.BodyPose] = field(default_factory=dict, init=False)
    last_stamp_ns: int = field(default=-1, init=False)

    def __post_init__(self) -> None:
        self.placement = placement_of(self.source.sensor_pose_world)
        self._store = typestore(self.ros2.distro)
        height_m = self.source.body_height_m or ros4hri_body.DEFAULT_HEIGHT_M
        self.human = ros4hri_body.build_human_model(height_m)
        self.tracked, self.joint_states, self.tf = ros4hri_topics(self.ros2, self.source)
        self._bodies_prefix = self.joint_states.fq_name.split("*")[0]
        self._max_age_ns = round(self.source.max_body_age_s * 1e9)

    def on_sample(self, key: str, payload: bytes, attachment: bytes | None) -> bytes | None:
        """One sample of any of the three topics: the frame to hand on (a tracked list), or None (kept).

        Raises:
            MessageError: ``wrong_topic`` and see the module docstring (nothing kept of a refused sample).
        """
        topic = key_topic(key)
        if topic == self.tracked.fq_name:
            return self._on_tracked(payload, judge_sample(key, len(payload), attachment, self.tracked.wire))
        if topic == self.tf.fq_name:
            judge_sample(key, len(payload), attachment, self.tf.wire)
            self._on_tf(payload)
            return None
        body_id, _, rest = topic.removeprefix(self._bodies_prefix).partition("/")
        if topic.startswith(self._bodies_prefix) and body_id and rest == JOINT_STATES_TOPIC:
            judge_sample(key, len(payload), attachment, self.joint_states.wire)
            self._keep(self.joints, body_id, ros4hri_body.decode_joint_state(payload, self._store, self.human, body_id))
            return None
        raise Ros2TrackerError("wrong_topic", f"topic {topic[:80]!r} is none of this tracker's")

    def _on_tf(self, payload: bytes) -> None:
        poses = ros4hri_body.decode_body_poses(payload, self._store, self.source.frame_id)
        for pose in poses:
            self._keep(self.poses, pose.body_id, pose)

    def _keep(self, table: dict[str, Any], body_id: str, value: Any) -> None:
        """The newest sample wins (one publisher's samples arrive in order; a forged future stamp is replaced by the
        next genuine one, and while it stands the body is lost: it is fresh at no list's stamp)."""
        if body_id not in table and len(table) >= 2 * ros2_people.MAX_PEOPLE:
            raise ros2_people.Ros2MessageError("too_many_people", f"more than {2 * ros2_people.MAX_PEOPLE} bodies kept")
        table[body_id] = value

    def _fresh(self, stamp_ns: int, list_stamp_ns: int) -> bool:
        """Within the age limit of the list's stamp, either side, and newer than the last frame: the door takes
        only frames stamped after the last one, so data a frame used already cannot stamp the next."""
        return abs(list_stamp_ns - stamp_ns) <= self._max_age_ns and stamp_ns > self.last_stamp_ns

    def _on_tracked(self, payload: bytes, attachment: Attachment) -> bytes:
        list_stamp_ns, ids = ros2_people.decode_ids_list(payload, self._store)
        for body_id in ids:
            ros4hri_body.check_body_id(body_id)
        people: list[tuple[str, BodyCapsules]] = []
        memories: dict[str, PersonMemory] = {}
        stamp_ns = list_stamp_ns
        for body_id in dict.fromkeys(ids):
            if body_id in self.memories:
                memories[body_id] = self.memories[body_id]  # a lost body keeps its memory while listed
            joints, pose = self.joints.get(body_id), self.poses.get(body_id)
            if joints is None or pose is None:
                continue
            if not (self._fresh(joints.stamp_ns, list_stamp_ns) and self._fresh(pose.stamp_ns, list_stamp_ns)):
                continue
            body_stamp_ns = min(joints.stamp_ns, pose.stamp_ns)
            try:
                body, memories[body_id] = ros4hri_body.body_capsules_world(
                    self.human, joints, pose, self.placement,
                    stamp_ns=body_stamp_ns, uncertainty_m=self.source.uncertainty_m, memory=self.memories.get(body_id),
                )  # fmt: skip
            except PersonUnplacedError:  # left out of the frame: lost at the gateway, its memory kept
                continue
            people.append((body_id, body))
            stamp_ns = min(stamp_ns, body_stamp_ns)
        out = humans_payload(self.tracker, attachment.sequence_number, stamp_ns, tuple(people))
        self.memories = memories
        self.last_stamp_ns = max(self.last_stamp_ns, stamp_ns)
        self._forget(set(ids), list_stamp_ns)
        return out

    def _forget(self, listed: set[str], list_stamp_ns: int) -> None:
        """Drop what is kept of bodies neither listed nor fresh (a body's data may come before its listing)."""
        for table in (self.joints, self.poses):
            for body_id in [
                b for b, v in table.items() if b not in listed and not self._fresh(v.stamp_ns, list_stamp_ns)
            ]:
                del table[body_id]


# ----------------------------------------------------------------------------------------------- subscriptions


class SampleCounts(NamedTuple):
    """What one subscription did: frames handed to the door, samples refused before it (by reason), samples kept
    without a frame (a ROS4HRI body's joint states and TF)."""

    converted: int
    refused: dict[str, int]
    kept: int = 0


@dataclass
class TrackerSubscription:
    """One ROS 2 tracker's samples, judged and converted on the receiving thread, then handed to the door.

    Args:
        adapter: the tracker's conversion.
        wire: the type on the wire (name, hash) its samples must carry.
        key: the tracker's cell key (``hrc/<cell>/tracker/<name>/humans``): what the door sees.
        door: the gateway's input door for that key.
        reject: counts a refusal and faults ``tracker/<name>``.
        clock: reads both clocks at arrival (``read_clocks``; a fake in tests).
    """

    adapter: SkeletonAdapter | Ros4hriAdapter
    wire: TopicType
    key: str
    door: Door
    reject: Rejection
    clock: Callable[[], Clocks] = read_clocks
    converted: int = 0
    refused: dict[str, int] = field(default_factory=dict)
    kept: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def topic(self) -> str:
        """The counters' topic: ``tracker/<name>``."""
        return f"tracker/{self.adapter.tracker}"

    def on_sample(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        """Judge, convert and hand on one sample (what the Zenoh callback calls); never raises."""
        received = self.clock()
        try:
            with self._lock:  # one at a time: the people's memories; the door orders the frames itself
                frame = self._convert(key, payload, attachment)
                if frame is None:
                    self.kept += 1
                else:
                    self.converted += 1
        except MessageError as exc:
            self._refuse(exc.reason, received)
            return
        except Exception:  # a hostile sample must never take the subscriber down: count it, fail closed
            log.exception("error while converting a ROS 2 sample of tracker %s on %s", self.adapter.tracker, key)
            self._refuse("internal_error", received)
            return
        if frame is not None:
            self.door(self.key, frame, received)

    def _convert(self, key: str, payload: bytes, attachment: bytes | None) -> bytes | None:
        if isinstance(self.adapter, Ros4hriAdapter):
            return self.adapter.on_sample(key, payload, attachment)
        return self.adapter.convert(payload, judge_sample(key, len(payload), attachment, self.wire))

    def counts(self) -> SampleCounts:
        with self._lock:
            return SampleCounts(self.converted, dict(self.refused), self.kept)

    def _refuse(self, reason: str, received: Clocks) -> None:
        with self._lock:
            self.refused[reason] = self.refused.get(reason, 0) + 1
        self.reject(self.topic, reason, received)


def tracker_subscriptions(config: CellConfig, door: Door, reject: Rejection) -> dict[str, TrackerSubscription]:
    """One subscription per tracker of the cell with a ROS 2 input (none without).

    Raises:
        ConfigError: an unknown distro or message type.
    """
    distro: Distro = config.ros2.distro
    subscriptions = {}
    for name, tracker in sorted(config.trackers.items()):
        if tracker.ros2 is None:
            continue
        wire = topic_type(distro, FORMATS[tracker.ros2.format].msgtype)
        adapter: SkeletonAdapter | Ros4hriAdapter
        if FORMATS[tracker.ros2.format].decode is None:  # several streams: ROS4HRI's
            adapter = Ros4hriAdapter(name, tracker.ros2, config.ros2)
        else:
            adapter = SkeletonAdapter(name, tracker.ros2, distro)
        subscriptions[name] = TrackerSubscription(adapter, wire, keys.tracker_humans(config.cell, name), door, reject)
    return subscriptions


def check_ros2_inputs(config: CellConfig, options: SessionOptions | None, plain_tcp_allowed: bool) -> None:
    """Refuse to read trackers from a ROS 2 session that anyone on the host could write to, unless allowed.

    The face's session alone reads nothing, and may use plain TCP on loopback without the flag; a tracker read from
    it is a safety input, so plain TCP needs ``--insecure-plain-tcp`` as the cell's own session does.

    Raises:
        SecurityError: a ROS 2 tracker on plain TCP without the flag.
    """
    readers = [name for name, tracker in config.trackers.items() if tracker.ros2 is not None]
    if readers and options is not None and options.tls is None and not plain_tcp_allowed:
        raise SecurityError(
            f"tracker(s) {', '.join(readers)} read from the ROS 2 session on plain TCP: any local process could "
            "move people; allowed: tls/ endpoints in [ros2], or --insecure-plain-tcp (development)"
        )


@dataclass
class Ros2Trackers:
    """The trackers' node on the ROS 2 session: per tracker a Zenoh subscriber and its ``MS`` liveliness token."""

    node: Ros2Node
    subscriptions: Mapping[str, TrackerSubscription]
    _handles: list[Any] = field(default_factory=list)

    def close(self) -> None:
        """Undeclare every subscriber and token, then the node (idempotent)."""
        for handle in self._handles:
            handle.undeclare()
        self._handles.clear()
        self.node.close()


def declare(node: Ros2Node, subscriptions: Mapping[str, TrackerSubscription], config: CellConfig) -> Ros2Trackers:
    """Each subscription on ``node``'s session: per topic of the tracker (:func:`tracker_topics`) listening on
    ``<domain>/<topic>/*/*`` (every type and hash, so that a wrong one is seen and counted), announced by an ``MS``
    token as an rmw_zenoh subscription (not a ROS4HRI body's joint states: one listener for every body)."""
    trackers = Ros2Trackers(node, subscriptions)
    topics = tracker_topics(config)
    entity_id = node.node_id
    for name, subscription in sorted(subscriptions.items()):

        def on_sample(sample: zenoh.Sample, subscription: TrackerSubscription = subscription) -> None:
            attachment = sample.attachment
            subscription.on_sample(
                str(sample.key_expr), sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes()
            )

        for topic in topics.get(name, ()):
            listen_key = f"{node.domain_id}/{topic.fq_name.strip('/')}/*/*"
            trackers._handles.append(node.session.declare_subscriber(listen_key, on_sample))
            if topic.announced:
                entity_id += 1
                token = endpoint_token(
                    "MS", node.domain_id, node.session_id, node.node_id, entity_id, node.namespace, node.name,
                    topic.fq_name, topic.wire, SENSOR_DATA_QOS,
                )  # fmt: skip
                trackers._handles.append(node.session.liveliness().declare_token(token))
            log.info("ROS 2 tracker %s: %s (%s) on %s", name, topic.fq_name, topic.wire.msgtype, listen_key)
    return trackers


@contextmanager
def running_ros2_trackers(
    config: CellConfig, session: zenoh.Session | None, door: Door, reject: Rejection
) -> Iterator[Ros2Trackers | None]:
    """The cell's ROS 2 trackers subscribed on ``session`` (the ROS 2 face's) while the block runs; None without.

    Raises:
        ConfigError: ROS 2 trackers without a ROS 2 session, or an unknown distro.
    """
    subscriptions = tracker_subscriptions(config, door, reject)
    if not subscriptions:
        yield None
        return
    if session is None:
        raise ConfigError("the cell has ROS 2 trackers but no ROS 2 session; allowed: [ros2] enabled = true")
    ros2 = config.ros2
    node = Ros2Node(session, trackers_node_name(ros2), ros2.namespace, ros2.domain_id, ros2.distro, NODE_ID)
    trackers = declare(node, subscriptions, config)
    try:
        yield trackers
    finally:
        trackers.close()
