"""The gateway's ROS 2 session under the cell's kind of access control, with real TLS sessions in this process.

A peer with a valid certificate of the cell CA but the wrong role publishes well-formed ZED frames on a ROS 2
tracker's topic: none reaches the door, none is even counted (the session drops them before any subscriber); the
tracker's own certificate, on the same topic, gets through. Members still find and read what the face publishes.
"""

from __future__ import annotations

import argparse
import json
import threading
from pathlib import Path
from typing import Any

import pytest
import zenoh
from support.paths import REPO_ROOT

from gateway.ros2_face import Ros2Face, ros2_policy, ros2_session_options
from gateway.ros2_trackers import running_ros2_trackers, tracker_topics
from hrc_contract.config import CellConfig, Ros2TrackerInput
from hrc_contract.messages import Capsule, Human, Humans
from hrc_devices.robots.model import RobotModel
from hrc_devices.ros2.rmw_zenoh import endpoint_token, liveliness_keys, topic_key
from hrc_runtime.access_control import ROS2_FACE, may_declare_token, may_put
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import SessionOptions, mutual_tls, session_config
from hrc_tools.cell.procs import free_port, wait_or_fail
from tracker_emu.body import BodyPose, body_capsules
from tracker_emu.ros2_zed import ZedPublishers, zed_sources

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

GENUINE_X_M = 4.0
FORGED_X_M = 1.0
"""The forged person stands at the robot; the genuine one 4 m away: each frame at the door says whose it is."""


@pytest.fixture
def config(tmp_path: Path) -> CellConfig:
    """configs/cell_ros2_zed.toml with its ROS 2 session on a free TLS endpoint."""
    config = load_cell_config(REPO_ROOT / "configs" / "cell_ros2_zed.toml")
    ros2 = config.ros2.model_copy(update={"listen": [f"tls/127.0.0.1:{free_port()}"]})
    return config.model_copy(update={"ros2": ros2})


def person_at(x_m: float, stamp_ns: int) -> Humans:
    capsules = [
        Capsule(name=c.name, a=tuple(c.a), b=tuple(c.b), radius=c.radius_m)
        for c in body_capsules(BodyPose(x_m, 0.0, 3.14, reach=0.3))
    ]
    return Humans(tracker="front", seq=1, stamp_ns=stamp_ns, humans=[Human(id="p", capsules=capsules)])


class Door:
    """Collects what reaches the gateway's door (and what is refused before it)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.frames: list[dict[str, Any]] = []
        self.refused: list[tuple[str, str]] = []

    def __call__(self, key: str, payload: bytes, received: Clocks) -> None:
        with self.lock:
            self.frames.append(json.loads(payload))

    def reject(self, topic: str, reason: str, received: Clocks) -> None:
        with self.lock:
            self.refused.append((topic, reason))

    def pelvis_xs(self) -> list[float]:
        with self.lock:
            frames = list(self.frames)
        return [c["a"][0] for f in frames for h in f["humans"] for c in h["capsules"] if c["name"] == "pelvis"]


def publishers(session: zenoh.Session, config: CellConfig) -> ZedPublishers:
    front = {"front": config.trackers["front"]}
    return ZedPublishers(session, config, zed_sources(config, front), {"front": 0.01})


def peer(pki_dir: Path, cn: str) -> SessionOptions:
    return SessionOptions("peer", mutual_tls(pki_dir, cn, None))  # a sender runs what it likes


@pytest.mark.parametrize("forger", ["controller-ur5", "tracker-side", "ros2"])
def test_only_the_trackers_own_certificate_reaches_the_door(tmp_path: Path, config: CellConfig, forger: str) -> None:
    pki_dir = tmp_path / "pki"
    options = ros2_session_options(argparse.Namespace(pki_dir=str(pki_dir)), config)
    endpoint = config.ros2.listen
    door = Door()
    with (
        zenoh.open(session_config(endpoint, [], options)) as gateway,
        running_ros2_trackers(config, gateway, door, door.reject) as trackers,
        zenoh.open(session_config([], endpoint, peer(pki_dir, forger))) as forged_session,
    ):
        assert trackers is not None
        forged = publishers(forged_session, config)
        clock = iter(range(1_790_000_000_000_000_000, 1_800_000_000_000_000_000, 33_000_000))
        # The forger is on the bus: it finds the gateway's subscription by its liveliness token.
        wait_or_fail(
            lambda: any("hrc_gateway_trackers" in k for k in liveliness_keys(forged_session, 0, 0.5)),
            5.0,
            "the forger seeing the gateway's ROS 2 trackers",
        )
        for _ in range(20):
            forged.publish("front", person_at(FORGED_X_M, next(clock)), ["p"])
        with zenoh.open(session_config([], endpoint, peer(pki_dir, "tracker-front"))) as genuine_session:
            genuine = publishers(genuine_session, config)

            def both_publish() -> bool:
                forged.publish("front", person_at(FORGED_X_M, next(clock)), ["p"])
                genuine.publish("front", person_at(GENUINE_X_M, next(clock)), ["p"])
                return len(door.pelvis_xs()) >= 5

            wait_or_fail(both_publish, 5.0, "the genuine tracker's frames at the door")
            genuine.close()
        forged.close()
        subscription = trackers.subscriptions["front"]
    # Compared once the gateway's session is closed: before, a sample still on its way when the publishers closed
    # could reach the door after the two were seen equal (a loaded full run: 5 converted, then 6 at the door). A
    # sample still being converted counts before it reaches the door: settle first.
    wait_or_fail(lambda: subscription.counts().converted == len(door.frames), 5.0, "the last frames at the door")
    counts = subscription.counts()
    xs = door.pelvis_xs()
    assert all(abs(x - GENUINE_X_M) < 0.5 for x in xs), xs
    assert counts.refused == {}  # the forged frames are counted nowhere
    assert door.refused == []
    assert counts.converted == len(door.frames)


def test_members_find_and_read_what_the_face_publishes(tmp_path: Path, config: CellConfig, ur5: RobotModel) -> None:
    pki_dir = tmp_path / "pki"
    options = ros2_session_options(argparse.Namespace(pki_dir=str(pki_dir)), config)
    endpoint = config.ros2.listen
    received: set[str] = set()
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            received.add(str(sample.key_expr))

    door = Door()
    with (
        zenoh.open(session_config(endpoint, [], options)) as gateway,
        Ros2Face(config, {"ur5": ur5}, gateway) as face,
        running_ros2_trackers(config, gateway, door, door.reject),
        zenoh.open(session_config([], endpoint, peer(pki_dir, "observer-rviz"))) as observer,
    ):
        observer.declare_subscriber("0/**", on_sample)
        tokens = {p.token_key for p in face.node.publishers} | {face.node.token_key}
        wait_or_fail(lambda: tokens <= set(liveliness_keys(observer, 0, 0.5)), 5.0, "every token of the face")
        seen = liveliness_keys(observer, 0, 0.5)  # the face's and the trackers' nodes and endpoints
        face_keys = {p.key for p in face.node.publishers}

        def put_each() -> bool:
            for publisher in face.node.publishers:
                publisher.put(b"\x00\x01\x00\x00")
            with lock:
                return received >= {p.key for p in face.node.publishers}

        wait_or_fail(put_each, 5.0, "every topic of the face at the observer")
    policy = ros2_policy(config)
    assert set(policy.face.puts) == face_keys
    assert len(seen) == 2 + len(face_keys) + 2  # two nodes, the face's publishers, two subscriptions
    assert all(may_declare_token(policy, ROS2_FACE, token) for token in seen), seen
    endpoints = [token for token in seen if "/NN/" not in token]  # a tracker may name its node anything
    assert not any(may_declare_token(policy, "tracker-front", token) for token in endpoints)


def test_a_ros4hri_tracker_may_put_every_topic_it_is_read_from_and_nothing_else(config: CellConfig) -> None:
    """Its tracked list, each body's joint states (one topic per body id) and /tf: with TLS, a policy that let it put
    only the tracked list would drop every joint state and root pose (the person would stay lost)."""
    ros4hri = Ros2TrackerInput(format="ros4hri_bodies", topic="/humans/bodies/tracked", frame_id="world")
    trackers = dict(config.trackers) | {"front": config.trackers["front"].model_copy(update={"ros2": ros4hri})}
    config = config.model_copy(update={"trackers": trackers})
    policy = ros2_policy(config)
    tracked, joint_states, tf = tracker_topics(config)["front"]
    body_js = "/humans/bodies/b7/joint_states"
    keys = {
        "tracked": topic_key(0, tracked.fq_name, tracked.wire),
        "joint_states": topic_key(0, body_js, joint_states.wire),
        "tf": topic_key(0, tf.fq_name, tf.wire),
    }
    assert all(may_put(policy, "tracker-front", key) for key in keys.values()), keys
    assert not any(may_put(policy, "tracker-side", key) for key in keys.values())
    assert not may_put(policy, "tracker-front", topic_key(0, "/humans/bodies/b7/other", joint_states.wire))
    publisher = endpoint_token("MP", 0, "a1b2", 3, 9, "/", "hri_fullbody", body_js, joint_states.wire)
    assert may_declare_token(policy, "tracker-front", publisher)
    assert not may_declare_token(policy, "tracker-side", publisher)
