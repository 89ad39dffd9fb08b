"""The soak: its seeded schedule, its event checks (pure), and a short run of the real cell (e2e)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import soak


def _event(seq: int, kind: str = "zone_changed", **fields: str) -> dict[str, object]:
    return {"seq": seq, "kind": kind, "message": "m", **fields}


def test_the_schedule_is_seeded_and_plays_every_fault_each_round() -> None:
    schedule = soak.fault_schedule(7, rounds=3)
    assert schedule == soak.fault_schedule(7, rounds=3)
    assert schedule != soak.fault_schedule(8, rounds=3)
    for k in range(3):
        assert sorted(schedule[k * len(soak.FAULT_KINDS) : (k + 1) * len(soak.FAULT_KINDS)]) == sorted(soak.FAULT_KINDS)


def test_events_are_split_into_gateway_runs_and_gaps_found() -> None:
    events = [_event(1, "start"), _event(2), _event(4), _event(1, "start"), _event(2)]
    runs = soak.split_runs(events)  # type: ignore[arg-type]
    assert [len(r) for r in runs] == [3, 2]
    assert soak.seq_gaps(runs[0]) == [3]
    assert soak.seq_gaps(runs[1]) == []


def test_stalls_and_their_missed_ticks_are_counted_by_cause_from_the_events() -> None:
    events = [
        _event(1, "loop_stall", cause="gc", message="loop stall: tick 9.0 ms late (2 missed), cause gc: ..."),
        _event(2, "loop_stall", cause="gc", message="loop stall: tick 5.0 ms late (1 missed), cause gc: ..."),
        _event(3, "loop_stall", cause="phase:decide", message="loop stall: tick 5.0 ms late (1 missed), ..."),
        _event(4),
    ]
    assert soak.stalls_by_cause(events) == ({"gc": 2, "phase:decide": 1}, {"gc": 3, "phase:decide": 1})  # type: ignore[arg-type]


def test_rss_growth_is_measured_over_each_process_lifetime_never_across_a_restart() -> None:
    """A restarted program's new process is compared with itself: the relay's +24 % "growth" of the 60-minute
    soak compared one process's start with the next's end."""

    def sample(**programs: tuple[int, int]) -> dict[str, dict[str, int]]:
        return {
            name: {"pid": pid, "rss_kb": rss_kb, "fds": 9, "threads": 3} for name, (pid, rss_kb) in programs.items()
        }

    samples = [
        sample(relay=(10, 80_000), audit=(20, 150_000)),
        sample(relay=(10, 81_000), audit=(20, 151_500)),
        sample(relay=(11, 100_000), audit=(20, 153_000)),  # the relay restarted: a bigger start
        sample(relay=(11, 101_000), audit=(20, 153_000)),
        {"relay": {"pid": 12}, "audit": {"pid": 20, "rss_kb": 153_000, "fds": 9, "threads": 3}},  # relay gone
    ]
    assert soak.rss_growth_percent(samples) == {"relay": 1.25, "audit": 2.0}
    spans = soak.lifetimes(samples)
    assert [(s.pid, s.samples) for s in spans["relay"]] == [(10, 2), (11, 2)]
    assert soak.rss_growth_percent(samples[:1]) == {}  # one sample shows no growth


def test_a_process_still_starting_is_not_compared() -> None:
    """A restarted gateway is small while it starts (models, kernels): its own warm-up is no growth."""
    samples = [
        {"gateway": {"pid": 5, "rss_kb": 150_000, "age_s": 2}},
        {"gateway": {"pid": 5, "rss_kb": 290_000, "age_s": 25}},
        {"gateway": {"pid": 5, "rss_kb": 292_900, "age_s": 30}},
    ]
    assert soak.rss_growth_percent(samples, warmup_s=20.0) == {"gateway": 1.0}


@pytest.mark.e2e
def test_a_short_soak_runs_the_cell_under_faults_and_reports(tmp_path: Path) -> None:
    """20 s: warm-up, a fault or two, the report. No violation, no event lost, each fault injected or said why."""
    code = soak.main(["--minutes", "0.34", "--seed", "3", "--out", str(tmp_path)])
    report = json.loads((tmp_path / "soak.json").read_text())
    assert report["audit"]["violations"] == 0, report["audit"]
    assert report["audit"]["cycles_audited"] > 0
    assert report["events"]["seq_gaps"] == {}
    assert report["faults"], "no fault was played"
    for fault in report["faults"]:
        assert fault["injected"] or fault["note"], fault
    assert set(report["resources_start"]) >= {"gateway", "controller", "tracker", "audit"}
    assert all(c["differing_seqs"] == [] for c in report["events"]["api_vs_file"] if c["checked"])
    assert code == 0
