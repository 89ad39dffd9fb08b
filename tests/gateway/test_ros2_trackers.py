"""ROS 2 body trackers at the gateway: rmw_zenoh samples built by rosbags → skeleton capsules → the same door.

Accepted frames carry the attachment's sequence number and the header's capture stamp; hostile ROS input (malformed
CDR, a wrong type hash, a missing attachment, absurd keypoints, stamps in the future or backwards, another frame) is
counted by reason and faults the tracker (δ = 0), never raising.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from support.paths import REPO_ROOT
from support.skeleton_poses import standing_keypoints

from gateway.inputs import InputStore
from gateway.ros2_trackers import (
    SampleCounts,
    TrackerSubscription,
    check_ros2_inputs,
    placement_of,
    tracker_subscriptions,
    tracker_topics,
)
from hrc_contract.config import CellConfig, ConfigError, Pose, Ros2TrackerInput
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import RobotModel
from hrc_devices.ros2.rmw_zenoh import (
    HUMBLE_TYPE_HASH,
    Attachment,
    Distro,
    encode_attachment,
    topic_key,
    topic_type,
    typestore,
)
from hrc_devices.trackers import ros4hri_body
from hrc_devices.trackers.ros2_people import IDS_LIST, ZED_OBJECTS
from hrc_devices.trackers.ros4hri_body import JOINT_NAMES, JOINT_STATE, TF_MESSAGE
from hrc_devices.trackers.skeletons import COMPILED, ZED_34_NAMES
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import PLAIN_TCP_LOOPBACK, SecurityError, SessionOptions

NOW = 1_790_000_000_000_000_000
MONO0 = 5_000_000_000
MS = 1_000_000
GID = bytes(range(16))
ZED_34 = COMPILED["zed_body_34"]
CELL_FILE = REPO_ROOT / "configs" / "cell_ros2_zed.toml"


@pytest.fixture(scope="module")
def config() -> CellConfig:
    return load_cell_config(CELL_FILE)


def at(t_ns: int = NOW) -> Clocks:
    return Clocks(t_ns, MONO0 + t_ns - NOW)


# -- ZED messages, built by rosbags from the vendored zed_msgs definitions ----------------------------------------


def zed_object(types: Any, label_id: int, keypoints: np.ndarray, state: int = 1, position: Any = None) -> Any:
    kp3, kp2, kp2i = (
        types["zed_msgs/msg/Keypoint3D"],
        types["zed_msgs/msg/Keypoint2Df"],
        types["zed_msgs/msg/Keypoint2Di"],
    )
    full = np.zeros((70, 3), dtype=np.float32)
    full[: len(keypoints)] = keypoints
    box3 = types["zed_msgs/msg/BoundingBox3D"](corners=[kp3(kp=np.zeros(3, np.float32)) for _ in range(8)])
    return types["zed_msgs/msg/Object"](
        label="Person", label_id=label_id, sublabel="", confidence=90.0,
        position=np.asarray(np.nanmean(keypoints, axis=0) if position is None else position, dtype=np.float32),
        position_covariance=np.array([1e-4, 0, 0, 1e-4, 0, 1e-4], dtype=np.float32),
        velocity=np.zeros(3, np.float32), tracking_available=True, tracking_state=state, action_state=0,
        bounding_box_2d=types["zed_msgs/msg/BoundingBox2Di"](corners=[kp2i(kp=np.zeros(2, np.uint32))] * 4),
        bounding_box_3d=box3, dimensions_3d=np.zeros(3, np.float32), skeleton_available=True, body_format=1,
        head_bounding_box_2d=types["zed_msgs/msg/BoundingBox2Df"](corners=[kp2(kp=np.zeros(2, np.float32))] * 4),
        head_bounding_box_3d=box3, head_position=np.zeros(3, np.float32),
        skeleton_2d=types["zed_msgs/msg/Skeleton2D"](keypoints=[kp2(kp=np.zeros(2, np.float32))] * 70),
        skeleton_3d=types["zed_msgs/msg/Skeleton3D"](keypoints=[kp3(kp=full[i]) for i in range(70)]),
    )  # fmt: skip


def zed_bytes(
    objects: list[tuple[int, np.ndarray]] | None = None,
    stamp_ns: int = NOW - 30 * MS,
    frame_id: str = "front_left_camera_frame",
    distro: Distro = "jazzy",
    states: dict[int, int] | None = None,
) -> bytes:
    """An ObjectsStamped of BODY_34 people (label, keypoints in the message's frame)."""
    store = typestore(distro)
    T = store.types
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
    )
    people = [(1, standing_keypoints(ZED_34, 2.0, 0.0))] if objects is None else objects
    built = [zed_object(T, label, kp, (states or {}).get(label, 1)) for label, kp in people]
    return bytes(store.serialize_cdr(T[ZED_OBJECTS](header=header, objects=built), ZED_OBJECTS))


def attachment(seq: int, stamp_ns: int = NOW) -> bytes:
    return encode_attachment(Attachment(seq, stamp_ns, GID))


class Rig:
    """The front tracker's subscription feeding a real InputStore, with a fake arrival clock."""

    def __init__(self, config: CellConfig, ur5: RobotModel, identity: bool = True) -> None:
        if identity:  # the messages' frame is the world: keypoints as given
            front = config.trackers["front"]
            assert front.ros2 is not None
            ros2 = front.ros2.model_copy(update={"sensor_pose_world": Pose()})
            trackers = dict(config.trackers) | {"front": front.model_copy(update={"ros2": ros2})}
            config = config.model_copy(update={"trackers": trackers})
        self.config = config
        self.store = InputStore(config, {"ur5": ur5})
        self.now = NOW
        self.clock_reads: list[int] = []
        self.subscription: TrackerSubscription = tracker_subscriptions(
            config, self.store.on_humans, self.store.count_rejection
        )["front"]
        self.subscription.clock = self._clock
        wire = self.subscription.wire
        self.key = f"0/front/zed_node/body_trk/skeletons/{wire.dds_name}/{wire.type_hash}"

    def _clock(self) -> Clocks:
        self.clock_reads.append(self.now)
        return at(self.now)

    def feed(self, payload: bytes, seq: int, key: str | None = None, attached: bytes | bool | None = True) -> None:
        extra = attachment(seq) if attached is True else (None if attached is False else attached)
        self.subscription.on_sample(key or self.key, payload, extra)

    def rejected(self) -> dict[str, int]:
        return self.store.counters()[0].get("tracker/front", {})

    def fault(self) -> str | None:
        fault = self.store.snapshot(at(self.now)).faults.get("tracker/front")
        return None if fault is None else fault.code

    def capsules(self) -> HumanCapsules:
        frame = self.store.snapshot(at(self.now)).humans["front"]
        assert frame is not None
        return frame.capsules


def inside(capsules: HumanCapsules, points: np.ndarray) -> np.ndarray:
    """Which points lie in some capsule."""
    out = np.zeros(len(points), dtype=bool)
    for a, b, r in zip(capsules.h_a_world, capsules.h_b_world, capsules.radius_m, strict=True):
        axis = b - a
        t = np.clip((points - a) @ axis / max(float(axis @ axis), 1e-12), 0.0, 1.0)
        out |= np.linalg.norm(points - (a + t[:, None] * axis), axis=1) <= r + 1e-9
    return out


# -- accepted frames -------------------------------------------------------------------------------------------


def test_a_zed_frame_passes_the_door_with_the_attachment_seq_and_the_capture_stamp(
    config: CellConfig, ur5: RobotModel
) -> None:
    rig = Rig(config, ur5)
    keypoints = standing_keypoints(ZED_34, 2.0, 0.5)
    rig.feed(zed_bytes([(7, keypoints)], stamp_ns=NOW - 40 * MS), seq=12)
    assert rig.rejected() == {}
    assert rig.fault() is None
    frame = rig.store.snapshot(at()).humans["front"]
    assert frame is not None
    assert (frame.seq, frame.stamp_ns, frame.human_count) == (12, NOW - 40 * MS, 1)
    assert frame.transit_ns == 40 * MS  # received at arrival, before the conversion: its cost counts in the age
    assert rig.clock_reads == [NOW]
    assert set(frame.capsules.human_ids) == {"front/7"}
    assert inside(frame.capsules, keypoints).all()


def test_the_sensor_pose_moves_the_skeleton_into_the_world(config: CellConfig, ur5: RobotModel) -> None:
    rig = Rig(config, ur5, identity=False)  # front: at (3.5, 0, 2.2), facing -x, pitched down
    source = config.trackers["front"].ros2
    assert source is not None
    world = standing_keypoints(ZED_34, 1.5, -0.5)
    placement = placement_of(source.sensor_pose_world)
    in_sensor = (world - placement.p_world_sensor) @ placement.R_world_sensor
    rig.feed(zed_bytes([(1, in_sensor)]), seq=1)
    assert rig.rejected() == {}
    capsules = rig.capsules()
    assert inside(capsules, world).all()
    assert capsules.h_a_world[:, 2].min() > 0.0
    assert capsules.h_b_world[:, 2].max() < 2.0


def test_a_hidden_arm_is_a_large_capsule_the_trackers_own_limit_lets_through(
    config: CellConfig, ur5: RobotModel
) -> None:
    keypoints = standing_keypoints(ZED_34, 2.0, 0.0)
    hidden = [ZED_34_NAMES.index(n) for n in ZED_34_NAMES if n.startswith("left_") and "hip" not in n]
    keypoints[hidden] = np.nan  # the left arm and leg unseen: reach spheres from the neck and the pelvis
    rig = Rig(config, ur5)
    rig.feed(zed_bytes([(1, keypoints)]), seq=1)
    assert rig.rejected() == {}
    capsules = rig.capsules()
    assert capsules.radius_m.max() > config.plausibility.max_capsule_radius_m  # the cell's limit would refuse it
    # The choice made: with the cell's own limits for this tracker the door refuses the frame (δ = 0 whenever a
    # hand is hidden); a large capsule only lowers δ, so the tracker gets limits that fit a skeleton.
    source = config.trackers["front"].ros2
    assert source is not None
    strict = source.model_copy(update={"max_capsule_radius_m": config.plausibility.max_capsule_radius_m})
    trackers = dict(config.trackers) | {"front": config.trackers["front"].model_copy(update={"ros2": strict})}
    rig_strict = Rig(config.model_copy(update={"trackers": trackers}), ur5)
    rig_strict.feed(zed_bytes([(1, keypoints)]), seq=1)
    assert rig_strict.rejected() == {"radius_too_large": 1}
    assert rig_strict.fault() == "tracker_implausible"


def test_searching_people_are_left_out_of_the_frame(config: CellConfig, ur5: RobotModel) -> None:
    rig = Rig(config, ur5)
    people = [(1, standing_keypoints(ZED_34, 2.0, 0.0)), (2, standing_keypoints(ZED_34, 3.0, 1.0))]
    rig.feed(zed_bytes(people, states={2: 2}), seq=1)
    assert rig.rejected() == {}
    assert set(rig.capsules().human_ids) == {"front/1"}  # the tracks keep person 2 as lost


# -- hostile ROS input -----------------------------------------------------------------------------------------


def _hostile_cases(rig: Rig) -> dict[str, tuple[bytes, str | None, bytes | bool | None]]:
    good = zed_bytes()
    absurd = standing_keypoints(ZED_34, 2.0, 0.0)
    absurd[5] = (1e6, 0.0, 1.0)
    wire = rig.subscription.wire
    return {
        "not_cdr": (good[: len(good) // 2], None, True),
        "wrong_type_hash": (good, rig.key.replace(wire.type_hash, HUMBLE_TYPE_HASH), True),
        "wrong_type": (good, rig.key.replace(wire.dds_name, "std_msgs::msg::dds_::String_"), True),
        "no_attachment": (good, None, False),
        "attachment_malformed": (good, None, b"\x01\x02"),
        "absurd_keypoint": (zed_bytes([(1, absurd)]), None, True),
        "wrong_frame": (zed_bytes(frame_id="base_link"), None, True),
        "stamp_in_future": (zed_bytes(stamp_ns=NOW + 500 * MS), None, True),
        "outside_world": (zed_bytes([(1, standing_keypoints(ZED_34, 30.0, 0.0))]), None, True),
    }


@pytest.mark.parametrize(
    "reason",
    ["not_cdr", "wrong_type_hash", "wrong_type", "no_attachment", "attachment_malformed", "absurd_keypoint",
     "wrong_frame", "stamp_in_future", "outside_world"],
)  # fmt: skip
def test_hostile_ros_input_is_counted_and_faults_the_tracker(config: CellConfig, ur5: RobotModel, reason: str) -> None:
    rig = Rig(config, ur5)
    rig.feed(zed_bytes(stamp_ns=NOW - 60 * MS), seq=1)  # a valid frame first: the fault must stop a running cell
    assert rig.fault() is None
    payload, key, extra = _hostile_cases(rig)[reason]
    rig.now += 10 * MS
    rig.feed(payload, seq=2, key=key, attached=extra)
    assert rig.rejected() == {reason: 1}
    assert rig.fault() is not None  # a tracker fault: δ = 0 for every robot (gateway.core)
    frame = rig.store.snapshot(at(rig.now)).humans["front"]
    assert frame is not None
    assert frame.seq == 1


def test_a_stamp_backwards_faults_the_tracker(config: CellConfig, ur5: RobotModel) -> None:
    rig = Rig(config, ur5)
    rig.feed(zed_bytes(stamp_ns=NOW - 30 * MS), seq=1)
    rig.feed(zed_bytes(stamp_ns=NOW - 60 * MS), seq=2)
    assert rig.rejected() == {"stamp_backwards": 1}
    assert rig.fault() == "tracker_out_of_order"


def test_fuzzed_samples_never_raise_and_are_all_refused(config: CellConfig, ur5: RobotModel) -> None:
    rig = Rig(config, ur5)
    good = zed_bytes()
    rng = np.random.default_rng(20)
    for seq in range(1, 201):
        data = bytearray(good)
        for i in rng.integers(4, len(data), size=int(rng.integers(1, 20))):
            data[i] = int(rng.integers(0, 256))
        cut = int(rng.integers(0, len(data) + 1)) if seq % 2 else len(data)
        rig.feed(bytes(data[:cut]), seq=seq)  # never raises
    refused = rig.subscription.counts()
    assert refused.converted + sum(refused.refused.values()) == 200
    assert "internal_error" not in refused.refused


# -- start-up ----------------------------------------------------------------------------------------------------


def test_ros2_trackers_on_plain_tcp_need_the_insecure_flag(config: CellConfig) -> None:
    with pytest.raises(SecurityError, match="plain TCP"):
        check_ros2_inputs(config, PLAIN_TCP_LOOPBACK, plain_tcp_allowed=False)
    check_ros2_inputs(config, PLAIN_TCP_LOOPBACK, plain_tcp_allowed=True)
    check_ros2_inputs(config, SessionOptions(), plain_tcp_allowed=True)


def test_a_ros2_tracker_without_the_ros2_section_is_refused(config: CellConfig) -> None:
    raw = config.model_dump(mode="json")
    raw["ros2"]["enabled"] = False
    with pytest.raises(ValueError, match=r"read ROS 2 but \[ros2\] is not enabled"):
        CellConfig.model_validate(raw)


def test_the_wire_type_is_rosbags_hash_of_the_zed_definitions(config: CellConfig) -> None:
    subscription = tracker_subscriptions(config, lambda *_: None, lambda *_: None)["front"]
    assert subscription.wire == topic_type("jazzy", ZED_OBJECTS)
    assert subscription.wire.type_hash.startswith("RIHS01_")
    with pytest.raises(ConfigError):
        topic_type("jazzy", "zed_msgs/msg/NoSuchType")


# -- ROS4HRI bodies: the tracked list, per body joint states and the body frame on /tf ---------------------------

BODY = "ukxbg"
CAMERA = "camera_color_optical_frame"
UNIT_Q = (0.0, 0.0, 0.0, 1.0)


def _header(frame_id: str, stamp_ns: int) -> Any:
    store = typestore("jazzy")
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return store.types["std_msgs/msg/Header"](
        stamp=store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
    )


def ids_bytes(ids: list[str], stamp_ns: int) -> bytes:
    store = typestore("jazzy")
    return bytes(store.serialize_cdr(store.types[IDS_LIST](header=_header(CAMERA, stamp_ns), ids=ids), IDS_LIST))


def joint_state_bytes(angles: dict[str, float], stamp_ns: int, body_id: str = BODY) -> bytes:
    store = typestore("jazzy")
    msg = store.types[JOINT_STATE](
        header=_header(CAMERA, stamp_ns), name=[f"{j}_{body_id}" for j in angles],
        position=np.array(list(angles.values()), dtype=np.float64), velocity=np.zeros(0), effort=np.zeros(0),
    )  # fmt: skip
    return bytes(store.serialize_cdr(msg, JOINT_STATE))


def tf_bytes(stamp_ns: int, xyz: tuple[float, float, float], parent: str = CAMERA, q: Any = UNIT_Q) -> bytes:
    store = typestore("jazzy")
    T = store.types
    transform = T["geometry_msgs/msg/TransformStamped"](
        header=_header(parent, stamp_ns), child_frame_id=f"body_{BODY}",
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )  # fmt: skip
    return bytes(store.serialize_cdr(T[TF_MESSAGE](transforms=[transform]), TF_MESSAGE))


def straight(**angles: float) -> dict[str, float]:
    return {name: angles.get(name, 0.0) for name in JOINT_NAMES}


class HriRig(Rig):
    """The front tracker as a ROS4HRI body tracker (its camera frame is the world), feeding a real InputStore."""

    def __init__(self, config: CellConfig, ur5: RobotModel, **source: Any) -> None:
        ros4hri = Ros2TrackerInput(format="ros4hri_bodies", topic="/humans/bodies/tracked", frame_id=CAMERA, **source)
        trackers = dict(config.trackers) | {"front": config.trackers["front"].model_copy(update={"ros2": ros4hri})}
        super().__init__(config.model_copy(update={"trackers": trackers}), ur5, identity=False)
        tracked, joint_states, tf = tracker_topics(self.config)["front"]
        self.key = topic_key(0, tracked.fq_name, tracked.wire)
        self.tf_key = topic_key(0, tf.fq_name, tf.wire)
        self.js_wire = joint_states.wire
        self.seq = 0
        self.height_m = ros4hri_body.DEFAULT_HEIGHT_M

    def js_key(self, body_id: str = BODY) -> str:
        return topic_key(0, f"/humans/bodies/{body_id}/joint_states", self.js_wire)

    def body(self, stamp_ns: int, angles: dict[str, float] | None = None, xyz: Any = (2.0, 0.5, None)) -> None:
        """What hri_fullbody publishes for one image: the body frame, the joint states, then the tracked list."""
        x, y, z = xyz
        self.seq += 1
        self.feed(tf_bytes(stamp_ns, (x, y, self.height_m * 3.5 / 7.5 if z is None else z)), self.seq, self.tf_key)
        self.feed(joint_state_bytes(straight() if angles is None else angles, stamp_ns), self.seq, self.js_key())
        self.feed(ids_bytes([BODY], stamp_ns), self.seq, self.key)


def test_a_ros4hri_body_passes_the_door_as_the_capsules_of_its_model(config: CellConfig, ur5: RobotModel) -> None:
    rig = HriRig(config, ur5)
    angles = straight(l_p_shoulder=1.5, r_elbow=1.0, waist=0.3, l_knee=-0.4)
    rig.body(NOW - 40 * MS, angles)
    assert rig.rejected() == {}
    assert rig.fault() is None
    frame = rig.store.snapshot(at()).humans["front"]
    assert frame is not None
    assert (frame.seq, frame.stamp_ns, frame.human_count) == (1, NOW - 40 * MS, 1)
    assert set(frame.capsules.human_ids) == {f"front/{BODY}"}
    human = ros4hri_body.build_human_model()
    keypoints, seen = ros4hri_body.body_keypoints(human, angles)
    assert seen.all()
    assert inside(frame.capsules, keypoints + np.array([2.0, 0.5, rig.height_m * 3.5 / 7.5])).all()
    assert rig.subscription.counts() == SampleCounts(1, {}, 2)


def test_the_camera_pose_moves_the_body_into_the_world(config: CellConfig, ur5: RobotModel) -> None:
    pose = Pose(xyz=(3.0, 0.0, 2.0), rpy=(0.0, 0.0, math.pi))
    rig = HriRig(config, ur5, sensor_pose_world=pose)
    rig.body(NOW - 30 * MS, xyz=(1.0, 0.0, -1.0))  # 1 m ahead of the camera, hips 1 m below it
    assert rig.rejected() == {}
    capsules = rig.capsules()
    centre = (capsules.h_a_world + capsules.h_b_world).mean(axis=0) / 2
    assert centre[0] == pytest.approx(2.0, abs=0.1)  # the camera faces -x from x = 3
    assert capsules.h_a_world[:, 2].min() == pytest.approx(1.0 - rig.height_m * 3.5 / 7.5, abs=1e-9)


def test_a_listed_body_without_fresh_joint_states_is_lost_not_gone(config: CellConfig, ur5: RobotModel) -> None:
    rig = HriRig(config, ur5)
    rig.now = NOW - 480 * MS
    rig.feed(tf_bytes(NOW - 500 * MS, (2.0, 0.0, 0.9)), 1, rig.tf_key)
    rig.feed(ids_bytes([BODY], NOW - 500 * MS), 1, rig.key)  # listed, no joint states yet
    assert rig.rejected() == {}
    frame = rig.store.snapshot(at(rig.now)).humans["front"]
    assert frame is not None
    assert (frame.seq, frame.human_count) == (1, 0)
    # newer than the last frame, but 390 ms older than the next list (max_body_age_s = 0.2)
    rig.feed(joint_state_bytes(straight(), NOW - 450 * MS), 2, rig.js_key())
    rig.now = NOW
    rig.feed(tf_bytes(NOW - 60 * MS, (2.0, 0.0, 0.9)), 2, rig.tf_key)
    rig.feed(ids_bytes([BODY], NOW - 60 * MS), 2, rig.key)
    assert rig.rejected() == {}
    frame = rig.store.snapshot(at(rig.now)).humans["front"]
    assert frame is not None
    assert (frame.seq, frame.human_count) == (2, 0)
    rig.seq = 2
    rig.body(NOW - 30 * MS)
    assert rig.rejected() == {}
    assert set(rig.capsules().human_ids) == {f"front/{BODY}"}


def test_data_a_frame_used_does_not_stamp_the_next(config: CellConfig, ur5: RobotModel) -> None:
    rig = HriRig(config, ur5)
    rig.body(NOW - 60 * MS)
    rig.feed(ids_bytes([BODY], NOW - 30 * MS), 2, rig.key)  # a list without new joint states: the body is lost
    assert rig.rejected() == {}  # no stamp_backwards: the frame is stamped with the list
    frame = rig.store.snapshot(at()).humans["front"]
    assert frame is not None
    assert (frame.seq, frame.stamp_ns, frame.human_count) == (2, NOW - 30 * MS, 0)


def test_a_placed_body_whose_waist_goes_missing_is_left_out_as_lost_not_a_fault(
    config: CellConfig, ur5: RobotModel
) -> None:
    rig = HriRig(config, ur5)
    rig.body(NOW - 60 * MS, straight(l_p_shoulder=1.5))
    no_waist = straight(l_p_shoulder=1.5)
    del no_waist["waist"]
    rig.body(NOW - 30 * MS, no_waist)
    assert rig.rejected() == {}
    assert rig.fault() is None
    frame = rig.store.snapshot(at()).humans["front"]
    assert frame is not None
    assert (frame.seq, frame.human_count) == (2, 0)  # not a whole-body column: lost at the gateway's tracks
    rig.body(NOW - 10 * MS, straight())
    assert set(rig.capsules().human_ids) == {f"front/{BODY}"}


def _hri_hostile(rig: HriRig) -> dict[str, tuple[bytes, str, bytes | bool | None]]:
    stamp = NOW - 20 * MS
    js = joint_state_bytes(straight(), stamp)
    humble_js = rig.js_key().replace(rig.js_wire.type_hash, HUMBLE_TYPE_HASH)
    return {
        "unknown_joint": (joint_state_bytes({"l_ankle": 0.0}, stamp), rig.js_key(), True),
        "joint_out_of_limits": (joint_state_bytes(straight(l_elbow=-1.0), stamp), rig.js_key(), True),
        "non_finite": (joint_state_bytes(straight(waist=float("nan")), stamp), rig.js_key(), True),
        "wrong_type_hash": (js, humble_js, True),
        "no_attachment": (js, rig.js_key(), False),
        "wrong_frame": (tf_bytes(stamp, (2.0, 0.0, 0.9), parent="base_link"), rig.tf_key, True),
        "bad_quaternion": (tf_bytes(stamp, (2.0, 0.0, 0.9), q=(0.0, 0.0, 0.0, 0.5)), rig.tf_key, True),
        "absurd_keypoint": (tf_bytes(stamp, (2.0, 0.0, 1e9)), rig.tf_key, True),
        "not_cdr": (ids_bytes([BODY], stamp)[:9], rig.key, True),
        "wrong_topic": (js, rig.js_key().replace("joint_states", "skeleton2d"), True),
    }


@pytest.mark.parametrize(
    "reason",
    ["unknown_joint", "joint_out_of_limits", "non_finite", "wrong_type_hash", "no_attachment", "wrong_frame",
     "bad_quaternion", "absurd_keypoint", "not_cdr", "wrong_topic"],
)  # fmt: skip
def test_hostile_ros4hri_input_is_counted_and_faults_the_tracker(
    config: CellConfig, ur5: RobotModel, reason: str
) -> None:
    rig = HriRig(config, ur5)
    rig.body(NOW - 60 * MS)
    assert rig.fault() is None
    payload, key, extra = _hri_hostile(rig)[reason]
    rig.now += 10 * MS
    rig.feed(payload, seq=5, key=key, attached=extra)
    assert rig.rejected() == {reason: 1}
    assert rig.fault() is not None  # a tracker fault: δ = 0 for every robot (gateway.core)


def test_fuzzed_ros4hri_samples_never_raise_and_are_all_counted(config: CellConfig, ur5: RobotModel) -> None:
    rig = HriRig(config, ur5)
    rng = np.random.default_rng(155)
    streams = [
        (rig.tf_key, tf_bytes(NOW - 30 * MS, (2.0, 0.0, 0.9))),
        (rig.js_key(), joint_state_bytes(straight(), NOW - 30 * MS)),
        (rig.key, ids_bytes([BODY, "other"], NOW - 30 * MS)),
    ]
    for seq in range(1, 301):
        key, good = streams[seq % 3]
        data = bytearray(good)
        for i in rng.integers(4, len(data), size=int(rng.integers(1, 20))):
            data[i] = int(rng.integers(0, 256))
        cut = int(rng.integers(0, len(data) + 1)) if seq % 2 else len(data)
        rig.feed(bytes(data[:cut]), seq=seq, key=key)  # never raises
    counts = rig.subscription.counts()
    assert counts.converted + counts.kept + sum(counts.refused.values()) == 300
    assert "internal_error" not in counts.refused


def test_a_ros4hri_tracker_reads_three_topics(config: CellConfig, ur5: RobotModel) -> None:
    rig = HriRig(config, ur5)
    topics = tracker_topics(rig.config)["front"]
    assert [(t.fq_name, t.wire.msgtype, t.announced) for t in topics] == [
        ("/humans/bodies/tracked", IDS_LIST, True),
        ("/humans/bodies/*/joint_states", JOINT_STATE, False),
        ("/tf", TF_MESSAGE, True),
    ]
    assert all(t.wire == topic_type("jazzy", t.wire.msgtype) for t in topics)
