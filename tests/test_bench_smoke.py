"""The benchmarks still run (tiny counts, a few seconds each) and their matching logic is right.

Not timed assertions: the figures depend on the machine; only the shape of the results is checked.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from bench import compute, loop, reaction
from bench.procs import with_gateway_rate, write_cell_config
from bench.reaction import OverrideSeen, Sample, StateSeen, StatusSeen, check_against_status, match_reactions
from hrc_common.config import load_cell_config

MS = 1_000_000


def _load(path: Path) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(path.read_text())
    assert doc["machine"]["nproc"] >= 1
    assert len(doc["load_average"]["start"]) == 3
    for target in doc["targets"]:
        assert target["verdict"] in ("PASS", "MISS")
    return doc


def test_temporary_cell_config_round_trips(tmp_path: Path) -> None:
    config = with_gateway_rate(load_cell_config(None), 500.0, 8123)
    path = write_cell_config(config, tmp_path / "cell.toml")  # raises if it does not load back equal
    assert load_cell_config(path).gateway.rate_hz == 500.0


def test_compute_benchmark_runs(tmp_path: Path) -> None:
    out = tmp_path / "compute.json"
    argv = ["--cycles", "30", "--scale-cycles", "5", "--breakdown-cycles", "10", "--warmup", "5"]
    assert compute.main([*argv, "--max-humans", "2", "--max-robots", "2", "--json", str(out)]) == 0
    doc = _load(out)
    reference = doc["results"]["reference"]
    assert reference["compute_us"]["n"] == 30
    # The reference workload is what it claims: fresh data, confirmed override path, 2 × 15 capsules.
    assert reference["sanity"]["faults"] == {}
    assert reference["sanity"]["capsules_per_cycle"] == 30
    assert {"kinematics", "distances", "total (snapshot + step)"} <= set(doc["results"]["breakdown_us"])
    assert [p["robots"] for p in doc["results"]["scaling_robots"]["points"]] == [1, 2]
    assert [p["humans"] for p in doc["results"]["scaling_humans"]["points"]] == [1, 2]
    assert all(p["sanity"]["faults"] == {} for p in doc["results"]["scaling_robots"]["points"])


# -- reaction: matching samples to overrides, on a synthetic gateway ----------------------------------


def _synthetic_run(
    sample_ns: list[int], period_ns: int, transit_ns: int
) -> tuple[list[Sample], list[OverrideSeen], list[StateSeen], list[int]]:
    """A gateway cycling every ``period_ns`` from t = 0 that sees a sample ``transit_ns`` after it was sent
    (δ = 0 before it has seen any), a subscriber ``transit_ns`` away, a controller applying each override
    4 ms after its stamp; and the true latency from each sample to the first override reflecting it."""
    samples = [Sample(k, t, k % 2 == 1) for k, t in enumerate(sample_ns)]
    overrides: list[OverrideSeen] = []
    expected: dict[int, int] = {}
    for seq, cycle_ns in enumerate(range(0, sample_ns[-1] + 10 * period_ns, period_ns)):
        seen = [s for s in samples if s.stamp_ns + transit_ns <= cycle_ns]
        delta = 0.0 if not seen or seen[-1].near else 1.0
        overrides.append(OverrideSeen(seq, cycle_ns, delta, cycle_ns + transit_ns))
        if seen:
            expected.setdefault(seen[-1].seq, cycle_ns - seen[-1].stamp_ns)
    states = [StateSeen(i, o.stamp_ns + 4 * MS, o.seq) for i, o in enumerate(overrides)]
    return samples, overrides, states, [expected.get(k, -1) for k in range(len(samples))]


def test_matching_finds_the_first_override_reflecting_each_sample() -> None:
    sample_ns = [10 * MS * k + 1_234_567 * (k % 3) for k in range(1, 40)]
    samples, overrides, states, expected = _synthetic_run(sample_ns, period_ns=4 * MS, transit_ns=150_000)
    reactions, excluded = match_reactions(samples, overrides, states)
    assert excluded == {}
    assert len(reactions) == len(samples)
    for r in reactions:
        assert r.decision_ns == expected[r.sample]
        assert r.received_ns == expected[r.sample] + 150_000
        assert r.applied_ns == expected[r.sample] + 4 * MS
        assert 150_000 <= r.decision_ns < 150_000 + 4 * MS


def test_matching_excludes_what_the_overrides_cannot_tell() -> None:
    # Cycles every 4 ms. Sample 1 (near, 20 ms) is superseded by sample 2 (far, 21 ms) before the cycle
    # at 24 ms: no override reflects 1, and the first δ = 0 after it (44 ms) reflects sample 3, sent
    # at 40 ms. Sample 2 follows a far override (sample 0), so its first δ = 1 cannot be told apart.
    sample_ns = [1 * MS, 20 * MS, 21 * MS, 40 * MS, 60 * MS]
    samples, overrides, states, expected = _synthetic_run(sample_ns, period_ns=4 * MS, transit_ns=100_000)
    reactions, excluded = match_reactions(samples, overrides, states)
    assert excluded == {
        1: "not reflected before sample k + 2 was sent",
        2: "ambiguous: the previous sample was never reflected",
    }
    assert {r.sample: r.decision_ns for r in reactions} == {0: 3 * MS, 3: 4 * MS, 4: 4 * MS}
    assert expected[1] == -1  # really never reflected


def test_status_cross_check_agrees_with_the_matching() -> None:
    sample_ns = [10 * MS * k + 777_000 * (k % 4) for k in range(1, 30)]
    samples, overrides, states, _ = _synthetic_run(sample_ns, period_ns=4 * MS, transit_ns=120_000)
    reactions, _ = match_reactions(samples, overrides, states)
    statuses = []
    for o in overrides[::3]:
        seen = [s for s in samples if s.stamp_ns + 120_000 <= o.stamp_ns]
        if not seen:
            continue
        used = seen[-1]
        statuses.append(StatusSeen(o.stamp_ns, o.seq, round((o.stamp_ns - used.stamp_ns) / 1e9, 4), (), 0, 0.0))
    check = check_against_status(samples, reactions, statuses)
    assert check["checked"] > 10
    assert check["disagree"] == 0


# -- the benchmarks with the real programs --------------------------------------------------------------


@pytest.mark.e2e
def test_reaction_benchmark_runs(tmp_path: Path) -> None:
    out = tmp_path / "reaction.json"
    assert reaction.main(["--samples", "40", "--rates", "250", "--settle", "0.2", "--json", str(out)]) == 0
    run = _load(out)["results"]["runs"][0]
    assert run["samples_sent"] == 40
    assert run["samples_matched"] >= 30
    assert run["status_cross_check"]["disagree"] == 0
    assert run["zenoh_oneway_floor_ms"]["n"] >= 30
    assert run["applied_ms"]["n"] >= 30
    # A sample cannot be reflected before it was sent, nor applied before it was decided.
    assert 0 < run["decision_ms"]["min"] <= run["published_received_ms"]["min"]
    assert run["decision_ms"]["p50"] <= run["applied_ms"]["p50"]


@pytest.mark.e2e
def test_loop_benchmark_runs(tmp_path: Path) -> None:
    out = tmp_path / "loop.json"
    argv = ["--duration", "1.5", "--warmup", "0.5", "--rates", "250", "--http-rates", "50", "--json", str(out)]
    assert loop.main(argv) == 0
    doc = _load(out)
    run = doc["results"]["runs"][0]
    assert run["period_ms"]["n"] > 100
    assert 2.0 < run["period_ms"]["p50"] < 8.0  # about 4 ms, on a busy machine too
    assert run["http"]["requests"] > 0
    assert len(doc["targets"]) == 1
