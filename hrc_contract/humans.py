"""Human capsules: from a tracker message to the flat arrays every consumer uses, and the merge of trackers.

One shape of the human data for the gateway, the auditor, the simulated cell and the tests:
:class:`HumanCapsules` (end points, radii, and who each capsule belongs to), in the cell's world frame.

    payload ──humans_from_payload──▶ HumansHeader, HumanCapsules ──implausible_reason──▶ (accepted)
    Humans message ──capsules_from_message──▶ HumanCapsules
                   ──merge_humans──▶ HumanCapsules of all trackers ──gateway.kernels.capsule_columns──▶ rows

Plausibility at the door: a capsule whose end points leave the cell's volume, longer or thicker than any human
body part, is refused (:func:`implausible_reason`). Besides catching a broken or hostile tracker, it keeps every
accepted coordinate within a few metres, where the segment distances are exact to ~1e-12 m (absurd magnitudes,
e.g. a capsule kilometres long passing a hand's width from the tool, lose all precision in floating point).
"""

from __future__ import annotations

import itertools
import operator
import re
from collections.abc import Callable, Sequence
from typing import Annotated, NamedTuple

import msgspec
import numpy as np
import numpy.typing as npt

from hrc_contract.config import PlausibilityConfig
from hrc_contract.messages import (
    MAX_CAPSULES_PER_MESSAGE,
    MAX_PAYLOAD_BYTES,
    Humans,
    MessageError,
    parse_message_reference,
)

FloatArray = npt.NDArray[np.float64]


class HumanCapsules(NamedTuple):
    """Human capsules, flattened over trackers and humans.

    Attributes:
        h_a_world, h_b_world: capsule end points, shape (H, 3) [m].
        radius_m: capsule radii, shape (H,) [m].
        human_ids: id of the human each capsule belongs to (prefixed with the tracker name).
        capsule_names: name of each capsule.
    """

    h_a_world: FloatArray
    h_b_world: FloatArray
    radius_m: FloatArray
    human_ids: tuple[str, ...]
    capsule_names: tuple[str, ...]

    @property
    def n_capsules(self) -> int:
        return len(self.radius_m)


NO_HUMANS = HumanCapsules(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), (), ())


def capsules_from_message(tracker: str, message: Humans) -> HumanCapsules:
    """Flatten a Humans message into arrays; human ids are prefixed with the tracker name.

    One flat list of floats and one ``np.array`` call (~8 µs for 15 capsules; a list of tuples per array
    cost twice that): the arrays are views of one (H, 7) array, rows ``a``, ``b``, ``radius``.
    """
    human_ids: list[str] = []
    names: list[str] = []
    values: list[float] = []
    for human in message.humans:
        human_id = f"{tracker}/{human.id}"
        for capsule in human.capsules:
            human_ids.append(human_id)
            names.append(capsule.name)
            values.extend(capsule.a)
            values.extend(capsule.b)
            values.append(capsule.radius)
    rows = np.array(values, dtype=np.float64).reshape(-1, 7)
    return _from_rows(rows, human_ids, names)


def _from_rows(rows: FloatArray, human_ids: list[str], names: list[str]) -> HumanCapsules:
    """Capsules as views of one (H, 7) array, rows ``a``, ``b``, ``radius``."""
    return HumanCapsules(rows[:, 0:3], rows[:, 3:6], rows[:, 6], tuple(human_ids), tuple(names))


class HumansHeader(NamedTuple):
    """What a tracker frame says besides its capsules, and where each person's capsules start."""

    tracker: str
    seq: int
    stamp_ns: int
    human_count: int
    human_starts: tuple[int, ...]
    """:func:`human_starts` of the frame's capsules, known to the decoder without a step per capsule: the index of
    each person's first capsule, and the end (a person listed twice in a row is one run of capsules, as there)."""


def _starts_of_runs(ids: Sequence[str], counts: Sequence[int]) -> tuple[int, ...]:
    """:func:`human_starts` of capsules listed person by person (``ids[k]`` with ``counts[k]`` capsules, each at
    least one): where the id changes, and the end."""
    starts = [0]
    total = 0
    previous = None
    for human_id, count in zip(ids, counts, strict=True):
        if total and human_id != previous:
            starts.append(total)
        total += count
        previous = human_id
    if total:
        starts.append(total)
    return tuple(starts)


_NAME = re.compile(r"[a-z0-9_-]{1,64}")
"""A tracker name (:data:`hrc_contract.messages.NAME_PATTERN`), matched in full (``$`` would take a final newline)."""

_Text64 = Annotated[str, msgspec.Meta(min_length=1, max_length=64)]
_NonNegativeInt = Annotated[int, msgspec.Meta(ge=0)]


class _WireCapsule(msgspec.Struct, forbid_unknown_fields=True):
    name: _Text64
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: Annotated[float, msgspec.Meta(ge=0.0, le=2.0)]


class _WireHuman(msgspec.Struct, forbid_unknown_fields=True):
    id: _Text64
    capsules: Annotated[list[_WireCapsule], msgspec.Meta(min_length=1, max_length=MAX_CAPSULES_PER_MESSAGE)]


class _WireHumans(msgspec.Struct, forbid_unknown_fields=True, rename={"schema_": "schema"}):
    schema_: str
    tracker: str
    seq: _NonNegativeInt
    stamp_ns: _NonNegativeInt
    humans: Annotated[list[_WireHuman], msgspec.Meta(max_length=256)]


_HUMANS_DECODER = msgspec.json.Decoder(_WireHumans)
_HUMANS_SCHEMA = Humans.model_fields["schema_"].default


def humans_from_payload(payload: bytes) -> tuple[HumansHeader, HumanCapsules]:
    """A tracker frame's payload at the door: its header and its capsules (ids prefixed with its tracker's name),
    without a pydantic object per capsule.

    The fast path decodes with ``msgspec`` into plain structs (stricter than the reference: no lax conversions,
    integers within 64 bits) and checks what the structs cannot say (the schema, the tracker's name in full, the
    total of capsules, every coordinate finite); whatever it refuses goes through
    :func:`hrc_contract.messages.parse_message_reference`, which decides whether and why a payload is rejected, so
    acceptance and reasons are the reference's by construction (the two agree on seeded mutations:
    ``tests/hrc_contract/test_humans.py``). 2000 capsules: ~1.4 ms against ~3.0 ms through pydantic
    (``python -m bench.door``).

    A payload that opens a MessagePack map is a packed frame (:func:`humans_from_packed`); JSON opens with ``{`` or
    whitespace, so neither is taken for the other.

    Raises:
        MessageError: as :func:`hrc_contract.messages.parse_message`, or :func:`humans_from_packed`'s reasons.
    """
    if is_packed(payload):
        return humans_from_packed(payload)
    fast = _humans_fast(payload)
    if fast is not None:
        return fast
    message = parse_message_reference(payload, Humans)
    capsules = capsules_from_message(message.tracker, message)
    starts = tuple(human_starts(capsules))
    return HumansHeader(message.tracker, message.seq, message.stamp_ns, len(message.humans), starts), capsules


def _humans_fast(payload: bytes) -> tuple[HumansHeader, HumanCapsules] | None:
    """:func:`humans_from_payload`'s fast path, or None where the reference must judge."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        return None
    try:
        wire = _HUMANS_DECODER.decode(payload)
    except (msgspec.ValidationError, msgspec.DecodeError):
        return None
    if wire.schema_ != _HUMANS_SCHEMA or _NAME.fullmatch(wire.tracker) is None:
        return None
    tracker = wire.tracker
    human_ids: list[str] = []
    names: list[str] = []
    values: list[tuple[float, ...]] = []
    for human in wire.humans:
        capsules = human.capsules
        human_ids.extend([f"{tracker}/{human.id}"] * len(capsules))
        names.extend([c.name for c in capsules])
        values.extend([(*c.a, *c.b, c.radius) for c in capsules])
        if len(values) > MAX_CAPSULES_PER_MESSAGE:
            return None
    rows = np.array(values, dtype=np.float64).reshape(-1, 7)
    if not np.isfinite(rows).all():
        return None
    starts = _starts_of_runs([h.id for h in wire.humans], [len(h.capsules) for h in wire.humans])
    header = HumansHeader(tracker, wire.seq, wire.stamp_ns, len(wire.humans), starts)
    return header, _from_rows(rows, human_ids, names)


# -- packed frames: the capsules as one binary array per person ----------------------------------------------------

PACKED_SCHEMA = "hrc.humans_packed/1"
"""The schema of a packed tracker frame (docs/contract.md, "Packed tracker frames")."""

PACKED_ROW_BYTES = 7 * 8
"""One capsule in a packed frame: ``a`` (x, y, z), ``b`` (x, y, z), ``radius``, little-endian float64 [m]."""

_PACKED_ROW = np.dtype("<f8")


class _PackedHuman(msgspec.Struct, forbid_unknown_fields=True):
    id: _Text64
    names: Annotated[list[_Text64], msgspec.Meta(min_length=1, max_length=MAX_CAPSULES_PER_MESSAGE)]
    capsules: bytes


class _PackedHumans(msgspec.Struct, forbid_unknown_fields=True, rename={"schema_": "schema"}):
    schema_: str
    tracker: str
    seq: _NonNegativeInt
    stamp_ns: _NonNegativeInt
    humans: Annotated[list[_PackedHuman], msgspec.Meta(max_length=256)]


_PACKED_DECODER = msgspec.msgpack.Decoder(_PackedHumans)
_PACKED_ENCODER = msgspec.msgpack.Encoder()


def is_packed(payload: bytes) -> bool:
    """Whether ``payload`` opens a MessagePack map (fixmap, map 16, map 32): a packed frame, not JSON."""
    return bool(payload) and (0x80 <= payload[0] <= 0x8F or payload[0] in (0xDE, 0xDF))


def packed_payload(message: Humans) -> bytes:
    """``message`` as a packed frame: per person its id, its capsules' names and one array of their rows."""
    humans = []
    for human in message.humans:
        rows = np.array([(*c.a, *c.b, c.radius) for c in human.capsules], dtype=_PACKED_ROW)
        humans.append({"id": human.id, "names": [c.name for c in human.capsules], "capsules": rows.tobytes()})
    doc = {"schema": PACKED_SCHEMA, "tracker": message.tracker, "seq": message.seq, "stamp_ns": message.stamp_ns}
    return _PACKED_ENCODER.encode({**doc, "humans": humans})


def _decode_packed(payload: bytes) -> _PackedHumans:
    """The packed frame's document, its schema and tracker name checked (:func:`humans_from_packed`'s reasons)."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MessageError("too_large", f"{len(payload)} bytes, at most {MAX_PAYLOAD_BYTES} allowed")
    try:
        wire = _PACKED_DECODER.decode(payload)
    except msgspec.ValidationError as exc:
        raise MessageError("invalid", str(exc)[:300]) from None
    except msgspec.DecodeError as exc:
        raise MessageError("not_msgpack", str(exc)[:200]) from None
    if wire.schema_ != PACKED_SCHEMA:
        raise MessageError("wrong_schema", f"schema {wire.schema_[:80]!r}, expected {PACKED_SCHEMA!r}")
    if _NAME.fullmatch(wire.tracker) is None:
        raise MessageError("invalid", f"tracker {wire.tracker[:80]!r}: not a name ([a-z0-9_-], 1 to 64 characters)")
    return wire


def humans_from_packed(payload: bytes) -> tuple[HumansHeader, HumanCapsules]:
    """A packed frame's header and capsules, held to the same rules as a JSON frame (docs/contract.md): a Python
    object per person and per name, none per coordinate.

    Raises:
        MessageError: ``too_large``, ``not_msgpack`` (not a MessagePack document of the packed frame's shape),
            ``wrong_schema``, ``invalid`` (a tracker name, an id, a part name, a count or a radius the contract
            does not allow, or capsule bytes that are not one row per name), ``non_finite``.
    """
    wire = _decode_packed(payload)
    tracker = wire.tracker
    human_ids: list[str] = []
    names: list[str] = []
    blocks: list[bytes] = []
    starts = [0]  # _starts_of_runs, in the same pass
    previous = None
    for k, human in enumerate(wire.humans):
        count = len(human.names)
        if len(human.capsules) != count * PACKED_ROW_BYTES:
            raise MessageError(
                "invalid",
                f"humans[{k}]: {len(human.capsules)} bytes of capsules for {count} names "
                f"({PACKED_ROW_BYTES} bytes each expected)",
            )
        if human.id != previous and names:
            starts.append(len(names))
        previous = human.id
        human_ids.extend([f"{tracker}/{previous}"] * count)
        names.extend(human.names)
        blocks.append(human.capsules)
    if len(names) > MAX_CAPSULES_PER_MESSAGE:  # the work above is bounded by the payload's size
        raise MessageError("invalid", f"more than {MAX_CAPSULES_PER_MESSAGE} capsules in one message")
    if names:
        starts.append(len(names))
    # joined into a bytearray: the array is writable without a second copy (bytes would give a read-only one)
    rows = np.frombuffer(bytearray().join(blocks), dtype=_PACKED_ROW).astype(np.float64, copy=False).reshape(-1, 7)
    if not np.isfinite(rows).all():
        raise MessageError("non_finite", "a capsule coordinate or radius is not a finite number")
    radius = rows[:, 6]
    if radius.size and not ((radius >= 0.0) & (radius <= 2.0)).all():
        raise MessageError("invalid", "a capsule radius outside 0 to 2 m")
    header = HumansHeader(tracker, wire.seq, wire.stamp_ns, len(wire.humans), tuple(starts))
    return header, _from_rows(rows, human_ids, names)


def merge_humans(frames: list[HumanCapsules]) -> HumanCapsules:
    """All capsules of several trackers in one set (duplicates are harmless: more rows)."""
    frames = [f for f in frames if f.n_capsules]
    if not frames:
        return NO_HUMANS
    if len(frames) == 1:
        return frames[0]
    human_ids: tuple[str, ...] = ()
    capsule_names: tuple[str, ...] = ()
    for f in frames:  # a few trackers: adding tuples is the cheapest way to join them
        human_ids += f.human_ids
        capsule_names += f.capsule_names
    return HumanCapsules(
        np.concatenate([f.h_a_world for f in frames]),
        np.concatenate([f.h_b_world for f in frames]),
        np.concatenate([f.radius_m for f in frames]),
        human_ids,
        capsule_names,
    )


def implausible_reason(capsules: HumanCapsules, plausibility: PlausibilityConfig) -> str | None:
    """Why a tracker's capsules cannot be real, or None if they can (:func:`implausible_detail` without the detail)."""
    found = implausible_detail(capsules, plausibility)
    return None if found is None else found[0]


def implausible_detail(
    capsules: HumanCapsules,
    plausibility: PlausibilityConfig,
    numbers: Callable[[HumanCapsules, Sequence[int], PlausibilityConfig], FrameNumbers] | None = None,
    starts: Sequence[int] | None = None,
) -> tuple[str, str] | None:
    """Why a tracker's capsules cannot be real, with what was found, or None if they can.

    ``numbers``: how the frame's :class:`FrameNumbers` are computed (default :func:`frame_numbers`, numpy; the
    gateway passes its compiled ones). ``starts``: :func:`human_starts` of ``capsules`` where the caller has them
    (the decoder's :attr:`HumansHeader.human_starts`); computed when None.

    Returns:
        The reason and a detail: ``outside_world`` (an end point outside ``world_min_m``..``world_max_m``),
        ``capsule_too_long`` (``‖b − a‖`` above ``max_capsule_length_m``), ``radius_too_large`` (above
        ``max_capsule_radius_m``); and what one reported person cannot be (docs/contract.md "What one person may
        be"): ``duplicate_human_id`` (one id listed twice in a frame), ``too_many_parts`` (more capsules than
        ``max_capsules_per_person``), ``duplicate_part_name`` (two capsules of one person with one name), or
        ``person_too_large`` (the diagonal of the box around one person's capsules, plus twice their largest
        radius, above ``max_person_extent_m``: people merged into one, or not a person).
    """
    if capsules.n_capsules == 0:
        return None
    starts = human_starts(capsules) if starts is None else list(starts)
    found = (numbers or frame_numbers)(capsules, starts, plausibility)
    if not found.inside_world:
        return "outside_world", "a capsule end point outside the cell's world volume"
    if found.longest_sq_m2 > plausibility.max_capsule_length_m**2:
        return (
            "capsule_too_long",
            f"a capsule {found.longest_sq_m2**0.5:.2f} m long, at most {plausibility.max_capsule_length_m} m",
        )
    if found.radius_max_m > plausibility.max_capsule_radius_m:
        return (
            "radius_too_large",
            f"a radius of {found.radius_max_m:.2f} m, at most {plausibility.max_capsule_radius_m} m",
        )
    return _implausible_person(capsules, starts, found.extent_m, plausibility)


class FrameNumbers(NamedTuple):
    """What the plausibility rules ask of a frame's numbers (:func:`frame_numbers`)."""

    inside_world: bool
    """Every end point within ``world_min_m``..``world_max_m`` (a coordinate that is not a number is not)."""
    longest_sq_m2: float
    """The largest ``‖b − a‖²`` [m²]."""
    radius_max_m: float
    extent_m: FloatArray
    """Per person: the diagonal of the box around their capsules' end points plus twice their largest radius [m]."""


def frame_numbers(capsules: HumanCapsules, starts: Sequence[int], plausibility: PlausibilityConfig) -> FrameNumbers:
    """:class:`FrameNumbers` of a frame of at least one capsule (``starts``: :func:`human_starts`), in numpy: the
    reference of the gateway's compiled ones (``gateway.kernels.frame_numbers``), which follow its order of
    arithmetic (each sum of squares x² + y², then + z²) to the bit."""
    ends = np.concatenate((capsules.h_a_world, capsules.h_b_world), axis=1)  # (n, 6): both end points of a capsule
    points = ends.reshape(-1, 3)
    inside = bool((points >= plausibility.world_min_m).all() and (points <= plausibility.world_max_m).all())
    axis = ends[:, 3:] - ends[:, :3]
    firsts = starts[:-1]
    low = np.minimum.reduceat(ends, firsts, axis=0)
    high = np.maximum.reduceat(ends, firsts, axis=0)
    span = np.maximum(high[:, :3], high[:, 3:]) - np.minimum(low[:, :3], low[:, 3:])
    return FrameNumbers(
        inside,
        float(_norm_sq(axis).max()),
        float(capsules.radius_m.max()),
        np.sqrt(_norm_sq(span)) + 2.0 * np.maximum.reduceat(capsules.radius_m, firsts),
    )


def _norm_sq(v: FloatArray) -> FloatArray:
    """Per row, x² + y², then + z²."""
    return v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2]


def human_starts(capsules: HumanCapsules) -> list[int]:
    """Index of each human's first capsule (a frame lists each human's capsules together), and the end."""
    ids = capsules.human_ids
    n = len(ids)
    if not n:
        return [0]
    # where an id differs from the one before it, without a Python step per capsule (a frame has up to 2000)
    return [0, *itertools.compress(itertools.count(1), map(operator.ne, itertools.islice(ids, 1, None), ids)), n]


def _implausible_person(
    capsules: HumanCapsules, starts: list[int], extent_m: FloatArray, plausibility: PlausibilityConfig
) -> tuple[str, str] | None:
    """What no single body is, per reported person (``starts``: :func:`human_starts`; ``extent_m``: per person, as
    :class:`FrameNumbers`). Every person judged in a few array operations; the first person found wanting is
    described as a check person by person would (too many parts, then a part name twice, then too large)."""
    ids = capsules.human_ids
    firsts = starts[:-1]
    if len(set(map(ids.__getitem__, firsts))) != len(firsts):  # one id per run of capsules: its first names it
        return "duplicate_human_id", "a human id listed twice in one frame"
    counts = np.diff(starts)
    names = capsules.capsule_names
    distinct = np.fromiter(map(len, map(set, map(names.__getitem__, map(slice, firsts, starts[1:])))), np.intp)
    wanting = (counts > plausibility.max_capsules_per_person) | (distinct != counts)
    wanting |= extent_m > plausibility.max_person_extent_m
    if not wanting.any():
        return None
    k = int(np.argmax(wanting))
    start, end = starts[k], starts[k + 1]
    if end - start > plausibility.max_capsules_per_person:
        return "too_many_parts", (
            f"person {ids[start]!r} has {end - start} capsules, at most {plausibility.max_capsules_per_person}"
        )
    if distinct[k] != end - start:
        part_names = names[start:end]
        twice = sorted({n for n in part_names if part_names.count(n) > 1})
        return "duplicate_part_name", f"person {ids[start]!r} has two capsules named {twice[0]!r}"
    return "person_too_large", (
        f"person {ids[start]!r} spans {extent_m[k]:.2f} m, at most {plausibility.max_person_extent_m} m"
    )
