"""The tracker emulator speaking ZED: body capsules → BODY_34 keypoints → ObjectsStamped (decoded here by rosbags,
through the gateway's decoder) with the ZED's tracking states, published over rmw_zenoh with attachments and tokens."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh
from support.paths import REPO_ROOT

from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.messages import Capsule, Human, Humans
from hrc_runtime.config import load_cell_config
from hrc_runtime.rmw_zenoh import decode_attachment, liveliness_keys, parse_endpoint_token, topic_type, typestore
from hrc_runtime.ros2_people import IDENTITY, ZED_OBJECTS, decode_zed_objects, people_capsules
from hrc_runtime.skeletons import ZED_34_NAMES, covers
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, wait_for
from tracker_emu.body import BodyPose, body_capsules
from tracker_emu.ros2_zed import OK, SEARCHING, TERMINATE, ZedPublishers, ZedSensor, zed_keypoints, zed_sources

NOW = 1_790_000_000_000_000_000


@pytest.fixture(scope="module")
def config() -> CellConfig:
    return load_cell_config(REPO_ROOT / "configs" / "cell_ros2_zed.toml")


def frame(people: dict[str, BodyPose], stamp_ns: int = NOW, drop: tuple[str, ...] = ()) -> Humans:
    """A measured frame of the emulator (world frame), without the capsules named in ``drop``."""
    humans = []
    for pid, pose in people.items():
        capsules = [
            Capsule(name=c.name, a=tuple(c.a), b=tuple(c.b), radius=c.radius_m)
            for c in body_capsules(pose)
            if c.name not in drop
        ]
        humans.append(Human(id=pid, capsules=capsules))
    return Humans(tracker="front", seq=1, stamp_ns=stamp_ns, humans=humans)


def sensor(config: CellConfig, name: str = "front") -> ZedSensor:
    source = config.trackers[name].ros2
    assert source is not None
    return ZedSensor(source, 0.01, "jazzy")


def test_every_keypoint_of_a_whole_body_is_seen_and_on_its_capsules() -> None:
    capsules = body_capsules(BodyPose(2.0, 1.0, 0.5, reach=0.7))
    keypoints = zed_keypoints((c.name, c.a, c.b, c.radius_m) for c in capsules)
    assert keypoints.shape == (34, 3)
    assert np.isfinite(keypoints).all()
    assert keypoints[:, 2].min() > 0.0
    assert keypoints[:, 2].max() < 1.76


def test_keypoints_of_hidden_capsules_are_nan_as_the_zed_sdk_leaves_them() -> None:
    capsules = [c for c in body_capsules(BodyPose(2.0, 1.0, 0.0)) if not c.name.endswith("_l")]
    keypoints = zed_keypoints((c.name, c.a, c.b, c.radius_m) for c in capsules)
    unseen = {ZED_34_NAMES[k] for k in range(34) if not np.isfinite(keypoints[k]).all()}
    assert unseen == {
        "left_clavicle", "left_shoulder", "left_elbow", "left_wrist", "left_hand", "left_handtip", "left_thumb",
        "left_hip", "left_knee", "left_ankle", "left_foot", "left_heel",
    }  # fmt: skip


def test_the_gateways_capsules_from_the_zed_message_contain_the_emulated_body(config: CellConfig) -> None:
    zed = sensor(config)
    pose = BodyPose(1.5, -0.5, 2.8, reach=1.0)
    payload = zed.objects(frame({"h1": pose}), ["h1"])
    decoded = decode_zed_objects(payload, typestore("jazzy"))
    assert decoded.stamp_ns == NOW
    assert decoded.frame_id == "front_left_camera_frame"
    placement = IDENTITY._replace(R_world_sensor=zed.R_world_sensor, p_world_sensor=zed.p_world_sensor)
    people, _ = people_capsules(decoded, {}, placement, uncertainty_m=0.05)
    ((pid, body),) = people
    assert pid == "0"
    assert not body.whole_body
    assert not body.estimated  # everything seen
    ends = np.array([p for c in body_capsules(pose) for p in (c.a, c.b)])
    assert covers(body, ends).all()  # every end point of the emulator's capsules (with noise 0)


def test_a_hidden_person_is_searching_then_terminated_then_gone(config: CellConfig) -> None:
    zed = sensor(config)
    store = typestore("jazzy")

    def states(payload: bytes) -> tuple[list[str], list[str]]:
        decoded = decode_zed_objects(payload, store)
        return [p.person_id for p in decoded.detections], list(decoded.searching)

    two = {"h1": BodyPose(2.0, 0.0, 0.0), "h2": BodyPose(3.0, 1.0, 0.0)}
    assert states(zed.objects(frame(two), ["h1", "h2"])) == (["0", "1"], [])
    hidden = frame({"h1": two["h1"]}, NOW + 33_000_000)  # h2 occluded, still in the scenario
    assert states(zed.objects(hidden, ["h1", "h2"])) == (["0"], ["1"])

    def tracking_states(payload: bytes) -> list[int]:
        return [int(o.tracking_state) for o in store.deserialize_cdr(payload, ZED_OBJECTS).objects]

    assert tracking_states(zed.objects(hidden, ["h1", "h2"])) == [OK, SEARCHING]
    assert tracking_states(zed.objects(hidden, ["h1"])) == [OK, TERMINATE]  # h2 left the scenario
    assert tracking_states(zed.objects(hidden, ["h1"])) == [OK]


def test_only_trackers_with_a_zed_input_can_be_played_as_zed(config: CellConfig) -> None:
    assert set(zed_sources(config, config.trackers)) == {"front", "side"}
    plain = {"front": config.trackers["front"].model_copy(update={"ros2": None})}
    with pytest.raises(ConfigError, match="no ros2 input of format zed_objects"):
        zed_sources(config, plain)


def test_published_over_rmw_zenoh_with_attachments_and_a_token(config: CellConfig) -> None:
    endpoint = free_endpoint()
    received: list[tuple[str, bytes, bytes | None]] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        attachment = sample.attachment
        with lock:
            received.append(
                (str(sample.key_expr), sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes())
            )

    with (
        zenoh.open(session_config(listen=[endpoint])) as listener,
        zenoh.open(session_config(connect=[endpoint])) as emulator,
    ):
        listener.declare_subscriber("0/**", on_sample)
        publishers = ZedPublishers(
            emulator, config, zed_sources(config, config.trackers), {"front": 0.01, "side": 0.01}
        )
        try:
            wait_for(lambda: len(liveliness_keys(listener, 0, 0.5)) >= 3, 10.0, "the emulator's tokens")
            tokens = [parse_endpoint_token(t) for t in liveliness_keys(listener, 0, 1.0)]
            message = frame({"h1": BodyPose(2.0, 0.0, 0.0)})
            for _ in range(5):  # until the subscriber is matched
                publishers.publish("front", message, ["h1"])
                time.sleep(0.1)
        finally:
            publishers.close()
    wire = topic_type("jazzy", ZED_OBJECTS)
    publishers_seen = {t["topic"]: t for t in tokens if t["kind"] == "MP"}
    assert set(publishers_seen) == {"/front/zed_node/body_trk/skeletons", "/side/zed_node/body_trk/skeletons"}
    assert (publishers_seen["/front/zed_node/body_trk/skeletons"]["hash"]) == wire.type_hash
    with lock:
        assert received
        key, payload, attachment = received[-1]
    assert key == f"0/front/zed_node/body_trk/skeletons/{wire.dds_name}/{wire.type_hash}"
    assert attachment is not None
    sequence = [decode_attachment(a).sequence_number for _, _, a in received if a is not None]
    assert sequence == sorted(sequence)
    assert sequence[-1] == 5
    assert [p.person_id for p in decode_zed_objects(payload, typestore("jazzy")).detections] == ["0"]
