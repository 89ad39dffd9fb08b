"""The status's ``human_capsules`` as JSON text, the numbers written by compiled code.

A crowd's status document lists thousands of capsules (2 trackers × 2000 in ``bench.crowded``), 25 times a second.
Turning 7 numbers per capsule into text was most of its cost: ~4 ms a document through Python floats and a JSON
encoder (a dict per capsule before that), all of it holding the interpreter lock the safety loop needs. Here the
names and the ids are each encoded in one call and one compiled pass, without the interpreter lock, writes the whole
list: the fixed keys, each capsule's numbers as ``model_dump_json`` writes them, its name and id copied from their
encoded arrays. The same bytes: a test holds them to the models, and :func:`check_capsules_json` to
:func:`reference_capsules_json` (every number written by Python) at start-up.

Why the compiled text is Python's: a number rounded to :data:`DIGITS` decimals is the double nearest to ``k / 10⁴``
for an integer ``k`` (numpy rounds as ``rint(x·10⁴) / 10⁴``, one correctly rounded division). The pass recovers
``k`` and writes it only where ``k / 10⁴`` is that very double and ``|k| < 10¹⁵``: then the decimal has at most 15
significant digits, no other decimal of as few digits rounds to the same double (a double tells all 15-digit
decimals apart), so it is the shortest text that reads back as the double, which is what Python, pydantic and
msgspec write (in fixed notation from 10⁻⁴ up to 10¹⁶: here from 0.0001 to below 10¹¹). Anything else (a value
beyond 10¹¹ m) makes the pass return -1 and the whole list goes the reference's way.
"""

from __future__ import annotations

import functools
from typing import Any

import msgspec
import numpy as np
import numpy.typing as npt

from gateway.kernels import compiled_with
from hrc_contract.config import ConfigError
from hrc_contract.humans import HumanCapsules

DIGITS = 4
"""The status rounds distances, times and δ to this many decimals (0.1 mm, 0.1 ms); the compiled pass writes it."""

_SCALE = float(10**DIGITS)
_LARGEST_K = 1e15
"""|k| below this: at most 15 significant digits (a value below 10¹¹ at 4 decimals)."""
_ROW_BYTES = 7 * 18 + 64
"""Room for one capsule's text beside its name and id: 7 numbers of at most 17 characters and a separator each, and
the fixed keys."""


_ENCODER = msgspec.json.Encoder()

FloatArray = npt.NDArray[np.float64]


def capsule_table(a_m: FloatArray, b_m: FloatArray, radius_m: FloatArray) -> FloatArray:
    """Capsules as rows ``[a_x, a_y, a_z, b_x, b_y, b_z, radius]`` rounded to 0.1 mm; a value that is not finite
    becomes 0 (the drawing only). One table, so one rounding for all capsules (numpy's cost is its calls, ~1–2 µs
    each, not the numbers)."""
    table = np.concatenate((a_m, b_m, radius_m[:, None]), axis=1).round(DIGITS)
    if not np.isfinite(table).all():  # never with plausible input; nan_to_num costs ~25 µs
        table = np.nan_to_num(table, nan=0.0, posinf=0.0, neginf=0.0)
    return table


@compiled_with(nogil=True, inline=True)
def _write_number(x: float, out: Any, at: int) -> int:
    """``x`` (rounded to 4 decimals) as Python writes it, at ``out[at:]``; the index after it, or -1 where the text
    could differ (see the module)."""
    k_float = np.rint(x * _SCALE)
    if not abs(k_float) < _LARGEST_K or k_float / _SCALE != x:
        return -1
    k = int(k_float)
    if k < 0 or (k == 0 and np.signbit(x)):
        out[at] = 45  # "-"
        at += 1
    k = abs(k)
    scale = 10**DIGITS
    whole, fraction = k // scale, k % scale
    digits = 1
    power = 10
    while power <= whole:
        digits += 1
        power *= 10
    for d in range(digits - 1, -1, -1):
        out[at + d] = 48 + whole % 10
        whole //= 10
    at += digits
    out[at] = 46  # "."
    at += 1
    if fraction == 0:
        out[at] = 48
        return at + 1
    width = DIGITS
    while fraction % 10 == 0:
        fraction //= 10
        width -= 1
    for d in range(width - 1, -1, -1):
        out[at + d] = 48 + fraction % 10
        fraction //= 10
    return at + width


@compiled_with(nogil=True, inline=True)
def _copy(source: Any, out: Any, at: int) -> int:
    for byte in source:  # a loop: a slice assignment makes two array views, dearer than a few bytes
        out[at] = byte
        at += 1
    return at


@compiled_with(nogil=True, inline=True)
def _copy_string_item(array_json: Any, start: int, out: Any, at: int) -> tuple[int, int]:
    """Copy the escaped text of the JSON string item opening at ``array_json[start]`` (its quote), without the
    quotes; the index after its closing quote and after the copy, or (-1, -1) if no item opens or closes there."""
    if start >= array_json.shape[0] or array_json[start] != 34:  # '"'
        return -1, -1
    i = start + 1
    while i < array_json.shape[0]:
        byte = array_json[i]
        if byte == 34:  # '"': the item ends
            return i + 1, at
        if byte == 92:  # "\\": an escape; its next byte is part of it
            out[at] = byte
            at += 1
            i += 1
            if i >= array_json.shape[0]:
                break
            byte = array_json[i]
        out[at] = byte
        at += 1
        i += 1
    return -1, -1


@compiled_with(nogil=True, inline=True)
def _write_numbers(row: Any, keys: Any, out: Any, at: int) -> int:
    """``"a_m":[…],"b_m":[…],"radius_m":…`` of one capsule's row (with the keys around them); -1 as
    :func:`_write_number`."""
    _, a_key, b_key, radius_key, _, _ = keys
    for j in range(7):
        if j == 0:
            at = _copy(a_key, out, at)
        elif j == 3:
            at = _copy(b_key, out, at)
        elif j == 6:
            at = _copy(radius_key, out, at)
        else:
            out[at] = 44  # ","
            at += 1
        at = _write_number(row[j], out, at)
        if at < 0:
            return -1
    return at


@compiled_with(nogil=True)
def _capsules_text(table: Any, names_json: Any, ids_json: Any, keys: Any, out: Any) -> int:
    """The whole JSON array ``[{"name":…,"a_m":[…],"b_m":[…],"radius_m":…,"human":…},…]`` at ``out``, the names and
    ids copied from their encoded JSON arrays; the length written, or -1 (a number whose text could differ, or
    string arrays that are not one item per capsule: the caller takes the reference's way). Runs without the
    interpreter lock."""
    opening, _, _, _, human_key, closing = keys
    out[0] = 91  # "["
    at = 1
    name_at, id_at = 1, 1  # each string array's next item (its opening quote)
    for i in range(table.shape[0]):
        if i:
            out[at] = 44  # ","
            at += 1
            name_at += 1  # the comma between two items
            id_at += 1
        at = _copy(opening, out, at)
        name_at, at = _copy_string_item(names_json, name_at, out, at)
        if at >= 0:
            at = _write_numbers(table[i], keys, out, at)
        if at >= 0:
            at = _copy(human_key, out, at)
            id_at, at = _copy_string_item(ids_json, id_at, out, at)
        if at < 0:
            return -1
        at = _copy(closing, out, at)
    if name_at != names_json.shape[0] - 1 or id_at != ids_json.shape[0] - 1:
        return -1  # more names or ids than capsules
    out[at] = 93  # "]"
    return at + 1


_KEYS = tuple(
    np.frombuffer(text, dtype=np.uint8)
    for text in (b'{"name":"', b'","a_m":[', b'],"b_m":[', b'],"radius_m":', b',"human":"', b'"}')
)


def _compiled_text(table: FloatArray, capsules: HumanCapsules) -> bytes | None:
    """:func:`_capsules_text`'s bytes, or None where it declines."""
    names_json = np.frombuffer(_ENCODER.encode(capsules.capsule_names), dtype=np.uint8)
    ids_json = np.frombuffer(_ENCODER.encode(capsules.human_ids), dtype=np.uint8)
    out = np.empty(len(table) * _ROW_BYTES + len(names_json) + len(ids_json), dtype=np.uint8)
    length = _capsules_text(table, names_json, ids_json, _KEYS, out)
    return None if length < 0 else out[:length].tobytes()


def _reference_numbers_pieces(table: FloatArray) -> list[bytes]:
    """Each capsule's numbers through Python floats and the JSON encoder (the reference; any finite value)."""
    a = _json_row_items(_ENCODER.encode(table[:, 0:3].tolist()))
    b = _json_row_items(_ENCODER.encode(table[:, 3:6].tolist()))
    r = _ENCODER.encode(table[:, 6].tolist())[1:-1].split(b",")
    return [b"".join(p) for p in zip(a, [b'],"b_m":['] * len(a), b, [b'],"radius_m":'] * len(a), r, strict=True)]


def _json_string_items(array_json: bytes) -> list[bytes]:
    """The items of a JSON array of strings, each as its escaped text without the quotes. Cut at ``","``: inside a
    string every ``"`` is escaped (``\\"``), so an unescaped quote, comma, quote is always between two items."""
    return array_json[2:-2].split(b'","')


def _json_row_items(array_json: bytes) -> list[bytes]:
    """The items of a JSON array of arrays of numbers, each as its numbers' text without the brackets."""
    return array_json[2:-2].split(b"],[")


def _assembled(capsules: HumanCapsules, numbers: list[bytes]) -> bytes:
    n = capsules.n_capsules
    pieces: list[bytes] = [b""] * (6 * n)
    pieces[0::6] = _json_string_items(_ENCODER.encode(capsules.capsule_names))
    pieces[1::6] = [b'","a_m":['] * n
    pieces[2::6] = numbers
    pieces[3::6] = [b',"human":"'] * n
    pieces[4::6] = _json_string_items(_ENCODER.encode(capsules.human_ids))
    pieces[5::6] = [b'"},{"name":"'] * (n - 1) + [b'"}]']
    return b'[{"name":"' + b"".join(pieces)


def _checked_count(capsules: HumanCapsules) -> int:
    n = capsules.n_capsules
    if len(capsules.capsule_names) != n or len(capsules.human_ids) != n:
        raise ValueError(f"{len(capsules.capsule_names)} names and {len(capsules.human_ids)} ids for {n} capsules")
    return n


def human_capsules_json(capsules: HumanCapsules) -> bytes:
    """The status's ``human_capsules`` (``gateway.status.human_capsules``) as a JSON array: the bytes of the models'
    ``model_dump_json``, without a Python object per capsule (the values are the gateway's own: numbers rounded by
    numpy, ids and names the door admitted; nothing to validate).

    Raises:
        ValueError: names or ids not one per capsule.
    """
    if not _checked_count(capsules):
        return b"[]"
    table = capsule_table(capsules.h_a_world, capsules.h_b_world, capsules.radius_m)
    text = _compiled_text(table, capsules)
    return _assembled(capsules, _reference_numbers_pieces(table)) if text is None else text


def reference_capsules_json(capsules: HumanCapsules) -> bytes:
    """:func:`human_capsules_json` with every number written by Python (what the compiled pass is held to)."""
    if not _checked_count(capsules):
        return b"[]"
    table = capsule_table(capsules.h_a_world, capsules.h_b_world, capsules.radius_m)
    return _assembled(capsules, _reference_numbers_pieces(table))


CHECK_SEED = 20160415
CHECK_VALUES_M = (0.0, -0.0, 1e-4, -1e-4, 5e-5, -5e-5, 1e-9, 0.1, 0.3, 1.0, -1.0, 2.5, 9.99995, 123456.78912)
"""Values whose text is easily wrong: signed zeros, the smallest step, halves rounded away, whole numbers."""
CHECK_LARGEST_M = 99999999999.9
"""The largest value the pass writes (beyond it, 1e11 and more, it must decline: the check has one of those too)."""


@functools.cache
def check_capsules_json(seed: int = CHECK_SEED) -> None:
    """Hold :func:`human_capsules_json` to :func:`reference_capsules_json` on seeded capsules, byte for byte (and
    compile the pass, or load it from numba's cache, before the first document). Once per process.

    Raises:
        ConfigError: the two differ.
    """
    rng = np.random.default_rng(seed)
    special = np.array((*CHECK_VALUES_M, CHECK_LARGEST_M))
    for k in range(8):
        n = 200
        values = rng.uniform(-25.0, 25.0, (n, 7)) * 10.0 ** rng.integers(-6, 3, (n, 7))
        values = np.where(rng.random((n, 7)) < 0.3, rng.choice(special, (n, 7)), values)
        if k == 7:
            values[n // 2, 3] = 3e11  # beyond what the pass writes: the reference's way, the same bytes
        ids = tuple(f"front/h{i // 15}" for i in range(n))
        names = tuple(f"part{i % 15}" for i in range(n))
        capsules = HumanCapsules(values[:, 0:3], values[:, 3:6], np.abs(values[:, 6]), ids, names)
        if human_capsules_json(capsules) != reference_capsules_json(capsules):
            raise ConfigError(f"the compiled capsule text differs from its reference on seeded set {k}")
