"""Body trackers' ROS 2 messages (CDR bytes) → per-person keypoints and tracking state.

Pure (no transport): the bytes of one sample in, a :class:`PeopleFrame` out, decoded by ``rosbags`` with the
publishers' own message definitions (vendored in ``hrc_devices/ros2/ros2_msgs``, see its README).

    ZED  zed_msgs/msg/ObjectsStamped      ──decode_zed_objects──▶ PeopleFrame ──people_capsules──▶ capsules per person
    K4A  visualization_msgs/msg/MarkerArray ──decode_k4abt_markers──▶ PeopleFrame
    ROS4HRI hri_msgs/msg/IdsList (/humans/bodies/tracked) ──decode_ids_list──▶ ids

Tracking states (ZED ``Object.tracking_state``): ``OK`` is a seen person (a detection). ``SEARCHING`` ("occlusion
occurred, trajectory is estimated") and ``TERMINATE`` (the last searching frame; the ZED deletes the track next) are
**not** detections: the person is left out of :attr:`PeopleFrame.detections` and listed in
:attr:`PeopleFrame.searching`, so that the gateway's track logic keeps them as *lost*. Neither may ever be read as
"gone": an occluded person is still there, and a ZED terminating its track says nothing about where they went.
``OFF`` (the object is not valid) is ignored.

Missing keypoints: the ZED SDK gives keypoints it could not detect non-finite values, and the ROS wrapper leaves the
keypoints beyond the format's count at zero; both are *unseen* (Stereolabs' own viewers test ``isfinite`` and a
non-zero norm), never an error. The Azure Kinect driver publishes every one of K4ABT's 32 joints of every body, with
no tracking state: each body is a detection, a joint absent from the array is unseen.

Hostile input raises :class:`Ros2MessageError` (a :class:`~hrc_contract.messages.MessageError`, counted like native
input) with a short ``reason``: ``too_large``, ``not_cdr`` (bytes that do not decode as the type: malformed, truncated,
another type), ``too_many_people``, ``too_many_markers``, ``bad_stamp``, ``non_finite`` (a position or marker pose),
``absurd_keypoint``, ``unknown_body_format``, ``unknown_tracking_state``, ``bad_marker_id``, ``duplicate_joint``,
``mixed_frames``. Nothing else escapes (``tests/hrc_devices/trackers/test_ros2_people.py`` fuzzes random and
truncated bytes).
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from rosbags.serde import SerdeError
from rosbags.typesys.store import Typestore

from hrc_contract.messages import MAX_PAYLOAD_BYTES, MessageError
from hrc_devices.trackers.skeletons import (
    COMPILED,
    MAX_COORDINATE_M,
    BodyCapsules,
    CompiledFormat,
    PersonMemory,
    PersonUnplacedError,
    body_capsules,
    whole_body_capsules,
)

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


ZED_OBJECTS = "zed_msgs/msg/ObjectsStamped"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
IDS_LIST = "hri_msgs/msg/IdsList"

MAX_PEOPLE = 256
"""At most this many objects or bodies in one message (the contract's ``Humans`` limit)."""
MAX_MARKERS = MAX_PEOPLE * 32
"""At most this many markers in one K4ABT array (32 joints per body)."""
K4ABT_JOINTS = 32


# rosbags raises these for bytes that are not the type (its generated deserialisers index, slice and unpack the
# buffer); the fuzz test shows nothing else escapes
_DECODE_ERRORS = (SerdeError, ValueError, IndexError, KeyError, TypeError, struct.error, UnicodeDecodeError,
                  AssertionError, OverflowError, MemoryError)  # fmt: skip


class Ros2MessageError(MessageError):
    """A ROS 2 sample that is not a valid body-tracker message; ``reason`` is a short key for counting."""


class TrackingState(enum.IntEnum):
    """``sl::OBJECT_TRACKING_STATE`` as ``zed_msgs/Object.tracking_state`` carries it."""

    OFF = 0
    OK = 1
    SEARCHING = 2
    TERMINATE = 3


class BodyFormat(enum.IntEnum):
    """``sl::BODY_FORMAT`` as ``zed_msgs/Object.body_format`` carries it."""

    BODY_18 = 0
    BODY_34 = 1
    BODY_38 = 2


ZED_FORMATS = {BodyFormat.BODY_18: "zed_body_18", BodyFormat.BODY_34: "zed_body_34", BodyFormat.BODY_38: "zed_body_38"}


class TrackedPerson(NamedTuple):
    """One detected person of a frame, in the message's frame (``PeopleFrame.frame_id``).

    Attributes:
        person_id: the tracker's id of the person (``label_id``, the K4ABT body id), as text.
        format: the keypoint format, or None when the tracker sent no skeleton (only ``position``).
        keypoints_m: keypoints, shape (N, 3) [m] (unseen rows: anything).
        seen: which keypoints were seen, shape (N,).
        position_m: the person's centre [m] (ZED ``position``; K4ABT: the pelvis).
        position_std_m: the tracker's stated standard deviation of the position (ZED ``position_covariance``: the
            root of its largest diagonal element; 0 if not stated) [m].
    """

    person_id: str
    format: CompiledFormat | None
    keypoints_m: FloatArray
    seen: BoolArray
    position_m: FloatArray
    position_std_m: float


class PeopleFrame(NamedTuple):
    """One sample of a body tracker.

    Attributes:
        stamp_ns: ``header.stamp``, the capture time [ns].
        frame_id: ``header.frame_id``: the frame of every coordinate.
        detections: people seen in this frame.
        searching: ids of people the tracker lost in this frame (SEARCHING, TERMINATE): not detections, never gone.
    """

    stamp_ns: int
    frame_id: str
    detections: tuple[TrackedPerson, ...]
    searching: tuple[str, ...]


def decode_cdr(payload: bytes, msgtype: str, store: Typestore) -> Any:
    """Decode CDR bytes as ``msgtype``.

    Raises:
        Ros2MessageError: ``too_large`` (above the contract's payload limit) or ``not_cdr``.
    """
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise Ros2MessageError("too_large", f"{len(payload)} bytes, at most {MAX_PAYLOAD_BYTES} allowed")
    try:
        return store.deserialize_cdr(bytes(payload), msgtype)
    except _DECODE_ERRORS as exc:
        raise Ros2MessageError("not_cdr", f"not a {msgtype}: {type(exc).__name__}: {str(exc)[:120]}") from exc


def stamp_ns(header: Any) -> int:
    """``header.stamp`` as nanoseconds.

    Raises:
        Ros2MessageError: ``bad_stamp``: before 1970 or ``nanosec`` not below 1e9.
    """
    sec, nanosec = int(header.stamp.sec), int(header.stamp.nanosec)
    if sec < 0 or not 0 <= nanosec < 1_000_000_000:
        raise Ros2MessageError("bad_stamp", f"stamp {sec} s {nanosec} ns; allowed: sec >= 0, 0 <= nanosec < 1e9")
    return sec * 1_000_000_000 + nanosec


def _finite_point(values: Any, what: str) -> FloatArray:
    point = np.asarray(values, dtype=np.float64).reshape(3)
    if not np.isfinite(point).all():
        raise Ros2MessageError("non_finite", f"{what} is not finite")
    if float(np.abs(point).max()) > MAX_COORDINATE_M:
        raise Ros2MessageError("absurd_keypoint", f"{what} beyond ±{MAX_COORDINATE_M} m")
    return point


def decode_zed_objects(payload: bytes, store: Typestore) -> PeopleFrame:
    """A ZED ``zed_msgs/msg/ObjectsStamped`` (body tracking) → the people of the frame.

    Raises:
        Ros2MessageError: see the module docstring.
    """
    msg = decode_cdr(payload, ZED_OBJECTS, store)
    if len(msg.objects) > MAX_PEOPLE:
        raise Ros2MessageError("too_many_people", f"{len(msg.objects)} objects, at most {MAX_PEOPLE} allowed")
    detections: list[TrackedPerson] = []
    searching: list[str] = []
    for obj in msg.objects:
        try:
            state = TrackingState(int(obj.tracking_state))
        except ValueError:
            raise Ros2MessageError(
                "unknown_tracking_state", f"tracking_state {obj.tracking_state}; allowed: 0 OFF, 1 OK, 2, 3"
            ) from None
        person_id = str(int(obj.label_id))
        if state is TrackingState.OFF:
            continue
        if state is not TrackingState.OK:
            searching.append(person_id)
            continue
        detections.append(_zed_person(obj, person_id))
    return PeopleFrame(stamp_ns(msg.header), str(msg.header.frame_id), tuple(detections), tuple(searching))


def _zed_person(obj: Any, person_id: str) -> TrackedPerson:
    position = _finite_point(obj.position, f"object {person_id} position")
    covariance = np.asarray(obj.position_covariance, dtype=np.float64)
    # upper triangle [p0 p1 p2; . p3 p4; . . p5]: the diagonal is 0, 3, 5
    variances = covariance[[0, 3, 5]]
    std = float(np.sqrt(variances.max())) if np.isfinite(variances).all() and variances.min() >= 0 else 0.0
    if not obj.skeleton_available:
        return TrackedPerson(person_id, None, position[None, :], np.ones(1, dtype=bool), position, std)
    try:
        fmt = COMPILED[ZED_FORMATS[BodyFormat(int(obj.body_format))]]
    except ValueError:
        raise Ros2MessageError(
            "unknown_body_format", f"body_format {obj.body_format}; allowed: 0 BODY_18, 1 BODY_34, 2 BODY_38"
        ) from None
    n = fmt.n_keypoints
    with np.errstate(invalid="ignore", over="ignore"):
        keypoints = np.array([k.kp for k in obj.skeleton_3d.keypoints[:n]], dtype=np.float64).reshape(n, 3)
        seen = np.isfinite(keypoints).all(axis=1) & (np.abs(keypoints).sum(axis=1) > 0.0)
    return TrackedPerson(person_id, fmt, keypoints, seen, position, std)


def decode_k4abt_markers(payload: bytes, store: Typestore) -> PeopleFrame:
    """An Azure Kinect ``visualization_msgs/msg/MarkerArray`` (``body_tracking_data``) → the people of the frame.

    ``marker.id // 100`` is the body id and ``marker.id % 100`` the K4ABT joint (the driver's
    ``id = body.id * 100 + joint``); the stamp and frame are the markers' (all the same). Markers that delete
    (``action`` 2, 3) carry no joint and are skipped.

    Raises:
        Ros2MessageError: see the module docstring.
    """
    msg = decode_cdr(payload, MARKER_ARRAY, store)
    if len(msg.markers) > MAX_MARKERS:
        raise Ros2MessageError("too_many_markers", f"{len(msg.markers)} markers, at most {MAX_MARKERS} allowed")
    bodies: dict[int, tuple[FloatArray, BoolArray]] = {}
    frame: tuple[int, str] | None = None
    for marker in msg.markers:
        if int(marker.action) in (2, 3):
            continue
        marker_id = int(marker.id)
        body_id, joint = divmod(marker_id, 100)
        if marker_id < 0 or joint >= K4ABT_JOINTS:
            raise Ros2MessageError("bad_marker_id", f"marker id {marker_id}; allowed: body * 100 + joint 0..31")
        this = (stamp_ns(marker.header), str(marker.header.frame_id))
        if frame is None:
            frame = this
        elif this != frame:
            raise Ros2MessageError("mixed_frames", f"markers of stamps/frames {frame} and {this} in one array")
        if body_id not in bodies:
            if len(bodies) >= MAX_PEOPLE:
                raise Ros2MessageError("too_many_people", f"more than {MAX_PEOPLE} bodies")
            bodies[body_id] = (np.zeros((K4ABT_JOINTS, 3)), np.zeros(K4ABT_JOINTS, dtype=bool))
        keypoints, seen = bodies[body_id]
        if seen[joint]:
            raise Ros2MessageError("duplicate_joint", f"body {body_id} joint {joint} twice")
        p = marker.pose.position
        keypoints[joint] = _finite_point((p.x, p.y, p.z), f"body {body_id} joint {joint}")
        seen[joint] = True
    fmt = COMPILED["k4abt_32"]
    detections = tuple(
        TrackedPerson(str(body_id), fmt, kp, seen, kp[0] if seen[0] else kp[seen].mean(axis=0), 0.0)
        for body_id, (kp, seen) in bodies.items()
    )
    stamp, frame_id = frame if frame is not None else (0, "")
    return PeopleFrame(stamp, frame_id, detections, ())


def decode_ids_list(payload: bytes, store: Typestore) -> tuple[int, tuple[str, ...]]:
    """A ROS4HRI ``hri_msgs/msg/IdsList`` (``/humans/bodies/tracked``) → (stamp [ns], ids).

    An id that leaves the list is a body the tracker no longer sees: lost, not gone.

    Raises:
        Ros2MessageError: ``too_large``, ``not_cdr``, ``bad_stamp``, ``too_many_people``.
    """
    msg = decode_cdr(payload, IDS_LIST, store)
    if len(msg.ids) > MAX_PEOPLE:
        raise Ros2MessageError("too_many_people", f"{len(msg.ids)} ids, at most {MAX_PEOPLE} allowed")
    return stamp_ns(msg.header), tuple(str(i) for i in msg.ids)


class Placement(NamedTuple):
    """Where a tracker's frame sits in the cell's world frame.

    ``p_world = R_world_sensor @ p_sensor + p_world_sensor`` [m].
    """

    R_world_sensor: FloatArray
    p_world_sensor: FloatArray


IDENTITY = Placement(np.eye(3), np.zeros(3))


def people_capsules(
    frame: PeopleFrame,
    memories: Mapping[str, PersonMemory],
    placement: Placement,
    *,
    uncertainty_m: float,
    memory_s: float = 1.0,
    floor_z_m: float = 0.0,
) -> tuple[tuple[tuple[str, BodyCapsules], ...], dict[str, PersonMemory]]:
    """Capsules of every detected person of a frame, in the world frame.

    Args:
        frame: a decoded frame.
        memories: per person id, the memory returned by the previous call.
        placement: the tracker's frame in the world.
        uncertainty_m: the tracker's stated keypoint uncertainty [m]; the ZED's stated position deviation (3σ) is
            added to it per person.
        memory_s, floor_z_m: see :func:`hrc_devices.trackers.skeletons.body_capsules`.

    Returns:
        ``(person id, capsules)`` per detection (a detection placed recently whose torso is not seen now is left
        out, :class:`hrc_devices.trackers.skeletons.PersonUnplacedError`), and the memories to pass next time
        (detections and searching people keep theirs; people the tracker no longer mentions lose it).

    Raises:
        SkeletonError: a keypoint beyond the bounds once in the world frame (see ``check_keypoints``).
    """
    people: list[tuple[str, BodyCapsules]] = []
    new_memories = {pid: memories[pid] for pid in frame.searching if pid in memories}
    for person in frame.detections:
        keypoints = person.keypoints_m @ placement.R_world_sensor.T + placement.p_world_sensor
        uncertainty = uncertainty_m + 3.0 * person.position_std_m
        if person.format is None:
            body = whole_body_capsules(keypoints, uncertainty, floor_z_m)
            memory = memories.get(person.person_id, PersonMemory())
        else:
            try:
                body, memory = body_capsules(
                    person.format,
                    np.where(person.seen[:, None], keypoints, 0.0),
                    person.seen,
                    stamp_ns=frame.stamp_ns,
                    uncertainty_m=uncertainty,
                    memory=memories.get(person.person_id),
                    memory_s=memory_s,
                    floor_z_m=floor_z_m,
                )
            except PersonUnplacedError:  # left out: lost at the gateway, as a SEARCHING person
                new_memories[person.person_id] = memories[person.person_id]
                continue
        people.append((person.person_id, body))
        new_memories[person.person_id] = memory
    return tuple(people), new_memories
