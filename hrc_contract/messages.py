"""Wire messages of the contract (`docs/contract.md`), as strict frozen pydantic models.

This module is a leaf: it imports nothing else of the project but the exception root
(``hrc_contract.errors``, itself a leaf), so that any side of the contract (emulators, gateway, tests, a
real device driver) can use it alone.

Every model rejects unknown fields, NaN and infinities, wrong array lengths and negative radii.
Parsing raw bytes goes through :func:`parse_message`, which turns every failure into a
:class:`MessageError` carrying a short machine-readable ``reason`` used for counting.
"""

from __future__ import annotations

import json
from typing import Annotated, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hrc_contract.errors import HrcError
from hrc_contract.vocabulary import ControllerMode

NAME_PATTERN = r"^[a-z0-9_-]+$"
"""Cell, robot and tracker names: the characters allowed in a key expression segment."""

MAX_PAYLOAD_BYTES = 1_000_000
"""Larger payloads are rejected before parsing: no legitimate message of the contract is this big."""

MAX_CAPSULES_PER_MESSAGE = 2_000
MAX_JOINTS = 32

Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=64)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Vec3 = Annotated[tuple[FiniteFloat, FiniteFloat, FiniteFloat], Field()]
JointVector = Annotated[list[FiniteFloat], Field(min_length=1, max_length=MAX_JOINTS)]
StampNs = Annotated[int, Field(ge=0)]
Seq = Annotated[int, Field(ge=0)]


class _Message(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, populate_by_name=True)


class JointState(_Message):
    """Joint state of one robot, published by the controller every cycle."""

    schema_: Literal["hrc.joint_state/1"] = Field(alias="schema", default="hrc.joint_state/1")
    robot: Name
    seq: Seq
    stamp_ns: StampNs
    q: JointVector
    qd: JointVector
    qd_nominal: JointVector
    override: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
    override_seq: int = Field(ge=-1)
    mode: ControllerMode

    @model_validator(mode="after")
    def _same_lengths(self) -> JointState:
        if not len(self.q) == len(self.qd) == len(self.qd_nominal):
            raise ValueError(
                f"q, qd and qd_nominal must have the same length, got {len(self.q)}, "
                f"{len(self.qd)}, {len(self.qd_nominal)}"
            )
        return self


class Capsule(_Message):
    """A capsule of a human body, in the cell's world frame [m]. A point has ``a == b``."""

    name: Annotated[str, Field(min_length=1, max_length=64)]
    a: Vec3
    b: Vec3
    radius: Annotated[float, Field(ge=0.0, le=2.0, allow_inf_nan=False)]


class Human(_Message):
    """One detected person: at least one capsule (a person with none would read as nobody)."""

    id: Annotated[str, Field(min_length=1, max_length=64)]
    capsules: Annotated[list[Capsule], Field(min_length=1, max_length=MAX_CAPSULES_PER_MESSAGE)]


class Humans(_Message):
    """Tracked humans of one sensor frame; ``stamp_ns`` is the capture time."""

    schema_: Literal["hrc.humans/1"] = Field(alias="schema", default="hrc.humans/1")
    tracker: Name
    seq: Seq
    stamp_ns: StampNs
    humans: Annotated[list[Human], Field(max_length=256)]

    @field_validator("humans")
    @classmethod
    def _bounded_capsule_count(cls, humans: list[Human]) -> list[Human]:
        total = sum(len(h.capsules) for h in humans)
        if total > MAX_CAPSULES_PER_MESSAGE:
            raise ValueError(f"{total} capsules in one message, at most {MAX_CAPSULES_PER_MESSAGE} allowed")
        return humans


class Override(_Message):
    """Speed override command, gateway to controller. ``delta`` in [0, 1] (not percent)."""

    schema_: Literal["hrc.override/1"] = Field(alias="schema", default="hrc.override/1")
    robot: Name
    seq: Seq
    stamp_ns: StampNs
    delta: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]


class JointCommand(_Message):
    """Joint reference for an *open* controller (``control = "open"``), gateway to controller, every cycle.

    ``q`` is the reference position q_{k+1} [rad] and ``qd`` the reference velocity q̇_{k+1} [rad/s] of LP (9)/(13)
    of paper 1, one entry per joint of the robot's model; ``delta`` is the δ_k the LP chose (for display; the
    controller follows ``q`` and ``qd``). A controller follows them within its own velocity and acceleration limits
    and stops on its own (within its braking time) when no valid command arrives for its watchdog time.
    """

    schema_: Literal["hrc.joint_command/1"] = Field(alias="schema", default="hrc.joint_command/1")
    robot: Name
    seq: Seq
    stamp_ns: StampNs
    q: JointVector
    qd: JointVector
    delta: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]

    @model_validator(mode="after")
    def _same_length(self) -> JointCommand:
        if len(self.q) != len(self.qd):
            raise ValueError(f"q has {len(self.q)} joints and qd {len(self.qd)}; they must be the same robot's")
        return self


class TrackReset(_Message):
    """An operator's reset of a lost person (docs/contract.md "Tracks"), put on ``hrc/<cell>/operator/track_reset``
    by the operator station (certificate role ``operator``) after checking the area.

    ``track`` is the label of a lost track as the status lists it (``front/h1``), or ``*`` for every lost track;
    ``operator`` names the person who checked (logged with the reset).
    """

    schema_: Literal["hrc.track_reset/1"] = Field(alias="schema", default="hrc.track_reset/1")
    operator: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9 ._@-]+$")]
    seq: Seq
    stamp_ns: StampNs
    track: Annotated[str, Field(min_length=1, max_length=160)]


M = TypeVar("M", bound=BaseModel)


class MessageError(HrcError, ValueError):
    """A payload that is not a valid message. ``reason`` is a short key for counting."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def _reject_constant(token: str) -> float:
    raise ValueError(f"non-finite number {token} is not allowed")


def _finite_float(token: str) -> float:
    value = float(token)
    if value in (float("inf"), float("-inf")):
        raise ValueError(f"non-finite number {token[:30]} is not allowed")
    return value


def parse_message(payload: bytes, model: type[M]) -> M:
    """Parse a UTF-8 JSON payload into ``model``.

    A valid payload takes the fast path: pydantic's own JSON parser (no Python objects in between),
    about 5× cheaper than ``json.loads`` + ``model_validate``. Whatever the fast path refuses goes through
    :func:`parse_message_reference`, which decides *whether* and *why* a payload is rejected, so the
    acceptance rules and the reasons are the reference's by construction. The fast path accepts nothing
    the reference refuses: every value is checked by the same strict model (``extra="forbid"``, finite
    floats), NaN, infinities and overflowing numbers fail its finite-number checks, and the schema must
    be on the wire under its alias (``by_name=False``, ``schema_`` set explicitly); the two agree on
    seeded random payloads and mutations (``tests/test_messages.py``).

    Raises:
        MessageError: with reason ``too_large``, ``not_json``, ``non_finite``, ``wrong_schema`` or
            ``invalid`` (any other validation failure: lengths, ranges, unknown fields).
    """
    if len(payload) <= MAX_PAYLOAD_BYTES:
        try:
            message = model.model_validate_json(payload, by_alias=True, by_name=False)
        except ValidationError:
            pass  # the reference says why
        else:
            if "schema_" not in model.model_fields or "schema_" in message.model_fields_set:
                return message
    return parse_message_reference(payload, model)


def parse_message_reference(payload: bytes, model: type[M]) -> M:
    """:func:`parse_message` through ``json.loads`` and ``model_validate``: slower, and the reference for
    which payloads are accepted and for the reason of each rejection.

    Raises:
        MessageError: as :func:`parse_message`.
    """
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MessageError("too_large", f"{len(payload)} bytes, at most {MAX_PAYLOAD_BYTES} allowed")
    try:
        raw = json.loads(payload, parse_constant=_reject_constant, parse_float=_finite_float)
    except RecursionError:
        raise MessageError("not_json", "JSON nested too deeply") from None
    except ValueError as exc:
        reason = "non_finite" if "non-finite" in str(exc) else "not_json"
        raise MessageError(reason, str(exc)[:200]) from exc
    if not isinstance(raw, dict):
        raise MessageError("not_json", f"expected a JSON object, got {type(raw).__name__}")
    expected_schema = model.model_fields["schema_"].default if "schema_" in model.model_fields else None
    if expected_schema is not None and raw.get("schema") != expected_schema:
        raise MessageError("wrong_schema", f"schema {raw.get('schema')!r}, expected {expected_schema!r}")
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise MessageError("invalid", f"{where}: {first['msg']}"[:300]) from exc


def to_payload(message: BaseModel) -> bytes:
    """Serialise a message to its UTF-8 JSON payload (aliases, so ``schema`` is the key)."""
    return message.model_dump_json(by_alias=True).encode()
