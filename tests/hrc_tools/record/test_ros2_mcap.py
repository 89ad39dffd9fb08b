"""The ROS 2 bag writer: read back by rosbags (a rosbag2 folder) and by the ``mcap`` reader with ``mcap_ros2``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from hrc_devices.ros2.rmw_zenoh import Distro, new_message, typestore
from hrc_runtime.mcap_sink import RecordingError
from hrc_tools.record.ros2_mcap import BAG_VERSION, Ros2BagSink, Ros2Topic, bag_custom_data, bag_file, qos

FLOAT64 = Ros2Topic("/ur5/speed_override", "std_msgs/msg/Float64")
JOINTS = Ros2Topic("/ur5/joint_states", "sensor_msgs/msg/JointState")
STAMP_NS = 1_790_000_000_000_000_000


def _float(distro: Distro) -> Any:
    def build(value: float) -> list[tuple[Ros2Topic, Any]]:
        return [(FLOAT64, new_message(distro, FLOAT64.msgtype, data=value))]

    return build


def _joints(distro: Distro) -> Any:
    def build(names: list[str]) -> list[tuple[Ros2Topic, Any]]:
        return [(JOINTS, new_message(distro, JOINTS.msgtype, name=names))]

    return build


def _read(bag: Path, distro: Distro) -> list[tuple[str, int, Any]]:
    """(topic, log time, decoded message) of every message, by rosbags."""
    with Reader(bag) as reader:
        return [(c.topic, t, typestore(distro).deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]


@pytest.mark.parametrize("distro", ["humble", "jazzy", "kilted"])
def test_a_bag_reads_back_with_rosbags_in_the_order_written(tmp_path: Path, distro: Distro) -> None:
    bag = tmp_path / "bag"
    with Ros2BagSink(bag, distro, custom_data={"cell": "demo"}) as sink:
        for i, delta in enumerate([1.0, 0.62, 0.0]):
            sink.offer(STAMP_NS + i, _float(distro), delta)
        sink.offer(STAMP_NS + 3, _joints(distro), ["a", "b"])
    summary = sink.close()
    assert (summary.records, summary.dropped, summary.complete) == (4, 0, True)
    read = _read(bag, distro)
    assert [(t, s, getattr(m, "data", None)) for t, s, m in read[:3]] == [
        (FLOAT64.name, STAMP_NS, 1.0),
        (FLOAT64.name, STAMP_NS + 1, 0.62),
        (FLOAT64.name, STAMP_NS + 2, 0.0),
    ]
    assert list(read[3][2].name) == ["a", "b"]
    assert bag_custom_data(bag) == {
        "cell": "demo", "hrc.records": "4", "hrc.dropped": "0", "hrc.complete": "true", "hrc.error": "",
    }  # fmt: skip
    assert f"version: {BAG_VERSION[distro]}" in (bag / "metadata.yaml").read_text()


def test_the_mcap_file_is_what_rosbag2_stores(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with Ros2BagSink(bag, "jazzy") as sink:
        sink.offer(STAMP_NS, _joints("jazzy"), ["a"])
    with bag_file(bag).open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        (schema,) = summary.schemas.values()
        (channel,) = summary.channels.values()
    definition, _ = typestore("jazzy").generate_msgdef(JOINTS.msgtype, ros_version=2)
    assert (schema.name, schema.encoding, schema.data.decode()) == (JOINTS.msgtype, "ros2msg", definition)
    assert "=" * 80 + "\nMSG: std_msgs/Header\n" in definition
    assert (channel.topic, channel.message_encoding) == (JOINTS.name, "cdr")
    assert "reliability: 1" in channel.metadata["offered_qos_profiles"]


def test_mcap_ros2_decodes_every_message(tmp_path: Path) -> None:
    decoder = pytest.importorskip("mcap_ros2.decoder")
    bag = tmp_path / "bag"
    with Ros2BagSink(bag, "humble") as sink:
        sink.offer(STAMP_NS, _float("humble"), 0.25)
        sink.offer(STAMP_NS, _joints("humble"), ["j1", "j2"])
    with bag_file(bag).open("rb") as f:
        decoded = [m for *_, m in make_reader(f, decoder_factories=[decoder.DecoderFactory()]).iter_decoded_messages()]
    assert decoded[0].data == 0.25
    assert list(decoded[1].name) == ["j1", "j2"]


def test_an_existing_bag_is_never_overwritten(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "keep").write_text("evidence")
    with pytest.raises(RecordingError, match="exists already"):
        Ros2BagSink(bag, "jazzy")
    assert (bag / "keep").read_text() == "evidence"


def test_a_message_that_cannot_be_built_is_dropped_not_the_bag(tmp_path: Path) -> None:
    bag = tmp_path / "bag"

    def broken(_: object) -> list[tuple[Ros2Topic, Any]]:
        raise ValueError("not a message")

    def wrong_type(_: object) -> list[tuple[Ros2Topic, Any]]:  # the topic is Float64 already
        return [(Ros2Topic(FLOAT64.name, JOINTS.msgtype), new_message("jazzy", JOINTS.msgtype))]

    with Ros2BagSink(bag, "jazzy") as sink:
        sink.offer(STAMP_NS, _float("jazzy"), 0.5)
        sink.offer(STAMP_NS + 1, broken, None)
        sink.offer(STAMP_NS + 2, wrong_type, None)
        sink.offer(STAMP_NS + 3, _float("jazzy"), 0.4)
    summary = sink.close()
    assert (summary.records, summary.dropped, summary.complete) == (2, 2, False)
    assert [m.data for _, _, m in _read(bag, "jazzy")] == [0.5, 0.4]
    assert bag_custom_data(bag)["hrc.complete"] == "false"


def test_a_full_queue_drops_and_counts_instead_of_waiting(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    sink = Ros2BagSink(bag, "jazzy", max_queued=1)  # not started: nothing drains the queue
    assert sink.offer(STAMP_NS, _float("jazzy"), 0.5)
    assert not sink.offer(STAMP_NS + 1, _float("jazzy"), 0.4)
    summary = sink.close()
    assert (summary.records, summary.dropped) == (1, 1)
    assert bag_custom_data(bag)["hrc.dropped"] == "1"


def test_tf_static_is_offered_transient_local(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    topic = Ros2Topic("/tf_static", "tf2_msgs/msg/TFMessage", qos(depth=1, transient_local=True))
    with Ros2BagSink(bag, "jazzy") as sink:
        sink.offer(STAMP_NS, lambda _: [(topic, new_message("jazzy", topic.msgtype))], None)
    with Reader(bag) as reader:
        (connection,) = reader.connections
        (offered,) = connection.ext.offered_qos_profiles  # type: ignore[union-attr]
    assert (offered.durability.name, offered.depth) == ("TRANSIENT_LOCAL", 1)


def test_bag_custom_data_of_a_folder_that_is_no_bag(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="not a closed ROS 2 bag"):
        bag_custom_data(tmp_path)
