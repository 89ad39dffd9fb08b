"""Wire messages of the contract: strict models, parse_message's reasons, round trips."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import BaseModel, ValidationError
from support.payload_mutations import mutate_payload, random_float_token

from hrc_contract.messages import (
    MAX_PAYLOAD_BYTES,
    Capsule,
    Human,
    Humans,
    JointState,
    MessageError,
    Override,
    parse_message,
    parse_message_reference,
    to_payload,
)

STAMP = 1_790_000_000_000_000_000


def joint_state_raw(**changes) -> dict:
    raw = {
        "schema": "hrc.joint_state/1",
        "robot": "ur5",
        "seq": 1042,
        "stamp_ns": STAMP,
        "q": [0.0, -1.2, 1.5, 0.1, 0.2, 0.3],
        "qd": [0.1] * 6,
        "qd_nominal": [0.2] * 6,
        "override": 0.62,
        "override_seq": 517,
        "mode": "running",
    }
    raw.update(changes)
    return raw


def capsule_raw(**changes) -> dict:
    raw = {"name": "forearm_r", "a": [1.0, 0.5, 1.2], "b": [1.2, 0.5, 1.1], "radius": 0.05}
    raw.update(changes)
    return raw


def human_raw(**changes) -> dict:
    raw = {"id": "h1", "capsules": [capsule_raw()]}
    raw.update(changes)
    return raw


def humans_raw(**changes) -> dict:
    raw = {"schema": "hrc.humans/1", "tracker": "front", "seq": 88, "stamp_ns": STAMP, "humans": [human_raw()]}
    raw.update(changes)
    return raw


def override_raw(**changes) -> dict:
    raw = {"schema": "hrc.override/1", "robot": "ur5", "seq": 517, "stamp_ns": STAMP, "delta": 0.62}
    raw.update(changes)
    return raw


MODELS: list[tuple[type[BaseModel], object]] = [
    (JointState, joint_state_raw),
    (Capsule, capsule_raw),
    (Human, human_raw),
    (Humans, humans_raw),
    (Override, override_raw),
]


def _payload(raw: dict) -> bytes:
    return json.dumps(raw).encode()


def _reason(raw: dict | bytes, model: type[BaseModel]) -> str:
    payload = raw if isinstance(raw, bytes) else _payload(raw)
    with pytest.raises(MessageError) as info:
        parse_message(payload, model)
    return info.value.reason


# -- valid messages -------------------------------------------------------------------------------


@pytest.mark.parametrize(("model", "make"), MODELS)
def test_valid_examples_parse(model, make) -> None:
    message = parse_message(_payload(make()), model)
    assert isinstance(message, model)


@pytest.mark.parametrize(("model", "make"), MODELS)
def test_round_trip(model, make) -> None:
    message = model.model_validate(make())
    payload = to_payload(message)
    again = parse_message(payload, model)
    assert again == message
    if "schema_" in model.model_fields:
        assert json.loads(payload)["schema"] == make()["schema"]  # the alias is on the wire, not schema_


def test_round_trip_random_joint_states_and_humans() -> None:
    rng = np.random.default_rng(13)
    for _ in range(50):
        n = int(rng.integers(1, 10))
        js = JointState.model_validate(
            joint_state_raw(
                seq=int(rng.integers(0, 2**40)),
                q=rng.normal(size=n).tolist(),
                qd=rng.normal(size=n).tolist(),
                qd_nominal=rng.normal(size=n).tolist(),
                override=float(rng.uniform()),
                mode=str(rng.choice(["running", "stopped", "protective_stop"])),
            )
        )
        assert parse_message(to_payload(js), JointState) == js
        humans = Humans.model_validate(
            humans_raw(
                humans=[
                    human_raw(
                        id=f"h{i}",
                        capsules=[
                            capsule_raw(
                                name=f"c{k}",
                                a=rng.uniform(-3, 3, 3).tolist(),
                                b=rng.uniform(-3, 3, 3).tolist(),
                                radius=float(rng.uniform(0, 0.3)),
                            )
                            for k in range(int(rng.integers(1, 5)))
                        ],
                    )
                    for i in range(int(rng.integers(0, 4)))
                ]
            )
        )
        assert parse_message(to_payload(humans), Humans) == humans


def test_point_capsule_and_empty_humans_are_valid() -> None:
    assert Capsule.model_validate(capsule_raw(a=[1, 2, 3], b=[1, 2, 3], radius=0.0)).radius == 0.0
    assert parse_message(_payload(humans_raw(humans=[])), Humans).humans == []


def test_models_are_frozen() -> None:
    message = Override.model_validate(override_raw())
    with pytest.raises(ValidationError):
        message.delta = 1.0  # type: ignore[misc]


# -- every model rejects ------------------------------------------------------------------------


NON_FINITE = [math.nan, math.inf, -math.inf]


@pytest.mark.parametrize("bad", NON_FINITE)
@pytest.mark.parametrize(
    "raw",
    [
        lambda x: joint_state_raw(q=[0.0, x, 0, 0, 0, 0]),
        lambda x: joint_state_raw(qd=[x] * 6),
        lambda x: joint_state_raw(qd_nominal=[0, 0, 0, 0, 0, x]),
        lambda x: joint_state_raw(override=x),
    ],
)
def test_joint_state_rejects_non_finite(raw, bad) -> None:
    with pytest.raises(ValidationError):
        JointState.model_validate(raw(bad))


@pytest.mark.parametrize("bad", NON_FINITE)
def test_capsule_human_humans_reject_non_finite(bad) -> None:
    for raw in (capsule_raw(a=[bad, 0, 0]), capsule_raw(b=[0, 0, bad]), capsule_raw(radius=bad)):
        with pytest.raises(ValidationError):
            Capsule.model_validate(raw)
    with pytest.raises(ValidationError):
        Human.model_validate(human_raw(capsules=[capsule_raw(a=[0, bad, 0])]))
    with pytest.raises(ValidationError):
        Humans.model_validate(humans_raw(humans=[human_raw(capsules=[capsule_raw(b=[0, bad, 0])])]))


@pytest.mark.parametrize("bad", NON_FINITE)
def test_override_rejects_non_finite(bad) -> None:
    with pytest.raises(ValidationError):
        Override.model_validate(override_raw(delta=bad))


@pytest.mark.parametrize(
    "raw",
    [
        joint_state_raw(q=[0.0] * 5),  # lengths differ
        joint_state_raw(qd=[0.0] * 7),
        joint_state_raw(qd_nominal=[0.0] * 5),
        joint_state_raw(q=[], qd=[], qd_nominal=[]),  # empty
        joint_state_raw(q=[0.0] * 33, qd=[0.0] * 33, qd_nominal=[0.0] * 33),  # more than MAX_JOINTS
    ],
)
def test_joint_state_rejects_wrong_lengths(raw) -> None:
    with pytest.raises(ValidationError):
        JointState.model_validate(raw)


@pytest.mark.parametrize("raw", [capsule_raw(a=[0.0, 1.0]), capsule_raw(b=[0.0, 1.0, 2.0, 3.0]), capsule_raw(a=[])])
def test_capsule_rejects_wrong_lengths(raw) -> None:
    with pytest.raises(ValidationError):
        Capsule.model_validate(raw)


def test_negative_radius_rejected_everywhere() -> None:
    with pytest.raises(ValidationError):
        Capsule.model_validate(capsule_raw(radius=-0.01))
    with pytest.raises(ValidationError):
        Human.model_validate(human_raw(capsules=[capsule_raw(radius=-0.01)]))
    with pytest.raises(ValidationError):
        Humans.model_validate(humans_raw(humans=[human_raw(capsules=[capsule_raw(radius=-1e-9)])]))


@pytest.mark.parametrize(("model", "make"), MODELS)
def test_unknown_fields_rejected(model, make) -> None:
    with pytest.raises(ValidationError):
        model.model_validate(make(velocity_scale=0.5))
    assert _reason(make(velocity_scale=0.5), model) == "invalid"


@pytest.mark.parametrize(
    ("model", "make", "wrong"),
    [
        (JointState, joint_state_raw, "hrc.joint_state/2"),
        (Humans, humans_raw, "hrc.override/1"),
        (Override, override_raw, "hrc.humans/1"),
    ],
)
def test_wrong_schema_rejected(model, make, wrong) -> None:
    with pytest.raises(ValidationError):
        model.model_validate(make(schema=wrong))
    assert _reason(make(schema=wrong), model) == "wrong_schema"
    raw = make()
    del raw["schema"]
    assert _reason(raw, model) == "wrong_schema"  # the schema must be on the wire


@pytest.mark.parametrize(
    "raw",
    [
        joint_state_raw(override=1.01),
        joint_state_raw(override=-0.1),
        joint_state_raw(seq=-1),
        joint_state_raw(stamp_ns=-5),
        joint_state_raw(robot="UR5"),  # upper case is not allowed in a key segment
        joint_state_raw(robot="ur5/x"),
        joint_state_raw(mode="dancing"),
        joint_state_raw(override_seq=-2),
        joint_state_raw(q="012345"),
    ],
)
def test_joint_state_rejects_out_of_range(raw) -> None:
    with pytest.raises(ValidationError):
        JointState.model_validate(raw)


def test_override_rejects_out_of_range() -> None:
    for delta in (-0.01, 1.0001, 62):  # 0–100 % confusion must not pass
        with pytest.raises(ValidationError):
            Override.model_validate(override_raw(delta=delta))


def test_too_many_capsules_rejected() -> None:
    many = [human_raw(id=f"h{i}", capsules=[capsule_raw()] * 1000) for i in range(3)]
    with pytest.raises(ValidationError):
        Humans.model_validate(humans_raw(humans=many))


# -- parse_message reasons ----------------------------------------------------------------------


def test_parse_reasons() -> None:
    assert _reason(b"{not json", JointState) == "not_json"
    assert _reason(b"\xff\xfe\x00", JointState) == "not_json"
    assert _reason(b"[1, 2, 3]", JointState) == "not_json"  # JSON but not an object
    assert _reason(b'"hello"', Humans) == "not_json"
    assert _reason(b"", Override) == "not_json"
    for literal in (b"NaN", b"Infinity", b"-Infinity"):
        payload = _payload(joint_state_raw()).replace(b'"override": 0.62', b'"override": ' + literal)
        assert _reason(payload, JointState) == "non_finite"
    assert _reason(b" " * (MAX_PAYLOAD_BYTES + 1), Humans) == "too_large"
    assert _reason(joint_state_raw(q=[0.0] * 5), JointState) == "invalid"


def test_overflowing_number_is_non_finite() -> None:
    # json turns 1e999 into inf without calling parse_constant: it must still count as non-finite
    payload = _payload(joint_state_raw()).replace(b'"override": 0.62', b'"override": 1e999')
    assert _reason(payload, JointState) == "non_finite"
    payload = _payload(capsule_raw()).replace(b'"radius": 0.05', b'"radius": -1e999')
    assert _reason(payload, Capsule) == "non_finite"
    payload = _payload(override_raw()).replace(b'"delta": 0.62', b'"delta": 1e308')  # large but finite: range
    assert _reason(payload, Override) == "invalid"


def test_deeply_nested_json_is_not_json() -> None:
    for depth in (1_000, 100_000):
        assert _reason(b"[" * depth + b"]" * depth, Humans) == "not_json"
        assert _reason(b'{"a":' * depth + b"1" + b"}" * depth, JointState) == "not_json"


def test_message_error_carries_reason_and_detail() -> None:
    with pytest.raises(MessageError) as info:
        parse_message(_payload(joint_state_raw(q=[0.0] * 5)), JointState)
    assert info.value.reason == "invalid"
    assert str(info.value).startswith("invalid: ")
    assert isinstance(info.value, ValueError)


# -- the fast path agrees with the reference ------------------------------------------------------


def _outcome(parse, payload: bytes, model: type[BaseModel]) -> tuple[str, str]:
    """``("ok", the message as JSON)`` or ``("error", reason)``: JSON tells -0.0 from 0.0 and every float bit."""
    try:
        return "ok", parse(payload, model).model_dump_json(by_alias=True)
    except MessageError as exc:
        return "error", exc.reason


@pytest.mark.parametrize(
    ("payload", "model", "reason"),
    [
        (_payload({k: v for k, v in override_raw().items() if k != "schema"}), Override, "wrong_schema"),
        # the field name instead of the wire name: the reference finds no schema
        (_payload({"schema_" if k == "schema" else k: v for k, v in override_raw().items()}), Override, "wrong_schema"),
        (_payload(human_raw(id="a\nb")).replace(b"\\n", b"\n"), Human, "not_json"),  # raw control character
        (_payload(override_raw()) + b" x", Override, "not_json"),  # trailing data
        (_payload(joint_state_raw(schema="hrc.joint_state/2", q=[0.0])), JointState, "wrong_schema"),
        (_payload(override_raw(delta="NaN")), Override, "invalid"),  # a string is not a number token
    ],
)
def test_fast_path_refusals_keep_the_reference_reason(payload: bytes, model, reason: str) -> None:
    assert _reason(payload, model) == reason
    assert _outcome(parse_message_reference, payload, model) == ("error", reason)


@pytest.mark.parametrize(
    ("payload", "model"),
    [
        ("\ufeff".encode() + _payload(override_raw()), Override),  # UTF-8 with a BOM: json.loads takes it
        (json.dumps(override_raw()).encode("utf-16"), Override),  # as it takes UTF-16
        (_payload(human_raw(id="\ud800x")), Human),  # a lone surrogate escape
        (_payload(override_raw()).replace(b'"seq": 517', b'"seq": 517, "seq": 518'), Override),  # last wins
        (_payload(capsule_raw(a=["1e1", True, 2])), Capsule),  # lax conversions
    ],
)
def test_what_the_reference_accepts_the_fast_path_accepts_the_same(payload: bytes, model) -> None:
    expected = _outcome(parse_message_reference, payload, model)
    assert _outcome(parse_message, payload, model) == expected


def test_fast_path_agrees_with_the_reference_on_seededmutate_payload() -> None:
    """Same acceptance, same reason, same values (to the bit) as ``json.loads`` + ``model_validate``."""
    rng = np.random.default_rng(7)
    outcomes: set[str] = set()
    for k in range(3000):
        model, make = MODELS[k % len(MODELS)]
        payload = _payload(make())
        if k % 3 == 0:
            payload = mutate_payload(rng, payload)
        elif k % 3 == 1:
            payload = mutate_payload(rng, mutate_payload(rng, payload))
        else:  # every float re-spelt: long mantissas, exponents near the limits
            text = payload.decode()
            for number in {w.strip(",]}") for w in text.split() if w[:1].isdigit() and "." in w}:
                text = text.replace(number, random_float_token(rng), 1)
            payload = text.encode()
        reference = _outcome(parse_message_reference, payload, model)
        assert _outcome(parse_message, payload, model) == reference, payload
        outcomes.add(reference[0] if reference[0] == "ok" else reference[1])
    # The mutations reach every reason, and valid payloads too.
    assert outcomes == {"ok", "not_json", "non_finite", "wrong_schema", "invalid"}
