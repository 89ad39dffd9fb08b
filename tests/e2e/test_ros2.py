"""End to end: a real gateway with ``[ros2]`` enabled, seen by a Zenoh client as an rmw_zenoh node would see it.

The client finds every endpoint through rmw_zenoh liveliness tokens (``liveliness().get``), subscribes to the keys
they name and decodes each message with rosbags, checking the type hash rosbags computes, the attachment and its
sequence numbers, for the Humble and the Jazzy key forms.
"""

from __future__ import annotations

import shutil
import threading
import time
from collections import defaultdict
from pathlib import Path

import pytest
import zenoh
from support.cell_files import CONFIGS, replace_once, write_cell

from hrc_devices.ros2.rmw_zenoh import (
    ADMIN_SPACE,
    HUMBLE_TYPE_HASH,
    Distro,
    decode_attachment,
    deserialize,
    liveliness_keys,
    parse_endpoint_token,
    topic_type,
)
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, running_cell, wait_for

pytestmark = pytest.mark.e2e

DOMAIN_ID = 7
EXPECTED_TYPES = {
    "/cell/ur5/speed_override": "std_msgs/msg/Float64",
    "/cell/ur5/joint_states": "sensor_msgs/msg/JointState",
    "/cell/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "/cell/hrc_markers": "visualization_msgs/msg/MarkerArray",
}


def _ros2_cell(tmp_path: Path, distro: str, endpoint: str) -> Path:
    section = (
        f'\n[ros2]\nenabled = true\ndistro = "{distro}"\ndomain_id = {DOMAIN_ID}\nnamespace = "/cell"\n'
        f'publish_rate_hz = 10.0\nlisten = ["{endpoint}"]\n'
    )
    for extra in ("body_regions.toml",):  # files the cell file may reference next to it
        if (CONFIGS / extra).exists():
            shutil.copy(CONFIGS / extra, tmp_path / extra)
    scenarios = replace_once('scenarios_dir = "scenarios"', f'scenarios_dir = "{CONFIGS / "scenarios"}"')
    return write_cell(tmp_path, cell=lambda text: scenarios(text) + section)


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_a_ros2_client_finds_and_decodes_every_topic(tmp_path: Path, distro: Distro) -> None:
    endpoint = free_endpoint()
    with (
        running_cell(tmp_path, config=_ros2_cell(tmp_path, distro, endpoint)) as cell,
        zenoh.open(session_config(connect=[endpoint])) as session,
    ):
        tokens: list[str] = []

        def endpoints_seen() -> bool:
            tokens[:] = liveliness_keys(session, DOMAIN_ID, timeout_s=1.0)
            return len([t for t in tokens if "/MP/" in t]) >= len(EXPECTED_TYPES)

        wait_for(endpoints_seen, 30.0, "the gateway's rmw_zenoh liveliness tokens", list(cell.procs.values()))
        assert all(t.startswith(f"{ADMIN_SPACE}/{DOMAIN_ID}/") for t in tokens)
        nodes = [parse_endpoint_token(t) for t in tokens if "/NN/" in t]
        assert [(n["namespace"], n["node"]) for n in nodes] == [("/cell", "hrc_gateway")]
        publishers = {p["topic"]: p for p in (parse_endpoint_token(t) for t in tokens) if p["kind"] == "MP"}
        assert set(publishers) == set(EXPECTED_TYPES)

        samples: dict[str, list[tuple[bytes, bytes | None]]] = defaultdict(list)
        lock = threading.Lock()
        subscribers = []
        for topic, token in publishers.items():
            wire = topic_type(distro, EXPECTED_TYPES[topic])
            assert (token["type"], token["hash"]) == (wire.dds_name, wire.type_hash)
            if distro == "humble":
                assert wire.type_hash == HUMBLE_TYPE_HASH
            else:
                assert wire.type_hash.startswith("RIHS01_")
            key = f"{DOMAIN_ID}/{topic.strip('/')}/{token['type']}/{token['hash']}"

            def on_sample(sample: zenoh.Sample, topic: str = topic) -> None:
                attachment = None if sample.attachment is None else sample.attachment.to_bytes()
                with lock:
                    samples[topic].append((sample.payload.to_bytes(), attachment))

            subscribers.append(session.declare_subscriber(key, on_sample))

        def enough() -> bool:
            with lock:
                # Links exist from the first joint state on: the round with the first joint states also published
                # markers before the second joint states.
                return all(len(samples[t]) >= 5 for t in EXPECTED_TYPES) and len(samples["/cell/ur5/joint_states"]) >= 2

        wait_for(enough, 30.0, "five messages on every topic", list(cell.procs.values()))
        with lock:
            got = {t: list(v) for t, v in samples.items()}

    robot_markers = 0
    for topic, received in got.items():
        msgtype = EXPECTED_TYPES[topic]
        sequences = []
        for payload, attachment in received:
            assert attachment is not None, f"{topic}: a sample without the attachment rmw_zenoh needs"
            decoded = decode_attachment(attachment)
            assert abs(decoded.source_timestamp_ns - time.time_ns()) < 120e9
            sequences.append(decoded.sequence_number)
            message = deserialize(distro, payload, msgtype)
            if msgtype == "std_msgs/msg/Float64":
                assert 0.0 <= message.data <= 1.0
            elif msgtype == "sensor_msgs/msg/JointState":
                assert len(message.name) == len(message.position) == 6
            elif msgtype == "diagnostic_msgs/msg/DiagnosticArray":
                assert [s.hardware_id for s in message.status] == ["ur5"]
            else:
                assert message.markers[0].action == 3  # DELETEALL first
                robot = [m for m in message.markers if m.ns == "robot/ur5"]  # none before the first joint state
                assert all(m.header.frame_id == "world" for m in robot)
                robot_markers += len(robot)
        assert sequences == sorted(set(sequences)), f"{topic}: sequence numbers not increasing: {sequences}"
    assert robot_markers > 0, "no robot link drawn, though the joint states came (with the markers of their round)"
