"""The tracker frames' door (:func:`hrc_contract.humans.humans_from_payload`): its fast path accepts exactly what the
reference accepts, refuses with the reference's reason, and gives the same capsules to the bit."""

from __future__ import annotations

import json

import msgspec
import numpy as np
import pytest
from support.payload_mutations import mutate_payload, random_float_token

from bench.door import STAMP_NS, random_frame
from hrc_contract import humans as door
from hrc_contract.humans import (
    PACKED_ROW_BYTES,
    HumanCapsules,
    HumansHeader,
    capsules_from_message,
    human_starts,
    humans_from_packed,
    humans_from_payload,
    is_packed,
    packed_payload,
)
from hrc_contract.messages import (
    MAX_CAPSULES_PER_MESSAGE,
    MAX_PAYLOAD_BYTES,
    Humans,
    MessageError,
    parse_message,
    parse_message_reference,
)

STAMP = STAMP_NS


def _frame(rng: np.random.Generator, people: int, parts: int) -> dict:
    return random_frame(rng, people, parts, seq=88)


def _reference(payload: bytes) -> tuple[HumansHeader, HumanCapsules]:
    message = parse_message_reference(payload, Humans)
    capsules = capsules_from_message(message.tracker, message)
    starts = tuple(human_starts(capsules))  # the door's are the decoder's: held to these on every seeded frame
    return HumansHeader(message.tracker, message.seq, message.stamp_ns, len(message.humans), starts), capsules


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
    assert header == HumansHeader("front", 88, STAMP, 3, (0, 15, 30, 45))
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
        if is_packed(payload):  # a mutated first byte that opens a MessagePack map: the packed door judges it
            assert _outcome(humans_from_payload, payload)[0] == "error"
            continue
        reference = _outcome(_reference, payload)
        assert _outcome(humans_from_payload, payload) == reference, payload
        outcomes.add(reference[0] if reference[0] == "ok" else str(reference[1]))
    assert outcomes == {"ok", "not_json", "non_finite", "wrong_schema", "invalid"}


# -- packed frames ---------------------------------------------------------------------------------------------------


def _packed_doc(raw: dict) -> dict:
    """The packed frame of a JSON frame, as a document (to be changed by a test, then encoded)."""
    return msgspec.msgpack.decode(packed_payload(parse_message(json.dumps(raw).encode(), Humans)))


def test_a_packed_frame_gives_the_same_header_and_capsules_as_its_json_to_the_bit() -> None:
    for people, parts in ((0, 1), (1, 1), (3, 15), (2, 1000)):
        payload = json.dumps(_frame(np.random.default_rng(people + parts), people, parts)).encode()
        packed = packed_payload(parse_message(payload, Humans))
        assert is_packed(packed)
        assert not is_packed(payload)
        assert not is_packed(b" " + payload)
        assert _outcome(humans_from_payload, packed) == _outcome(_reference, payload)
        assert len(packed) < len(payload)


def test_where_each_person_starts_is_known_to_every_decoder_even_for_an_id_listed_twice() -> None:
    """The header's starts are :func:`human_starts` of the capsules on the JSON fast path, the reference path and the
    packed path, also where one id is listed twice in a row (one run of capsules there; the plausibility check then
    refuses it) or apart."""
    raw = _frame(np.random.default_rng(9), 5, 3)
    for k, human_id in enumerate(("a", "a", "b", "a", "c")):
        raw["humans"][k]["id"] = human_id
    raw["humans"][4]["capsules"] = raw["humans"][4]["capsules"][:1]
    payload = json.dumps(raw).encode()
    reference = parse_message_reference(payload, Humans)
    capsules = capsules_from_message(reference.tracker, reference)
    want = (0, 6, 9, 12, 13)
    assert tuple(human_starts(capsules)) == want
    lax = payload.replace(b'"seq": 88', b'"seq": 88.0')  # not for the fast path (an integer): the reference's
    assert lax != payload
    assert door._humans_fast(lax) is None
    for header, _ in (
        door._humans_fast(payload),
        humans_from_payload(lax),
        humans_from_payload(packed_payload(reference)),
    ):
        assert header.human_starts == want


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (lambda doc: doc.update(schema="hrc.humans/1"), "wrong_schema"),
        (lambda doc: doc.update(tracker="Front"), "invalid"),
        (lambda doc: doc.update(tracker="front\n"), "invalid"),
        (lambda doc: doc.update(seq=-1), "invalid"),
        (lambda doc: doc.update(extra=1), "invalid"),
        (lambda doc: doc.pop("stamp_ns"), "invalid"),
        (lambda doc: doc["humans"][0].update(id=""), "invalid"),
        (lambda doc: doc["humans"][0].update(id="x" * 65), "invalid"),
        (lambda doc: doc["humans"][0]["names"].append("extra"), "invalid"),  # a name without its row
        (lambda doc: doc["humans"][0].update(capsules=doc["humans"][0]["capsules"][:-1]), "invalid"),
        (lambda doc: doc["humans"][0].update(names=[], capsules=b""), "invalid"),  # a person with no capsule
        (lambda doc: doc["humans"][0]["names"].__setitem__(0, ""), "invalid"),
        (lambda doc: doc["humans"][0].update(capsules="not bytes"), "invalid"),
        (lambda doc: doc["humans"].extend(doc["humans"] * 200), "invalid"),  # more capsules than a frame may carry
    ],
)
def test_packed_refusals_carry_their_reason(change, reason: str) -> None:
    doc = _packed_doc(_frame(np.random.default_rng(5), 2, 10))
    change(doc)
    payload = msgspec.msgpack.encode(doc)
    assert _outcome(humans_from_payload, payload) == ("error", reason)


@pytest.mark.parametrize(
    ("value", "reason"),
    [(float("nan"), "non_finite"), (float("inf"), "non_finite"), (-0.01, "invalid"), (2.01, "invalid")],
)
def test_a_packed_radius_or_coordinate_the_contract_refuses_is_refused(value: float, reason: str) -> None:
    doc = _packed_doc(_frame(np.random.default_rng(6), 1, 3))
    rows = np.frombuffer(doc["humans"][0]["capsules"], dtype="<f8").copy().reshape(-1, 7)
    rows[1, 6 if reason == "invalid" else 2] = value
    doc["humans"][0]["capsules"] = rows.tobytes()
    assert _outcome(humans_from_payload, msgspec.msgpack.encode(doc)) == ("error", reason)


def test_what_is_not_a_packed_frame_is_refused_with_a_reason_never_an_exception() -> None:
    assert _outcome(humans_from_packed, b"\x81") == ("error", "not_msgpack")  # a map cut short
    assert _outcome(humans_from_packed, b"\x81\xa6schema") == ("error", "not_msgpack")  # a key without its value
    assert _outcome(humans_from_packed, b"\xde\x00") == ("error", "not_msgpack")
    assert _outcome(humans_from_packed, msgspec.msgpack.encode([1, 2])) == ("error", "invalid")
    big = b"\x81" + b"\x00" * MAX_PAYLOAD_BYTES
    assert _outcome(humans_from_payload, big) == ("error", "too_large")


def test_seeded_damage_to_packed_frames_is_refused_or_read_as_a_frame_the_contract_allows() -> None:
    """Bytes flipped, cut or inserted anywhere: every outcome is a refusal with a reason, or a frame whose every
    value the contract allows (the damage hit a coordinate: still finite, still a frame)."""
    rng = np.random.default_rng(12)
    outcomes: set[str] = set()
    for _ in range(1500):
        packed = bytearray(packed_payload(parse_message(json.dumps(_frame(rng, 2, 3)).encode(), Humans)))
        for _ in range(int(rng.integers(1, 4))):
            if not packed:
                break
            at = int(rng.integers(len(packed)))
            what = rng.random()
            if what < 0.6:
                packed[at] = int(rng.integers(256))
            elif what < 0.8:
                del packed[at:]
            else:
                packed[at:at] = bytes(rng.integers(0, 256, int(rng.integers(1, 9))).astype(np.uint8))
        outcome = _outcome(humans_from_payload, bytes(packed))
        outcomes.add(outcome[0] if outcome[0] == "ok" else str(outcome[1]))
        if outcome[0] == "ok":
            _, rows, ids, names = outcome[1]
            values = np.frombuffer(rows, dtype=np.float64).reshape(-1, 7)
            assert np.isfinite(values).all()
            assert ((values[:, 6] >= 0.0) & (values[:, 6] <= 2.0)).all()
            assert len(ids) == len(names) == len(values) <= MAX_CAPSULES_PER_MESSAGE
            assert all(0 < len(n) <= 64 for n in names)
    assert {"ok", "not_msgpack", "invalid"} <= outcomes
    # a damaged first byte no longer opens a map: the JSON door refuses it
    assert outcomes <= {"ok", "not_msgpack", "invalid", "non_finite", "wrong_schema", "not_json"}


def test_a_packed_row_is_seven_little_endian_doubles() -> None:
    raw = _frame(np.random.default_rng(7), 1, 1)
    doc = _packed_doc(raw)
    capsule = raw["humans"][0]["capsules"][0]
    expected = np.array([*capsule["a"], *capsule["b"], capsule["radius"]], dtype="<f8").tobytes()
    assert doc["humans"][0]["capsules"] == expected
    assert len(expected) == PACKED_ROW_BYTES
