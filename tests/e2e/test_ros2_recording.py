"""``hrc-record --format ros2`` on the real default cell: a ROS 2 bag that ROS tools' readers open (issue 20).

One module-wide run: gateway, controller emulator, tracker emulator (a person walks in) and two recorders of the
same traffic, ``--format ros2 --distro jazzy`` and the JSON one, until the gateway has slowed the robot; then SIGINT
to each. The bag opens with ``rosbags.rosbag2.Reader`` (folder with ``metadata.yaml``) and every message decodes
with rosbags' type store; the MCAP file inside opens with the ``mcap`` reader (profile ``ros2``, ``ros2msg``
schemas, ``cdr`` messages) and every message decodes with ``mcap_ros2``'s decoder (judged by a library that is not
rosbags). The overrides in the bag are those of the JSON recording.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from hrc_devices.ros2.rmw_zenoh import typestore
from hrc_tools.cell.procs import Cell, free_endpoint, free_port, stop_program
from hrc_tools.record.ros2_mcap import bag_custom_data, bag_file

pytestmark = pytest.mark.e2e

START_TIMEOUT_S = 40.0
CELL = "demo"


@dataclass(frozen=True)
class Recorded:
    bag: Path
    json_mcap: Path
    exit_codes: dict[str, int]
    tail: str


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Recorded]:
    tmp = tmp_path_factory.mktemp("ros2_recording")
    gw_ep, ctrl_ep, http_port = free_endpoint(), free_endpoint(), free_port()
    bag, json_mcap = tmp / "cell_bag", tmp / "cell.mcap"
    events = ["--events-url", f"http://127.0.0.1:{http_port}"]
    commands = {
        "gateway": ("gateway", ["--zenoh-listen", gw_ep, "--http-port", str(http_port)]),
        "ros2": (
            "hrc_tools.record",
            ["--zenoh-connect", gw_ep, "--format", "ros2", "--distro", "jazzy", "--output", str(bag), *events],
        ),
        "json": ("hrc_tools.record", ["--zenoh-connect", gw_ep, "--output", str(json_mcap), *events]),
        "controller": ("controller_emu", ["--zenoh-listen", ctrl_ep, "--zenoh-connect", gw_ep]),
        "tracker": ("tracker_emu", ["--zenoh-connect", gw_ep, "--seed", "0"]),
    }
    cell = Cell({}, commands, http_port, gw_ep, ctrl_ep, {name: tmp / f"{name}.log" for name in commands})
    codes: dict[str, int] = {}
    try:
        for name in ("gateway", "controller"):
            cell.start(name)
        cell.wait_until(lambda s: s["delta_applied"] is not None, START_TIMEOUT_S, "the controller's joint states")
        for name in ("ros2", "json", "tracker"):
            cell.start(name)
        cell.wait_until(lambda s: 0.0 < s["delta"] < 1.0, START_TIMEOUT_S, "δ slowed for the approaching person")
        for name in ("ros2", "json"):  # SIGINT: each closes its recording
            codes[name] = stop_program(cell.procs[name])
        yield Recorded(bag, json_mcap, codes, cell.tail())
    finally:
        for proc in cell.procs.values():
            if proc.poll() is None:
                stop_program(proc)


EXPECTED = {
    "/ur5/joint_states": "sensor_msgs/msg/JointState",
    "/ur5/speed_override": "std_msgs/msg/Float64",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "/hrc_markers": "visualization_msgs/msg/MarkerArray",
    "/trackers/front/markers": "visualization_msgs/msg/MarkerArray",
    "/trackers/side/markers": "visualization_msgs/msg/MarkerArray",
    "/truth/ur5/joint_states": "sensor_msgs/msg/JointState",
    "/truth/markers": "visualization_msgs/msg/MarkerArray",
    "/rosout": "rcl_interfaces/msg/Log",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}


def _rosbags_messages(bag: Path) -> tuple[dict[str, str], dict[str, list[Any]], dict[str, int]]:
    """topic → type; topic → decoded messages; topic → message count (``metadata.yaml``)."""
    store = typestore("jazzy")
    types: dict[str, str] = {}
    messages: dict[str, list[Any]] = {}
    with Reader(bag) as reader:
        for connection in reader.connections:
            types[connection.topic] = connection.msgtype
        for connection, _, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(store.deserialize_cdr(raw, connection.msgtype))
        counts = {c.topic: c.msgcount for c in reader.connections}
    return types, messages, counts


def test_recorders_close_on_ctrl_c(recorded: Recorded) -> None:
    assert recorded.exit_codes == {"ros2": 0, "json": 0}, recorded.tail


def test_the_bag_opens_with_rosbags_and_every_message_decodes(recorded: Recorded) -> None:
    assert (recorded.bag / "metadata.yaml").is_file()
    types, messages, counts = _rosbags_messages(recorded.bag)
    for topic, msgtype in EXPECTED.items():
        assert types.get(topic) == msgtype, f"{topic}: {types.get(topic)}; topics {sorted(types)}\n{recorded.tail}"
        assert messages.get(topic), f"no message on {topic}"
    assert {t: len(m) for t, m in messages.items()} == counts
    custom = bag_custom_data(recorded.bag)
    assert (custom["hrc.complete"], custom["cell"]) == ("true", CELL)
    joints = messages["/ur5/joint_states"][-1]
    assert list(joints.name) == [
        "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
    ]  # fmt: skip
    assert len(joints.position) == 6
    assert any(0.0 < m.data < 1.0 for m in messages["/ur5/speed_override"]), "the slowing down is in the bag"
    zones = {kv.value for d in messages["/diagnostics"] for s in d.status for kv in s.values if kv.key == "zone"}
    assert zones - {"autonomous"}, zones
    assert any(m.ns == "front/h1" for a in messages["/trackers/front/markers"] for m in a.markers)
    assert any(line.function == "start" for line in messages["/rosout"])


def test_the_mcap_file_is_a_ros2_mcap_that_mcap_ros2_decodes(recorded: Recorded) -> None:
    decoder = pytest.importorskip("mcap_ros2.decoder")
    with bag_file(recorded.bag).open("rb") as f:
        reader = make_reader(f, decoder_factories=[decoder.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None, "no summary: the file was not closed"
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        schemas = {s.name: s.data.decode() for s in summary.schemas.values()}
        assert "MSG: std_msgs/Header" in schemas["sensor_msgs/msg/JointState"]  # nested definitions concatenated
        decoded: dict[str, int] = {}
        for _, channel, _, message in reader.iter_decoded_messages():
            decoded[channel.topic] = decoded.get(channel.topic, 0) + 1
            assert message is not None
    assert decoded == _rosbags_messages(recorded.bag)[2]


def test_the_overrides_are_those_of_the_json_recording(recorded: Recorded) -> None:
    _, messages, _ = _rosbags_messages(recorded.bag)
    with recorded.json_mcap.open("rb") as f:
        json_deltas = {
            json.loads(m.data)["delta"]
            for _, c, m in make_reader(f).iter_messages()
            if c.topic == f"/hrc/{CELL}/robot/ur5/override"
        }
    ros2_deltas = {m.data for m in messages["/ur5/speed_override"]}
    # the two recorders joined a moment apart: most of what one holds, the other holds too
    assert len(ros2_deltas & json_deltas) >= 0.9 * min(len(ros2_deltas), len(json_deltas)) > 0
