"""The Universal Robots RTDE wire codec (protocol version 2), pure: bytes in, values out, and back.

Every message is a 3-byte big-endian header (``uint16`` size including the header, ``uint8`` type) and a payload::

    data = pack_message(MessageType.REQUEST_PROTOCOL_VERSION, encode_version_request(2))
    messages = take_messages(buffer)           # consumes whole messages from a bytearray
    recipe = Recipe(1, ("timestamp", "actual_q"), ("DOUBLE", "VECTOR6D"))
    values = decode_data(recipe, payload)      # (12.5, (0.0, ...))

Types (UR's RTDE guide, "Protocol"): ``V`` 86 protocol version, ``v`` 118 controller version, ``O`` 79 output
setup (frequency + names), ``I`` 73 input setup, ``S`` 83 start, ``P`` 80 pause, ``U`` 85 data, ``M`` 77 text.
A setup is answered with a recipe id and the variables' types, ``NOT_FOUND`` for a name the controller does not
know and ``IN_USE`` for an input another client controls. Data packages carry the recipe id in their first byte.

Both the controller emulator's RTDE face (the server) and the bridge's client use this module. Every decoder
treats its bytes as hostile: a short, long, non-ASCII or non-finite payload raises :class:`RtdeError` with a
``reason`` for counting, never an ``IndexError`` or ``struct.error``.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property
from types import MappingProxyType

from hrc_contract.errors import HrcError

HEADER = struct.Struct(">HB")
HEADER_SIZE = HEADER.size

PROTOCOL_VERSION = 2
"""The protocol version this codec speaks (recipe ids in data packages, text messages with a source)."""

MAX_MESSAGE_BYTES = 4096
"""The largest message accepted, header included [bytes]. ur-rtde's receive interface asking for every variable
it knows sends about 1.1 kB; anything near the uint16 limit is hostile."""

MAX_NAMES = 128
"""Most variable names in one recipe."""

NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")


class RtdeError(HrcError):
    """Bytes that are not a valid RTDE message (or not the one expected).

    Attributes:
        reason: a short key for counting: ``garbage`` (header size below 3), ``oversize``, ``unknown_type``,
            ``malformed`` (payload does not decode), ``unknown_recipe``, ``bad_type`` (an unusable type name).
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason = reason


class MessageType(IntEnum):
    """The RTDE message types (the ASCII code of their letter)."""

    REQUEST_PROTOCOL_VERSION = 86  # V
    GET_URCONTROL_VERSION = 118  # v
    TEXT_MESSAGE = 77  # M
    DATA_PACKAGE = 85  # U
    CONTROL_PACKAGE_SETUP_OUTPUTS = 79  # O
    CONTROL_PACKAGE_SETUP_INPUTS = 73  # I
    CONTROL_PACKAGE_START = 83  # S
    CONTROL_PACKAGE_PAUSE = 80  # P


class TextLevel(IntEnum):
    """Severity of a text message (``M``)."""

    EXCEPTION = 0
    ERROR = 1
    WARNING = 2
    INFO = 3


# The controller's state codes, as UR's client libraries and ur_rtde define them.
RUNTIME_STOPPING = 0
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
RUNTIME_PAUSING = 3
RUNTIME_PAUSED = 4
RUNTIME_RESUMING = 5
ROBOT_MODE_RUNNING = 7
SAFETY_NORMAL = 1
SAFETY_REDUCED = 2
SAFETY_PROTECTIVE_STOP = 3
ROBOT_STATUS_POWER_ON = 1
ROBOT_STATUS_PROGRAM_RUNNING = 2
SAFETY_STATUS_NORMAL = 1
SAFETY_STATUS_REDUCED = 2
SAFETY_STATUS_PROTECTIVE_STOPPED = 4

_TYPE_FORMATS = MappingProxyType(
    {
        "BOOL": "?",
        "UINT8": "B",
        "UINT32": "I",
        "UINT64": "Q",
        "INT32": "i",
        "DOUBLE": "d",
        "VECTOR3D": "ddd",
        "VECTOR6D": "dddddd",
        "VECTOR6INT32": "iiiiii",
        "VECTOR6UINT32": "IIIIII",
    }
)
"""Struct format of each RTDE type (big-endian is added per recipe)."""

OUTPUT_TYPES_VERSION = (5, 11, 0, 0)
"""The controller software whose outputs :data:`OUTPUT_TYPES` lists (major, minor, bugfix, build: e-Series 5.11)."""

OUTPUT_TYPES = MappingProxyType(
    {
        # UR's RTDE guide, "Robot Controller Outputs", the variables with a fixed name, as an e-Series controller with
        # software 5.11 serves them (the guide's "introduced in" where it gives one). Newer ones are not here, so a
        # 5.11 controller's answer to them, NOT_FOUND, is kept: actual_current_window, actual_current_as_torque
        # (ur-rtde 1.6.5 asks for it from 5.23), tcp_offset, actual_TCP_acceleration, target_TCP_acceleration,
        # actual_configurable_digital_input_bits, target_execution_time, joint_position_deviation_ratio,
        # collision_detection_ratio, time_scale_source, wrench_calc_from_currents, target_gravity,
        # target_base_acceleration.
        "timestamp": "DOUBLE",
        "target_q": "VECTOR6D",
        "target_qd": "VECTOR6D",
        "target_qdd": "VECTOR6D",
        "target_current": "VECTOR6D",
        "target_moment": "VECTOR6D",
        "actual_q": "VECTOR6D",
        "actual_qd": "VECTOR6D",
        "actual_current": "VECTOR6D",
        "joint_control_output": "VECTOR6D",
        "actual_TCP_pose": "VECTOR6D",
        "actual_TCP_speed": "VECTOR6D",
        "actual_TCP_force": "VECTOR6D",
        "target_TCP_pose": "VECTOR6D",
        "target_TCP_speed": "VECTOR6D",
        "actual_digital_input_bits": "UINT64",
        "joint_temperatures": "VECTOR6D",
        "actual_execution_time": "DOUBLE",
        "robot_mode": "INT32",
        "joint_mode": "VECTOR6INT32",
        "safety_mode": "INT32",
        "safety_status": "INT32",  # 5.4.0
        "actual_tool_accelerometer": "VECTOR3D",
        "speed_scaling": "DOUBLE",
        "target_speed_fraction": "DOUBLE",
        "actual_momentum": "DOUBLE",
        "actual_main_voltage": "DOUBLE",
        "actual_robot_voltage": "DOUBLE",
        "actual_robot_current": "DOUBLE",
        "actual_joint_voltage": "VECTOR6D",
        "actual_digital_output_bits": "UINT64",
        "runtime_state": "UINT32",
        "elbow_position": "VECTOR3D",  # 5.0.0
        "elbow_velocity": "VECTOR3D",  # 5.0.0
        "robot_status_bits": "UINT32",
        "safety_status_bits": "UINT32",
        "analog_io_types": "UINT32",
        "standard_analog_input0": "DOUBLE",
        "standard_analog_input1": "DOUBLE",
        "standard_analog_output0": "DOUBLE",
        "standard_analog_output1": "DOUBLE",
        "io_current": "DOUBLE",
        "euromap67_input_bits": "UINT32",
        "euromap67_output_bits": "UINT32",
        "euromap67_24V_voltage": "DOUBLE",
        "euromap67_24V_current": "DOUBLE",
        "tool_mode": "UINT32",
        "tool_analog_input_types": "UINT32",
        "tool_analog_input0": "DOUBLE",
        "tool_analog_input1": "DOUBLE",
        "tool_output_voltage": "INT32",
        "tool_output_current": "DOUBLE",
        "tool_temperature": "DOUBLE",
        "tcp_force_scalar": "DOUBLE",
        "output_bit_registers0_to_31": "UINT32",
        "output_bit_registers32_to_63": "UINT32",
        "input_bit_registers0_to_31": "UINT32",  # the inputs read back
        "input_bit_registers32_to_63": "UINT32",
        "tool_output_mode": "UINT8",  # 5.2.0
        "tool_digital_output0_mode": "UINT8",  # 5.2.0
        "tool_digital_output1_mode": "UINT8",  # 5.2.0
        "payload": "DOUBLE",  # 5.5.1 (ur-rtde's gate)
        "payload_cog": "VECTOR3D",  # 5.5.1
        "payload_inertia": "VECTOR6D",  # 5.11.0
        "script_control_line": "UINT32",  # in UR's client library table; no "introduced in" found for it
        "ft_raw_wrench": "VECTOR6D",  # 5.9.0
    }
)
"""The output variables with a fixed name and their RTDE types; the registers are :func:`output_type`'s."""

SLIDER_INPUT_TYPES = MappingProxyType({"speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE"})
"""The speed slider inputs (``speed_slider_mask`` 1 = apply ``speed_slider_fraction``, 0–1)."""


_REGISTER = re.compile(r"(input|output)_(bit|int|double)_register_(0|[1-9][0-9]{0,2})")


def _register_type(name: str, direction: str) -> str | None:
    """The type of a general purpose register (UR's RTDE guide): bits 64-127 (0-63 are the two UINT32 words),
    integers and doubles 0-47; None for any other name (a leading zero included, as the controller has no such name)."""
    match = _REGISTER.fullmatch(name)
    if match is None or match.group(1) != direction:
        return None
    kind, index = match.group(2), int(match.group(3))
    if kind == "bit":
        return "BOOL" if 64 <= index <= 127 else None
    if index > 47:
        return None
    return "INT32" if kind == "int" else "DOUBLE"


def output_type(name: str) -> str | None:
    """The RTDE type of an output variable (UR's RTDE guide, "Robot Controller Outputs"), or None if unknown.

    The names of :data:`OUTPUT_TYPES`, the output registers, and the input registers read back (a client may
    subscribe to an input register to read the value last written).
    """
    fixed = OUTPUT_TYPES.get(name)
    if fixed is not None:
        return fixed
    return _register_type(name, "output") or _register_type(name, "input")


def input_type(name: str) -> str | None:
    """The RTDE type of a writable input variable (UR's RTDE guide, "Controller inputs"), or None if unknown.

    Covers the speed slider, the general purpose input registers and the controller's physical outputs that a
    client may drive (digital, configurable, tool and analog), which ur-rtde's IO interface sets up.
    """
    if name in SLIDER_INPUT_TYPES:
        return SLIDER_INPUT_TYPES[name]
    fixed = _FIXED_INPUTS.get(name)
    if fixed is not None:
        return fixed
    return _register_type(name, "input")


_FIXED_INPUTS = MappingProxyType(
    {
        "standard_digital_output_mask": "UINT8",
        "standard_digital_output": "UINT8",
        "configurable_digital_output_mask": "UINT8",
        "configurable_digital_output": "UINT8",
        "tool_digital_output_mask": "UINT8",
        "tool_digital_output": "UINT8",
        "standard_analog_output_mask": "UINT8",
        "standard_analog_output_type": "UINT8",
        "standard_analog_output_0": "DOUBLE",
        "standard_analog_output_1": "DOUBLE",
        "input_bit_registers0_to_31": "UINT32",
        "input_bit_registers32_to_63": "UINT32",
    }
)


@dataclass(frozen=True)
class Message:
    """One whole message: its type code (not necessarily a known :class:`MessageType`) and payload."""

    type_code: int
    payload: bytes


@dataclass(frozen=True)
class Recipe:
    """A set-up recipe: the variables of one data package, in order.

    Attributes:
        recipe_id: 1–255 (0 is a failed setup).
        names: the variable names.
        types: their RTDE types (same length).

    Raises:
        RtdeError: ``bad_type`` if a type is ``NOT_FOUND``, ``IN_USE`` or unknown; ``malformed`` for an id
            outside 1–255 or lengths that differ.
    """

    recipe_id: int
    names: tuple[str, ...]
    types: tuple[str, ...]

    def __post_init__(self) -> None:
        if not 1 <= self.recipe_id <= 255:
            raise RtdeError("malformed", f"recipe id {self.recipe_id}; allowed: 1-255")
        if len(self.names) != len(self.types) or not self.names:
            raise RtdeError("malformed", f"{len(self.names)} names and {len(self.types)} types; need the same, >= 1")
        unusable = [f"{n}={t}" for n, t in zip(self.names, self.types, strict=True) if t not in _TYPE_FORMATS]
        if unusable:
            raise RtdeError("bad_type", f"unusable variables {', '.join(unusable)}; allowed types: {_type_list()}")

    @cached_property
    def layout(self) -> struct.Struct:
        """The packed layout of the values (without the recipe id byte)."""
        return struct.Struct(">" + "".join(_TYPE_FORMATS[t] for t in self.types))


def _type_list() -> str:
    return ", ".join(_TYPE_FORMATS)


def pack_message(message_type: int, payload: bytes = b"") -> bytes:
    """One message: header and payload.

    Raises:
        RtdeError: ``oversize`` if it exceeds :data:`MAX_MESSAGE_BYTES`.
    """
    size = HEADER_SIZE + len(payload)
    if size > MAX_MESSAGE_BYTES:
        raise RtdeError("oversize", f"message of {size} bytes; allowed: <= {MAX_MESSAGE_BYTES}")
    return HEADER.pack(size, message_type) + payload


def take_messages(buffer: bytearray, max_bytes: int = MAX_MESSAGE_BYTES) -> list[Message]:
    """Remove and return the whole messages at the start of ``buffer``; a partial one stays.

    Raises:
        RtdeError: ``garbage`` for a size field below the header's 3 bytes, ``oversize`` above ``max_bytes``
            (the buffer is then unusable: the stream has lost its framing).
    """
    messages: list[Message] = []
    offset = 0
    while len(buffer) - offset >= HEADER_SIZE:
        size, type_code = HEADER.unpack_from(buffer, offset)
        if size < HEADER_SIZE:
            raise RtdeError("garbage", f"message size field {size}; allowed: >= {HEADER_SIZE} (header included)")
        if size > max_bytes:
            raise RtdeError("oversize", f"message size field {size}; allowed: <= {max_bytes}")
        if len(buffer) - offset < size:
            break
        messages.append(Message(type_code, bytes(buffer[offset + HEADER_SIZE : offset + size])))
        offset += size
    del buffer[:offset]
    return messages


def _exact(payload: bytes, layout: struct.Struct, what: str) -> tuple[int | float | bool, ...]:
    if len(payload) != layout.size:
        raise RtdeError("malformed", f"{what}: {len(payload)} bytes; expected {layout.size}")
    return layout.unpack(payload)


_U16 = struct.Struct(">H")
_U8 = struct.Struct(">B")
_F64 = struct.Struct(">d")
_VERSION = struct.Struct(">IIII")


def encode_version_request(version: int) -> bytes:
    """``V`` request payload: the protocol version (uint16)."""
    return _U16.pack(version)


def decode_version_request(payload: bytes) -> int:
    """The version a ``V`` request asks for."""
    return int(_exact(payload, _U16, "protocol version request")[0])


def encode_accepted(accepted: bool) -> bytes:
    """``V``, ``S`` or ``P`` reply payload: 1 accepted / 0 refused."""
    return _U8.pack(1 if accepted else 0)


def decode_accepted(payload: bytes) -> bool:
    """Whether a ``V``, ``S`` or ``P`` reply says accepted (exactly one byte, 0 or 1)."""
    value = int(_exact(payload, _U8, "accepted flag")[0])
    if value not in (0, 1):
        raise RtdeError("malformed", f"accepted flag {value}; allowed: 0 or 1")
    return value == 1


def encode_controller_version(major: int, minor: int, bugfix: int, build: int) -> bytes:
    """``v`` reply payload: four uint32."""
    return _VERSION.pack(major, minor, bugfix, build)


def decode_controller_version(payload: bytes) -> tuple[int, int, int, int]:
    """The (major, minor, bugfix, build) of a ``v`` reply."""
    major, minor, bugfix, build = _exact(payload, _VERSION, "controller version")
    return int(major), int(minor), int(bugfix), int(build)


def _encode_names(names: tuple[str, ...] | list[str]) -> bytes:
    return ",".join(names).encode("ascii")


def _decode_names(raw: bytes, what: str) -> tuple[str, ...]:
    """Comma-separated names; empty ones (ur-rtde ends its list with a comma) are dropped."""
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise RtdeError("malformed", f"{what}: names are not ASCII") from None
    names = tuple(name for name in text.split(",") if name)
    if not names:
        raise RtdeError("malformed", f"{what}: no variable names")
    if len(names) > MAX_NAMES:
        raise RtdeError("malformed", f"{what}: {len(names)} names; allowed: <= {MAX_NAMES}")
    bad = [name[:70] for name in names if not _NAME.match(name)]
    if bad:
        raise RtdeError("malformed", f"{what}: invalid names {bad[:3]!r}; allowed: letters, digits, _ (<= 64)")
    return names


def encode_output_setup(frequency_hz: float, names: tuple[str, ...] | list[str]) -> bytes:
    """``O`` request payload: the frequency (double) and the comma-separated names."""
    return _F64.pack(frequency_hz) + _encode_names(names)


def decode_output_setup(payload: bytes) -> tuple[float, tuple[str, ...]]:
    """The (frequency [Hz], names) of an ``O`` request. The frequency is finite; its range is the server's call."""
    if len(payload) < _F64.size:
        raise RtdeError("malformed", f"output setup: {len(payload)} bytes; expected >= {_F64.size}")
    (frequency_hz,) = _F64.unpack_from(payload)
    if not math.isfinite(frequency_hz):
        raise RtdeError("malformed", f"output setup: frequency {frequency_hz}; allowed: a finite number")
    return float(frequency_hz), _decode_names(payload[_F64.size :], "output setup")


def encode_input_setup(names: tuple[str, ...] | list[str]) -> bytes:
    """``I`` request payload: the comma-separated names."""
    return _encode_names(names)


def decode_input_setup(payload: bytes) -> tuple[str, ...]:
    """The names of an ``I`` request."""
    return _decode_names(payload, "input setup")


def encode_setup_reply(recipe_id: int, types: tuple[str, ...] | list[str]) -> bytes:
    """``O``/``I`` reply payload: the recipe id (0 = failed) and the comma-separated types."""
    return _U8.pack(recipe_id) + ",".join(types).encode("ascii")


def decode_setup_reply(payload: bytes) -> tuple[int, tuple[str, ...]]:
    """The (recipe id, types) of an ``O``/``I`` reply; types may include ``NOT_FOUND`` and ``IN_USE``."""
    if not payload:
        raise RtdeError("malformed", "setup reply: empty")
    try:
        types = tuple(payload[1:].decode("ascii").split(","))
    except UnicodeDecodeError:
        raise RtdeError("malformed", "setup reply: types are not ASCII") from None
    return payload[0], types


def encode_data(recipe: Recipe, values: tuple[object, ...] | list[object]) -> bytes:
    """``U`` payload: the recipe id and the values packed in the recipe's order (vectors flattened).

    Raises:
        RtdeError: ``malformed`` if the values do not fit the recipe.
    """
    flat: list[object] = []
    for name, kind, value in zip(recipe.names, recipe.types, values, strict=True):
        if kind.startswith("VECTOR"):
            if not isinstance(value, tuple | list) or len(value) != len(_TYPE_FORMATS[kind]):
                raise RtdeError("malformed", f"{name}: {value!r} is not a {kind}")
            flat.extend(value)
        else:
            flat.append(value)
    try:
        return _U8.pack(recipe.recipe_id) + recipe.layout.pack(*flat)
    except struct.error as exc:
        raise RtdeError("malformed", f"values do not fit recipe {recipe.recipe_id}: {exc}") from None


def data_recipe_id(payload: bytes) -> int:
    """The recipe id of a ``U`` payload (its first byte)."""
    if not payload:
        raise RtdeError("malformed", "data package: empty")
    return payload[0]


def decode_data(recipe: Recipe, payload: bytes) -> tuple[int | float | bool | tuple[int | float, ...], ...]:
    """The values of a ``U`` payload for ``recipe``, vectors as tuples, in the recipe's order.

    Raises:
        RtdeError: ``unknown_recipe`` for another recipe id, ``malformed`` for a wrong length.
    """
    if data_recipe_id(payload) != recipe.recipe_id:
        raise RtdeError("unknown_recipe", f"data package for recipe {payload[0]}; expected {recipe.recipe_id}")
    flat = _exact(payload[1:], recipe.layout, f"data package of recipe {recipe.recipe_id}")
    values: list[int | float | bool | tuple[int | float, ...]] = []
    offset = 0
    for kind in recipe.types:
        width = len(_TYPE_FORMATS[kind])
        if kind.startswith("VECTOR"):
            values.append(tuple(flat[offset : offset + width]))
        else:
            values.append(flat[offset])
        offset += width
    return tuple(values)


def encode_text(message: str, source: str, level: TextLevel) -> bytes:
    """``M`` payload (protocol 2): message length, message, source length, source, level."""
    raw_message = message.encode("utf-8")[:255]
    raw_source = source.encode("utf-8")[:255]
    return _U8.pack(len(raw_message)) + raw_message + _U8.pack(len(raw_source)) + raw_source + _U8.pack(level)


def decode_text(payload: bytes) -> tuple[str, str, int]:
    """The (message, source, level) of an ``M`` payload (protocol 2)."""
    try:
        n_message = payload[0]
        message = payload[1 : 1 + n_message]
        n_source = payload[1 + n_message]
        source = payload[2 + n_message : 2 + n_message + n_source]
        level = payload[2 + n_message + n_source]
    except IndexError:
        raise RtdeError("malformed", f"text message: {len(payload)} bytes do not hold its fields") from None
    if len(payload) != 3 + n_message + n_source or len(message) != n_message or len(source) != n_source:
        raise RtdeError("malformed", "text message: lengths do not match")
    return message.decode("utf-8", "replace"), source.decode("utf-8", "replace"), level
