"""bench.pfl_bounded_by: every decision of ContactAware is tallied by its label, for both mass models."""

from __future__ import annotations

import os

import pytest

from bench import pfl_bounded_by
from gateway.methods import ContactAware


def test_one_short_case_tallies_every_decision_of_both_mass_models(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("HRC_ALLOW_UNSAFE", raising=False)
    original = ContactAware.bound
    assert pfl_bounded_by.main(["--scenarios", "1", "--duration-s", "0.4"]) == 0
    assert ContactAware.bound is original  # the tally is undone
    assert "HRC_ALLOW_UNSAFE" not in os.environ  # the simple mass is allowed only inside
    out = capsys.readouterr().out
    totals = [line for line in out.splitlines() if "contact rows bound δ in" in line]
    assert [line.split(":")[0] for line in totals] == ["link_bound", "simple"]
    for line in totals:
        decisions = int(line.split(" of ")[1].split()[0])
        assert decisions >= 0.4 * 250 * 0.9  # one robot at 250 Hz for 0.4 s, each decision counted


def test_a_bad_count_is_refused() -> None:
    with pytest.raises(SystemExit):
        pfl_bounded_by.main(["--scenarios", "0"])
