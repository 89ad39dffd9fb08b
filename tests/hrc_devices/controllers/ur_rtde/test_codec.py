"""The RTDE codec: known messages, round trips, and hostile bytes that must raise RtdeError and nothing else."""

from __future__ import annotations

import contextlib
import math
import random
import struct
from collections.abc import Callable

import pytest
from support.ur_rtde_cases import UR_RTDE_DEFAULT_OUTPUTS

from hrc_devices.controllers.ur_rtde import codec as rtde
from hrc_devices.controllers.ur_rtde.codec import MessageType, Recipe, RtdeError


def test_header_is_big_endian_size_including_itself_then_type() -> None:
    assert (
        rtde.pack_message(MessageType.REQUEST_PROTOCOL_VERSION, rtde.encode_version_request(2)) == b"\x00\x05V\x00\x02"
    )
    assert rtde.pack_message(MessageType.CONTROL_PACKAGE_START) == b"\x00\x03S"


def test_take_messages_keeps_a_partial_message_for_later() -> None:
    data = rtde.pack_message(MessageType.GET_URCONTROL_VERSION) + rtde.pack_message(
        MessageType.DATA_PACKAGE, b"\x01abc"
    )
    buffer = bytearray(data[:-2])
    assert [m.type_code for m in rtde.take_messages(buffer)] == [MessageType.GET_URCONTROL_VERSION]
    buffer += data[-2:]
    assert rtde.take_messages(buffer) == [rtde.Message(MessageType.DATA_PACKAGE, b"\x01abc")]
    assert buffer == bytearray()


@pytest.mark.parametrize(("raw", "reason"), [(b"\x00\x02V", "garbage"), (b"\xff\xffU", "oversize")])
def test_take_messages_refuses_a_broken_size_field(raw: bytes, reason: str) -> None:
    with pytest.raises(RtdeError) as caught:
        rtde.take_messages(bytearray(raw))
    assert caught.value.reason == reason


def test_pack_message_refuses_oversize() -> None:
    with pytest.raises(RtdeError, match="oversize"):
        rtde.pack_message(MessageType.DATA_PACKAGE, bytes(rtde.MAX_MESSAGE_BYTES))


def test_output_setup_drops_the_trailing_comma_ur_rtde_sends() -> None:
    payload = struct.pack(">d", 500.0) + b"timestamp,actual_q,"
    assert rtde.decode_output_setup(payload) == (500.0, ("timestamp", "actual_q"))
    assert rtde.decode_output_setup(rtde.encode_output_setup(125.0, ["speed_scaling"])) == (125.0, ("speed_scaling",))


@pytest.mark.parametrize(
    "payload",
    [
        b"\x00\x00",  # shorter than the frequency
        struct.pack(">d", math.nan) + b"timestamp",
        struct.pack(">d", 125.0) + b",,,",
        struct.pack(">d", 125.0) + "zeit\u00e4".encode(),
        struct.pack(">d", 125.0) + b"a;drop",
        struct.pack(">d", 125.0) + b",".join([b"x"] * (rtde.MAX_NAMES + 1)),
    ],
)
def test_output_setup_refuses_malformed_payloads(payload: bytes) -> None:
    with pytest.raises(RtdeError) as caught:
        rtde.decode_output_setup(payload)
    assert caught.value.reason == "malformed"


def test_data_round_trip_with_vectors() -> None:
    recipe = Recipe(
        3, ("timestamp", "actual_q", "runtime_state", "safety_mode"), ("DOUBLE", "VECTOR6D", "UINT32", "INT32")
    )
    values = (1.5, (0.0, 1.0, 2.0, 3.0, 4.0, 5.0), 2, -1)
    payload = rtde.encode_data(recipe, values)
    assert payload[0] == 3
    assert len(payload) == 1 + 8 + 48 + 4 + 4
    assert rtde.decode_data(recipe, payload) == values


def test_slider_package_as_ur_rtde_sends_it() -> None:
    """ur-rtde's recipe 4: ``input_int_register_23, speed_slider_mask, speed_slider_fraction`` (field notes)."""
    recipe = Recipe(
        4, ("input_int_register_23", "speed_slider_mask", "speed_slider_fraction"), ("INT32", "UINT32", "DOUBLE")
    )
    payload = b"\x04" + struct.pack(">iId", 22, 1, 0.5)
    assert rtde.decode_data(recipe, payload) == (22, 1, 0.5)


def test_decode_data_refuses_wrong_length_and_foreign_recipe() -> None:
    recipe = Recipe(1, ("speed_slider_mask", "speed_slider_fraction"), ("UINT32", "DOUBLE"))
    good = rtde.encode_data(recipe, (1, 0.5))
    with pytest.raises(RtdeError, match="malformed"):
        rtde.decode_data(recipe, good[:-1])
    with pytest.raises(RtdeError, match="unknown_recipe"):
        rtde.decode_data(recipe, b"\x02" + good[1:])
    with pytest.raises(RtdeError, match="malformed"):
        rtde.encode_data(recipe, (1, "fast"))


@pytest.mark.parametrize("kind", [rtde.NOT_FOUND, rtde.IN_USE, "FLOAT"])
def test_recipe_refuses_unusable_types(kind: str) -> None:
    with pytest.raises(RtdeError) as caught:
        Recipe(1, ("a",), (kind,))
    assert caught.value.reason == "bad_type"


def test_input_types_from_the_rtde_guide() -> None:
    assert rtde.input_type("speed_slider_mask") == "UINT32"
    assert rtde.input_type("speed_slider_fraction") == "DOUBLE"
    assert rtde.input_type("input_int_register_23") == "INT32"
    assert rtde.input_type("input_double_register_47") == "DOUBLE"
    assert rtde.input_type("input_bit_register_64") == "BOOL"
    assert rtde.input_type("standard_digital_output") == "UINT8"
    assert rtde.input_type("input_int_register_48") is None
    assert rtde.input_type("input_bit_register_3") is None
    assert rtde.input_type("input_int_register_023") is None  # no such name: a leading zero is not an index
    assert rtde.input_type("output_int_register_2") is None
    assert rtde.input_type("actual_q") is None


def test_output_types_from_the_rtde_guide() -> None:
    """Every output ur-rtde 1.6.5 asks a 5.11 controller for by default is known; newer ones and bad indices not."""
    assert all(rtde.output_type(name) is not None for name in UR_RTDE_DEFAULT_OUTPUTS)
    assert rtde.output_type("actual_TCP_pose") == "VECTOR6D"
    assert rtde.output_type("joint_mode") == "VECTOR6INT32"
    assert rtde.output_type("actual_digital_input_bits") == "UINT64"
    assert rtde.output_type("tool_output_mode") == "UINT8"
    assert rtde.output_type("output_bit_register_64") == "BOOL"
    assert rtde.output_type("output_double_register_0") == "DOUBLE"
    assert rtde.output_type("input_int_register_23") == "INT32"  # an input read back
    for newer in ("actual_current_as_torque", "joint_position_deviation_ratio", "tcp_offset", "time_scale_source"):
        assert rtde.output_type(newer) is None
    for unknown in ("output_bit_register_63", "output_int_register_48", "output_int_register_023", "speed_slider_mask"):
        assert rtde.output_type(unknown) is None


def test_text_message_round_trip_and_truncation() -> None:
    payload = rtde.encode_text("bad frequency", "emu", rtde.TextLevel.ERROR)
    assert rtde.decode_text(payload) == ("bad frequency", "emu", rtde.TextLevel.ERROR)
    for cut in range(len(payload)):
        with pytest.raises(RtdeError):
            rtde.decode_text(payload[:cut])


def test_controller_version_and_accepted_flags() -> None:
    assert rtde.decode_controller_version(rtde.encode_controller_version(5, 11, 0, 7)) == (5, 11, 0, 7)
    assert rtde.decode_accepted(b"\x01") is True
    assert rtde.decode_accepted(b"\x00") is False
    for bad in (b"", b"\x02", b"\x01\x00"):
        with pytest.raises(RtdeError):
            rtde.decode_accepted(bad)


def test_random_bytes_raise_only_rtde_error() -> None:
    """Every decoder on seeded random bytes: a value or an RtdeError, never another exception."""
    rng = random.Random(19)
    recipe = Recipe(1, ("timestamp", "actual_q", "runtime_state"), ("DOUBLE", "VECTOR6D", "UINT32"))
    decoders: list[Callable[[bytes], object]] = [
        rtde.decode_version_request,
        rtde.decode_accepted,
        rtde.decode_controller_version,
        rtde.decode_output_setup,
        rtde.decode_input_setup,
        rtde.decode_setup_reply,
        rtde.decode_text,
        lambda payload: rtde.decode_data(recipe, payload),
        lambda payload: rtde.take_messages(bytearray(payload)),
    ]
    for _ in range(3000):
        payload = rng.randbytes(rng.randrange(0, 80))
        for decode in decoders:
            with contextlib.suppress(RtdeError):
                decode(payload)
