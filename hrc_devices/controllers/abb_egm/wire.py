"""The protocol-buffers wire format, the little of it EGM's messages use: pure, bytes in, fields out, and back.

    fields = read_fields(data)              # {field number: [values in order]}; ints, floats or bytes
    data = b"".join([field_varint(1, 7), field_double(2, 1.5), field_message(3, inner)])

A message is a sequence of fields ``tag value`` with ``tag = number << 3 | wire type``: 0 a varint (``uint32``,
``uint64``, ``bool``, enums), 1 eight little-endian bytes (``double``), 2 a varint length and that many bytes (an
embedded message, or a *packed* repeated scalar), 5 four bytes (``float``, never used by EGM). Groups (3, 4) are
refused: no EGM message has one. Readers keep every occurrence of a field in order, so that a caller applies
protobuf's rules: the last value of a scalar wins, the values of a repeated field concatenate, and the
occurrences of an embedded message merge (which is parsing their bytes concatenated).

The bytes are hostile: anything truncated, over-long or of a wire type the caller does not expect raises
:class:`EgmError` with a ``reason`` for counting, never an ``IndexError`` or ``struct.error``.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

from hrc_contract.errors import HrcError

__all__ = [
    "EgmError",
    "field_bool",
    "field_double",
    "field_message",
    "field_varint",
    "read_doubles",
    "read_fields",
    "read_varint",
]

_DOUBLE = struct.Struct("<d")
_MAX_VARINT_BYTES = 10

WireValue = int | float | bytes
"""One occurrence of a field: a varint's ``int``, a fixed64's ``float`` (as a double), a length-delimited
field's ``bytes`` (an embedded message or a packed repeated scalar), a fixed32's ``int`` (its raw bits)."""


class EgmError(HrcError):
    """Bytes that are not a valid EGM message (or not one this side can use).

    Attributes:
        reason: a short key for counting: ``malformed`` (the wire format does not decode), ``oversize``,
            ``non_finite`` (a NaN or infinite double), ``joint_count`` (not the robot's joints), ``too_many`` (more
            values in a field than any robot has).
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason = reason


def read_varint(data: bytes, pos: int) -> tuple[int, int]:
    """The varint at ``data[pos:]`` and the position after it.

    Raises:
        EgmError: ``malformed``: truncated, or longer than 10 bytes.
    """
    value = 0
    for i in range(_MAX_VARINT_BYTES):
        if pos + i >= len(data):
            raise EgmError("malformed", f"varint truncated at byte {pos + i} of {len(data)}")
        byte = data[pos + i]
        value |= (byte & 0x7F) << (7 * i)
        if byte < 0x80:
            return value & 0xFFFF_FFFF_FFFF_FFFF, pos + i + 1
    raise EgmError("malformed", f"varint at byte {pos} longer than {_MAX_VARINT_BYTES} bytes")


def read_fields(data: bytes) -> dict[int, list[WireValue]]:
    """Every field of one message, by number, each occurrence in order (see the module docstring).

    Raises:
        EgmError: ``malformed``: a field number 0, a group, a truncated value.
    """
    fields: dict[int, list[WireValue]] = {}
    pos = 0
    end = len(data)
    while pos < end:
        tag, pos = read_varint(data, pos)
        number, wire_type = tag >> 3, tag & 7
        if number == 0 or number > 0x1FFF_FFFF:
            raise EgmError("malformed", f"field number {number} at byte {pos}; allowed: 1..2^29-1")
        value: WireValue
        if wire_type == 0:
            value, pos = read_varint(data, pos)
        elif wire_type == 1:
            if pos + 8 > end:
                raise EgmError("malformed", f"field {number}: fixed64 truncated at byte {pos} of {end}")
            value = _DOUBLE.unpack_from(data, pos)[0]
            pos += 8
        elif wire_type == 2:
            length, pos = read_varint(data, pos)
            if pos + length > end:
                raise EgmError("malformed", f"field {number}: {length} bytes announced at byte {pos}, {end - pos} left")
            value = bytes(data[pos : pos + length])
            pos += length
        elif wire_type == 5:
            if pos + 4 > end:
                raise EgmError("malformed", f"field {number}: fixed32 truncated at byte {pos} of {end}")
            value = int.from_bytes(data[pos : pos + 4], "little")
            pos += 4
        else:
            raise EgmError("malformed", f"field {number}: wire type {wire_type}; allowed: 0, 1, 2, 5 (no groups)")
        fields.setdefault(number, []).append(value)
    return fields


def read_doubles(values: Sequence[WireValue], what: str, max_count: int) -> tuple[float, ...]:
    """A repeated ``double`` field's values, whether sent one by one (fixed64) or packed (length-delimited).

    Args:
        values: the field's occurrences (:func:`read_fields`).
        what: the field's name, for the error message.
        max_count: the most values accepted.

    Raises:
        EgmError: ``malformed`` (a varint, or a packed run not a multiple of 8 bytes), ``non_finite``, ``too_many``.
    """
    out: list[float] = []
    for value in values:
        if isinstance(value, float):
            out.append(value)
        elif isinstance(value, bytes) and len(value) % 8 == 0:
            out.extend(v for (v,) in _DOUBLE.iter_unpack(value))
        else:
            raise EgmError("malformed", f"{what}: a {type(value).__name__} where doubles were expected")
        if len(out) > max_count:
            raise EgmError("too_many", f"{what}: more than {max_count} values")
    if not all(math.isfinite(v) for v in out):
        raise EgmError("non_finite", f"{what} = {out}; allowed: finite values")
    return tuple(out)


def _varint(value: int) -> bytes:
    value &= 0xFFFF_FFFF_FFFF_FFFF  # a negative int32 is sent as 10 bytes, as protobuf does
    out = bytearray()
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def field_varint(number: int, value: int) -> bytes:
    """A varint field (``uint32``, ``uint64``, an enum): tag and value."""
    return _varint(number << 3) + _varint(value)


def field_bool(number: int, value: bool) -> bytes:
    """A ``bool`` field."""
    return field_varint(number, int(value))


def field_double(number: int, value: float) -> bytes:
    """A ``double`` field (one value of a repeated one: proto2 repeated scalars are not packed by default)."""
    return _varint(number << 3 | 1) + _DOUBLE.pack(value)


def field_message(number: int, body: bytes) -> bytes:
    """An embedded message field (its serialized ``body``; an empty body still marks the field as present)."""
    return _varint(number << 3 | 2) + _varint(len(body)) + body
