"""The gateway's ROS 2 face: what the status shows, published as ROS 2 messages over rmw_zenoh (docs/ros2.md).

    status thread ──offer(StatusJob, status document)──▶ [one-place slot] ──▶ face thread: ROS 2 messages ──▶
                                                                              Zenoh session of its own (CN ``ros2``)

Per robot ``<robot>``, under the configured namespace (``[ros2]`` of the cell file):

- ``<robot>/speed_override`` — ``std_msgs/Float64``: the commanded δ in [0, 1]. Not percent: the UR ROS 2 driver's
  ``speed_scaling_factor`` topic is in percent (0–100), and mixing the two is a known failure (a 0.62 read as
  0.62 %, or 62 read as 62×); the name and the unit here follow the contract's ``delta``.
- ``<robot>/joint_states`` — ``sensor_msgs/JointState``: the newest joint state the decision used (stamped when the
  controller measured it; velocity = applied override × nominal velocity, as the controller reports).

and for the cell ``diagnostics`` (``diagnostic_msgs/DiagnosticArray``: one status per robot, level OK / WARN
(reduced speed) / ERROR (safety exception or a fault), with zone, δ and every fault's code and reason as values)
and ``hrc_markers`` (``visualization_msgs/MarkerArray``: each robot link and human capsule as a CYLINDER with a
SPHERE at each end, coloured by zone, an open robot's plan around people as a LINE_STRIP, after a DELETEALL so that
people who left, and plans that ended, vanish in RViz).

The face never runs on the safety loop's thread, and builds no status document of its own: the status thread
(:class:`gateway.main.StatusThread`) hands it each one it built, with its job; :meth:`Ros2Face.offer` costs that
thread an append and an eventfd write (:class:`gateway.handoff.LatestJobThread`), and drops what comes sooner than
``publish_rate_hz`` allows. The face reads nothing from ROS 2; the cell's ROS 2 trackers are subscribed on its
session (:mod:`gateway.ros2_trackers`), under the session's access control (:func:`ros2_policy`).
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

import numpy as np
import zenoh

from gateway.handoff import LatestJobThread
from gateway.ros2_trackers import tracker_topics, trackers_node_name
from gateway.status import StatusJob
from hrc_contract.config import CellConfig
from hrc_contract.status_models import CapsuleStatus, GatewayStatus
from hrc_devices.robots.model import RobotModel
from hrc_devices.ros2.rmw_zenoh import (
    ADMIN_SPACE,
    Distro,
    Ros2Node,
    Ros2Publisher,
    TopicType,
    endpoint_token,
    fully_qualified_name,
    new_message,
    node_token,
    serialize,
    topic_key,
    topic_type,
)
from hrc_runtime.access_control import ROS2_FACE, Ros2Policy, Ros2Rights
from hrc_runtime.pki import default_pki_dir
from hrc_runtime.zenoh_session import (
    PLAIN_TCP_LOOPBACK,
    SessionOptions,
    check_endpoints,
    endpoint_host,
    endpoint_protocol,
    mutual_tls,
    session_config,
)

log = logging.getLogger("hrc-gateway.ros2")

ROS2_COMMON_NAME = ROS2_FACE
"""The certificate CN of the face's own session when its endpoints are TLS (issued in ``--pki-dir`` on first start)."""

FLOAT64 = "std_msgs/msg/Float64"
JOINT_STATE = "sensor_msgs/msg/JointState"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"

ZONE_RGBA: dict[str, tuple[float, float, float, float]] = {
    "autonomous": (0.1, 0.7, 0.1, 0.6),
    "guarded_distance": (0.9, 0.8, 0.1, 0.6),
    "reduced_speed": (1.0, 0.5, 0.0, 0.7),
    "safety_exception": (0.9, 0.1, 0.1, 0.8),
}
HUMAN_RGBA = (0.3, 0.5, 0.9, 0.6)
"""A person no robot is slowing down for."""
ZONE_SEVERITY = ("autonomous", "guarded_distance", "reduced_speed", "safety_exception")
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR = 0, 1, 2

CYLINDER, SPHERE, LINE_STRIP = 3, 2, 4
ADD, DELETEALL = 0, 3
PLAN_RGBA = (0.31, 0.89, 0.84, 0.9)
"""An open robot's plan around people (the operator page's colour for it)."""
PLAN_LINE_WIDTH_M = 0.015


class JointView(NamedTuple):
    """A robot's joint state as the decision used it.

    Attributes:
        names: the joints, in the order of ``q_rad``.
        q_rad: positions [rad]. qd_radps: velocities [rad/s]. stamp_ns: when measured [ns since the epoch].
    """

    names: tuple[str, ...]
    q_rad: np.ndarray
    qd_radps: np.ndarray
    stamp_ns: int


def ros_token(name: str) -> str:
    """A cell name (``[a-z0-9_-]``) as a ROS name token: ``-`` → ``_``, a leading digit prefixed with ``r_``."""
    token = name.replace("-", "_")
    return f"r_{token}" if token[:1].isdigit() else token


# ------------------------------------------------------------------------------------------- messages (pure)


def _time(distro: Distro, stamp_ns: int) -> Any:
    return new_message(
        distro, "builtin_interfaces/msg/Time", sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )


def _header(distro: Distro, stamp_ns: int, frame_id: str) -> Any:
    return new_message(distro, "std_msgs/msg/Header", stamp=_time(distro, stamp_ns), frame_id=frame_id)


def speed_override_message(distro: Distro, delta: float) -> Any:
    """``std_msgs/Float64`` with the commanded δ in [0, 1]."""
    return new_message(distro, FLOAT64, data=float(delta))


def joint_state_message(distro: Distro, joints: JointView) -> Any:
    """``sensor_msgs/JointState`` of one robot (no efforts: the gateway has none)."""
    return new_message(
        distro,
        JOINT_STATE,
        header=_header(distro, joints.stamp_ns, ""),
        name=list(joints.names),
        position=np.asarray(joints.q_rad, dtype=np.float64),
        velocity=np.asarray(joints.qd_radps, dtype=np.float64),
    )


def diagnostic_level(zone: str, faults: int) -> int:
    """OK in the autonomous and guarded zones, WARN at reduced speed, ERROR in a safety exception or with a fault."""
    if faults or zone == "safety_exception":
        return LEVEL_ERROR
    return LEVEL_WARN if zone == "reduced_speed" else LEVEL_OK


def diagnostics_message(distro: Distro, doc: GatewayStatus, node_name: str) -> Any:
    """``diagnostic_msgs/DiagnosticArray``: one status per robot with its zone, δ, distances and faults."""
    statuses = []
    for robot, status in sorted(doc.robots.items()):
        codes = [f.code for f in status.faults]
        pairs = {
            "zone": status.zone,
            "delta": f"{status.delta:.4f}",
            "delta_bound": f"{status.delta_bound:.4f}",
            "min_distance_m": "" if status.min_distance_m is None else f"{status.min_distance_m:.4f}",
            "clearance_m": f"{status.clearance_m:.4f}",
            "t_delay_s": f"{status.t_delay_s:.4f}",
            "faults": ",".join(codes),
        } | {f"fault/{f.code}": f.reason for f in status.faults}
        message = f"{status.zone} δ={status.delta:.2f}" + (f" faults: {', '.join(codes)}" if codes else "")
        statuses.append(
            new_message(
                distro,
                "diagnostic_msgs/msg/DiagnosticStatus",
                level=diagnostic_level(status.zone, len(codes)),
                name=f"{node_name}: {robot}",
                message=message,
                hardware_id=robot,
                values=[new_message(distro, "diagnostic_msgs/msg/KeyValue", key=k, value=v) for k, v in pairs.items()],
            )
        )
    return new_message(distro, DIAGNOSTIC_ARRAY, header=_header(distro, doc.stamp_ns, ""), status=statuses)


def z_to_direction_quaternion(u: Sequence[float]) -> tuple[float, float, float, float]:
    """The shortest rotation taking +z to the unit vector ``u``, as (x, y, z, w)."""
    ux, uy, uz = u
    if uz < -1.0 + 1e-9:  # opposite: half a turn about x
        return (1.0, 0.0, 0.0, 0.0)
    x, y, z, w = -uy, ux, 0.0, 1.0 + uz  # axis z × u, angle via the half-way vector
    n = math.sqrt(x * x + y * y + w * w)
    return (x / n, y / n, z, w / n)


def capsule_markers(
    distro: Distro, capsule: CapsuleStatus, ns: str, first_id: int, rgba: tuple[float, ...], header: Any
) -> list[Any]:
    """A capsule as RViz draws it: a CYLINDER between the end points (none for a point) and a SPHERE at each end."""
    a, b, r = capsule.a_m, capsule.b_m, capsule.radius_m
    d = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    length = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    color = new_message(distro, "std_msgs/msg/ColorRGBA", r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])

    def marker(kind: int, offset: int, centre: Sequence[float], q: Sequence[float], scale: Sequence[float]) -> Any:
        pose = new_message(
            distro,
            "geometry_msgs/msg/Pose",
            position=new_message(distro, "geometry_msgs/msg/Point", x=centre[0], y=centre[1], z=centre[2]),
            orientation=new_message(distro, "geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        vector = new_message(distro, "geometry_msgs/msg/Vector3", x=scale[0], y=scale[1], z=scale[2])
        return new_message(
            distro, "visualization_msgs/msg/Marker", header=header, ns=ns, id=first_id + offset, type=kind,
            action=ADD, pose=pose, scale=vector, color=color,
        )  # fmt: skip

    identity = (0.0, 0.0, 0.0, 1.0)
    ball = (2.0 * r, 2.0 * r, 2.0 * r)
    markers = [marker(SPHERE, 0, a, identity, ball)]
    if length > 1e-9:
        centre = (a[0] + d[0] / 2, a[1] + d[1] / 2, a[2] + d[2] / 2)
        q = z_to_direction_quaternion((d[0] / length, d[1] / length, d[2] / length))
        markers += [marker(SPHERE, 1, b, identity, ball), marker(CYLINDER, 2, centre, q, (2.0 * r, 2.0 * r, length))]
    return markers


def human_zones(doc: GatewayStatus) -> dict[str, str]:
    """Per human, the most severe zone of the robots whose closest person they are (others: none)."""
    zones: dict[str, str] = {}
    for status in doc.robots.values():
        if status.closest is None:
            continue
        human = status.closest.human.removesuffix(" (lost)")
        previous = zones.get(human, "autonomous")
        zones[human] = max(previous, status.zone, key=ZONE_SEVERITY.index)
    return zones


def plan_marker(distro: Distro, ns: str, path_m: Sequence[Sequence[float]], header: Any) -> Any:
    """An open robot's plan around people: a LINE_STRIP through the tool's positions along it (world frame) [m]."""
    points = [new_message(distro, "geometry_msgs/msg/Point", x=p[0], y=p[1], z=p[2]) for p in path_m]
    pose = new_message(
        distro,
        "geometry_msgs/msg/Pose",
        position=new_message(distro, "geometry_msgs/msg/Point", x=0.0, y=0.0, z=0.0),
        orientation=new_message(distro, "geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
    )
    r, g, b, a = PLAN_RGBA
    return new_message(
        distro, "visualization_msgs/msg/Marker", header=header, ns=ns, id=0, type=LINE_STRIP, action=ADD, pose=pose,
        scale=new_message(distro, "geometry_msgs/msg/Vector3", x=PLAN_LINE_WIDTH_M, y=0.0, z=0.0),
        color=new_message(distro, "std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a), points=points,
    )  # fmt: skip


def markers_message(distro: Distro, doc: GatewayStatus, frame_id: str) -> Any:
    """``visualization_msgs/MarkerArray``: DELETEALL, then every robot link (``robot/<name>``, its zone's colour),
    an open robot's plan around people as a LINE_STRIP through the tool's path (``plan/<name>``), and every human
    capsule (``human``, the zone of the robots it holds; blue if none). Ids step by 3 per capsule."""
    header = _header(distro, doc.stamp_ns, frame_id)
    markers = [new_message(distro, "visualization_msgs/msg/Marker", header=header, action=DELETEALL)]
    for robot, status in sorted(doc.robots.items()):
        rgba = ZONE_RGBA[status.zone]
        for i, link in enumerate(status.links):
            markers += capsule_markers(distro, link, f"robot/{robot}", 3 * i, rgba, header)
        if status.plan is not None and status.plan.path_tool_m:
            markers.append(plan_marker(distro, f"plan/{robot}", status.plan.path_tool_m, header))
    zones = human_zones(doc)
    for i, capsule in enumerate(doc.human_capsules):
        zone = zones.get(capsule.human)
        rgba = HUMAN_RGBA if zone is None else ZONE_RGBA[zone]
        markers += capsule_markers(distro, capsule, "human", 3 * i, rgba, header)
    return new_message(distro, MARKER_ARRAY, markers=markers)


def joint_views(job: StatusJob, robots: Mapping[str, RobotModel]) -> dict[str, JointView]:
    """The joint state each robot's decision used, where it had one."""
    views = {}
    for name, sample in job.cycle.inputs.joint.items():
        if sample is None or name not in robots:
            continue
        qd = sample.override * np.asarray(sample.qd_nominal_radps, dtype=np.float64)
        views[name] = JointView(
            robots[name].joint_names, np.asarray(sample.q_rad, dtype=np.float64), qd, sample.stamp_ns
        )
    return views


# ---------------------------------------------------------------------------------------------------- the thread


class Snapshot(NamedTuple):
    """What the face publishes of one cycle: the status thread's job and the status document it built of it."""

    job: StatusJob
    doc: GatewayStatus


class Ros2Face:
    """Publishes each offered status snapshot as ROS 2 messages, on a thread of its own (see the module).

    Args:
        config: the cell (``[ros2]`` says what and where).
        robots: the robots' models (joint and link names).
        session: an open Zenoh session for the ROS 2 side (the caller closes it, after :meth:`close`).
    """

    def __init__(self, config: CellConfig, robots: Mapping[str, RobotModel], session: zenoh.Session) -> None:
        ros2 = config.ros2
        self._config = config
        self._robots = robots
        self._distro: Distro = ros2.distro
        self._period_s = 1.0 / min(ros2.publish_rate_hz, config.gateway.status_rate_hz)
        self._next_due_s = 0.0
        self.node = Ros2Node(session, ros2.node_name, ros2.namespace, ros2.domain_id, ros2.distro)
        self._speed: dict[str, Ros2Publisher] = {}
        self._joints: dict[str, Ros2Publisher] = {}
        for robot in sorted(config.robots):
            token = ros_token(robot)
            self._speed[robot] = self.node.create_publisher(f"{token}/{ros2.speed_override_topic}", FLOAT64)
            self._joints[robot] = self.node.create_publisher(f"{token}/{ros2.joint_states_topic}", JOINT_STATE)
        self._diagnostics = self.node.create_publisher(ros2.diagnostics_topic, DIAGNOSTIC_ARRAY)
        self._markers = self.node.create_publisher(ros2.markers_topic, MARKER_ARRAY)
        for msgtype in (FLOAT64, JOINT_STATE, DIAGNOSTIC_ARRAY, MARKER_ARRAY):  # rosbags compiles a serialiser
            serialize(self._distro, new_message(self._distro, msgtype))  # per type on first use: ~0.1–0.2 s, now
        self._closed = False
        self.skipped = 0
        self.publish_s_total = 0.0
        """Time spent building and putting snapshots, on the face's thread [s] (with :attr:`publish_s_max`)."""
        self.publish_s_max = 0.0
        self._thread = LatestJobThread(self._publish_timed, "hrc-ros2", "publishing ROS 2 messages", log)

    @property
    def published(self) -> int:
        """Snapshots published."""
        return self._thread.published

    @property
    def errors(self) -> int:
        """Snapshots not published for an error (logged)."""
        return self._thread.errors

    def offer(self, job: StatusJob, doc_of: Callable[[], GatewayStatus]) -> None:
        """Hand over a snapshot, the job and the status document built of it (never blocks): dropped if it comes
        sooner than the publish rate allows; ``doc_of`` builds the document, called only for a snapshot taken."""
        now_s = time.monotonic()
        if now_s < self._next_due_s:
            self.skipped += 1
            return
        self._next_due_s = now_s + self._period_s
        self._thread.offer(Snapshot(job, doc_of()))

    def messages(self, snapshot: Snapshot) -> list[tuple[Ros2Publisher, bytes, int]]:
        """Every (publisher, CDR payload, source stamp [ns]) of one snapshot (what :meth:`publish` puts)."""
        job, doc = snapshot
        distro = self._distro
        out = [(self._speed[r], serialize(distro, speed_override_message(distro, s.delta)), doc.stamp_ns)
               for r, s in sorted(doc.robots.items()) if r in self._speed]  # fmt: skip
        for robot, joints in sorted(joint_views(job, self._robots).items()):
            out.append((self._joints[robot], serialize(distro, joint_state_message(distro, joints)), joints.stamp_ns))
        diagnostics = diagnostics_message(distro, doc, self._config.ros2.node_name)
        out.append((self._diagnostics, serialize(distro, diagnostics), doc.stamp_ns))
        markers = markers_message(distro, doc, self._config.ros2.frame_id)
        out.append((self._markers, serialize(distro, markers), doc.stamp_ns))
        return out

    def publish(self, snapshot: Snapshot) -> None:
        """Build and put one snapshot's messages (on the face's thread)."""
        for publisher, payload, stamp_ns in self.messages(snapshot):
            publisher.put(payload, stamp_ns)

    def close(self) -> None:
        """Stop the thread, then undeclare the node's endpoints and tokens; idempotent."""
        if self._closed:
            return
        self._closed = True
        self._thread.close()
        self.node.close()
        log.info(
            "ROS 2 face: %d snapshots published (%d skipped by the rate, %d errors), %.2f ms each on average, "
            "%.2f ms at most",
            self.published,
            self.skipped,
            self.errors,
            1e3 * self.publish_s_total / max(1, self.published),
            1e3 * self.publish_s_max,
        )

    def __enter__(self) -> Ros2Face:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _publish_timed(self, snapshot: Snapshot) -> None:
        start_s = time.perf_counter()
        self.publish(snapshot)
        took_s = time.perf_counter() - start_s
        self.publish_s_total += took_s
        self.publish_s_max = max(self.publish_s_max, took_s)


# ------------------------------------------------------------------------------------------- session and start


def published_topics(config: CellConfig) -> list[tuple[str, str]]:
    """(topic, message type) of every publisher of the face, relative to ``[ros2] namespace``: per robot its speed
    override and joint states, then the diagnostics and the markers."""
    ros2 = config.ros2
    topics = []
    for robot in sorted(config.robots):
        token = ros_token(robot)
        topics += [
            (f"{token}/{ros2.speed_override_topic}", FLOAT64),
            (f"{token}/{ros2.joint_states_topic}", JOINT_STATE),
        ]
    return [*topics, (ros2.diagnostics_topic, DIAGNOSTIC_ARRAY), (ros2.markers_topic, MARKER_ARRAY)]


RUN_TIME_CHUNKS = (2, 3, 4)
"""Chunks of an rmw_zenoh liveliness key chosen at run time: the session's Zenoh id, the node's and entity's ids."""
NODE_CHUNKS = (6, 7, 8)
"""The enclave, namespace and node name of a liveliness key: a tracker's own (a ZED wrapper's ``zed_node``)."""
TOPIC_NAME_CHUNK = 9
TYPE_CHUNKS = (10, 11)
QOS_CHUNK = 12
ANY_TYPE = TopicType("*", "*", "*")


def token_expr(token: str, wildcards: Sequence[int]) -> str:
    """An rmw_zenoh liveliness key with the chunks at ``wildcards`` (``/``-separated, from 0) replaced by ``*``."""
    chunks = token.split("/")
    for i in wildcards:
        chunks[i] = "*"
    return "/".join(chunks)


def ros2_policy(config: CellConfig) -> Ros2Policy:
    """The ROS 2 session's access control (:class:`hrc_runtime.access_control.Ros2Policy`) from the cell's keys.

    The face may put exactly its publishers' data keys and declare its two nodes' tokens (``<node_name>`` and its
    trackers' node) and its publishers' and subscriptions' tokens; a ROS 2 tracker may put on its own topic (any
    type and hash: a wrong one is then counted at the gateway) and declare a node's token and its topic's publisher
    token; members read the domain (``<domain>/**``, ``@ros2_lv/<domain>/**``).

    Raises:
        ConfigError: an unknown distro, a bad topic or node name.
    """
    ros2 = config.ros2
    domain, ns, node = ros2.domain_id, ros2.namespace, ros2.node_name
    puts: list[str] = []
    tokens = [token_expr(node_token(domain, "0", 0, ns, name), RUN_TIME_CHUNKS)
              for name in (node, trackers_node_name(ros2))]  # fmt: skip
    for topic, msgtype in published_topics(config):
        fq_name, wire = fully_qualified_name(ns, topic), topic_type(ros2.distro, msgtype)
        puts.append(topic_key(domain, fq_name, wire))
        token = endpoint_token("MP", domain, "0", 0, 0, ns, node, fq_name, wire)
        tokens.append(token_expr(token, (*RUN_TIME_CHUNKS, QOS_CHUNK)))
    trackers = []
    for name, topics in tracker_topics(config).items():
        own_puts: list[str] = []
        own_tokens = [token_expr(node_token(domain, "0", 0, "/", "n"), (*RUN_TIME_CHUNKS, *NODE_CHUNKS))]
        for source in topics:
            if source.announced:
                token = endpoint_token(
                    "MS", domain, "0", 0, 0, ns, trackers_node_name(ros2), source.fq_name, source.wire
                )
                tokens.append(token_expr(token, (*RUN_TIME_CHUNKS, QOS_CHUNK)))
            # A name with ``*`` (a ROS4HRI body's joint states, one topic per body id): any topic name in the token.
            name_chunk = () if source.announced else (TOPIC_NAME_CHUNK,)
            publisher = endpoint_token("MP", domain, "0", 0, 0, "/", "n", source.fq_name.replace("*", "b"), source.wire)
            own_tokens.append(
                token_expr(publisher, (*RUN_TIME_CHUNKS, *NODE_CHUNKS, *name_chunk, *TYPE_CHUNKS, QOS_CHUNK))
            )
            own_puts.append(topic_key(domain, source.fq_name, ANY_TYPE))
        trackers.append((name, Ros2Rights(tuple(own_puts), tuple(own_tokens))))
    read = (f"{domain}/**", f"{ADMIN_SPACE}/{domain}/**")
    return Ros2Policy(read, Ros2Rights(tuple(puts), tuple(tokens)), tuple(trackers))


def ros2_session_options(args: argparse.Namespace, config: CellConfig) -> SessionOptions:
    """How the gateway's ROS 2 session joins the ROS 2 side (``args``: the gateway's command line, for
    ``--pki-dir``); the face publishes on it and the cell's ROS 2 trackers are read from it.

    TLS endpoints: mutual TLS as CN :data:`ROS2_COMMON_NAME` from ``--pki-dir``, with the ROS 2 session's access
    control (:func:`ros2_policy`: only a tracker's own certificate, or the tracker emulator's, may put on its topic).
    Plain ``tcp/`` endpoints: loopback only (the host's rmw_zenohd router), no authentication and no access control;
    a cell that reads trackers from them also needs ``--insecure-plain-tcp``
    (:func:`gateway.ros2_trackers.check_ros2_inputs`), one that only publishes does not.

    Raises:
        SecurityError: plain TCP off loopback, or TLS and plain endpoints mixed.
        PkiError: the ``ros2`` identity cannot be had.
        ConfigError: see :func:`ros2_policy`.
    """
    ros2 = config.ros2
    endpoints = [*ros2.listen, *ros2.connect]
    if all(endpoint_protocol(e) == "tls" for e in endpoints):
        hosts = [endpoint_host(e) for e in ros2.listen]
        pki_dir = Path(args.pki_dir) if getattr(args, "pki_dir", None) else default_pki_dir()
        return SessionOptions(ros2.mode, mutual_tls(pki_dir, ROS2_COMMON_NAME, ros2_policy(config), hosts))
    options = SessionOptions(ros2.mode, PLAIN_TCP_LOOPBACK.tls)
    check_endpoints(endpoints, options)
    reads = any(t.ros2 is not None for t in config.trackers.values())
    log.warning(
        "ROS 2 session on plain TCP (%s): loopback only, unauthenticated, no access control; it publishes robot "
        "state and people's positions to anyone on this host%s",
        ", ".join(endpoints),
        " and reads the ROS 2 trackers from anyone on this host (--insecure-plain-tcp)" if reads else "",
    )
    return options


@contextmanager
def running_ros2_face(
    config: CellConfig, robots: Mapping[str, RobotModel], options: SessionOptions | None
) -> Iterator[Ros2Face | None]:
    """The face with its own session while the block runs; None when ``[ros2]`` is not enabled."""
    if not config.ros2.enabled or options is None:
        yield None
        return
    ros2 = config.ros2
    with zenoh.open(session_config(ros2.listen, ros2.connect, options)) as session:
        face = Ros2Face(config, robots, session)
        log.info(
            "ROS 2 face: node %s in domain %d (%s keys), %s",
            face.node.token_key.rsplit("/", 1)[-1],
            ros2.domain_id,
            ros2.distro,
            ", ".join(p.key for p in face.node.publishers),
        )
        try:
            yield face
        finally:
            face.close()
