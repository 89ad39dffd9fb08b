"""The status's capsule text written by compiled code (gateway/capsules_json.py) is the models' JSON, byte for byte."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import TypeAdapter

from gateway import capsules_json
from gateway.capsules_json import check_capsules_json, human_capsules_json, reference_capsules_json
from gateway.status import human_capsules
from hrc_contract.config import ConfigError
from hrc_contract.humans import HumanCapsules
from hrc_contract.status_models import HumanCapsuleStatus

_MODELS: TypeAdapter[list[HumanCapsuleStatus]] = TypeAdapter(list[HumanCapsuleStatus])

ODD_TEXT = ('"', "\\", '\\"', '","', "],[", "\x00\x1f", "käsi \u2603 \t", "\U0001f9cd", "a" * 64)
"""Names and ids whose JSON text is escaped, or could be cut in the wrong place."""


def random_capsules(rng: np.random.Generator, n: int, largest_exponent: int = 3) -> HumanCapsules:
    """``n`` capsules with coordinates over many magnitudes (1e-7 to 10^largest_exponent), signed zeros, halves
    rounded away and values the rounding makes whole; ids and names with quotes, escapes and beyond ASCII."""
    values = rng.uniform(-9.99, 9.99, (n, 7)) * 10.0 ** rng.integers(-7, largest_exponent, (n, 7))
    special = np.array([0.0, -0.0, 1e-4, -1e-4, 5e-5, -4.9e-5, 0.00015, 2.5, 1.99995, -0.30000000000000004])
    values = np.where(rng.random((n, 7)) < 0.25, rng.choice(special, (n, 7)), values)
    ids = tuple(f"front/h{i // 15}" if i % 4 else f"säde/{ODD_TEXT[i % len(ODD_TEXT)]}{i // 15}" for i in range(n))
    names = tuple(f"part{i % 15}" if i % 3 else f"{ODD_TEXT[(i // 3) % len(ODD_TEXT)]}" for i in range(n))
    return HumanCapsules(values[:, 0:3], values[:, 3:6], np.abs(values[:, 6]), ids, names)


def models_json(capsules: HumanCapsules) -> bytes:
    return _MODELS.dump_json(human_capsules(capsules))


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_text_is_the_models_json(seed: int) -> None:
    rng = np.random.default_rng(seed)
    capsules = random_capsules(rng, int(rng.integers(1, 600)))
    assert (
        capsules_json._compiled_text(  # the compiled pass wrote it (it declines nothing below 1e11 m)
            capsules_json.capsule_table(capsules.h_a_world, capsules.h_b_world, capsules.radius_m), capsules
        )
        is not None
    )
    assert human_capsules_json(capsules) == models_json(capsules)
    assert reference_capsules_json(capsules) == models_json(capsules)


def test_values_beyond_what_the_pass_writes_take_the_references_way_with_the_same_bytes() -> None:
    rng = np.random.default_rng(7)
    capsules = random_capsules(rng, 50, largest_exponent=14)  # up to 1e14 m: written by Python, not the pass
    table = capsules_json.capsule_table(capsules.h_a_world, capsules.h_b_world, capsules.radius_m)
    assert capsules_json._compiled_text(table, capsules) is None
    assert human_capsules_json(capsules) == models_json(capsules)


def test_values_that_are_not_numbers_are_drawn_at_zero_as_the_models_get_them() -> None:
    a = np.array([[np.nan, np.inf, -np.inf], [1.0, 2.0, 3.0]])
    capsules = HumanCapsules(a, a[::-1].copy(), np.array([0.1, np.nan]), ("t/a", "t/a"), ("x", "y"))
    text = human_capsules_json(capsules)
    assert text == models_json(capsules)
    assert b'"a_m":[0.0,0.0,0.0]' in text


def test_no_capsules_is_an_empty_list_and_names_or_ids_not_one_per_capsule_are_refused() -> None:
    nothing = np.zeros((0, 3))
    assert human_capsules_json(HumanCapsules(nothing, nothing, np.zeros(0), (), ())) == b"[]"
    one = np.zeros((1, 3))
    with pytest.raises(ValueError, match="2 names and 1 ids for 1 capsules"):
        human_capsules_json(HumanCapsules(one, one, np.zeros(1), ("t/a",), ("x", "y")))


def test_the_start_up_check_refuses_a_pass_that_writes_other_text(monkeypatch: pytest.MonkeyPatch) -> None:
    check_capsules_json.cache_clear()
    real = capsules_json._compiled_text

    def trailing_zero(table: np.ndarray, capsules: HumanCapsules) -> bytes | None:
        text = real(table, capsules)
        return None if text is None else text.replace(b".5,", b".50,", 1)

    monkeypatch.setattr(capsules_json, "_compiled_text", trailing_zero)
    with pytest.raises(ConfigError, match="compiled capsule text differs"):
        check_capsules_json()
    check_capsules_json.cache_clear()
    monkeypatch.setattr(capsules_json, "_compiled_text", real)
    check_capsules_json()  # the real pass passes
