"""ROS 2 body-tracker messages, serialised by ``rosbags`` from the publishers' own definitions → people → capsules."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from support.skeleton_poses import standing_keypoints

from hrc_contract.messages import MessageError
from hrc_devices.ros2.rmw_zenoh import typestore
from hrc_devices.trackers.ros2_people import (
    IDENTITY,
    IDS_LIST,
    MARKER_ARRAY,
    ZED_OBJECTS,
    PeopleFrame,
    Placement,
    Ros2MessageError,
    decode_ids_list,
    decode_k4abt_markers,
    decode_zed_objects,
    people_capsules,
)
from hrc_devices.trackers.skeletons import COMPILED, covers

STORE = typestore("humble")
T = STORE.types
STAMP = (1_790_000_000, 5_000)


def _header(frame_id: str = "zed_left_camera_frame") -> Any:
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=STAMP[0], nanosec=STAMP[1]), frame_id=frame_id
    )


def _zed_object(label_id: int, state: int, body_format: int, keypoints: np.ndarray, skeleton: bool = True) -> Any:
    kp3 = T["zed_msgs/msg/Keypoint3D"]
    kp2 = T["zed_msgs/msg/Keypoint2Df"]
    kp2i = T["zed_msgs/msg/Keypoint2Di"]
    full = np.zeros((70, 3), dtype=np.float32)  # the wrapper leaves keypoints beyond the format's count at zero
    full[: len(keypoints)] = keypoints
    box3 = T["zed_msgs/msg/BoundingBox3D"](corners=[kp3(kp=np.zeros(3, np.float32)) for _ in range(8)])
    return T["zed_msgs/msg/Object"](
        label=f"Body_{label_id}",
        label_id=label_id,
        sublabel="",
        confidence=90.0,
        position=np.asarray(np.nanmean(keypoints, axis=0), dtype=np.float32),
        position_covariance=np.array([1e-4, 0, 0, 1e-4, 0, 4e-4], dtype=np.float32),
        velocity=np.zeros(3, np.float32),
        tracking_available=True,
        tracking_state=state,
        action_state=0,
        bounding_box_2d=T["zed_msgs/msg/BoundingBox2Di"](corners=[kp2i(kp=np.zeros(2, np.uint32)) for _ in range(4)]),
        bounding_box_3d=box3,
        dimensions_3d=np.zeros(3, np.float32),
        skeleton_available=skeleton,
        body_format=body_format,
        head_bounding_box_2d=T["zed_msgs/msg/BoundingBox2Df"](
            corners=[kp2(kp=np.zeros(2, np.float32)) for _ in range(4)]
        ),
        head_bounding_box_3d=box3,
        head_position=np.zeros(3, np.float32),
        skeleton_2d=T["zed_msgs/msg/Skeleton2D"](keypoints=[kp2(kp=np.zeros(2, np.float32)) for _ in range(70)]),
        skeleton_3d=T["zed_msgs/msg/Skeleton3D"](keypoints=[kp3(kp=full[i]) for i in range(70)]),
    )


def zed_payload(objects: list[Any]) -> bytes:
    return bytes(STORE.serialize_cdr(T[ZED_OBJECTS](header=_header(), objects=objects), ZED_OBJECTS))


def k4abt_payload(bodies: dict[int, np.ndarray], skip: tuple[int, ...] = ()) -> bytes:
    """The Azure Kinect driver's array: a SPHERE per joint, ``id = body * 100 + joint``, in metres."""
    markers = []
    for body_id, kp in bodies.items():
        for joint, p in enumerate(kp):
            if joint in skip:
                continue
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            )
            markers.append(
                T["visualization_msgs/msg/Marker"](
                    header=_header("depth_camera_link"),
                    ns="",
                    id=body_id * 100 + joint,
                    type=2,
                    action=0,
                    pose=pose,
                    scale=T["geometry_msgs/msg/Vector3"](x=0.05, y=0.05, z=0.05),
                    color=T["std_msgs/msg/ColorRGBA"](r=1.0, g=0.0, b=0.0, a=1.0),
                    lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=250_000_000),
                    frame_locked=False,
                    points=[],
                    colors=[],
                    texture_resource="",
                    texture=T["sensor_msgs/msg/CompressedImage"](
                        header=_header(), format="", data=np.zeros(0, np.uint8)
                    ),
                    uv_coordinates=[],
                    text="",
                    mesh_resource="",
                    mesh_file=T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
                    mesh_use_embedded_materials=False,
                )
            )
    return bytes(STORE.serialize_cdr(T[MARKER_ARRAY](markers=markers), MARKER_ARRAY))


def _capsules(frame: PeopleFrame, placement: Placement = IDENTITY) -> dict[str, Any]:
    people, _ = people_capsules(frame, {}, placement, uncertainty_m=0.03)
    return dict(people)


@pytest.mark.parametrize(("body_format", "name"), [(0, "zed_body_18"), (1, "zed_body_34"), (2, "zed_body_38")])
def test_zed_objects_become_capsules_that_contain_every_keypoint(body_format: int, name: str) -> None:
    kp = standing_keypoints(COMPILED[name])
    frame = decode_zed_objects(zed_payload([_zed_object(4, 1, body_format, kp)]), STORE)
    assert frame.stamp_ns == STAMP[0] * 1_000_000_000 + STAMP[1]
    assert frame.frame_id == "zed_left_camera_frame"
    assert [p.person_id for p in frame.detections] == ["4"]
    assert frame.detections[0].seen.all()
    body = _capsules(frame)["4"]
    assert covers(body, kp.astype(np.float32).astype(float)).all()
    assert not body.estimated


def test_a_placement_moves_the_capsules_into_the_world() -> None:
    kp_sensor = standing_keypoints(COMPILED["zed_body_34"], 0.0, 0.0)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    placement = Placement(R, np.array([1.0, 2.0, 0.0]))
    frame = decode_zed_objects(zed_payload([_zed_object(1, 1, 1, kp_sensor)]), STORE)
    body = _capsules(frame, placement)["1"]
    assert covers(body, kp_sensor.astype(np.float32) @ R.T + placement.p_world_sensor).all()


def test_nan_keypoints_of_the_zed_are_unseen_and_never_shrink_the_person() -> None:
    kp = standing_keypoints(COMPILED["zed_body_34"])
    first = decode_zed_objects(zed_payload([_zed_object(2, 1, 1, kp)]), STORE)
    people, memories = people_capsules(first, {}, IDENTITY, uncertainty_m=0.03)
    hidden = kp.copy()
    hidden[[13, 14, 15, 16, 17]] = np.nan  # right elbow, wrist, hand, hand tip, thumb
    second = decode_zed_objects(zed_payload([_zed_object(2, 1, 1, hidden)]), STORE)
    assert not second.detections[0].seen[[13, 14, 15, 16, 17]].any()
    people2, _ = people_capsules(second, memories, IDENTITY, uncertainty_m=0.03)
    before, after = dict(people)["2"], dict(people2)["2"]
    assert after.names == before.names
    assert {"forearm_r", "hand_r"} <= set(after.estimated)
    rng = np.random.default_rng(1)
    for k in (before.names.index("forearm_r"), before.names.index("hand_r")):
        t = rng.random((300, 1))
        samples = before.a_m[k] + t * (before.b_m[k] - before.a_m[k])
        assert covers(after, samples).all()
    assert covers(after, kp.astype(np.float32).astype(float)).all()


@pytest.mark.parametrize("state", [2, 3])
def test_searching_or_terminate_is_no_detection_but_lost(state: int) -> None:
    kp = standing_keypoints(COMPILED["zed_body_34"])
    seen = decode_zed_objects(zed_payload([_zed_object(5, 1, 1, kp)]), STORE)
    _, memories = people_capsules(seen, {}, IDENTITY, uncertainty_m=0.0)
    frame = decode_zed_objects(zed_payload([_zed_object(5, state, 1, kp)]), STORE)
    assert frame.detections == ()
    assert frame.searching == ("5",)
    people, memories2 = people_capsules(frame, memories, IDENTITY, uncertainty_m=0.0)
    assert people == ()
    assert "5" in memories2  # kept for when the ZED finds them again


def test_off_objects_are_ignored() -> None:
    kp = standing_keypoints(COMPILED["zed_body_34"])
    frame = decode_zed_objects(zed_payload([_zed_object(6, 0, 1, kp)]), STORE)
    assert frame.detections == ()
    assert frame.searching == ()


def test_a_zed_object_without_skeleton_is_a_whole_body() -> None:
    kp = standing_keypoints(COMPILED["zed_body_34"])
    frame = decode_zed_objects(zed_payload([_zed_object(8, 1, 1, kp, skeleton=False)]), STORE)
    body = _capsules(frame)["8"]
    assert body.whole_body
    assert covers(body, kp).all()


def test_k4abt_markers_become_one_person_per_body() -> None:
    fmt = COMPILED["k4abt_32"]
    bodies = {1: standing_keypoints(fmt, 2.0, 0.0), 3: standing_keypoints(fmt, 0.0, 2.0, 1.0)}
    frame = decode_k4abt_markers(k4abt_payload(bodies, skip=(9,)), STORE)
    assert frame.frame_id == "depth_camera_link"
    assert sorted(p.person_id for p in frame.detections) == ["1", "3"]
    people = _capsules(frame)
    for body_id, kp in bodies.items():
        assert covers(people[str(body_id)], kp).all()  # joint 9 (left hand tip) unseen, still covered
        assert "hand_l" in people[str(body_id)].estimated


def test_ids_list_of_ros4hri() -> None:
    msg = T[IDS_LIST](header=_header(), ids=["b1", "xk3"])
    stamp, ids = decode_ids_list(bytes(STORE.serialize_cdr(msg, IDS_LIST)), STORE)
    assert ids == ("b1", "xk3")
    assert stamp > 0


def test_jazzy_types_decode_too() -> None:
    jazzy = typestore("jazzy")
    kp = standing_keypoints(COMPILED["zed_body_38"])
    payload = zed_payload([_zed_object(1, 1, 2, kp)])  # zed_msgs is the same in both distributions
    assert decode_zed_objects(payload, jazzy).detections[0].seen.all()


def _reason(call: Any) -> str:
    with pytest.raises(Ros2MessageError) as err:
        call()
    return err.value.reason


def test_hostile_zed_messages_are_refused_with_a_reason() -> None:
    kp = standing_keypoints(COMPILED["zed_body_34"])
    assert _reason(lambda: decode_zed_objects(zed_payload([_zed_object(1, 7, 1, kp)]), STORE)) == (
        "unknown_tracking_state"
    )
    assert _reason(lambda: decode_zed_objects(zed_payload([_zed_object(1, 1, 9, kp)]), STORE)) == "unknown_body_format"
    obj = _zed_object(1, 1, 1, kp)
    obj.position[0] = np.inf
    assert _reason(lambda: decode_zed_objects(zed_payload([obj]), STORE)) == "non_finite"
    valid = zed_payload([_zed_object(1, 1, 1, kp)])
    assert _reason(lambda: decode_zed_objects(valid[: len(valid) // 2], STORE)) == "not_cdr"
    float64 = bytes(STORE.serialize_cdr(T["std_msgs/msg/Float64"](data=0.5), "std_msgs/msg/Float64"))
    assert _reason(lambda: decode_zed_objects(float64, STORE)) == "not_cdr"
    assert _reason(lambda: decode_zed_objects(b"\x00" * 2_000_000, STORE)) == "too_large"


def test_an_absurd_zed_keypoint_is_refused() -> None:
    kp = standing_keypoints(COMPILED["zed_body_34"])
    kp[5] = (3e5, 0.0, 1.0)
    obj = _zed_object(1, 1, 1, kp)
    obj.position[:] = (2.0, 1.0, 1.0)
    frame = decode_zed_objects(zed_payload([obj]), STORE)
    with pytest.raises(MessageError) as err:
        people_capsules(frame, {}, IDENTITY, uncertainty_m=0.0)
    assert err.value.reason == "absurd_keypoint"


def test_hostile_marker_arrays_are_refused_with_a_reason() -> None:
    fmt = COMPILED["k4abt_32"]
    kp = standing_keypoints(fmt)
    msg = STORE.deserialize_cdr(k4abt_payload({1: kp}), MARKER_ARRAY)
    msg.markers[3].id = 1 * 100 + 45
    bad_id = bytes(STORE.serialize_cdr(msg, MARKER_ARRAY))
    assert _reason(lambda: decode_k4abt_markers(bad_id, STORE)) == "bad_marker_id"
    msg.markers[3].id = 100 + 4  # joint 4 twice
    assert _reason(lambda: decode_k4abt_markers(bytes(STORE.serialize_cdr(msg, MARKER_ARRAY)), STORE)) == (
        "duplicate_joint"
    )
    msg.markers[3].id = 103
    msg.markers[3].pose.position.x = float("nan")
    assert _reason(lambda: decode_k4abt_markers(bytes(STORE.serialize_cdr(msg, MARKER_ARRAY)), STORE)) == "non_finite"


def test_fuzzed_bytes_raise_only_message_errors() -> None:
    """Random bytes, truncations and bit flips of valid messages: a MessageError with a reason, or a valid frame
    whose capsules are finite; never another exception."""
    rng = np.random.default_rng(2020)
    kp = standing_keypoints(COMPILED["zed_body_38"])
    valid = {
        "zed": zed_payload([_zed_object(1, 1, 2, kp), _zed_object(2, 2, 2, kp)]),
        "k4a": k4abt_payload({1: standing_keypoints(COMPILED["k4abt_32"])}),
        "ids": bytes(STORE.serialize_cdr(T[IDS_LIST](header=_header(), ids=["a"]), IDS_LIST)),
    }
    decoders = {"zed": decode_zed_objects, "k4a": decode_k4abt_markers, "ids": decode_ids_list}
    reasons: dict[str, int] = {}
    for i in range(3000):
        kind = ("zed", "k4a", "ids")[i % 3]
        base = valid[kind]
        mode = i % 4
        if mode == 0:
            payload = rng.bytes(int(rng.integers(0, 400)))
        elif mode == 1:
            payload = base[: int(rng.integers(0, len(base)))]
        else:
            raw = bytearray(base)
            for _ in range(int(rng.integers(1, 8))):
                raw[int(rng.integers(4, len(raw)))] = int(rng.integers(0, 256))
            payload = bytes(raw)
        try:
            result = decoders[kind](payload, STORE)
            if isinstance(result, PeopleFrame):
                people, _ = people_capsules(result, {}, IDENTITY, uncertainty_m=0.0)
                for _, body in people:
                    assert np.isfinite(body.a_m).all()
                    assert np.isfinite(body.radius_m).all()
        except MessageError as exc:
            reasons[exc.reason] = reasons.get(exc.reason, 0) + 1
    assert reasons.get("not_cdr", 0) > 1000


def test_a_detection_whose_torso_goes_unseen_is_left_out_as_lost_with_its_memory() -> None:
    """The ZED still reports the person (OK), but without a neck: not placed, so not in the frame (the gateway's
    track keeps them as lost, growing), and placed again when the neck is back."""
    kp = standing_keypoints(COMPILED["zed_body_34"])
    first = decode_zed_objects(zed_payload([_zed_object(4, 1, 1, kp)]), STORE)
    _, memories = people_capsules(first, {}, IDENTITY, uncertainty_m=0.0)
    no_neck = kp.copy()
    no_neck[list(COMPILED["zed_body_34"].neck)] = np.nan  # every keypoint that places the neck
    frame = decode_zed_objects(zed_payload([_zed_object(4, 1, 1, no_neck)]), STORE)
    assert len(frame.detections) == 1
    people, memories2 = people_capsules(frame, memories, IDENTITY, uncertainty_m=0.0)
    assert people == ()
    assert memories2["4"] is memories["4"]
    again, _ = people_capsules(first, memories2, IDENTITY, uncertainty_m=0.0)
    assert [pid for pid, _ in again] == ["4"]
