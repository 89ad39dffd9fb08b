"""The stall tracer (bench/stall_trace.py): the window it keeps, the events file it follows, and a real capture
from the kernel's trace buffer (root and tracefs, else skipped with the reason)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from bench import stall_trace

LINE = "          python-4242    (   4240) [001] d.h1.  1234.500000: irq_handler_entry: irq=11 name=virtio0"


def test_a_trace_line_has_its_time_and_a_header_none() -> None:
    assert stall_trace.trace_line_time_s(LINE) == 1234.5
    assert stall_trace.trace_line_time_s("# tracer: nop") is None
    assert stall_trace.trace_line_time_s("CPU 1 buffer started") is None


def test_the_window_covers_the_interval_between_the_two_wake_ups_and_the_margin_before() -> None:
    event = {
        "stamp_ns": 10_000_000_000 + 5_000_000_000,
        "message": "… on CPU 12.6 ms of 12.5 ms since the previous wake-up",
    }
    start_s, end_s = stall_trace.capture_window_s(event, wall_minus_mono_ns=5_000_000_000, before_s=0.02)
    assert start_s == pytest.approx(10.0 - 0.0125 - 0.02)
    assert end_s == pytest.approx(10.002)
    start_s, _ = stall_trace.capture_window_s({"stamp_ns": 10**10}, 0, 0.0)
    assert start_s == pytest.approx(9.95)  # no interval named: 50 ms


def test_only_the_lines_within_the_window_are_kept_in_time_order() -> None:
    lines = [LINE.replace("1234.500000", t) for t in ("1234.600000", "1234.400000", "1234.450000", "1234.300000")]
    kept = stall_trace.lines_within(iter(["# header\n", *lines]), 1234.35, 1234.55)
    assert [stall_trace.trace_line_time_s(x) for x in kept] == [1234.4, 1234.45]


def test_the_follower_reads_each_event_once_across_a_rotation_and_skips_a_torn_line(tmp_path: Path) -> None:
    path = tmp_path / "events.jsonl"
    follower = stall_trace.EventsFollower(path)
    assert follower.new_events() == []  # not there yet
    path.write_text('{"seq": 1}\n{"seq": 2}\n{"seq": 3')  # the third still being written
    assert [e["seq"] for e in follower.new_events()] == [1, 2]
    with path.open("a") as f:
        f.write('}\n{"se\n')  # completed, then a torn line (a kill)
    assert [e["seq"] for e in follower.new_events()] == [3]
    path.rename(tmp_path / "events.jsonl.1")
    path.write_text('{"seq": 1}\n')  # a new gateway run, a new file
    assert [e["seq"] for e in follower.new_events()] == [1]
    assert follower.new_events() == []


def test_a_capture_holds_the_kernels_scheduler_events_of_the_window(tmp_path: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("tracefs needs root")
    if not (stall_trace.TRACEFS / "instances").is_dir():
        pytest.skip(f"tracefs is not mounted at {stall_trace.TRACEFS}")
    if (stall_trace.TRACEFS / "instances" / stall_trace.INSTANCE).exists():
        pytest.skip("another stall tracer is running on this machine")
    with stall_trace.trace_instance(buffer_kb=1024) as inst:
        t0_ns = time.time_ns()
        for _ in range(20):
            time.sleep(0.001)  # this thread sleeps and wakes: sched_switch and sched_wakeup of its own
        event = {"kind": "loop_stall", "cause": "unknown", "stamp_ns": time.time_ns(), "message": ""}
        event["message"] = f"of {(event['stamp_ns'] - t0_ns) / 1e6:.1f} ms since the previous wake-up"
        path = stall_trace.capture(inst, event, before_s=0.0, out=tmp_path)
        assert (inst / "tracing_on").read_text().strip() == "1"  # recording again
    assert not (stall_trace.TRACEFS / "instances" / stall_trace.INSTANCE).exists()  # removed
    text = path.read_text()
    assert json.loads(text.splitlines()[0][2:]) == event
    me = f"-{os.getpid()} "
    assert any("sched_switch" in line and me in line for line in text.splitlines()), text[:2000]


def _rec(t_s: float, cpu: int, comm: str, tid: int, event: str, rest: str) -> str:
    tgid = "-------" if tid == 0 else f"{tid:7d}"
    return f"{comm:>16s}-{tid:<7d} ({tgid}) [{cpu:03d}] d..2. {t_s:.6f}: {event}: {rest}"


def test_a_busy_cpu_that_records_nothing_for_longer_than_a_tick_is_the_longest_silence() -> None:
    """CPU 0 runs task 50 and ticks every 4 ms, then records nothing for 14 ms (its virtual CPU not run); CPU 1 is
    idle and silent for 20 ms, which is no silence of a busy CPU."""
    lines = [
        _rec(
            10.000,
            1,
            "<idle>",
            0,
            "sched_switch",
            "prev_comm=a prev_pid=7 prev_state=S ==> next_comm=swapper/1 next_pid=0",
        ),
        _rec(10.001, 0, "python", 50, "local_timer_entry", "vector=236"),
        _rec(10.005, 0, "python", 50, "local_timer_entry", "vector=236"),
        _rec(10.019, 0, "python", 50, "local_timer_entry", "vector=236"),
        _rec(10.020, 1, "<idle>", 0, "local_timer_entry", "vector=236"),
    ]
    records = stall_trace.parse_records(["# tracer: nop", *lines])
    assert len(records) == len(lines)
    silence = stall_trace.busy_cpu_silence(records, 9.99, 10.03)
    assert silence is not None
    assert silence.cpu == 0
    assert silence.tid == 50
    assert silence.duration_s == pytest.approx(0.014)
    assert stall_trace.busy_cpu_silence(records, 10.006, 10.010).duration_s == pytest.approx(0.004)  # clipped


def test_an_idle_cpu_that_takes_the_loops_timer_late_is_the_hosts_delay() -> None:
    """The loop (tid 42, woken at the loop's real-time priority) is due at 10.010 on idle CPU 0, which records its
    timer only at 10.0145; woken on a busy CPU instead, there is no idle delay to tell."""
    idle_then_late_lines = [
        _rec(
            10.000,
            0,
            "python",
            42,
            "sched_switch",
            "prev_comm=python prev_pid=42 prev_state=S ==> next_comm=swapper/0 next_pid=0",
        ),
        _rec(10.0145, 0, "<idle>", 0, "local_timer_entry", "vector=236"),
        _rec(10.0146, 0, "<idle>", 0, "sched_wakeup", "comm=python pid=42 prio=89 target_cpu=000"),
    ]
    idle_then_late = stall_trace.parse_records(idle_then_late_lines)
    assert stall_trace._loop_tid(idle_then_late) == 42
    assert stall_trace.idle_timer_delay_s(idle_then_late, 42, 10.010, 10.02) == pytest.approx(0.0045)
    busy_lines = [
        _rec(
            10.000,
            0,
            "python",
            50,
            "sched_switch",
            "prev_comm=python prev_pid=42 prev_state=S ==> next_comm=python next_pid=50",
        ),
        _rec(10.0145, 0, "python", 50, "sched_wakeup", "comm=python pid=42 prio=89 target_cpu=000"),
    ]
    busy = stall_trace.parse_records(busy_lines)
    assert stall_trace.idle_timer_delay_s(busy, 42, 10.010, 10.02) is None
    assert stall_trace.idle_timer_delay_s(idle_then_late, 42, 10.016, 10.02) is None  # woken before it was due


def test_from_the_loops_wake_up_to_its_running_the_idle_cpus_interrupts_and_silence_are_the_hosts() -> None:
    """Woken on idle CPU 0 at 10.0146, the CPU spends 0.5 ms in a timer interrupt and records nothing for 0.4 and
    1.5 ms around it; the loop's first record comes at 10.0170. A record of another CPU meanwhile changes nothing."""
    records = stall_trace.parse_records(
        [
            _rec(10.0146, 0, "<idle>", 0, "sched_wakeup", "comm=python pid=42 prio=89 target_cpu=000"),
            _rec(10.0150, 0, "<idle>", 0, "local_timer_entry", "vector=236"),
            _rec(10.0152, 1, "python", 50, "sched_wakeup", "comm=python pid=60 prio=120 target_cpu=001"),
            _rec(10.0155, 0, "<idle>", 0, "local_timer_exit", "vector=236"),
            _rec(10.0170, 0, "python", 42, "sys_exit", "NR 202 = 0"),
        ]
    )
    run = stall_trace.wake_to_run(records, 42, 10.014, 10.02)
    assert run is not None
    assert run.total_s == pytest.approx(0.0024)
    assert run.in_interrupts_s == pytest.approx(0.0005)
    assert run.silent_s == pytest.approx(0.0019)
    assert stall_trace.wake_to_run(records, 42, 10.017, 10.02) is None  # woken before it was due
