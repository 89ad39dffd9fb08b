"""The tracker emulator speaking ZED: each measured frame as a ``zed_msgs/ObjectsStamped`` over rmw_zenoh.

    measured frame (hrc.humans/1: the capsules each sensor sees) ──[body fitting: fitted_capsules]──▶ capsules
        ──zed_keypoints──▶ BODY_34 or BODY_38 keypoints per person
        ──ZedSensor.objects──▶ ObjectsStamped in the sensor's frame ──rosbags CDR──▶ ``<domain>/<topic>/…`` + attachment

Keypoints come from the emulator's body model (:mod:`tracker_emu.body`): each is an end point of the capsules it
belongs to (an elbow ends the upper arm and starts the forearm). The model has no feet, hands' fingers or face: feet,
toes and heels are put under the ankles, the fingers on the hand's capsule, the face on the head's axis.

What a keypoint the sensor does not see becomes follows the camera's ``enable_body_fitting`` (the tracker's
``[trackers.<name>.ros2]``, the ZED wrapper's ``body_tracking.enable_body_fitting``), as the ZED SDK does:

- **off** (the wrapper's default, with its default ``BODY_38``): NaN. The SDK gives a keypoint it could not detect
  "non finite values" (``BodyData.keypoint``), and the wrapper copies the SDK's keypoints into ``skeleton_3d``.
- **on** (``BODY_34``, which the SDK only offers with fitting): an estimate. The SDK's fitting "deduces all missing
  keypoints" from a human kinematic model; here the emulator's own body model is fitted (:func:`fit_pose`: floor
  position, heading, reach) to the capsules the sensor saw, noise and all, and the hidden capsules are the fitted
  body's. A seen keypoint stays as measured.

Tracking states as a ZED reports them: ``OK`` for a person the sensor sees; a person seen before and now hidden
(occluded, missed) is ``SEARCHING`` while the scenario still has them, then ``TERMINATE`` once when they are gone,
then no longer listed. Ids are ``label_id`` 0, 1, … in order of first sight.

On the wire, as the ZED wrapper's node would appear over rmw_zenoh: a node ``zed_emulator`` with one publisher per
sensor, its ``MP`` liveliness token, and rmw_zenoh's attachment (sequence number from 1, source timestamp, GID) on
every sample; the header stamp is the capture time.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import zenoh

from hrc_contract.config import CellConfig, ConfigError, Ros2TrackerInput, TrackerConfig
from hrc_contract.messages import Human, Humans
from hrc_devices.robots.model import pose_to_rotation_translation
from hrc_devices.ros2.rmw_zenoh import Distro, Qos, Ros2Node, Ros2Publisher, typestore
from hrc_devices.trackers import ros2_people
from hrc_devices.trackers.skeletons import ZED_34_NAMES, ZED_38_NAMES
from hrc_runtime.pki import default_pki_dir
from hrc_runtime.zenoh_session import (
    SecurityError,
    SessionOptions,
    check_endpoints,
    endpoint_protocol,
    mutual_tls,
    plain_tcp_allowed,
)
from tracker_emu.body import CAPSULE_NAMES, BodyPose, body_capsules, body_capsules_local

FloatArray = npt.NDArray[np.float64]

NODE_NAME = "zed_emulator"
DEFAULT_FRAME_ID = "zed_left_camera_frame"
"""The frame of the messages when the tracker's ``ros2.frame_id`` names none (the ZED wrapper's default)."""
SENSOR_DATA_QOS = Qos(reliability=2, durability=2, history=1, depth=5)
"""What the publishers announce: rclcpp's sensor-data profile, as the ZED wrapper's body-tracking topic."""
OK, SEARCHING, TERMINATE = 1, 2, 3
BODY_34, BODY_38 = 1, 2
"""``zed_msgs/Object.body_format`` (``sl::BODY_FORMAT``): BODY_34 with body fitting (the SDK offers it only so),
BODY_38 without (the ZED wrapper's default format and fitting)."""
ZED_KEYPOINTS = 70
"""``zed_msgs/Skeleton3D.keypoints`` holds 70; the wrapper leaves those beyond the format's count at zero."""
FLOOR_Z_M = 0.02
"""Height of the feet, toes and heels keypoints above the floor [m]."""


# ------------------------------------------------------------------------------------------- keypoints (pure)

Where = tuple[tuple[str, str], ...]
"""Where a keypoint lies: ``(capsule, end)`` alternatives, the first measured one wins (see :func:`_owners`)."""


def _owners() -> dict[str, Where]:
    """BODY_34 and BODY_38 keypoint name → where it lies on the body model's capsules.

    ``end`` is ``a``, ``b``, ``mid`` (the middle of the axis), ``floor`` (``b`` lowered to the floor), ``tip``
    (``b`` extended by the capsule's radius: the finger tips), ``neck``, ``clavicle``.
    """
    owners: dict[str, Where] = {
        "pelvis": (("pelvis", "mid"),),
        "naval_spine": (("torso", "a"),),
        "chest_spine": (("torso", "b"),),
        "spine_1": (("torso", "a"),),
        "spine_2": (("torso", "mid"),),
        "spine_3": (("torso", "b"),),
        "neck": (("head", "a"), ("torso", "neck")),
        "head": (("head", "b"),),
        "nose": (("head", "mid"),),
    }
    for side, s in (("left", "l"), ("right", "r")):
        hand, shin = f"hand_{s}", f"shin_{s}"
        owners |= {
            f"{side}_clavicle": ((f"upper_arm_{s}", "clavicle"),),
            f"{side}_shoulder": ((f"upper_arm_{s}", "a"),),
            f"{side}_elbow": ((f"upper_arm_{s}", "b"), (f"forearm_{s}", "a")),
            f"{side}_wrist": ((f"forearm_{s}", "b"), (hand, "a")),
            f"{side}_hand": ((hand, "mid"),),
            f"{side}_handtip": ((hand, "tip"),),
            f"{side}_thumb": ((hand, "b"),),
            f"{side}_hand_thumb_4": ((hand, "b"),),
            f"{side}_hand_index_1": ((hand, "mid"),),
            f"{side}_hand_middle_4": ((hand, "tip"),),
            f"{side}_hand_pinky_1": ((hand, "mid"),),
            f"{side}_hip": ((f"thigh_{s}", "a"),),
            f"{side}_knee": ((f"thigh_{s}", "b"), (shin, "a")),
            f"{side}_ankle": ((shin, "b"),),
            f"{side}_foot": ((shin, "floor"),),
            f"{side}_big_toe": ((shin, "floor"),),
            f"{side}_small_toe": ((shin, "floor"),),
            f"{side}_heel": ((shin, "floor"),),
            f"{side}_eye": (("head", "b"),),
            f"{side}_ear": (("head", "b"),),
        }
    return owners


OWNERS = _owners()
"""Where each BODY_34 and BODY_38 keypoint comes from (see :func:`_owners`)."""

Capsules = dict[str, tuple[FloatArray, FloatArray, float]]
"""A person's capsules by name: ``(a, b, radius)`` [m]."""


def _point(capsules: Capsules, capsule: str, end: str) -> FloatArray | None:
    if capsule not in capsules:
        return None
    a, b, radius_m = capsules[capsule]
    if end == "a":
        return a
    if end == "b":
        return b
    if end == "mid":
        return (a + b) / 2.0
    if end == "floor":
        return np.array([b[0], b[1], FLOOR_Z_M])
    if end == "tip":
        axis = b - a
        length = float(np.linalg.norm(axis))
        return b + (axis / length * radius_m if length > 0.0 else 0.0)
    if end == "neck":  # 0.2 m beyond the top of the torso's axis: where the head capsule starts
        return b + (b - a) / max(float(np.linalg.norm(b - a)), 1e-9) * 0.2
    # "clavicle": halfway from the shoulder to the body's midline at shoulder height
    neck = _point(capsules, "head", "a")
    return None if neck is None else (a + np.array([neck[0], neck[1], a[2]])) / 2.0


def by_name(capsules: Iterable[tuple[str, npt.ArrayLike, npt.ArrayLike, float]]) -> Capsules:
    """A person's capsules (name, a, b, radius) [m] as arrays by name."""
    return {n: (np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64), float(r)) for n, a, b, r in capsules}


def zed_keypoints(
    capsules: Iterable[tuple[str, npt.ArrayLike, npt.ArrayLike, float]], names: Sequence[str] = ZED_34_NAMES
) -> FloatArray:
    """A person's keypoints from the capsules a sensor measured (name, a, b, radius) [m].

    Args:
        capsules: the person's measured (or fitted) capsules.
        names: the keypoints, in the format's order: :data:`ZED_34_NAMES` or :data:`ZED_38_NAMES`.

    Returns:
        Shape (len(names), 3), the frame of the capsules; a keypoint none of whose capsules was measured is NaN.
    """
    measured = by_name(capsules)
    keypoints = np.full((len(names), 3), np.nan)
    for k, name in enumerate(names):
        for capsule, end in OWNERS[name]:
            point = _point(measured, capsule, end)
            if point is not None:
                keypoints[k] = point
                break
    return keypoints


# ---------------------------------------------------------------------------------------- body fitting (pure)

FIT_REACH_STEPS = 51
"""Reach values the fit tries, evenly from 0 to 1 (a step of 0.02), each with one and with both arms reaching."""


def _fit_grid() -> tuple[tuple[tuple[float, bool], ...], FloatArray]:
    """The postures the fit tries and their capsule ends in the body frame: shape (G, capsules, 2, 3) [m]."""
    postures = tuple((float(r), both) for both in (False, True) for r in np.linspace(0.0, 1.0, FIT_REACH_STEPS))
    ends = np.array([[(c.a, c.b) for c in body_capsules_local(r, both)] for r, both in postures])
    return postures, ends


FIT_POSTURES, FIT_ENDS_BODY = _fit_grid()
"""The fit's postures ``(reach, both_arms)`` and their capsule ends, body frame (see :func:`_fit_grid`) [m]."""


def fit_pose(measured: Capsules) -> BodyPose:
    """The emulator's body fitted to a person's measured capsules: least squares over their end points [m].

    For each posture of :data:`FIT_POSTURES`, the heading and floor position are the 2D Procrustes solution
    (Umeyama 1991, rotation about the vertical only: the body stands on the floor), ``θ = atan2(Σ p × q, Σ p · q)``
    over the centred floor coordinates; the posture with the least residual (heights included) wins. A body seen only
    along its vertical axis (the head alone) has no heading: θ = 0.

    Args:
        measured: the capsules the sensor saw (names of :data:`CAPSULE_NAMES`; others are ignored), world frame [m].

    Returns:
        The pose whose body best matches them.

    Raises:
        ValueError: no capsule of the body model among them.
    """
    seen = [k for k, name in enumerate(CAPSULE_NAMES) if name in measured]
    if not seen:
        raise ValueError(f"no capsule to fit among {sorted(measured)}; allowed: {', '.join(CAPSULE_NAMES)}")
    q = np.array([measured[CAPSULE_NAMES[k]][:2] for k in seen]).reshape(-1, 3)  # (2 k, 3)
    p = FIT_ENDS_BODY[:, seen].reshape(len(FIT_POSTURES), -1, 3)  # (G, 2 k, 3)
    q_mean, p_mean = q[:, :2].mean(axis=0), p[..., :2].mean(axis=1)
    qc, pc = q[:, :2] - q_mean, p[..., :2] - p_mean[:, None, :]
    theta = np.arctan2(
        (pc[..., 0] * qc[:, 1] - pc[..., 1] * qc[:, 0]).sum(axis=1),
        (pc[..., 0] * qc[:, 0] + pc[..., 1] * qc[:, 1]).sum(axis=1),
    )
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    rotated = np.stack((c * pc[..., 0] - s * pc[..., 1], s * pc[..., 0] + c * pc[..., 1]), axis=-1)
    residual = ((rotated - qc) ** 2).sum(axis=(1, 2)) + ((p[..., 2] - q[:, 2]) ** 2).sum(axis=1)
    best = int(np.argmin(residual))
    cb, sb = float(np.cos(theta[best])), float(np.sin(theta[best]))
    x_m, y_m = q_mean - np.array([[cb, -sb], [sb, cb]]) @ p_mean[best]
    reach, both_arms = FIT_POSTURES[best]
    return BodyPose(float(x_m), float(y_m), float(theta[best]), reach=reach, both_arms=both_arms)


def fitted_capsules(measured: Capsules) -> Capsules:
    """A person's capsules as a fitting tracker gives them: the measured ones, and the hidden ones from the body
    fitted to those (:func:`fit_pose`), world frame [m]."""
    if all(name in measured for name in CAPSULE_NAMES):
        return measured
    fitted = {c.name: (c.a, c.b, c.radius_m) for c in body_capsules(fit_pose(measured)) if c.name not in measured}
    return measured | fitted


# ------------------------------------------------------------------------------------------------- messages


class _Parts:
    """The constant parts of an ``Object`` (zero boxes, 2D skeleton), built once per distro."""

    def __init__(self, distro: Distro) -> None:
        self.store = typestore(distro)
        T = self.store.types
        self.T = T
        kp3, kp2, kp2i = T["zed_msgs/msg/Keypoint3D"], T["zed_msgs/msg/Keypoint2Df"], T["zed_msgs/msg/Keypoint2Di"]
        self.kp3 = kp3
        self.box3 = T["zed_msgs/msg/BoundingBox3D"](corners=[kp3(kp=np.zeros(3, np.float32)) for _ in range(8)])
        self.box2i = T["zed_msgs/msg/BoundingBox2Di"](corners=[kp2i(kp=np.zeros(2, np.uint32)) for _ in range(4)])
        self.box2f = T["zed_msgs/msg/BoundingBox2Df"](corners=[kp2(kp=np.zeros(2, np.float32)) for _ in range(4)])
        self.skeleton_2d = T["zed_msgs/msg/Skeleton2D"](
            keypoints=[kp2(kp=np.zeros(2, np.float32)) for _ in range(ZED_KEYPOINTS)]
        )
        self.zero3 = np.zeros(3, np.float32)


def zed_object(
    parts: _Parts,
    label_id: int,
    state: int,
    position_m: FloatArray,
    std_m: float,
    keypoints_m: FloatArray | None,
    body_format: int = BODY_34,
) -> Any:
    """One ``zed_msgs/Object`` as the ZED wrapper fills it for a body (keypoints of ``body_format``, or none: not
    available)."""
    T = parts.T
    full = np.zeros((ZED_KEYPOINTS, 3), dtype=np.float32)
    if keypoints_m is not None:
        full[: len(keypoints_m)] = keypoints_m
    variance = np.float32(std_m**2)
    return T["zed_msgs/msg/Object"](
        label="Person",
        label_id=label_id,
        sublabel="Body",
        confidence=90.0 if state == OK else 10.0,
        position=np.asarray(position_m, dtype=np.float32),
        position_covariance=np.array([variance, 0, 0, variance, 0, variance], dtype=np.float32),
        velocity=parts.zero3,
        tracking_available=True,
        tracking_state=state,
        action_state=0,
        bounding_box_2d=parts.box2i,
        bounding_box_3d=parts.box3,
        dimensions_3d=parts.zero3,
        skeleton_available=keypoints_m is not None,
        body_format=body_format,
        head_bounding_box_2d=parts.box2f,
        head_bounding_box_3d=parts.box3,
        head_position=parts.zero3,
        skeleton_2d=parts.skeleton_2d,
        skeleton_3d=T["zed_msgs/msg/Skeleton3D"](keypoints=[parts.kp3(kp=full[i]) for i in range(ZED_KEYPOINTS)]),
    )


@dataclass
class ZedSensor:
    """One emulated ZED: measured frames → ``ObjectsStamped`` CDR in its own frame, with its tracks' states.

    Args:
        source: the tracker's ROS 2 input (its pose in the world: the inverse placement; its frame id; whether the
            camera fits bodies, ``enable_body_fitting``: BODY_34 with hidden keypoints estimated, else BODY_38 with
            them NaN).
        noise_std_m: the emulated noise, stated as the position covariance.
        distro: whose definitions serialise the messages.
    """

    source: Ros2TrackerInput
    noise_std_m: float
    distro: Distro
    labels: dict[str, int] = field(default_factory=dict)
    """The ``label_id`` of each person seen so far."""
    positions: dict[str, FloatArray] = field(default_factory=dict)
    """Where each person not terminated was last seen, sensor frame [m]."""

    def __post_init__(self) -> None:
        self.R_world_sensor, self.p_world_sensor = pose_to_rotation_translation(self.source.sensor_pose_world)
        self.parts = _Parts(self.distro)
        self.body_format = BODY_34 if self.source.enable_body_fitting else BODY_38
        self.names = ZED_34_NAMES if self.source.enable_body_fitting else ZED_38_NAMES

    def keypoints(self, human: Human) -> FloatArray:
        """One measured person's keypoints in the sensor's frame: hidden ones fitted or NaN (see the module) [m]."""
        capsules = by_name((c.name, c.a, c.b, c.radius) for c in human.capsules)
        if self.source.enable_body_fitting:
            capsules = fitted_capsules(capsules)
        keypoints = zed_keypoints(((n, a, b, r) for n, (a, b, r) in capsules.items()), self.names)
        return self.to_sensor(keypoints)  # NaN rows stay NaN

    def to_sensor(self, points_world_m: FloatArray) -> FloatArray:
        """World points (…, 3) in the sensor's frame: ``R_world_sensorᵀ (p − p_world_sensor)`` [m]."""
        return (points_world_m - self.p_world_sensor) @ self.R_world_sensor

    def objects(self, message: Humans, present_ids: Iterable[str]) -> bytes:
        """The CDR bytes of one measured frame (``message``: what the sensor sees, world frame), stamped with its
        capture time; ``present_ids``: who the scenario has now (a hidden person among them is SEARCHING)."""
        parts = self.parts
        objects = []
        seen = set()
        for human in message.humans:
            keypoints = self.keypoints(human)
            position = np.nanmean(keypoints, axis=0)
            label = self.labels.setdefault(human.id, len(self.labels))
            self.positions[human.id] = position
            seen.add(human.id)
            objects.append(zed_object(parts, label, OK, position, self.noise_std_m, keypoints, self.body_format))
        present = set(present_ids)
        for person, position in list(self.positions.items()):
            if person in seen:
                continue
            state = SEARCHING if person in present else TERMINATE
            objects.append(
                zed_object(parts, self.labels[person], state, position, self.noise_std_m, None, self.body_format)
            )
            if state == TERMINATE:
                del self.positions[person]
        sec, nanosec = divmod(message.stamp_ns, 1_000_000_000)
        T = parts.T
        header = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
            frame_id=self.source.frame_id or DEFAULT_FRAME_ID,
        )
        msg = T[ros2_people.ZED_OBJECTS](header=header, objects=objects)
        return bytes(parts.store.serialize_cdr(msg, ros2_people.ZED_OBJECTS))


# ---------------------------------------------------------------------------------------------------- transport


def zed_sources(config: CellConfig, trackers: Mapping[str, TrackerConfig]) -> dict[str, Ros2TrackerInput]:
    """The ROS 2 input of each tracker to play as a ZED.

    Raises:
        ConfigError: a tracker without a ``zed_objects`` ROS 2 input, or ``[ros2]`` without endpoints.
    """
    wrong = [n for n, t in trackers.items() if t.ros2 is None or t.ros2.format != "zed_objects"]
    if wrong:
        raise ConfigError(
            f"--publish zed: tracker(s) {', '.join(wrong)} have no ros2 input of format zed_objects; allowed: "
            'trackers with [trackers.<name>.ros2] format = "zed_objects"'
        )
    if not (config.ros2.listen or config.ros2.connect):
        raise ConfigError("--publish zed: [ros2] has no endpoints; allowed: listen or connect endpoints")
    return {name: t.ros2 for name, t in trackers.items() if t.ros2 is not None}


def with_body_fitting(trackers: Mapping[str, TrackerConfig], enabled: bool) -> dict[str, TrackerConfig]:
    """The trackers with their ZED inputs' ``enable_body_fitting`` set to ``enabled`` (``--zed-body-fitting``);
    trackers without a ROS 2 input unchanged."""
    return {
        name: t
        if t.ros2 is None
        else t.model_copy(update={"ros2": t.ros2.model_copy(update={"enable_body_fitting": enabled})})
        for name, t in trackers.items()
    }


def ros2_endpoints(config: CellConfig) -> list[str]:
    """Where the emulator's ROS 2 session connects: the gateway's ROS 2 listen endpoints, else its router's."""
    return list(config.ros2.listen or config.ros2.connect)


def ros2_session_options(args: argparse.Namespace, endpoints: Sequence[str]) -> SessionOptions:
    """The ROS 2 session's options: mutual TLS as the emulator (``tracker-emu``) for ``tls/`` endpoints, else plain
    TCP on loopback with ``--insecure-plain-tcp`` (the emulator puts people into the cell).

    Raises:
        SecurityError: plain TCP without the flag, or off loopback.
    """
    if endpoints and all(endpoint_protocol(e) == "tls" for e in endpoints):
        pki_dir = Path(args.pki_dir) if getattr(args, "pki_dir", None) else default_pki_dir()
        return SessionOptions("peer", mutual_tls(pki_dir, "tracker-emu", None))
    if not plain_tcp_allowed(args):
        raise SecurityError(
            f"ROS 2 endpoints {', '.join(endpoints)} are plain TCP; allowed: tls/ endpoints, or --insecure-plain-tcp"
        )
    options = SessionOptions("peer")
    check_endpoints(endpoints, options)
    return options


class ZedPublishers:
    """One ZED publisher per sensor on a ROS 2 session: a node, ``MP`` tokens, attachments with sequence numbers.

    Args:
        session: an open Zenoh session on the ROS 2 side (the caller closes it, after :meth:`close`).
        config: the cell (``[ros2]``: domain, distro, namespace).
        sources: each sensor's ROS 2 input (:func:`zed_sources`).
        noise_std_m: each sensor's noise (stated in the position covariance) [m].
    """

    def __init__(
        self,
        session: zenoh.Session,
        config: CellConfig,
        sources: Mapping[str, Ros2TrackerInput],
        noise_std_m: Mapping[str, float],
    ) -> None:
        ros2 = config.ros2
        distro: Distro = ros2.distro
        self.node = Ros2Node(session, NODE_NAME, ros2.namespace, ros2.domain_id, distro)
        self.sensors: dict[str, ZedSensor] = {}
        self.publishers: dict[str, Ros2Publisher] = {}
        for name, source in sorted(sources.items()):
            self.sensors[name] = ZedSensor(source, noise_std_m[name], distro)
            self.publishers[name] = self.node.create_publisher(source.topic, ros2_people.ZED_OBJECTS, SENSOR_DATA_QOS)

    def publish(self, tracker: str, message: Humans, present_ids: Iterable[str]) -> None:
        """Put one measured frame of ``tracker`` as ObjectsStamped, with the next sequence number."""
        self.publishers[tracker].put(self.sensors[tracker].objects(message, present_ids))

    def close(self) -> None:
        """Undeclare the publishers, their tokens and the node's (idempotent)."""
        self.node.close()
