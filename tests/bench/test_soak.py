"""The soak: its seeded schedule, its event checks (pure), its host clocks, and a short run of the real cell (e2e)."""

from __future__ import annotations

import json
import os
import queue
import random
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from bench import soak

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)


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
    runs = soak.split_runs(events)
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
    assert soak.stalls_by_cause(events) == ({"gc": 2, "phase:decide": 1}, {"gc": 3, "phase:decide": 1})


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


def test_the_rss_floor_leaves_out_a_swing_caught_in_the_last_sample() -> None:
    """A controller's queue while its link was cut, caught by the last sample: +6 % last against first, no growth of
    its floor; a growth that stays shows in both."""
    swinging = [130_000, 131_000, 130_500, 131_000, 130_200, 138_000]
    growing = [100_000, 100_500, 101_000, 102_000, 103_000, 104_000]
    samples = [
        {"controller": {"pid": 7, "rss_kb": a, "age_s": 20 + 5 * k}, "audit": {"pid": 9, "rss_kb": b, "age_s": 20}}
        for k, (a, b) in enumerate(zip(swinging, growing, strict=True))
    ]
    assert soak.rss_growth_percent(samples) == {"controller": 6.15, "audit": 4.0}
    assert soak.rss_floor_growth_percent(samples, window=2) == {"controller": 0.15, "audit": 3.0}
    assert soak.rss_floor_growth_percent(samples[:1]) == {}  # one sample shows no growth


def test_the_growth_after_trim_compares_each_living_process_with_its_own_first_sample() -> None:
    """The auditor held 7 MB of freed heap at the end: trimmed, it is 1 % above its first sample; a gateway that
    restarted meanwhile is compared with the new process's first sample, a program gone at the end not at all."""
    samples = []
    for k in range(7):
        gateway_pid, gateway_k = (5, k) if k < 3 else (6, k - 3)  # restarted after the third sample
        samples.append(
            {
                "audit": {"pid": 9, "rss_kb": 130_000 + 1_000 * k, "age_s": 20 + 5 * k},
                "gateway": {"pid": gateway_pid, "rss_kb": 260_000 + 100 * k, "age_s": 20 + 5 * gateway_k},
                "relay-tracker": {"pid": 4, "rss_kb": 60_000, "age_s": 20 + 5 * k},
            }
        )
    trimmed = {"audit": {"pid": 9, "rss_kb": 131_300}, "gateway": {"pid": 6, "rss_kb": 260_300}}
    assert soak.rss_growth_percent(samples)["audit"] == 4.62
    assert soak.rss_after_trim_growth_percent(samples, trimmed) == {"audit": 1.0, "gateway": 0.0}


def test_a_process_still_starting_is_not_compared() -> None:
    """A restarted gateway is small while it starts (models, kernels): its own warm-up is no growth."""
    samples = [
        {"gateway": {"pid": 5, "rss_kb": 150_000, "age_s": 2}},
        {"gateway": {"pid": 5, "rss_kb": 290_000, "age_s": 25}},
        {"gateway": {"pid": 5, "rss_kb": 292_900, "age_s": 30}},
    ]
    assert soak.rss_growth_percent(samples, warmup_s=20.0) == {"gateway": 1.0}


def test_clock_steps_are_seeded_sized_one_to_five_seconds_and_alternate_in_direction() -> None:
    steps = [soak.clock_step_s(random.Random(4), i, -1) for i in range(6)]
    assert steps == [soak.clock_step_s(random.Random(4), i, -1) for i in range(6)]
    assert [s > 0 for s in steps] == [False, True, False, True, False, True]
    assert all(soak.CLOCK_STEP_S[0] <= abs(s) <= soak.CLOCK_STEP_S[1] for s in steps)
    assert "clock-step:tracker" in soak.FAULT_KINDS
    assert "clock-step:controller" in soak.FAULT_KINDS


def test_a_host_clock_preloads_libfaketime_reading_its_offset_file_and_steps_it_whole(tmp_path: Path) -> None:
    clock = soak.HostClock(Path("/lib/libfaketimeMT.so.1"), tmp_path / "clock.offset")
    env = clock.environment({"PATH": "/bin", "FAKETIME": "+1d", "LD_PRELOAD": "/lib/other.so"})
    assert env["LD_PRELOAD"] == "/lib/libfaketimeMT.so.1 /lib/other.so"
    assert "FAKETIME" not in env  # it would override the file
    assert env["FAKETIME_TIMESTAMP_FILE"] == str(tmp_path / "clock.offset")
    assert env["FAKETIME_DONT_FAKE_MONOTONIC"] == "1"
    assert env["FAKETIME_CACHE_DURATION"] == "1"
    assert env["PATH"] == "/bin"
    clock.step(-2.5)
    assert (tmp_path / "clock.offset").read_text() == "-2.500\n"
    clock.step(0.0)
    assert (tmp_path / "clock.offset").read_text() == "+0.000\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clock.offset"]


def test_libfaketimes_leftovers_of_ended_processes_are_removed_and_no_others(tmp_path: Path) -> None:
    alive, ended = os.getpid(), 999_999_999
    names = [f"faketime_shm_{alive}", f"sem.faketime_sem_{alive}", f"faketime_shm_{ended}", f"sem.faketime_sem_{ended}"]
    for name in [*names, "faketime_shm_x", "other_99999999"]:
        (tmp_path / name).touch()
    assert soak.remove_dead_faketime_files(tmp_path) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*names[:2], "faketime_shm_x", "other_99999999"])


_CLOCK_PRINTER = """
import datetime, threading, time, zenoh
from hrc_runtime.zenoh_session import session_config
with zenoh.open(session_config()) as session:
    while True:
        zenoh_s = session.new_timestamp().get_time().replace(tzinfo=datetime.UTC).timestamp()
        print(time.time_ns(), time.monotonic_ns(), zenoh_s, flush=True)
        threading.Event().wait(0.05)  # not time.sleep: libfaketime 0.9.10 breaks it (HostClock)
"""


@pytest.mark.e2e
@pytest.mark.skipif(soak.find_libfaketime() is None, reason=soak.NO_FAKETIME)
def test_a_host_clock_steps_a_programs_wall_clock_in_python_and_in_zenoh_and_leaves_its_monotonic_clock(
    tmp_path: Path,
) -> None:
    """A Python program with a Zenoh session under :class:`soak.HostClock`: ``time.time_ns`` and the Rust library's
    ``SystemTime`` (a session timestamp) follow the offset file; ``time.monotonic_ns`` stays this host's."""
    library = soak.find_libfaketime()
    assert library is not None
    clock = soak.HostClock(library, tmp_path / "clock.offset")
    clock.step(0.0)
    env = clock.environment(os.environ)
    lines: queue.Queue[str] = queue.Queue()
    with subprocess.Popen([sys.executable, "-c", _CLOCK_PRINTER], env=env, stdout=subprocess.PIPE, text=True) as proc:
        assert proc.stdout is not None
        stdout = proc.stdout

        def read_lines() -> None:
            for line in stdout:
                lines.put(line)

        threading.Thread(target=read_lines, daemon=True).start()
        try:

            def offsets() -> tuple[float, float, float]:
                """The program's wall, monotonic and Zenoh clocks minus this process's, from its next line [s]."""
                wall_ns, mono_ns, zenoh_s = lines.get(timeout=30.0).split()
                return (
                    (int(wall_ns) - time.time_ns()) / 1e9,
                    (int(mono_ns) - time.monotonic_ns()) / 1e9,
                    float(zenoh_s) - time.time(),
                )

            def until(holds: Callable[[tuple[float, float, float]], bool], what: str) -> tuple[float, float, float]:
                deadline_s = time.monotonic() + 30.0
                while time.monotonic() < deadline_s:
                    seen = offsets()
                    if holds(seen):
                        return seen
                raise AssertionError(f"{what}: the program's clocks are off by {seen} s")

            until(lambda o: abs(o[0]) < 0.5, "on this host's clock at +0")
            clock.step(2.5)
            _, mono_s, zenoh_s = until(lambda o: o[0] > 2.0, "2.5 s ahead")
            assert abs(mono_s) < 0.5
            assert 2.0 < zenoh_s < 3.0
            clock.step(-3.0)
            _, mono_s, _ = until(lambda o: o[0] < -2.5, "3 s behind")
            assert abs(mono_s) < 0.5
            clock.step(0.0)
            until(lambda o: abs(o[0]) < 0.5, "set right")
        finally:
            proc.kill()
    proc.wait()
    soak.remove_dead_faketime_files()


@pytest.mark.e2e
def test_a_short_soak_runs_the_cell_under_faults_and_reports(tmp_path: Path) -> None:
    """20 s: warm-up, a fault or two, the report. No violation, no event lost, each fault injected or said why."""
    code = soak.main(["--minutes", "0.34", "--seed", "3", "--out", str(tmp_path)])
    report = json.loads((tmp_path / "soak.json").read_text())
    assert report["audit"]["violations"] == 0, report["audit"]
    assert report["audit"]["cycles_audited"] > 0
    gap_cycles = report["audit_truth_gap_cycles"]
    assert set(gap_cycles) == {"ur5"}, gap_cycles
    assert isinstance(gap_cycles["ur5"], int), gap_cycles
    assert report["events"]["seq_gaps"] == {}
    assert report["faults"], "no fault was played"
    for fault in report["faults"]:
        assert fault["injected"] or fault["note"], fault
    assert set(report["resources_start"]) >= {"gateway", "controller", "tracker", "audit", "zenoh-bystander"}
    assert report["resources_end"]["zenoh-bystander"].get("rss_kb"), "the bystander did not run to the end"
    assert all(c["differing_seqs"] == [] for c in report["events"]["api_vs_file"] if c["checked"])
    assert code == 0


def test_a_process_that_exited_but_is_not_yet_reaped_is_gone_not_an_error() -> None:
    """A fault kills a program; sampled before its parent reaps it, it is a zombie with no memory lines (the soak
    raised KeyError 'VmRSS' in a fresh-clone CI run)."""
    assert soak.resources(os.getpid()) is not None
    with subprocess.Popen([sys.executable, "-c", "pass"]) as proc:
        deadline_s = time.monotonic() + 30.0
        while Path(f"/proc/{proc.pid}/stat").read_text().rpartition(")")[2].split()[0] != "Z":
            assert time.monotonic() < deadline_s, "the child never exited"
            time.sleep(0.01)
        assert soak.resources(proc.pid) is None
