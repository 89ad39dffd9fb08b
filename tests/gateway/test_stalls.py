"""The stall record: known answers of the attribution, the phase trace, the collections seen, the monitor's counts,
the metrics by cause, and the real loop recording a stall it was made to have."""

from __future__ import annotations

import gc
import json
import threading
import time
from pathlib import Path

import pytest
import support.status_examples as ex

from gateway import main as gateway_main
from gateway.events import EventLog
from gateway.http.metrics import GatewayMetrics
from gateway.stalls import (
    CAUSES,
    GcWindows,
    OtherThreads,
    Phase,
    PhaseTrace,
    StallMonitor,
    StallRecord,
    StallSample,
    StallSummary,
    ThreadSchedstat,
    ThreadTime,
    attribute,
)
from hrc_contract.config import CellConfig
from hrc_contract.status_models import Event
from hrc_runtime.signals import StopEvent

MS = 1_000_000
PERIOD_NS = 4 * MS


def _sample(**fields: object) -> StallSample:
    """A tick 10 ms late at 250 Hz, asleep at the due time, nothing measured: override what a case needs."""
    base: dict[str, object] = {
        "late_ns": 10 * MS,
        "period_ns": PERIOD_NS,
        "interval_ns": 14 * MS,
        "slept_ns": 3 * MS,
        "phase": "sleep",
        "gc_ns": 0,
        "cpu_ns": 1 * MS,
        "runqueue_ns": 0,
    }
    return StallSample(**(base | fields))  # type: ignore[arg-type]


# -- known answers --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("fields", "cause"),
    [
        ({"gc_ns": 6 * MS, "runqueue_ns": 9 * MS, "phase": "decide"}, "gc"),  # a collection first
        ({"gc_ns": 4 * MS, "runqueue_ns": 5 * MS, "phase": "decide"}, "runqueue"),
        ({"runqueue_ns": 4 * MS, "phase": "decide"}, "phase:decide"),
        ({"phase": "publish", "cpu_ns": 1 * MS}, "phase:publish"),  # blocked in a put: still the phase
        ({"cpu_ns": 1 * MS}, "blocked"),  # woke late, 10 ms neither running nor runnable
        ({"cpu_ns": 1 * MS, "timeslices": 2}, "blocked"),  # and blocked again after its sleep (a lock)
        ({"cpu_ns": 1 * MS, "timeslices": 1}, "stolen"),  # but it blocked only in its sleep: the CPU did not run
        ({"phase": "decide", "cpu_ns": 1 * MS, "timeslices": 0}, "stolen"),  # at work, never blocked: not ours
        ({"phase": "publish", "cpu_ns": 1 * MS, "timeslices": 1}, "phase:publish"),  # at work, blocked in a put
        ({"cpu_ns": 9 * MS, "timeslices": 1}, "unknown"),  # on a CPU all along: not stolen either
        ({"cpu_ns": 9 * MS, "sleep_cpu_ns": 6 * MS, "timeslices": 1}, "kernel"),  # and most of it in its sleep
        # none half: the largest part, if the parts (run queue, blocked, CPU in its sleep) together cover half
        ({"cpu_ns": 9 * MS, "sleep_cpu_ns": 4 * MS}, "kernel"),  # 4 ms in its sleep, 2 ms blocked
        ({"cpu_ns": 5 * MS, "runqueue_ns": 4 * MS, "sleep_cpu_ns": 3 * MS}, "runqueue"),  # 4 + 2 + 3
        ({"cpu_ns": 6 * MS, "runqueue_ns": 1 * MS, "sleep_cpu_ns": 2 * MS, "timeslices": 4}, "blocked"),  # 1 + 4 + 2
        ({"cpu_ns": 6 * MS, "runqueue_ns": 1 * MS, "sleep_cpu_ns": 2 * MS, "timeslices": 1}, "stolen"),
        ({"cpu_ns": 9 * MS, "runqueue_ns": 1 * MS, "sleep_cpu_ns": 1 * MS}, "unknown"),  # 1 + 1 + 1 of 10 ms
        ({"gc_ns": 4 * MS, "cpu_ns": 10 * MS, "sleep_cpu_ns": 1 * MS}, "unknown"),  # a collection is not a part
        ({"phase": "decide", "cpu_ns": 9 * MS, "sleep_cpu_ns": 9 * MS, "timeslices": 1}, "phase:decide"),
        ({"cpu_ns": 9 * MS}, "unknown"),  # woke late, on a CPU all along (nothing explains it)
        ({"cpu_ns": None, "runqueue_ns": None}, "unknown"),  # no schedstat
        ({"cpu_ns": None, "runqueue_ns": None, "phase": "status"}, "phase:status"),
    ],
)
def test_each_stall_gets_the_first_cause_that_explains_half_its_lateness_else_its_largest_part(
    fields: dict[str, object], cause: str
) -> None:
    assert attribute(_sample(**fields)) == cause
    assert cause in CAUSES


def test_blocked_is_what_is_left_of_the_interval_after_intended_sleep_cpu_and_run_queue() -> None:
    assert _sample(cpu_ns=2 * MS, runqueue_ns=1 * MS).blocked_ns == 14 * MS - 3 * MS - 2 * MS - 1 * MS
    assert _sample(cpu_ns=20 * MS).blocked_ns == 0
    assert _sample(cpu_ns=None).blocked_ns is None


def test_blocking_again_is_being_put_on_a_cpu_more_often_than_the_sleep_alone_explains() -> None:
    assert _sample(timeslices=1).blocked_again is False  # asleep at the due time: once, when the sleep ended
    assert _sample(timeslices=2).blocked_again is True
    assert _sample(phase="decide", timeslices=0).blocked_again is False  # the sleep began late: it did not wait
    assert _sample(phase="decide", timeslices=1).blocked_again is True
    assert _sample().blocked_again is None  # no schedstat


def test_the_trace_tells_the_phase_at_a_time_and_the_intended_sleep() -> None:
    trace = PhaseTrace()
    trace.restart(Phase.READ, 100)
    for phase, at in ((Phase.DECIDE, 110), (Phase.PUBLISH, 150), (Phase.EVENTS, 160), (Phase.SLEEP, 170)):
        trace.enter(phase, at)
    assert trace.phase_at(90) is Phase.READ  # before them all: the first
    assert trace.phase_at(110) is Phase.DECIDE
    assert trace.phase_at(149) is Phase.DECIDE
    assert trace.phase_at(165) is Phase.EVENTS
    assert trace.phase_at(500) is Phase.SLEEP
    assert trace.slept_ns(200) == 30
    assert trace.slept_ns(150) == 0  # due while still at work: no intended sleep
    trace.restart(Phase.READ, 600)
    assert trace.phase_at(700) is Phase.READ


def test_a_trace_keeps_its_last_place_when_an_iteration_enters_more_phases_than_it_holds() -> None:
    trace = PhaseTrace()
    trace.restart(Phase.READ, 0)
    for k in range(1, 40):
        trace.enter(Phase.DECIDE if k % 2 else Phase.PUBLISH, k)
    trace.enter(Phase.SLEEP, 100)
    assert trace.phase_at(100) is Phase.SLEEP


def test_collections_are_seen_with_their_time_and_the_callback_goes_away() -> None:
    windows = GcWindows()
    windows.install()
    try:
        start_ns = time.monotonic_ns()
        gc.collect()
        end_ns = time.monotonic_ns()
    finally:
        windows.remove()
    assert windows.collections >= 1
    assert 0 < windows.within_ns(start_ns, end_ns) <= end_ns - start_ns
    assert windows.within_ns(end_ns + 1, end_ns + 10**9) == 0
    assert windows.on_gc not in gc.callbacks


def test_collections_overlap_only_within_the_interval() -> None:
    now = [0]
    windows = GcWindows(clock_ns=lambda: now[0])
    for start, stop in ((10, 20), (30, 60)):
        now[0] = start
        windows.on_gc("start", {})
        now[0] = stop
        windows.on_gc("stop", {})
    assert windows.within_ns(0, 100) == 40
    assert windows.within_ns(15, 40) == 5 + 10
    assert windows.within_ns(60, 100) == 0


def test_this_threads_schedstat_counts_cpu_time() -> None:
    schedstat = ThreadSchedstat()
    if not schedstat.available:
        pytest.skip("no /proc/self/task/<tid>/schedstat here")
    try:
        before = schedstat.read()
        sum(range(200_000))
        time.sleep(0.001)  # a block: put on a CPU once more when it ends
        after = schedstat.read()
    finally:
        schedstat.close()
    assert before is not None
    assert after is not None
    assert after[0] > before[0]
    assert after[1] >= before[1]
    assert after[2] > before[2]
    assert schedstat.read() is None  # closed


# -- the other threads ----------------------------------------------------------------------------


def _task_dir(root: Path, threads: dict[int, tuple[int, int]]) -> Path:
    """A fake ``/proc/self/task``: per thread id, its schedstat ``(on_cpu_ns, runqueue_ns)``."""
    for tid, (cpu_ns, runq_ns) in threads.items():
        (root / str(tid)).mkdir(exist_ok=True)
        (root / str(tid) / "schedstat").write_text(f"{cpu_ns} {runq_ns} 7\n")
    return root


def test_other_python_threads_are_named_and_timed_between_two_readings_the_most_first(tmp_path: Path) -> None:
    tasks = _task_dir(tmp_path, {1: (0, 0), 2: (0, 0), 3: (0, 0), 4: (0, 0), 5: (0, 0)})
    python = {1: "MainThread", 2: "hrc-status", 3: "zenoh-input", 4: "hrc-override-ur5"}
    others = OtherThreads(own_tid=1, task_dir=tasks, names=lambda: dict(python))
    try:
        assert others.names == {2: "hrc-status (2)", 3: "zenoh-input (3)", 4: "hrc-override-ur5 (4)"}  # not 1, 5
        before = others.read()
        _task_dir(tasks, {2: (1 * MS, 6 * MS), 3: (2 * MS, 0), 4: (50_000, 0), 5: (9 * MS, 0)})
        after = others.read()
        assert others.between(before, after) == (
            ThreadTime("hrc-status (2)", 1 * MS, 6 * MS),
            ThreadTime("zenoh-input (3)", 2 * MS, 0),
        )  # thread 4: 0.05 ms, below what is worth naming; thread 5 never ran Python
        assert others.between(after, after) == ()
    finally:
        others.close()


def test_other_threads_follow_threads_started_and_ended_at_a_refresh(tmp_path: Path) -> None:
    tasks = _task_dir(tmp_path, {1: (0, 0), 2: (0, 0), 5: (0, 0)})
    python = {1: "MainThread", 2: "Thread-1"}
    others = OtherThreads(own_tid=1, task_dir=tasks, names=lambda: dict(python))
    try:
        python[5] = "zenoh-input"
        assert set(others.read()) == {2}  # not followed before a refresh
        del python[2]
        others.refresh()
        assert others.names == {5: "zenoh-input (5)"}
        assert set(others.read()) == {5}
        assert others.between({}, others.read()) == ()  # no earlier reading: nothing to compare
        python[6] = "ended-before-the-refresh"  # no task directory
        others.refresh()
        assert set(others.names) == {5}
    finally:
        others.close()


def test_another_thread_of_this_process_on_a_cpu_meanwhile_is_seen_with_its_python_name() -> None:
    others = OtherThreads()
    if not (Path("/proc/self/task") / str(threading.get_native_id()) / "schedstat").exists():
        others.close()
        pytest.skip("no /proc/self/task/<tid>/schedstat here")
    go, burnt, release = threading.Event(), threading.Event(), threading.Event()

    def burn() -> None:
        go.wait()  # only after ``before`` is read: a thread that ran at once would show nothing between the reads
        sum(range(3_000_000))  # some ms on a CPU, while this thread waits
        burnt.set()
        release.wait()

    thread = threading.Thread(target=burn, name="burner")
    thread.start()
    try:
        others.refresh()
        before = others.read()
        go.set()
        burnt.wait()
        after = others.read()
    finally:
        release.set()
        thread.join()
        others.close()
    (burner,) = (t for t in others.between(before, after) if t.name.startswith("burner ("))
    assert burner.cpu_ns > 0


def test_a_stall_message_names_the_threads_that_ran_meanwhile() -> None:
    sample = _sample(others=(ThreadTime("hrc-status (12)", 1 * MS, 6 * MS), ThreadTime("Thread-3 (3)", 2 * MS, 0)))
    message = StallRecord("blocked", 2, sample).message()
    assert message.endswith(
        "; meanwhile hrc-status (12) on CPU 1.0 ms, run-queue wait 6.0 ms; "
        "Thread-3 (3) on CPU 2.0 ms, run-queue wait 0.0 ms"
    )
    assert "meanwhile" not in StallRecord("blocked", 2, _sample()).message()


# -- the monitor ----------------------------------------------------------------------------------


class _Schedstat(ThreadSchedstat):
    """Scripted ``(on_cpu_ns, runqueue_ns, timeslices)`` readings."""

    def __init__(self, readings: list[tuple[int, int, int]]) -> None:
        self._fd = None
        self._readings = readings

    def read(self) -> tuple[int, int, int] | None:
        return self._readings.pop(0)


class _OtherThreads(OtherThreads):
    """One other thread, ``status`` (id 2), with scripted schedstat texts; counts the refreshes."""

    def __init__(self, readings: list[bytes]) -> None:
        self._fds = {}
        self.names = {2: "status (2)"}
        self._readings = readings
        self.refreshes = 0

    def refresh(self) -> None:
        self.refreshes += 1

    def read(self) -> dict[int, bytes]:
        return {2: self._readings.pop(0)}


def test_the_monitor_records_late_ticks_only_and_counts_every_missed_tick_by_cause() -> None:
    schedstat = _Schedstat([(0, 0, 0), (1 * MS, 0, 1), (2 * MS, 0, 2), (3 * MS, 0, 3), (4 * MS, 12 * MS, 5)])
    readings = [b"0 0 0", b"0 0 0", b"0 0 0", b"0 0 0", b"0 0 0", b"3000000 0 0", b"3000000 0 0"]
    others = _OtherThreads(readings)
    with StallMonitor(0.004, schedstat=schedstat, gc_windows=GcWindows(), others=others) as monitor:
        t0 = time.monotonic_ns()
        assert monitor.woke(t0, tick=True, late_s=0.0001, missed_cycles=0) is None
        assert monitor.woke(t0 + 3 * MS, tick=False, late_s=0.0, missed_cycles=0) is None  # an event cycle
        # Work ran past the due time: decide from t0 + 3 ms to t0 + 20 ms (blocked in it), the tick due at t0 + 4 ms.
        monitor.trace.enter(Phase.DECIDE, t0 + 3 * MS)
        record = monitor.woke(t0 + 20 * MS, tick=True, late_s=0.016, missed_cycles=4)
        assert record is not None
        assert (record.cause, record.missed, record.sample.phase) == ("phase:decide", 4, "decide")
        assert record.sample.others == ()  # the other thread was idle
        # Asleep at the due time, and 12 ms on the run queue: another program ran.
        monitor.trace.enter(Phase.SLEEP, t0 + 21 * MS)
        record = monitor.woke(t0 + 40 * MS, tick=True, late_s=0.015, missed_cycles=7)
        assert record is not None
        assert (record.cause, record.missed) == ("runqueue", 3)
        assert record.sample.others == (ThreadTime("status (2)", 3 * MS, 0),)
        assert "runqueue" in record.message()
        assert "12.0 ms" in record.message()
        assert others.refreshes == 2  # at each stall: a thread started since is followed from then on
    assert monitor.stalls == {"phase:decide": 1, "runqueue": 1}
    assert monitor.missed == {"phase:decide": 4, "runqueue": 3}
    assert sum(monitor.missed.values()) == 7  # the loop's missed_cycles


def test_the_monitor_reads_the_loops_cpu_clock_in_its_sleep_and_names_time_there_kernel() -> None:
    """The loop thread is on a CPU for 12 ms after its sleep mark (here: it spins; in a cell: kernel time charged to
    it), the tick comes 10 ms late: its own clock says so, whatever schedstat lags."""
    schedstat = _Schedstat([])
    schedstat.read = lambda: (time.thread_time_ns(), 0, 0)  # type: ignore[method-assign]  # this thread's own clock
    others = _OtherThreads([b"0 0 0"] * 6)
    with StallMonitor(0.004, schedstat=schedstat, gc_windows=GcWindows(), others=others) as monitor:
        assert monitor.woke(time.monotonic_ns(), tick=True, late_s=0.0, missed_cycles=0) is None
        monitor.enter(Phase.SLEEP)
        spin_until_ns = time.thread_time_ns() + 12 * MS  # on its own CPU clock: a loaded machine only makes it longer
        while time.thread_time_ns() < spin_until_ns:
            pass
        record = monitor.woke(time.monotonic_ns(), tick=True, late_s=0.010, missed_cycles=2)
    assert record is not None
    assert record.sample.sleep_cpu_ns is not None
    assert record.sample.sleep_cpu_ns >= 12 * MS
    assert record.cause == "kernel"
    assert "of it in its sleep" in record.message()


def test_cpu_time_held_between_the_sleep_marks_two_clock_reads_counts_in_the_sleep() -> None:
    """The soak's one ``unknown`` stall: 8.8 ms late, on a CPU 12.8 of 12.8 ms, 0.5 ms of it after the sleep mark,
    never put on a CPU (never left it). The phases before the mark took 0.3 ms of wall time, so 12 ms of the CPU time
    its clock shows before the mark ran between the mark's monotonic stamp and its CPU read: held there, as in its
    sleep (``kernel``). Without that excess its sleep shows 0.5 ms and nothing explains half (``unknown``)."""
    t0 = 1_000 * MS
    mono = iter([t0, t0 + 300_000])  # the monitor's start, the sleep mark's stamp
    cpu = iter([62_300_000])  # the sleep mark's read (the wake-ups' come with schedstat's readings)
    schedstat = _Schedstat([(50 * MS, 0, 7), (50 * MS, 0, 7), (62_800_000, 0, 7)])
    others = _OtherThreads([b"0 0 0"] * 6)
    with StallMonitor(
        0.004,
        schedstat=schedstat,
        gc_windows=GcWindows(),
        others=others,
        clock_ns=lambda: next(mono),
        cpu_clock_ns=lambda: next(cpu),
    ) as monitor:
        assert monitor.woke(t0, tick=True, late_s=0.0, missed_cycles=0) is None
        monitor.enter(Phase.SLEEP)
        record = monitor.woke(t0 + 12_800_000, tick=True, late_s=0.0088, missed_cycles=2)
    assert record is not None
    assert record.sample.phase == "sleep"
    assert (record.sample.cpu_ns, record.sample.timeslices) == (12_800_000, 0)
    assert record.sample.sleep_cpu_ns == 500_000 + 12_000_000
    assert record.cause == "kernel"


def test_cpu_time_within_the_wall_time_before_the_sleep_mark_stays_out_of_the_sleep() -> None:
    """Work before the mark that ran 3 ms of CPU time in 3.2 ms: none of it is the sleep's."""
    t0 = 1_000 * MS
    mono = iter([t0, t0 + 3_200_000])
    cpu = iter([3 * MS])
    schedstat = _Schedstat([(0, 0, 0), (0, 0, 0), (3_400_000, 0, 1)])
    with StallMonitor(
        0.004,
        schedstat=schedstat,
        gc_windows=GcWindows(),
        others=_OtherThreads([b"0 0 0"] * 6),
        clock_ns=lambda: next(mono),
        cpu_clock_ns=lambda: next(cpu),
    ) as monitor:
        assert monitor.woke(t0, tick=True, late_s=0.0, missed_cycles=0) is None
        monitor.enter(Phase.SLEEP)
        record = monitor.woke(t0 + 14 * MS, tick=True, late_s=0.010, missed_cycles=2)
    assert record is not None
    assert record.sample.sleep_cpu_ns == 400_000
    assert record.cause == "stolen"  # 10.6 ms on none of its clocks, put on a CPU once (by its sleep's end)


def test_the_monitor_refuses_a_period_or_threshold_that_is_not_positive() -> None:
    for period_s, threshold in ((0.0, 1.0), (0.004, 0.0), (float("nan"), 1.0)):
        with pytest.raises(ValueError, match="allowed: > 0"):
            StallMonitor(period_s, threshold, schedstat=_Schedstat([]), gc_windows=GcWindows())


def test_a_stall_is_an_event_of_the_log_with_its_cause() -> None:
    log = EventLog()
    log.started(1, "demo", "0" * 64)
    (event,) = log.stalled(2, "gc", "loop stall: ...")
    assert (event.seq, event.kind, event.cause) == (3, "loop_stall", "gc")
    assert Event.model_validate_json(event.model_dump_json()) == event


def test_the_metrics_count_stalls_and_missed_ticks_by_cause() -> None:
    status = ex.gateway_status(ur5=ex.robot_status())
    loop = status.loop.model_copy(update={"stalls": {"gc": 2, "phase:decide": 1}, "missed_by_cause": {"gc": 5}})
    metrics = GatewayMetrics(0.004)
    metrics.observe(status.model_copy(update={"loop": loop}))
    text = metrics.exposition().decode()
    assert 'hrc_loop_stalls_total{cause="gc"} 2.0' in text
    assert 'hrc_loop_stalls_total{cause="phase:decide"} 1.0' in text
    assert 'hrc_loop_stalls_total{cause="runqueue"} 0.0' in text  # every cause exported before its first
    assert 'hrc_loop_missed_cycles_by_cause_total{cause="gc"} 5.0' in text


# -- the real loop --------------------------------------------------------------------------------

HOLD_S = 0.2  # long beside what a loaded machine's run queue adds (a cause must cover half the lateness)
"""The first status hand-off is held up this long (12 periods at 250 Hz)."""


class _Publisher:
    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.payloads.append(payload)


class _Http:
    """The HTTP child's side the loop uses: records events; its first exit check holds the loop up."""

    def __init__(self) -> None:
        self.events: list[Event] = []
        self.lines: list[bytes] = []
        self.checks = 0

    def offer(self, line: bytes) -> None:
        self.lines.append(line)

    def offer_events(self, events: list[Event]) -> None:
        self.events += events

    def exit_code(self) -> int | None:
        self.checks += 1
        if self.checks == 1:
            time.sleep(HOLD_S)
        return None


def test_the_loop_records_a_hold_up_in_its_status_hand_off_as_a_stall_with_that_phase(
    cell_config: CellConfig,
) -> None:
    """The real loop and node, fake outputs: the first status hand-off holds the loop 200 ms; the next tick is a
    stall in phase ``status``, logged as an event and counted in the next status documents, and every missed tick
    has a cause."""
    node = gateway_main.build_node(cell_config, None)
    http, status_key = _Http(), _Publisher()
    sink = gateway_main._StatusSink(cell_config, node.robots, status_key, http)  # type: ignore[arg-type]
    stop = StopEvent()
    status_thread = gateway_main.StatusThread(sink.publish)

    class _StopAfterStatuses(_Publisher):
        def put(self, payload: bytes) -> None:
            super().put(payload)
            if len(status_key.payloads) >= 3 or len(self.payloads) >= 2500:
                stop.set()

    out = gateway_main._Outputs({"ur5": _StopAfterStatuses()}, http, status_thread)  # type: ignore[arg-type]
    with status_thread:
        assert gateway_main._loop(cell_config, node, out, stop, None) == 0

    # a loaded machine may add stalls of its own (run queue) before or after the planned one
    held = [e for e in http.events if e.kind == "loop_stall" and e.cause == "phase:status"]
    assert held, http.events
    assert "phase status at the due time" in held[0].message
    last = json.loads(status_key.payloads[-1])["loop"]
    assert last["stalls"].get("phase:status", 0) >= 1
    assert sum(last["missed_by_cause"].values()) == last["missed_cycles"] >= round(HOLD_S * 250) - 2


def test_stalls_of_an_interval_make_one_line_with_counts_by_cause_and_a_warning_only_when_the_budget_is_hurt() -> None:
    s = 1_000_000_000
    summary = StallSummary(60 * s, now_ns=0, overruns=2)
    summary.add(StallRecord("runqueue", 1, _sample(late_ns=4_000_000)))
    summary.add(StallRecord("gc", 2, _sample(late_ns=9_500_000)))
    summary.add(StallRecord("runqueue", 1, _sample(late_ns=5_000_000)))
    assert summary.due(59 * s, overruns=2) is None, "not before the interval's end"
    hurt, line = summary.due(60 * s, overruns=2) or (None, "")
    assert hurt is False
    assert line.startswith("loop stalls in the last 60 s: 3 (runqueue 2, gc 1), 4 ticks missed, worst 9.5 ms late")
    assert "budget" not in line

    # A new interval: nothing happened, nothing to say; then an overrun makes the line a warning.
    assert summary.due(121 * s, overruns=2) is None
    summary.add(StallRecord("unknown", 0, _sample(late_ns=5_000_000)))
    hurt, line = summary.due(182 * s, overruns=3) or (None, "")
    assert hurt is True
    assert "1 (unknown 1), 0 ticks missed, worst 5.0 ms late; 1 decisions with δ > 0 held beyond" in line

    # Overruns alone (no stall recorded) are still said.
    hurt, line = summary.due(243 * s, overruns=5) or (None, "")
    assert hurt is True
    assert ": 0 (none)" in line
    assert "; 2 decisions" in line
