"""The cell's topics as ROS 2 messages, for ``hrc-record --format ros2`` (a rosbag2 bag: :mod:`.ros2_mcap`).

Every message the recorder receives (a contract message, validated as the JSON recording validates it) becomes
ROS 2 messages of the chosen distro, on the topics the gateway's ROS 2 face publishes (:mod:`gateway.ros2_face`,
built by its functions), so that ``ros2 bag play`` of a recording looks like the face to RViz, plus what only the
recorder sees. Names under ``[ros2] namespace``, topic names from ``[ros2]`` (defaults shown):

=========================================  ======================================  ====================================
topic                                      type                                    from
=========================================  ======================================  ====================================
``<robot>/joint_states``                   ``sensor_msgs/msg/JointState``          each joint state of the controller
                                                                                   (names from the cell file, header
                                                                                   stamp = ``stamp_ns``)
``<robot>/speed_override``                 ``std_msgs/msg/Float64``                each override δ in [0, 1] (not %)
``diagnostics``                            ``diagnostic_msgs/msg/DiagnosticArray`` each gateway status: zone, δ, faults
``hrc_markers``                            ``visualization_msgs/msg/MarkerArray``  each gateway status: robot links
                                                                                   and human capsules by zone
``trackers/<tracker>/markers``             ``visualization_msgs/msg/MarkerArray``  each tracker frame's capsules
``truth/<robot>/joint_states``,            as above                                the emulators' ground truth
``truth/markers``
``/rosout``                                ``rcl_interfaces/msg/Log``              the gateway's event log
``/tf_static``                             ``tf2_msgs/msg/TFMessage``              once: ``world`` → ``<robot>/base``
                                                                                   (``base_pose_world``)
``rejected``                               ``std_msgs/msg/String``                 a payload that is not a valid
                                                                                   message of its key (JSON: key,
                                                                                   reason, payload in base64)
=========================================  ======================================  ====================================

A robot or tracker name becomes a ROS name token (``-`` and other characters → ``_``, a leading digit prefixed
``r_``: :func:`key_token`). Pure functions of (cell, message); :class:`Ros2CellRecorder` validates on the caller's
thread and hands the translation to the sink's writer thread.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel

from gateway.ros2_face import (
    DELETEALL,
    DIAGNOSTIC_ARRAY,
    FLOAT64,
    HUMAN_RGBA,
    JOINT_STATE,
    MARKER_ARRAY,
    JointView,
    capsule_markers,
    diagnostics_message,
    joint_state_message,
    markers_message,
    speed_override_message,
)
from hrc_contract.config import CellConfig, Pose
from hrc_contract.messages import Humans, JointState, Override
from hrc_contract.status_models import CapsuleStatus, Event, GatewayStatus
from hrc_devices.ros2.rmw_zenoh import Distro, fully_qualified_name, new_message
from hrc_tools.record.ros2_mcap import Ros2BagSink, Ros2Topic, qos
from hrc_tools.record.topics import RejectedPayload, receive

log = logging.getLogger("hrc-record.ros2")

LOG = "rcl_interfaces/msg/Log"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
STRING = "std_msgs/msg/String"
LOG_INFO, LOG_WARN = 20, 30
"""``rcl_interfaces/msg/Log`` levels."""
WARN_EVENTS = frozenset({"fault_raised", "loop_stall", "track_lost", "planner_died"})
"""Event kinds logged at WARN on ``/rosout``; the others at INFO."""
ROSOUT = Ros2Topic("/rosout", LOG, qos(depth=1000))
TF_STATIC = Ros2Topic("/tf_static", TF_MESSAGE, qos(depth=1, transient_local=True))

_NOT_TOKEN = re.compile(r"[^A-Za-z0-9_]")


def key_token(chunk: str) -> str:
    """A key chunk (a robot or tracker name) as a ROS name token: every character but ``[A-Za-z0-9_]`` → ``_``; a
    leading digit (or nothing) prefixed with ``r_`` (``ur-5`` → ``ur_5``, ``2nd`` → ``r_2nd``). For the cell's names
    (``[a-z0-9_-]``) it is the face's :func:`gateway.ros2_face.ros_token`; any other chunk a key may carry still
    makes a valid name."""
    token = _NOT_TOKEN.sub("_", chunk)
    return token if token[:1].isalpha() or token[:1] == "_" else f"r_{token}"


@dataclass(frozen=True)
class Ros2Cell:
    """What the translation needs of the cell.

    Attributes:
        cell: the cell's name (its keys ``hrc/<cell>/…``).
        distro: whose message definitions.
        namespace: ``[ros2] namespace`` ('' for none).
        frame_id: the world frame of markers and transforms (``[ros2] frame_id``).
        node_name: the gateway's ROS 2 node (``[ros2] node_name``): the name of its diagnostics and log lines.
        speed_override_topic, joint_states_topic, diagnostics_topic, markers_topic: from ``[ros2]``.
        joints: per robot, its joint names in the order of ``q``.
        base_poses: per robot, its base pose in the world frame.
    """

    cell: str
    distro: Distro
    namespace: str
    frame_id: str
    node_name: str
    speed_override_topic: str
    joint_states_topic: str
    diagnostics_topic: str
    markers_topic: str
    joints: Mapping[str, tuple[str, ...]]
    base_poses: Mapping[str, Pose]

    @classmethod
    def of(cls, config: CellConfig, distro: Distro) -> Ros2Cell:
        """The cell of ``config``, in ``distro`` (which may differ from ``[ros2] distro``)."""
        ros2 = config.ros2
        return cls(
            config.cell,
            distro,
            ros2.namespace,
            ros2.frame_id,
            ros2.node_name,
            ros2.speed_override_topic,
            ros2.joint_states_topic,
            ros2.diagnostics_topic,
            ros2.markers_topic,
            {name: tuple(robot.model.joints) for name, robot in config.robots.items()},
            {name: robot.base_pose_world for name, robot in config.robots.items()},
        )

    def topic(self, name: str, msgtype: str) -> Ros2Topic:
        """``name`` under the namespace, with the face's QoS."""
        return Ros2Topic(fully_qualified_name(self.namespace, name), msgtype)

    def joint_names(self, robot: str, count: int) -> tuple[str, ...]:
        """The configured joint names of ``robot``; ``joint_<i>`` when unknown or of another count."""
        names = self.joints.get(robot, ())
        return names if len(names) == count else tuple(f"joint_{i}" for i in range(count))


# ------------------------------------------------------------------------------------------------ messages (pure)


def _header(cell: Ros2Cell, stamp_ns: int) -> Any:
    sec, nanosec = divmod(max(0, stamp_ns), 1_000_000_000)
    stamp = new_message(cell.distro, "builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)
    return new_message(cell.distro, "std_msgs/msg/Header", stamp=stamp, frame_id=cell.frame_id)


def joint_state(cell: Ros2Cell, robot: str, message: JointState, truth: bool) -> list[tuple[Ros2Topic, Any]]:
    """``<robot>/joint_states`` (or ``truth/<robot>/joint_states``): positions [rad] and velocities [rad/s]."""
    names = cell.joint_names(robot, len(message.q))
    view = JointView(
        names, np.asarray(message.q, dtype=np.float64), np.asarray(message.qd, dtype=np.float64), message.stamp_ns
    )
    name = f"{key_token(robot)}/{cell.joint_states_topic}"
    topic = cell.topic(f"truth/{name}" if truth else name, JOINT_STATE)
    return [(topic, joint_state_message(cell.distro, view))]


def speed_override(cell: Ros2Cell, robot: str, message: Override) -> list[tuple[Ros2Topic, Any]]:
    """``<robot>/speed_override``: the δ in [0, 1] the gateway commanded."""
    topic = cell.topic(f"{key_token(robot)}/{cell.speed_override_topic}", FLOAT64)
    return [(topic, speed_override_message(cell.distro, message.delta))]


def status(cell: Ros2Cell, doc: GatewayStatus) -> list[tuple[Ros2Topic, Any]]:
    """``diagnostics`` and ``hrc_markers`` of one status document (the face's messages)."""
    return [
        (cell.topic(cell.diagnostics_topic, DIAGNOSTIC_ARRAY), diagnostics_message(cell.distro, doc, cell.node_name)),
        (cell.topic(cell.markers_topic, MARKER_ARRAY), markers_message(cell.distro, doc, cell.frame_id)),
    ]


def humans_markers(cell: Ros2Cell, frame: Humans) -> Any:
    """A ``MarkerArray`` of a humans frame: DELETEALL, then each capsule (namespace ``<tracker>/<id>``, ids step by 3:
    a SPHERE at each end and a CYLINDER between), blue, stamped with the frame's ``stamp_ns``."""
    header = _header(cell, frame.stamp_ns)
    markers = [new_message(cell.distro, "visualization_msgs/msg/Marker", header=header, action=DELETEALL)]
    for human in frame.humans:
        for i, capsule in enumerate(human.capsules):
            shape = CapsuleStatus(name=capsule.name, a_m=capsule.a, b_m=capsule.b, radius_m=capsule.radius)
            ns = f"{frame.tracker}/{human.id}"
            markers += capsule_markers(cell.distro, shape, ns, 3 * i, HUMAN_RGBA, header)
    return new_message(cell.distro, MARKER_ARRAY, markers=markers)


def tracker_frame(cell: Ros2Cell, tracker: str | None, frame: Humans) -> list[tuple[Ros2Topic, Any]]:
    """``trackers/<tracker>/markers``, or ``truth/markers`` for the ground truth (``tracker`` None)."""
    name = "truth/markers" if tracker is None else f"trackers/{key_token(tracker)}/markers"
    return [(cell.topic(name, MARKER_ARRAY), humans_markers(cell, frame))]


def event_log(cell: Ros2Cell, event: Event) -> list[tuple[Ros2Topic, Any]]:
    """``/rosout``: one line per event of the gateway's log, WARN for :data:`WARN_EVENTS`, INFO otherwise; the
    kind in ``function``, the event's ``seq`` in ``line``."""
    sec, nanosec = divmod(event.stamp_ns, 1_000_000_000)
    line = new_message(
        cell.distro,
        LOG,
        stamp=new_message(cell.distro, "builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec),
        level=LOG_WARN if event.kind in WARN_EVENTS else LOG_INFO,
        name=cell.node_name,
        msg=event.message if event.robot is None else f"{event.robot}: {event.message}",
        file="",
        function=event.kind,
        line=min(event.seq, 2**32 - 1),
    )
    return [(ROSOUT, line)]


def rejected(cell: Ros2Cell, payload: RejectedPayload) -> list[tuple[Ros2Topic, Any]]:
    """``rejected``: the JSON of :class:`hrc_tools.record.topics.RejectedPayload` in a ``std_msgs/String``."""
    return [(cell.topic("rejected", STRING), new_message(cell.distro, STRING, data=payload.model_dump_json()))]


def quaternion_of_rpy(rpy: Sequence[float]) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the URDF roll-pitch-yaw ``rpy`` [rad]: R = R_z(yaw) R_y(pitch) R_x(roll)."""
    cr, sr = math.cos(rpy[0] / 2), math.sin(rpy[0] / 2)
    cp, sp = math.cos(rpy[1] / 2), math.sin(rpy[1] / 2)
    cy, sy = math.cos(rpy[2] / 2), math.sin(rpy[2] / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def base_transforms(cell: Ros2Cell, stamp_ns: int) -> list[tuple[Ros2Topic, Any]]:
    """``/tf_static``: ``<frame_id>`` → ``<robot>/base`` for every robot, from its ``base_pose_world``."""
    header = _header(cell, stamp_ns)
    transforms = []
    for robot, pose in sorted(cell.base_poses.items()):
        x, y, z, w = quaternion_of_rpy(pose.rpy)
        transform = new_message(
            cell.distro,
            "geometry_msgs/msg/Transform",
            translation=new_message(
                cell.distro, "geometry_msgs/msg/Vector3", x=pose.xyz[0], y=pose.xyz[1], z=pose.xyz[2]
            ),
            rotation=new_message(cell.distro, "geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
        )
        transforms.append(
            new_message(
                cell.distro,
                "geometry_msgs/msg/TransformStamped",
                header=header,
                child_frame_id=f"{key_token(robot)}/base",
                transform=transform,
            )
        )
    return [(TF_STATIC, new_message(cell.distro, TF_MESSAGE, transforms=transforms))]


def ros2_messages(cell: Ros2Cell, key: str, message: BaseModel) -> list[tuple[Ros2Topic, Any]]:
    """The ROS 2 messages of a valid contract ``message`` received on ``key`` (none for a key of no topic)."""
    kind = key.split("/")[2:]
    if isinstance(message, JointState) and kind[0] == "robot":
        return joint_state(cell, kind[1], message, truth=False)
    if isinstance(message, JointState) and kind[:2] == ["truth", "robot"]:
        return joint_state(cell, kind[2], message, truth=True)
    if isinstance(message, Override):
        return speed_override(cell, kind[1], message)
    if isinstance(message, Humans):
        return tracker_frame(cell, kind[1] if kind[0] == "tracker" else None, message)
    if isinstance(message, GatewayStatus):
        return status(cell, message)
    return []


# -------------------------------------------------------------------------------------------------------- recorder


class Ros2CellRecorder:
    """Writes what the subscribers receive to a ROS 2 bag (callbacks on Zenoh threads; the sink never blocks).

    The same interface as :class:`hrc_tools.record.cell.CellRecorder`: payloads validated by the same rules, a bad
    one recorded on ``rejected``; the translation runs on the sink's writer thread.
    """

    def __init__(self, sink: Ros2BagSink, cell: Ros2Cell, start_ns: int) -> None:
        self.sink = sink
        self.cell = cell
        self.unknown_keys = 0
        sink.offer(start_ns, lambda stamp_ns: base_transforms(cell, stamp_ns), start_ns)

    def on_sample(self, key: str, payload: bytes, received_ns: int) -> None:
        """Record one payload received on ``key``: its messages, or a ``rejected`` line."""
        received = receive(self.cell.cell, key, payload)
        if received is None:
            self.unknown_keys += 1
        elif isinstance(received, RejectedPayload):
            self.sink.offer(received_ns, lambda value: rejected(self.cell, value), received)
        else:
            self.sink.offer(received_ns, lambda value: ros2_messages(self.cell, key, value), received.message)

    def on_events(self, events: Sequence[Event], received_ns: int) -> None:
        """Record the events of one poll of the gateway's log on ``/rosout``, at ``received_ns`` (their arrival)."""
        for event in events:
            self.sink.offer(received_ns, lambda value: event_log(self.cell, value), event)
