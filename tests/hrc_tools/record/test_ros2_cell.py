"""The cell's contract messages, received as bytes, recorded as ROS 2 messages: read back from the bag by rosbags."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import pytest
from pydantic import BaseModel
from rosbags.rosbag2 import Reader
from support.status_examples import gateway_status, near_robot_status

from gateway import ros2_face as face
from hrc_contract.config import CellConfig
from hrc_contract.messages import Capsule, Human, Humans, JointState, Override
from hrc_contract.status_models import CapsuleStatus, Event
from hrc_devices.ros2.rmw_zenoh import Distro, typestore
from hrc_runtime.config import load_cell_config
from hrc_tools.record.ros2_cell import LOG_INFO, LOG_WARN, Ros2Cell, Ros2CellRecorder, key_token, quaternion_of_rpy
from hrc_tools.record.ros2_mcap import Ros2BagSink

STAMP_NS = 1_790_000_000_123_456_789
UR5_JOINTS = [
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
]  # fmt: skip


@pytest.fixture(scope="module")
def config() -> CellConfig:
    return load_cell_config()


def _joint_state(seq: int = 1) -> JointState:
    return JointState(
        robot="ur5", seq=seq, stamp_ns=STAMP_NS, q=[0.1, -1.2, 1.3, 0.0, 0.5, 0.6], qd=[0.2, 0.0, 0.0, 0.0, 0.0, -0.1],
        qd_nominal=[0.4, 0.0, 0.0, 0.0, 0.0, -0.2], override=0.5, override_seq=3, mode="running",
    )  # fmt: skip


def _humans(tracker: str) -> Humans:
    capsules = [
        Capsule(name="torso", a=[1.0, 0.0, 0.9], b=[1.0, 0.0, 1.5], radius=0.2),
        Capsule(name="head", a=[1.0, 0.0, 1.7], b=[1.0, 0.0, 1.7], radius=0.12),
    ]
    return Humans(tracker=tracker, seq=1, stamp_ns=STAMP_NS, humans=[Human(id="h1", capsules=capsules)])


def _wire(message: BaseModel) -> bytes:
    return message.model_dump_json(by_alias=True).encode()


def _record(tmp_path: Path, config: CellConfig, distro: Distro, samples: list[tuple[str, bytes]]) -> Ros2CellRecorder:
    cell = Ros2Cell.of(config, distro)
    with Ros2BagSink(tmp_path / "bag", distro) as sink:
        recorder = Ros2CellRecorder(sink, cell, STAMP_NS)
        for i, (key, payload) in enumerate(samples):
            recorder.on_sample(key, payload, STAMP_NS + i)
        recorder.on_events(
            [
                Event(seq=1, stamp_ns=STAMP_NS, kind="start", message="gateway started"),
                Event(seq=2, stamp_ns=STAMP_NS, kind="fault_raised", robot="ur5", message="tracker_stale"),
            ],
            STAMP_NS + 100,
        )
    return recorder


def _messages(bag: Path, distro: Distro) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    with Reader(bag) as reader:
        for connection, _, raw in reader.messages():
            out.setdefault(connection.topic, []).append(typestore(distro).deserialize_cdr(raw, connection.msgtype))
    return out


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_every_topic_of_the_cell_is_recorded_as_its_ros2_message(
    tmp_path: Path, config: CellConfig, distro: Distro
) -> None:
    cell = config.cell
    status = gateway_status(ur5=near_robot_status(0.62)).model_copy(
        update={"cell": cell, "robots": {"ur5": near_robot_status(0.62).model_copy(update={"links": [
            CapsuleStatus(name="tool", a_m=[0.0, 0.0, 1.0], b_m=[0.0, 0.3, 1.0], radius_m=0.07)
        ]})}}
    )  # fmt: skip
    samples = [
        (f"hrc/{cell}/robot/ur5/state", _wire(_joint_state())),
        (f"hrc/{cell}/robot/ur5/override", _wire(Override(robot="ur5", seq=1, stamp_ns=STAMP_NS, delta=0.62))),
        (f"hrc/{cell}/tracker/front/humans", _wire(_humans("front"))),
        (f"hrc/{cell}/gateway/status", status.model_dump_json().encode()),
        (f"hrc/{cell}/truth/robot/ur5/state", _wire(_joint_state())),
        (f"hrc/{cell}/truth/humans", _wire(_humans("truth"))),
    ]
    _record(tmp_path, config, distro, samples)
    messages = _messages(tmp_path / "bag", distro)

    (joints,) = messages["/ur5/joint_states"]
    assert list(joints.name) == UR5_JOINTS
    assert joints.position == pytest.approx(_joint_state().q)
    assert joints.velocity == pytest.approx(_joint_state().qd)
    assert (joints.header.stamp.sec, joints.header.stamp.nanosec) == divmod(STAMP_NS, 1_000_000_000)
    assert list(messages["/truth/ur5/joint_states"][0].name) == UR5_JOINTS
    assert [m.data for m in messages["/ur5/speed_override"]] == [0.62]  # δ, not percent
    (diagnostics,) = messages["/diagnostics"]
    assert {kv.key: kv.value for kv in diagnostics.status[0].values}["zone"] == "reduced_speed"
    assert diagnostics.status[0].level == face.LEVEL_WARN
    robot_markers = [m for m in messages["/hrc_markers"][0].markers if m.ns == "robot/ur5"]
    assert len(robot_markers) == 3  # the tool: two spheres and a cylinder
    for topic, ns in (("/trackers/front/markers", "front/h1"), ("/truth/markers", "truth/h1")):
        first, *markers = messages[topic][0].markers
        assert first.action == face.DELETEALL
        assert all(m.ns == ns and m.header.frame_id == "world" for m in markers)
        assert len(markers) == 3 + 1  # torso: two spheres and a cylinder; head: a point, one sphere
    (tf,) = messages["/tf_static"][0].transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ("world", "ur5/base")
    assert [line.level for line in messages["/rosout"]] == [LOG_INFO, LOG_WARN]
    assert messages["/rosout"][1].msg == "ur5: tracker_stale"


def test_human_markers_cover_every_capsule(tmp_path: Path, config: CellConfig) -> None:
    frame = _humans("front")
    _record(tmp_path, config, "jazzy", [(f"hrc/{config.cell}/tracker/front/humans", _wire(frame))])
    markers = _messages(tmp_path / "bag", "jazzy")["/trackers/front/markers"][0].markers[1:]
    spheres = [m for m in markers if m.type == face.SPHERE]
    for capsule in frame.humans[0].capsules:
        for end in (capsule.a, capsule.b):
            assert any(
                np.allclose([s.pose.position.x, s.pose.position.y, s.pose.position.z], end)
                and s.scale.x == pytest.approx(2 * capsule.radius)
                for s in spheres
            ), f"{capsule.name} end {end} not drawn"
    (cylinder,) = [m for m in markers if m.type == face.CYLINDER]
    assert (cylinder.scale.x, cylinder.scale.z, cylinder.pose.position.z) == pytest.approx((0.4, 0.6, 1.2))


def test_a_bad_payload_is_kept_on_rejected_and_unknown_keys_are_counted(tmp_path: Path, config: CellConfig) -> None:
    cell = config.cell
    bad = json.dumps(_joint_state().model_dump(by_alias=True) | {"override": 2.0}).encode()
    recorder = _record(
        tmp_path, config, "jazzy",
        [(f"hrc/{cell}/robot/ur5/state", bad), (f"hrc/{cell}/robot/ur5/state", _wire(_joint_state(2))),
         (f"hrc/{cell}/robot/ur5/unknown", b"{}"), ("hrc/other_cell/gateway/status", b"{}")],
    )  # fmt: skip
    messages = _messages(tmp_path / "bag", "jazzy")
    (rejected,) = messages["/rejected"]
    assert json.loads(rejected.data)["key"] == f"hrc/{cell}/robot/ur5/state"
    assert len(messages["/ur5/joint_states"]) == 1  # only the valid one
    assert recorder.unknown_keys == 2


def test_a_key_with_any_robot_name_makes_a_valid_ros_name(tmp_path: Path, config: CellConfig) -> None:
    hostile = "robot.ü 1"
    key = f"hrc/{config.cell}/robot/{hostile}/override"
    _record(tmp_path, config, "jazzy", [(key, _wire(Override(robot="ur5", seq=1, stamp_ns=STAMP_NS, delta=0.3)))])
    messages = _messages(tmp_path / "bag", "jazzy")
    assert [m.data for m in messages["/robot___1/speed_override"]] == [0.3]


@pytest.mark.parametrize(
    ("chunk", "token"), [("ur5", "ur5"), ("ur-5", "ur_5"), ("2nd", "r_2nd"), ("", "r_"), ("_x", "_x"), ("a/b", "a_b")]
)
def test_key_token(chunk: str, token: str) -> None:
    assert key_token(chunk) == token


def test_key_token_is_the_faces_ros_token_for_cell_names() -> None:
    for name in ("ur5", "left-arm", "9axis", "a_b-c"):
        assert key_token(name) == face.ros_token(name)


def test_quaternion_of_rpy_known_answer() -> None:
    s = math.sqrt(0.5)
    assert quaternion_of_rpy((0.0, 0.0, math.pi / 2)) == pytest.approx((0.0, 0.0, s, s))
    assert quaternion_of_rpy((0.0, 0.0, 0.0)) == pytest.approx((0.0, 0.0, 0.0, 1.0))


def test_quaternion_of_rpy_is_the_urdf_rotation() -> None:
    rng = np.random.default_rng(20)
    for rpy in rng.uniform(-math.pi, math.pi, size=(50, 3)):
        x, y, z, w = quaternion_of_rpy(tuple(rpy))
        rotation = pin.Quaternion(w, x, y, z).toRotationMatrix()
        np.testing.assert_allclose(rotation, pin.rpy.rpyToMatrix(*rpy), atol=1e-12)
