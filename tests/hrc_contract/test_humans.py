"""The tracker frames' door (:func:`hrc_contract.humans.humans_from_payload`): its fast path accepts exactly what the
reference accepts, refuses with the reference's reason, and gives the same capsules to the bit."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.payload_mutations import mutate_payload, random_float_token

from hrc_contract import humans as door
from hrc_contract.humans import HumanCapsules, HumansHeader, capsules_from_message, humans_from_payload
from hrc_contract.messages import MAX_CAPSULES_PER_MESSAGE, Humans, MessageError, parse_message_reference

STAMP = 1_790_000_000_000_000_000


def _frame(rng: np.random.Generator, people: int, parts: int) -> dict:
    humans = []
    for k in range(people):
        capsules = []
        for j in range(parts):
            a = rng.uniform(-3.0, 3.0, 3)
            b = a + rng.uniform(-0.2, 0.2, 3)
            radius = float(rng.uniform(0, 0.2))
            capsules.append({"name": f"part{j}", "a": a.tolist(), "b": b.tolist(), "radius": radius})
        humans.append({"id": f"p{k}", "capsules": capsules})
    return {"schema": "hrc.humans/1", "tracker": "front", "seq": 88, "stamp_ns": STAMP, "humans": humans}


def _reference(payload: bytes) -> tuple[HumansHeader, HumanCapsules]:
    message = parse_message_reference(payload, Humans)
    header = HumansHeader(message.tracker, message.seq, message.stamp_ns, len(message.humans))
    return header, capsules_from_message(message.tracker, message)


def _outcome(parse, payload: bytes) -> tuple[str, object]:
    """``("ok", header, the capsules' bytes, ids, names)`` or ``("error", reason)``: bytes tell every float bit."""
    try:
        header, capsules = parse(payload)
    except MessageError as exc:
        return "error", exc.reason
    rows = np.concatenate((capsules.h_a_world, capsules.h_b_world, capsules.radius_m[:, None]), axis=1)
    return "ok", (header, rows.tobytes(), capsules.human_ids, capsules.capsule_names)


def _nested_mutation(rng: np.random.Generator, raw: dict) -> bytes:
    """A mutation inside one person or one capsule (the top-level mutations do not reach them)."""
    humans = raw["humans"]
    if not humans:
        return mutate_payload(rng, json.dumps(raw).encode())
    human = humans[int(rng.integers(len(humans)))]
    if rng.random() < 0.5:
        target, index, container = human, None, humans
    else:
        index = int(rng.integers(len(human["capsules"])))
        target, container = human["capsules"][index], human["capsules"]
    mutated = mutate_payload(rng, json.dumps(target).encode())
    try:
        replacement = json.loads(mutated)
    except ValueError:
        replacement = mutated.decode("utf-8", "replace")
    container[humans.index(human) if container is humans else index] = replacement
    return json.dumps(raw).encode()


def test_a_valid_frame_gives_the_references_header_and_capsules() -> None:
    payload = json.dumps(_frame(np.random.default_rng(1), 3, 15)).encode()
    outcome = _outcome(humans_from_payload, payload)
    assert outcome == _outcome(_reference, payload)
    assert _outcome(door._humans_fast, payload) == outcome, "a valid frame takes the fast path"
    header, capsules = humans_from_payload(payload)
    assert header == HumansHeader("front", 88, STAMP, 3)
    assert capsules.n_capsules == 45
    assert capsules.human_ids[:2] == ("front/p0", "front/p0")
    assert capsules.human_ids[-1] == "front/p2"


def test_an_empty_frame_is_nobody() -> None:
    header, capsules = humans_from_payload(json.dumps(_frame(np.random.default_rng(1), 0, 0)).encode())
    assert (header.human_count, capsules.n_capsules, capsules.h_a_world.shape) == (0, 0, (0, 3))


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (lambda raw: raw.update(tracker="front\n"), "invalid"),  # a name the key could not carry
        (lambda raw: raw.update(schema="hrc.humans/2"), "wrong_schema"),
        (lambda raw: raw["humans"][0]["capsules"][0].update(radius=2.5), "invalid"),
        (lambda raw: raw["humans"][0]["capsules"][0].update(a=[0.0, 1.0]), "invalid"),
        (lambda raw: raw["humans"][0].update(capsules=[]), "invalid"),
        (lambda raw: raw["humans"][0].update(id=""), "invalid"),
        (lambda raw: raw.update(seq=-1), "invalid"),
        (lambda raw: raw.update(extra=1), "invalid"),
        (lambda raw: raw["humans"].extend(raw["humans"] * 150), "invalid"),  # more capsules than a frame may carry
    ],
)
def test_refusals_carry_the_references_reason(change, reason: str) -> None:
    raw = _frame(np.random.default_rng(2), 2, 10)
    change(raw)
    payload = json.dumps(raw).encode()
    assert _outcome(humans_from_payload, payload) == ("error", reason)
    assert _outcome(_reference, payload) == ("error", reason)


def test_overflowing_and_non_finite_numbers_are_refused_as_the_reference_does() -> None:
    payload = json.dumps(_frame(np.random.default_rng(3), 1, 2)).encode()
    first = payload.index(b'"a": [') + len(b'"a": [')
    for token in (b"1e400", b"-1e999", b"NaN", b"Infinity"):
        bad = payload[:first] + token + b", " + payload[first:].split(b", ", 1)[1]
        assert _outcome(humans_from_payload, bad) == _outcome(_reference, bad)
        assert _outcome(humans_from_payload, bad)[0] == "error"


def test_the_most_capsules_a_frame_may_carry_are_accepted() -> None:
    raw = _frame(np.random.default_rng(4), 100, 20)
    assert sum(len(h["capsules"]) for h in raw["humans"]) == MAX_CAPSULES_PER_MESSAGE
    header, capsules = humans_from_payload(json.dumps(raw).encode())
    assert capsules.n_capsules == MAX_CAPSULES_PER_MESSAGE
    assert header.human_count == 100


def test_the_door_agrees_with_the_reference_on_seeded_mutations() -> None:
    """Same acceptance, same reason, same header and capsules (to the bit) as ``json.loads`` + ``model_validate``."""
    rng = np.random.default_rng(11)
    outcomes: set[str] = set()
    for k in range(1500):
        raw = _frame(rng, int(rng.integers(0, 4)), int(rng.integers(1, 4)))
        payload = json.dumps(raw).encode()
        if k % 4 == 0:
            payload = mutate_payload(rng, payload)
        elif k % 4 == 1:
            payload = _nested_mutation(rng, raw)
        elif k % 4 == 2:
            payload = mutate_payload(rng, _nested_mutation(rng, raw))
        else:  # every float re-spelt: long mantissas, exponents near the limits
            text = payload.decode()
            for number in {w.strip(",]}") for w in text.split() if w[:1].isdigit() and "." in w}:
                text = text.replace(number, random_float_token(rng), 1)
            payload = text.encode()
        reference = _outcome(_reference, payload)
        assert _outcome(humans_from_payload, payload) == reference, payload
        outcomes.add(reference[0] if reference[0] == "ok" else str(reference[1]))
    assert outcomes == {"ok", "not_json", "non_finite", "wrong_schema", "invalid"}
