"""rmw_zenoh's wire format: known answers from its design document, attachments, and hostile samples."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest
import zenoh

from hrc_contract.config import ConfigError
from hrc_devices.ros2 import rmw_zenoh as rz
from hrc_runtime.zenoh_session import session_config

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

CHATTER_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"  # design.md's example
GID = bytes(range(16))


def test_keys_match_the_design_document_examples() -> None:
    wire = rz.topic_type("jazzy", "std_msgs/msg/String")
    assert wire == rz.TopicType("std_msgs/msg/String", "std_msgs::msg::dds_::String_", CHATTER_HASH)
    assert rz.topic_key(0, "/chatter", wire) == f"0/chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH}"
    assert rz.topic_key(0, rz.fully_qualified_name("/robot1", "chatter"), wire).startswith("0/robot1/chatter/")
    session = "aac3178e146ba6f1fc6e6a4085e77f21"
    assert rz.node_token(2, session, 0, "", "listener") == f"@ros2_lv/2/{session}/0/0/NN/%/%/listener"
    token = rz.endpoint_token("MS", 2, session, 0, 10, "/", "listener", "/chatter", wire, rz.Qos(depth=10))
    assert token == (
        f"@ros2_lv/2/{session}/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH}/1:2:1,10:,:,:,,"
    )
    assert rz.parse_endpoint_token(token)["topic"] == "/chatter"


def test_humble_keys_carry_no_hash() -> None:
    wire = rz.topic_type("humble", "std_msgs/msg/Float64")
    assert wire.type_hash == "TypeHashNotSupported"
    assert rz.topic_key(3, "/a/b", wire) == "3/a/b/std_msgs::msg::dds_::Float64_/TypeHashNotSupported"


def test_namespaces_are_mangled() -> None:
    wire = rz.topic_type("jazzy", "std_msgs/msg/Float64")
    token = rz.endpoint_token("MP", 0, "z", 0, 1, "cell/a", "gw", "/cell/a/speed", wire)
    assert "/MP/%/%cell%a/gw/%cell%a%speed/" in token


@pytest.mark.parametrize(("namespace", "name"), [("/a//b", "x"), ("", "1x"), ("", "a-b"), ("", "")])
def test_bad_ros_names_are_refused(namespace: str, name: str) -> None:
    with pytest.raises(ConfigError):
        rz.fully_qualified_name(namespace, name)


def test_attachment_round_trip_is_33_bytes_as_the_design_document_lays_out() -> None:
    data = rz.encode_attachment(rz.Attachment(7, 1_790_000_000_000_000_000, GID))
    assert len(data) == 33
    assert data == struct.pack("<qqB", 7, 1_790_000_000_000_000_000, 16) + GID
    assert rz.decode_attachment(data) == rz.Attachment(7, 1_790_000_000_000_000_000, GID)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\x00" * 32,
        b"\x00" * 34,
        struct.pack("<qqB", 1, 1, 15) + GID,
        struct.pack("<qqB", -1, 1, 16) + GID,
        struct.pack("<qqB", 1, -5, 16) + GID,
    ],
)
def test_malformed_attachments_are_refused(data: bytes) -> None:
    with pytest.raises(rz.AttachmentError):
        rz.decode_attachment(data)


def _subscription(received: list[tuple[bytes, rz.Attachment]], distro: rz.Distro = "jazzy") -> rz.Ros2Subscription:
    wire = rz.topic_type(distro, "sensor_msgs/msg/JointState")
    return rz.Ros2Subscription("0/js/*/*", "token", wire, lambda p, a: received.append((p, a)), max_payload_bytes=1000)


def test_hostile_samples_are_dropped_and_counted_by_reason() -> None:
    received: list[tuple[bytes, rz.Attachment]] = []
    sub = _subscription(received)
    good_key = rz.topic_key(0, "/js", sub.wire)
    attachment = rz.encode_attachment(rz.Attachment(1, time.time_ns(), GID))
    sub.on_sample(good_key, b"ok", attachment)
    sub.on_sample(good_key, b"x", None)
    sub.on_sample(good_key, b"x", attachment[:-1])
    sub.on_sample(good_key, b"x", b"garbage")
    sub.on_sample(good_key, b"x" * 1001, attachment)
    sub.on_sample(good_key.replace(sub.wire.type_hash, "TypeHashNotSupported"), b"x", attachment)
    sub.on_sample(good_key.replace(sub.wire.type_hash, "RIHS01_" + "0" * 64), b"x", attachment)
    sub.on_sample("0/js/std_msgs::msg::dds_::String_/" + sub.wire.type_hash, b"x", attachment)
    assert received == [(b"ok", rz.Attachment(1, received[0][1].source_timestamp_ns, GID))]
    assert sub.counts() == (
        1,
        {"no_attachment": 1, "attachment_malformed": 2, "too_large": 1, "wrong_type_hash": 2, "wrong_type": 1},
    )


def test_a_raising_callback_is_counted_never_raised() -> None:
    def boom(payload: bytes, attachment: rz.Attachment) -> None:
        rz.deserialize("jazzy", payload, "sensor_msgs/msg/JointState")  # malformed CDR raises inside

    wire = rz.topic_type("jazzy", "sensor_msgs/msg/JointState")
    sub = rz.Ros2Subscription("0/js/*/*", "t", wire, boom)
    sub.on_sample(
        rz.topic_key(0, "/js", wire), b"\x00\x01\x00\x00\xff\xff", rz.encode_attachment(rz.Attachment(1, 1, GID))
    )
    assert sub.counts() == (0, {"callback_error": 1})


def test_messages_round_trip_in_each_distro() -> None:
    for distro in rz.DISTROS:
        message = rz.new_message(distro, "sensor_msgs/msg/JointState", name=["a"], position=np.array([0.5]))
        back = rz.deserialize(distro, rz.serialize(distro, message), "sensor_msgs/msg/JointState")
        assert (back.name, back.position.tolist()) == (["a"], [0.5])


def test_nodes_talk_over_loopback_with_tokens_and_attachments() -> None:
    received: list[tuple[bytes, rz.Attachment]] = []
    with zenoh.open(session_config()) as session, rz.Ros2Node(session, "gw", "/cell", 5, "humble") as node:
        pub = node.create_publisher("speed", "std_msgs/msg/Float64")
        sub = node.create_subscription("speed", "std_msgs/msg/Float64", lambda p, a: received.append((p, a)))
        tokens = rz.liveliness_keys(session, 5)
        assert {node.token_key, pub.token_key, sub.token_key} <= set(tokens)
        for value in (0.25, 0.5):
            pub.publish(rz.new_message("humble", "std_msgs/msg/Float64", data=value))
        deadline = time.monotonic() + 5.0
        while len(received) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert [rz.deserialize("humble", p, "std_msgs/msg/Float64").data for p, _ in received] == [0.25, 0.5]
    assert [a.sequence_number for _, a in received] == [1, 2]
    assert {a.source_gid for _, a in received} == {pub.gid}
