"""The tracker emulator speaking ZED: body capsules → BODY_34 (body fitting on: hidden keypoints fitted) or BODY_38
(off: hidden keypoints NaN) keypoints → ObjectsStamped (decoded here by rosbags, through the gateway's decoder) with the
ZED's tracking states, published over rmw_zenoh with attachments and tokens."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh
from support.paths import REPO_ROOT

from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.messages import Capsule, Human, Humans
from hrc_devices.ros2.rmw_zenoh import decode_attachment, liveliness_keys, parse_endpoint_token, topic_type, typestore
from hrc_devices.trackers.ros2_people import IDENTITY, ZED_OBJECTS, decode_zed_objects, people_capsules
from hrc_devices.trackers.skeletons import ZED_34_NAMES, ZED_38_NAMES, covers
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, wait_for
from tracker_emu.body import BodyPose, body_capsules
from tracker_emu.main import cli
from tracker_emu.ros2_zed import (
    BODY_34,
    BODY_38,
    OK,
    SEARCHING,
    TERMINATE,
    ZedPublishers,
    ZedSensor,
    by_name,
    fit_pose,
    fitted_capsules,
    with_body_fitting,
    zed_keypoints,
    zed_sources,
)

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

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


LEGS = ("thigh_l", "thigh_r", "shin_l", "shin_r")
"""What the table hides of a person at it, seen from the front sensor."""


def sensor(config: CellConfig, name: str = "front", body_fitting: bool | None = None) -> ZedSensor:
    """The tracker's ZED as the cell file sets it up, or with ``enable_body_fitting`` set."""
    trackers = {name: config.trackers[name]}
    if body_fitting is not None:
        trackers = with_body_fitting(trackers, body_fitting)
    source = trackers[name].ros2
    assert source is not None
    return ZedSensor(source, 0.01, "jazzy")


def world_keypoints(zed: ZedSensor, payload: bytes) -> tuple[int, np.ndarray]:
    """The body format and world-frame keypoints of the message's only person."""
    store = typestore("jazzy")
    (obj,) = store.deserialize_cdr(payload, ZED_OBJECTS).objects
    n = len(zed.names)
    keypoints_sensor = np.array([k.kp for k in obj.skeleton_3d.keypoints[:n]], dtype=np.float64)
    return int(obj.body_format), keypoints_sensor @ zed.R_world_sensor.T + zed.p_world_sensor


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


def test_body_38_keypoints_of_a_whole_body_are_seen_and_those_of_hidden_capsules_nan() -> None:
    capsules = body_capsules(BodyPose(2.0, 1.0, 0.5, reach=0.7))
    whole = zed_keypoints(((c.name, c.a, c.b, c.radius_m) for c in capsules), ZED_38_NAMES)
    assert whole.shape == (38, 3)
    assert np.isfinite(whole).all()
    hidden = zed_keypoints(((c.name, c.a, c.b, c.radius_m) for c in capsules if c.name not in LEGS), ZED_38_NAMES)
    unseen = {ZED_38_NAMES[k] for k in range(38) if not np.isfinite(hidden[k]).all()}
    assert unseen == {
        f"{side}_{part}"
        for side in ("left", "right")
        for part in ("knee", "ankle", "big_toe", "small_toe", "heel", "hip")
    }


@pytest.mark.parametrize(
    "pose",
    [BodyPose(1.5, -0.5, 2.8, reach=0.5), BodyPose(0.9, 0.3, -2.9, reach=0.86, both_arms=True)],
)
def test_the_fit_recovers_the_pose_from_the_seen_capsules_alone(pose: BodyPose) -> None:
    seen = by_name((c.name, c.a, c.b, c.radius_m) for c in body_capsules(pose) if c.name not in LEGS)
    fitted = fit_pose(seen)
    assert (fitted.x_m, fitted.y_m) == pytest.approx((pose.x_m, pose.y_m), abs=1e-9)
    assert fitted.heading_rad == pytest.approx(pose.heading_rad, abs=1e-9)
    assert (fitted.reach, fitted.both_arms) == (pytest.approx(pose.reach), pose.both_arms)
    legs = fitted_capsules(seen)
    for c in body_capsules(pose):
        np.testing.assert_allclose(legs[c.name][0], c.a, atol=1e-9)
        np.testing.assert_allclose(legs[c.name][1], c.b, atol=1e-9)


def test_fitted_hidden_capsules_follow_the_true_body_within_the_noise() -> None:
    """Invariant over seeded random people and noise: the fitted legs lie where the true legs are, within a few
    noise deviations; the seen capsules are kept as measured."""
    rng = np.random.default_rng(7)
    noise_m = 0.015
    for _ in range(50):
        x_m, y_m = rng.uniform(-3.0, 3.0, 2)
        pose = BodyPose(x_m, y_m, rng.uniform(-np.pi, np.pi), reach=rng.uniform(), both_arms=rng.random() < 0.5)
        truth = body_capsules(pose)
        seen = by_name(
            (c.name, c.a + rng.normal(0.0, noise_m, 3), c.b + rng.normal(0.0, noise_m, 3), c.radius_m)
            for c in truth
            if c.name not in LEGS
        )
        fitted = fitted_capsules(seen)
        assert all(fitted[name] is seen[name] for name in seen)
        for c in truth:
            if c.name in LEGS:
                assert np.linalg.norm(fitted[c.name][0] - c.a) < 6 * noise_m
                assert np.linalg.norm(fitted[c.name][1] - c.b) < 6 * noise_m


def test_the_cell_files_zeds_follow_the_wrappers_default_no_body_fitting(config: CellConfig) -> None:
    zed = sensor(config)
    assert not zed.source.enable_body_fitting
    assert zed.body_format == BODY_38
    assert sensor(config, body_fitting=True).body_format == BODY_34


def test_without_body_fitting_hidden_keypoints_are_nan_and_become_reach_spheres(config: CellConfig) -> None:
    zed = sensor(config, body_fitting=False)
    pose = BodyPose(1.5, -0.5, 2.8, reach=1.0)
    payload = zed.objects(frame({"h1": pose}, drop=LEGS), ["h1"])
    body_format, keypoints = world_keypoints(zed, payload)
    assert body_format == BODY_38
    assert not np.isfinite(keypoints[ZED_38_NAMES.index("left_knee")]).any()
    placement = IDENTITY._replace(R_world_sensor=zed.R_world_sensor, p_world_sensor=zed.p_world_sensor)
    ((_, body),), _ = people_capsules(
        decode_zed_objects(payload, typestore("jazzy")), {}, placement, uncertainty_m=0.05
    )
    assert {"thigh_l", "shin_l"} <= set(body.estimated)


def test_with_body_fitting_hidden_keypoints_are_the_fitted_body(config: CellConfig) -> None:
    zed = sensor(config, body_fitting=True)
    pose = BodyPose(1.5, -0.5, 2.8, reach=1.0)
    payload = zed.objects(frame({"h1": pose}, drop=LEGS), ["h1"])
    body_format, keypoints = world_keypoints(zed, payload)
    assert body_format == BODY_34
    assert np.isfinite(keypoints).all()
    truth = by_name((c.name, c.a, c.b, c.radius_m) for c in body_capsules(pose))
    np.testing.assert_allclose(keypoints, zed_keypoints((n, a, b, r) for n, (a, b, r) in truth.items()), atol=1e-5)
    placement = IDENTITY._replace(R_world_sensor=zed.R_world_sensor, p_world_sensor=zed.p_world_sensor)
    ((_, body),), _ = people_capsules(
        decode_zed_objects(payload, typestore("jazzy")), {}, placement, uncertainty_m=0.05
    )
    assert not body.estimated  # the gateway takes fitted keypoints for seen ones: no reach spheres
    ends = np.array([p for c in body_capsules(pose) for p in (c.a, c.b)])
    assert covers(body, ends).all()


def test_the_body_fitting_option_needs_the_zed_form() -> None:
    with pytest.raises(SystemExit) as exc:
        cli(["--zed-body-fitting", "on"])
    assert exc.value.code == 2


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
