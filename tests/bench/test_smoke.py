"""The benchmarks still run (tiny counts, a few seconds each) and their matching logic is right.

Not timed assertions: the figures depend on the machine; only the shape of the results is checked.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pytest

from bench import compute, loop, reaction
from bench._progress import Progress, progress_line
from bench.reaction import OverrideSeen, Sample, StateSeen, StatusSeen, check_against_status, match_reactions
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.procs import with_gateway_rate, write_cell_config

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
    # the cycles that take new tracker frames (every 8th, from the 5 warm-up cycles on: 8, 16, 24, 32) apart
    split = reference["compute_us_by_frame"]
    assert split["with_new_tracker_frames"]["n"] == 4
    assert split["without"]["n"] == 26
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
    # Every sample is matched or excluded with its reason. How many are matched depends on the machine's load, not
    # on the code: a sender thread held off the CPU for a period has its override replaced by the next decision's
    # (gateway.main.OverrideSenders), a seq gap the matching cannot see through (CI at 082724c: 10 of 40 matched, 21
    # seq gaps, 23 missed cycles). So the test asks for figures, and the benchmark's report says how many.
    assert run["samples_matched"] + sum(run["excluded"].values()) == run["samples_sent"]
    assert run["samples_matched"] >= 5
    assert run["status_cross_check"]["disagree"] == 0
    assert run["zenoh_oneway_floor_ms"]["n"] >= 30
    assert 1 <= run["applied_ms"]["n"] <= run["samples_matched"]
    # A sample cannot be reflected before it was sent, nor applied before it was decided.
    assert 0 < run["decision_ms"]["min"] <= run["published_received_ms"]["min"]
    assert run["decision_ms"]["p50"] <= run["applied_ms"]["p50"]


@pytest.mark.e2e
def test_loop_benchmark_runs_with_and_without_sse_clients(tmp_path: Path) -> None:
    out = tmp_path / "loop.json"
    argv = ["--duration", "1.5", "--warmup", "0.5", "--rates", "250", "--http-rates", "50", "--sse-clients", "2"]
    assert loop.main([*argv, "--json", str(out)]) == 0
    doc = _load(out)
    without, with_sse = doc["results"]["runs"]  # the pair at the same rate: without, then with the clients
    for run in (without, with_sse):
        assert run["period_ms"]["n"] > 100
        assert 2.0 < run["period_ms"]["p50"] < 8.0  # about 4 ms, on a busy machine too
        assert run["http"]["requests"] > 0
    assert (without["sse_clients"], without["sse"]) == (0, None)
    sse = with_sse["sse"]
    assert sse["clients"] == 2
    assert sse["errors"] == []
    assert sse["min_docs_per_s"] > 0
    assert all(c["documents"] > 0 and c["docs_per_s"] > 0 for c in sse["per_client"])
    # The status rate bounds what a client can get (the stream sends each document once).
    assert sse["docs_per_s"]["max"] <= 1.2 * doc["parameters"]["status_rate_hz"]
    targets = {t["name"]: t for t in doc["targets"]}
    assert len(targets) == 4  # period p99 of each run, documents/s of the slowest client, p99 with / without
    docs = targets["SSE documents/s to each of 2 clients (slowest) at 250 Hz, 50 req/s"]
    assert docs["at_least"]
    assert docs["measured"] == sse["min_docs_per_s"]
    ratio = targets["period p99 with 2 SSE clients / without at 250 Hz, 50 req/s"]
    assert ratio["measured"] == pytest.approx(with_sse["period_ms"]["p99"] / without["period_ms"]["p99"], abs=1e-3)


def test_stream_rate_counts_the_window_and_its_worst_second() -> None:
    received_s = [0.5, *(10.0 + k / 25 for k in range(50)), 12.5, 13.5]  # 25/s for 2 s, then one each second
    rate = loop.stream_rate(received_s, 10.0, 14.0)
    assert rate == {"documents": 52, "docs_per_s": 13.0, "fewest_in_a_second": 1}
    assert loop.versions_skipped([3, 4, 5, 7, 10]) == 3


# -- progress ---------------------------------------------------------------------------------------------


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def test_progress_on_a_terminal_redraws_one_line_in_place() -> None:
    out, clock = io.StringIO(), FakeClock()
    with Progress("bench", 4, "runs", stream=out, tty=True, redraw_s=0.1, clock_s=clock, columns=200) as progress:
        for k in range(1, 5):
            clock.now_s = 10.0 * k
            progress.update(k, note=f"run {k}")
            progress.update(k)  # no time passed: not drawn again (not even the end)
        assert "\n" not in out.getvalue()
    text = out.getvalue()
    assert text.endswith("\n")
    assert text.count("\n") == 1  # one line, ended once at close
    frames = text.rstrip("\n").split("\r")[1:]
    assert len(frames) == 5  # each update that moved time, and the last state at close
    assert frames[0].startswith("bench  [" + "#" * 6 + "-" * 18 + "]   25%  1/4 runs  0:10 elapsed, ~0:30 left")
    assert frames[-1].rstrip().endswith("100%  4/4 runs  0:40 elapsed, ~0:00 left  run 4")


def test_progress_off_a_terminal_writes_a_line_every_few_seconds_or_percent() -> None:
    out, clock = io.StringIO(), FakeClock()
    progress = Progress("bench", 100.0, "s", stream=out, every_s=5.0, step_percent=50.0, clock_s=clock)
    assert not progress.tty  # StringIO is no terminal
    for t_s, done in [(1.0, 10.0), (6.0, 20.0), (7.0, 60.0), (8.0, 70.0), (9.0, 100.0)]:
        clock.now_s = t_s
        progress.update(done)
    progress.close()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    # 20 %: 5 s since the start; 60 %: past 50 %; 100 %: past 100 % (close does not repeat it).
    assert lines == [
        progress_line("bench", 20.0, 100.0, "s", 6.0, bar=False),
        progress_line("bench", 60.0, 100.0, "s", 7.0, bar=False),
        progress_line("bench", 100.0, 100.0, "s", 9.0, bar=False),
    ]
    assert lines[0] == "bench   20%  20/100 s  0:06 elapsed, ~0:24 left"


def test_progress_message_clears_the_bar_and_draws_it_again(capsys: pytest.CaptureFixture[str]) -> None:
    out, clock = io.StringIO(), FakeClock()
    progress = Progress("bench", 2, stream=out, tty=True, clock_s=clock, columns=40)
    clock.now_s = 1.0
    progress.update(1)
    progress.message("... run 2")
    assert capsys.readouterr().out == "... run 2\n"
    drawn = out.getvalue().split("\r")
    assert drawn[1] == "bench  [" + "#" * 12 + "-" * 12 + "]   50%"  # cut to 39 columns
    assert drawn[2].strip() == ""  # the bar cleared before the message
    assert drawn[-1] == drawn[1]  # and drawn again after it
