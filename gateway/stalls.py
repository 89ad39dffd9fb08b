"""The stall record: when a tick comes late by more than a period, what the loop thread was doing, and why.

    loop thread:  woke(now) ──▶ read ──▶ decide ──▶ publish ──▶ events ──▶ [status] ──▶ sleep ──▶ woke(now) ...
                    │  each mark: a phase id and a monotonic stamp into preallocated arrays (no object built)
                    └─ a tick later than the threshold: a :class:`StallRecord` with one cause

What is measured between two wake-ups of the loop thread (the interval a late tick lies in):

- the phase the loop was in when the tick fell due (:class:`PhaseTrace`): ``sleep`` means the wake-up itself came
  late, any other phase that our own work ran past the due time;
- the garbage collections that ran meanwhile, on any thread (``gc.callbacks`` start and stop stamps,
  :class:`GcWindows`): a collection holds the interpreter lock, so it holds the loop wherever it runs;
- the thread's time waiting on a run queue, runnable but not running (``/proc/self/task/<tid>/schedstat``, its
  second field), and its time on a CPU (its CPU clock: the schedstat field lags by up to a scheduler tick),
  :class:`ThreadSchedstat`; read at each wake-up (3 µs measured: ``os.pread`` of a descriptor kept open and
  ``time.thread_time_ns``, ~0.08 % of a core at 250 Hz), and how many times it was put on a CPU (the third
  field): once when its sleep ended, once more after each other block or preemption;
- what is left, neither intended sleep, nor on a CPU, nor runnable: *blocked* (waiting for the interpreter lock
  another thread holds, for a lock or I/O, or the process was stopped). The only lock the loop takes is the HTTP
  child's event queue (phase ``events``); a Zenoh put waits only while the link's queue is full (``publish``).
  If the thread did not block again (put on a CPU once if asleep at the due time, else never), that time is on
  none of its clocks although it waited for nothing: its CPU did not run at all (*stolen*: on a virtual machine
  the hypervisor did not run the virtual CPU, whose steal time the kernel leaves out of the task's clocks, or
  woke an idle one late for the timer; on bare metal, interrupts held off by firmware);
- the process's other Python threads' time on a CPU and on a run queue meanwhile (:class:`OtherThreads`, each
  one's schedstat: one ``pread`` per thread at each wake-up, parsed only at a stall; 11.5 µs measured for the
  default cell's 7, ~0.4 % of a core at 250 ticks and ~60 tracker frames a second), so that a stall names who ran
  while the loop waited: a thread on a CPU may hold the interpreter lock in a long C call; one that waited on a
  run queue may have held it while descheduled (a priority inversion).

:func:`attribute` gives each stall one cause, checked in this order: ``gc`` (collections overlapped at least half
the lateness), ``runqueue`` (the thread waited on a run queue at least half of it: another thread or program ran),
``stolen`` (at least half of it on none of the thread's clocks, and the thread did not block again: the CPU did not
run, see above), ``phase:<name>`` (our own work ran past the due time, in that phase), ``blocked`` (the wake-up was
late and the thread was blocked at least half of it), ``kernel`` (the wake-up was late and the thread's CPU clock
ran at least half of it during its ``sleep`` phase, whose own code takes microseconds: time in the kernel charged to
the thread; CPU time its clock shows before the sleep mark beyond the wall time before the mark counts there too: it
ran between the mark's two clock reads, a microsecond of our code. On the development VM a kernel trace
(``bench/stall_trace.py``) shows it is the host's: timer interrupts of 0.3–1.5 ms instead of ~10 µs, the loop's CPU
recording nothing for milliseconds after the loop was woken, a wait for the interpreter lock that stays on the CPU;
on bare metal it would be interrupts and softirqs, which a kernel
without ``CONFIG_IRQ_TIME_ACCOUNTING`` charges to the running thread); a late wake-up that none of these explains
alone goes to the largest of its run-queue wait (``runqueue``), blocked time (``blocked``, or ``stolen`` if it did not
block again) and CPU time in its sleep (``kernel``) if the three together cover at least half the lateness (a stall
of several parts: its message gives each); else ``unknown``. A stall with ``missed`` ticks
counts them all for its cause, so the missed ticks by cause add up to the status's ``loop.missed_cycles``.
"""

from __future__ import annotations

import gc
import os
import threading
import time
from array import array
from collections.abc import Callable, Mapping
from enum import IntEnum
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

NS_PER_S = 1_000_000_000

STALL_THRESHOLD_PERIODS = 1.0
"""A tick later than this many periods is a stall: exactly the ticks that make the loop skip (miss) a tick."""

GC_WINDOWS = 64
"""The most recent garbage collections remembered (start and stop)."""

MAX_MARKS = 16
"""Phase marks kept per loop iteration (an iteration has at most 6)."""

OTHERS_SHOWN = 3
"""A stall's message names at most this many of the other threads (the most time on a CPU or a run queue)."""

OTHERS_MIN_NS = 100_000
"""Another thread is named in a stall's message only with at least this much time on a CPU or a run queue [ns]."""

OTHERS_REFRESH_NS = NS_PER_S
"""The process's Python threads are listed again after this long, and at each stall [ns]."""


class Phase(IntEnum):
    """What the loop thread is doing; the ids written into the marks."""

    SLEEP = 0
    """Waiting for the next tick (or a tracker frame)."""
    READ = 1
    """Reading the clocks and the decision's time budget."""
    DECIDE = 2
    """``node.cycle``: inputs to decisions."""
    PUBLISH = 3
    """Putting the overrides on Zenoh."""
    EVENTS = 4
    """The service manager's ping, the event log and its hand-off to the HTTP child."""
    STATUS = 5
    """Handing the cycle to the status thread."""


PHASE_NAMES = tuple(p.name.lower() for p in Phase)
CAUSES = (
    "gc",
    "runqueue",
    "stolen",
    "blocked",
    "kernel",
    "unknown",
    *(f"phase:{name}" for name in PHASE_NAMES[1:]),
)
"""Every cause :func:`attribute` can give (the metrics export each, 0 before the first)."""


class StallSample(NamedTuple):
    """What was measured for one late tick, between the loop thread's previous wake-up and this one.

    Attributes:
        late_ns: how late the tick came [ns].
        period_ns: the tick period [ns].
        interval_ns: from the previous wake-up to this one [ns].
        slept_ns: of the interval, time asleep on purpose: in ``sleep`` before the tick was due [ns].
        phase: the phase the loop was in when the tick fell due (``sleep``: the wake-up came late).
        gc_ns: garbage collections (any thread) within the interval [ns].
        cpu_ns: the loop thread's time on a CPU within the interval [ns]; None without schedstat.
        runqueue_ns: its time runnable but waiting for a CPU within the interval [ns]; None without schedstat.
        timeslices: how many times the loop thread was put on a CPU within the interval: once when its sleep
            ended, once more after each other block (the interpreter lock, a lock, I/O) or preemption; None
            without schedstat.
        others: the process's other Python threads that were on a CPU or waited on a run queue within the interval,
            the most first (:meth:`OtherThreads.between`); empty without schedstat.
        sleep_cpu_ns: of the loop thread's time on a CPU, what fell in its last ``sleep`` phase (its CPU clock at the
            ``sleep`` mark and at the wake-up) [ns]; None if it did not sleep in the interval.
    """

    late_ns: int
    period_ns: int
    interval_ns: int
    slept_ns: int
    phase: str
    gc_ns: int
    cpu_ns: int | None
    runqueue_ns: int | None
    timeslices: int | None = None
    others: tuple[ThreadTime, ...] = ()
    sleep_cpu_ns: int | None = None

    @property
    def blocked_ns(self) -> int | None:
        """Neither asleep on purpose, nor on a CPU, nor runnable [ns] (None without schedstat)."""
        if self.cpu_ns is None or self.runqueue_ns is None:
            return None
        return max(0, self.interval_ns - self.slept_ns - self.cpu_ns - self.runqueue_ns)

    @property
    def blocked_again(self) -> bool | None:
        """Whether the loop thread blocked within the interval other than in its sleep for the tick (the interpreter
        lock, a lock, I/O; or a second wait of its sleep, for a tracker frame), or was preempted (None without
        schedstat): put on a CPU more often than its sleep alone explains (once if asleep at the due time, else
        never: the sleep began after the due time and did not wait)."""
        if self.timeslices is None:
            return None
        return self.timeslices > (1 if self.phase == PHASE_NAMES[Phase.SLEEP] else 0)


class ThreadTime(NamedTuple):
    """Another thread's time within a stall's interval (from its schedstat: it lags by up to a scheduler tick).

    Attributes:
        name: the thread's Python name and its id.
        cpu_ns: its time on a CPU [ns].
        runqueue_ns: its time runnable but waiting for a CPU [ns].
    """

    name: str
    cpu_ns: int
    runqueue_ns: int


class StallRecord(NamedTuple):
    """One stall: a tick later than the threshold, with its cause.

    Attributes:
        cause: see :func:`attribute`.
        missed: ticks the loop skipped because of it.
        sample: what was measured.
    """

    cause: str
    missed: int
    sample: StallSample

    def message(self) -> str:
        """For people: how late, how many ticks missed, the cause and the figures behind it."""
        s = self.sample

        def ms(value_ns: int | None) -> str:
            return "n/a" if value_ns is None else f"{value_ns / 1e6:.1f} ms"

        others = "".join(
            f"; {t.name} on CPU {ms(t.cpu_ns)}, run-queue wait {ms(t.runqueue_ns)}" for t in s.others[:OTHERS_SHOWN]
        )
        return (
            f"loop stall: tick {ms(s.late_ns)} late ({self.missed} missed), cause {self.cause}: in phase {s.phase} "
            f"at the due time; gc {ms(s.gc_ns)}, run-queue wait {ms(s.runqueue_ns)}, blocked {ms(s.blocked_ns)}, "
            f"on CPU {ms(s.cpu_ns)} of {ms(s.interval_ns)} since the previous wake-up ({ms(s.sleep_cpu_ns)} of it in "
            f"its sleep), put on a CPU "
            f"{'n/a' if s.timeslices is None else s.timeslices} time(s)"
            + (f"; meanwhile{others[1:]}" if others else "")
        )


STALL_SUMMARY_EVERY_S = 60.0
"""The stalls of this long are logged as one line (each stall in full at DEBUG, in the events and the metrics)."""


class StallSummary:
    """The stalls of an interval gathered into one log line: counts by cause, ticks missed, the worst lateness.

    A loaded machine makes the loop late several times a second; an operator wants one line a minute, and a
    warning only when a decision's delay budget was hurt (a decision with δ > 0 in force longer than it counted).
    Pure: the caller gives the times and the budget overruns so far.
    """

    def __init__(self, every_ns: int, now_ns: int, overruns: int = 0) -> None:
        self.every_ns = every_ns
        self._begin(now_ns, overruns)

    def _begin(self, now_ns: int, overruns: int) -> None:
        self._start_ns = now_ns
        self._overruns_at_start = overruns
        self._counts: dict[str, int] = {}
        self._missed = 0
        self._worst_late_ns = 0

    def add(self, record: StallRecord) -> None:
        """One more stall of this interval."""
        self._counts[record.cause] = self._counts.get(record.cause, 0) + 1
        self._missed += record.missed
        self._worst_late_ns = max(self._worst_late_ns, record.sample.late_ns)

    def due(self, now_ns: int, overruns: int) -> tuple[bool, str] | None:
        """At the interval's end: ``(budget_hurt, line)`` if anything happened in it (then a new interval
        begins), else None; ``overruns``: the loop's budget overruns so far."""
        if now_ns - self._start_ns < self.every_ns:
            return None
        new_overruns = overruns - self._overruns_at_start
        line = None
        if self._counts or new_overruns:
            line = summary_line(self._counts, self._missed, self._worst_late_ns, now_ns - self._start_ns, new_overruns)
        self._begin(now_ns, overruns)
        return None if line is None else (new_overruns > 0, line)


def summary_line(
    counts: Mapping[str, int], missed: int, worst_late_ns: int, interval_ns: int, budget_overruns: int
) -> str:
    """For people: the stalls of an interval in one line, the most frequent cause first."""
    causes = ", ".join(f"{cause} {n}" for cause, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    line = (
        f"loop stalls in the last {interval_ns / NS_PER_S:.0f} s: {sum(counts.values())} ({causes or 'none'}), "
        f"{missed} ticks missed, worst {worst_late_ns / 1e6:.1f} ms late"
    )
    if budget_overruns:
        line += f"; {budget_overruns} decisions with δ > 0 held beyond their delay budget (loop.budget_overruns)"
    return line + " (each stall at DEBUG, in the events and in /metrics)"


def attribute(sample: StallSample) -> str:
    """The one cause of a late tick (the order is the module docstring's).

    Returns:
        ``gc``, ``runqueue``, ``stolen``, ``phase:<name>``, ``blocked``, ``kernel`` or ``unknown``.
    """
    half_late_ns = sample.late_ns / 2
    if sample.gc_ns >= half_late_ns:
        return "gc"
    if sample.runqueue_ns is not None and sample.runqueue_ns >= half_late_ns:
        return "runqueue"
    blocked_ns = sample.blocked_ns
    unaccounted = blocked_ns is not None and blocked_ns >= half_late_ns
    if unaccounted and sample.blocked_again is False:
        return "stolen"
    if sample.phase != PHASE_NAMES[Phase.SLEEP]:
        return f"phase:{sample.phase}"
    if unaccounted:
        return "blocked"
    if sample.sleep_cpu_ns is not None and sample.sleep_cpu_ns >= half_late_ns:
        return "kernel"
    # Several parts, none half: the largest, if the parts (disjoint: on a run queue, blocked, on a CPU in its sleep)
    # together cover half the lateness. A collection overlaps the blocked time it causes: it is not one of the parts.
    parts = {
        "runqueue": sample.runqueue_ns or 0,
        "stolen" if sample.blocked_again is False else "blocked": blocked_ns or 0,
        "kernel": sample.sleep_cpu_ns or 0,
    }
    if sum(parts.values()) >= half_late_ns:
        return max(parts, key=lambda cause: parts[cause])
    return "unknown"


class PhaseTrace:
    """The phases one loop iteration entered, in order, with their start [monotonic ns]; preallocated.

    :meth:`enter` writes a phase id and a stamp into two arrays (no object is kept); :meth:`restart` begins the next
    iteration. :meth:`phase_at` reads which phase was running at a given time.
    """

    def __init__(self) -> None:
        self._phases = array("b", bytes(MAX_MARKS))
        self._starts_ns = array("q", bytes(8 * MAX_MARKS))
        self._count = 0

    def restart(self, phase: Phase, now_ns: int) -> None:
        """A new iteration begins with ``phase`` at ``now_ns``."""
        self._count = 0
        self.enter(phase, now_ns)

    def enter(self, phase: Phase, now_ns: int) -> None:
        """The loop enters ``phase`` at ``now_ns`` [monotonic ns] (beyond :data:`MAX_MARKS`: the last is replaced)."""
        k = min(self._count, MAX_MARKS - 1)
        self._phases[k] = phase
        self._starts_ns[k] = now_ns
        self._count = k + 1

    def phase_at(self, when_ns: int) -> Phase:
        """The phase running at ``when_ns``: the last entered at or before it (the first if before them all)."""
        found = self._phases[0]
        for k in range(self._count):
            if self._starts_ns[k] > when_ns:
                break
            found = self._phases[k]
        return Phase(found)

    def slept_ns(self, due_ns: int) -> int:
        """Time in ``sleep`` before ``due_ns`` (the intended sleep) [ns]."""
        total = 0
        for k in range(self._count):
            if self._phases[k] != Phase.SLEEP:
                continue
            end_ns = self._starts_ns[k + 1] if k + 1 < self._count else due_ns
            total += max(0, min(end_ns, due_ns) - self._starts_ns[k])
        return total


class GcWindows:
    """When the garbage collector ran (any thread): the last :data:`GC_WINDOWS` start and stop stamps.

    :meth:`install` appends :meth:`on_gc` to ``gc.callbacks``; :meth:`remove` takes it away.
    """

    def __init__(self, clock_ns: Any = time.monotonic_ns) -> None:
        self._clock_ns = clock_ns
        self._starts_ns = array("q", bytes(8 * GC_WINDOWS))
        self._stops_ns = array("q", bytes(8 * GC_WINDOWS))
        self._next = 0
        self._started_ns = 0
        self.collections = 0

    def on_gc(self, phase: str, info: dict[str, int]) -> None:
        """A ``gc.callbacks`` callback: ``phase`` is ``start`` or ``stop``."""
        if phase == "start":
            self._started_ns = self._clock_ns()
            return
        k = self._next
        self._starts_ns[k] = self._started_ns
        self._stops_ns[k] = self._clock_ns()
        self._next = (k + 1) % GC_WINDOWS
        self.collections += 1

    def within_ns(self, start_ns: int, end_ns: int) -> int:
        """Time collections ran between ``start_ns`` and ``end_ns`` [monotonic ns] (as far as remembered) [ns]."""
        total = 0
        for k in range(min(self.collections, GC_WINDOWS)):
            total += max(0, min(self._stops_ns[k], end_ns) - max(self._starts_ns[k], start_ns))
        return total

    def install(self) -> None:
        gc.callbacks.append(self.on_gc)

    def remove(self) -> None:
        if self.on_gc in gc.callbacks:
            gc.callbacks.remove(self.on_gc)


class ThreadSchedstat:
    """The creating thread's time on a CPU (its CPU clock) and waiting on a run queue
    (``/proc/self/task/<tid>/schedstat``, second field) [ns], and how many times it was put on a CPU (third field:
    once after each block or preemption); read on that thread only.

    The descriptor stays open; :meth:`read` is one ``pread`` and one clock read (3 µs measured). Where the file is
    missing (not Linux, a kernel without ``CONFIG_SCHED_INFO``), :attr:`available` is False and :meth:`read`
    returns None.
    """

    def __init__(self, tid: int | None = None) -> None:
        tid = threading.get_native_id() if tid is None else tid
        try:
            self._fd: int | None = os.open(f"/proc/self/task/{tid}/schedstat", os.O_RDONLY)
        except OSError:
            self._fd = None

    @property
    def available(self) -> bool:
        return self._fd is not None

    def read(self) -> tuple[int, int, int] | None:
        """``(on_cpu_ns, runqueue_ns, timeslices)`` since the thread started, None if unavailable."""
        if self._fd is None:
            return None
        try:
            fields = os.pread(self._fd, 128, 0).split()
            return time.thread_time_ns(), int(fields[1]), int(fields[2])
        except (OSError, ValueError, IndexError):
            return None

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def _python_thread_names() -> dict[int, str]:
    """The Python threads' names by native id (threads Python never saw are absent)."""
    return {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}


def _parse_schedstat(raw: bytes) -> tuple[int, int] | None:
    """``(on_cpu_ns, runqueue_ns)`` from the text of a schedstat file (None if it does not parse)."""
    fields = raw.split()
    try:
        return int(fields[0]), int(fields[1])
    except (ValueError, IndexError):
        return None


class OtherThreads:
    """The process's other Python threads (those that can hold the interpreter lock: Python's own and the foreign
    threads that called into Python, such as Zenoh's callback threads), their schedstat read at each wake-up of
    the loop and compared at a stall.

    :meth:`read` is one ``pread`` per thread (descriptors kept open, bytes kept unparsed: ~1–2 µs a thread);
    :meth:`between` parses two readings only when a tick was late. :meth:`refresh` takes the threads Python knows
    now (``names``) and opens the new ones' schedstat in ``task_dir``. A thread started since the last refresh is
    missing until the next; one that ended is dropped. Threads that never run Python code (Zenoh's runtime, a BLAS
    pool) are left out: they cannot hold the lock, and they cannot take a CPU from the loop under SCHED_FIFO.

    Args:
        own_tid: the thread left out (the loop's own).
        task_dir: the process's task directory.
        names: the Python threads' names by native id.
    """

    def __init__(
        self,
        own_tid: int | None = None,
        task_dir: Path = Path("/proc/self/task"),
        names: Callable[[], dict[int, str]] = _python_thread_names,
    ) -> None:
        self._own_tid = threading.get_native_id() if own_tid is None else own_tid
        self._task_dir = task_dir
        self._names_of = names
        self._fds: dict[int, int] = {}
        self.names: dict[int, str] = {}
        """The threads followed, ``name (id)`` by id."""
        self.refresh()

    def refresh(self) -> None:
        """Follow the Python threads there are now (open the new ones' schedstat, close the ended ones')."""
        python_names = self._names_of()
        python_names.pop(self._own_tid, None)
        for tid in set(self._fds) - set(python_names):
            os.close(self._fds.pop(tid))
        for tid in set(python_names) - set(self._fds):
            try:
                self._fds[tid] = os.open(self._task_dir / str(tid) / "schedstat", os.O_RDONLY)
            except OSError:  # ended meanwhile
                continue
        self.names = {tid: f"{python_names[tid]} ({tid})" for tid in self._fds}

    def read(self) -> dict[int, bytes]:
        """Each thread's schedstat text now (a thread that ended is left out)."""
        reading = {}
        for tid, fd in self._fds.items():
            try:
                reading[tid] = os.pread(fd, 128, 0)
            except OSError:
                continue
        return reading

    def between(self, before: Mapping[int, bytes], after: Mapping[int, bytes]) -> tuple[ThreadTime, ...]:
        """The threads' time on a CPU and on a run queue between two readings, those with at least
        :data:`OTHERS_MIN_NS` of either, the most (CPU plus run queue) first."""
        times = []
        for tid, raw in after.items():
            then = _parse_schedstat(before.get(tid, b""))
            now = _parse_schedstat(raw)
            if then is None or now is None:
                continue
            cpu_ns, runq_ns = now[0] - then[0], now[1] - then[1]
            if max(cpu_ns, runq_ns) >= OTHERS_MIN_NS:
                times.append(ThreadTime(self.names.get(tid, str(tid)), cpu_ns, runq_ns))
        return tuple(sorted(times, key=lambda t: -(t.cpu_ns + t.runqueue_ns)))

    def close(self) -> None:
        for fd in self._fds.values():
            os.close(fd)
        self._fds.clear()


class StallMonitor:
    """The loop thread's stall record: phase marks, garbage collections, schedstat, counts by cause.

    Create it on the loop thread (its schedstat is the creating thread's) as a context manager, call :meth:`woke`
    right after each wake-up and :meth:`enter` at each phase; :meth:`woke` returns a :class:`StallRecord` for a
    tick later than ``threshold_periods`` periods. Only the loop thread calls it.

    Args:
        period_s: the tick period [s].
        threshold_periods: a tick later than this many periods is a stall (> 0).
        schedstat: the loop thread's schedstat (default: the calling thread's).
        gc_windows: the collections (default: new ones, installed in ``gc.callbacks`` until closed).
        others: the process's other Python threads (default: all but the calling one; read at each wake-up).
        clock_ns: the monotonic clock of the phase marks [ns] (tests give their own).
        cpu_clock_ns: the loop thread's CPU clock at the sleep mark and without schedstat [ns] (tests give their own;
            with schedstat, :meth:`ThreadSchedstat.read` reads it at each wake-up).

    Raises:
        ValueError: ``period_s`` or ``threshold_periods`` not > 0.
    """

    def __init__(
        self,
        period_s: float,
        threshold_periods: float = STALL_THRESHOLD_PERIODS,
        schedstat: ThreadSchedstat | None = None,
        gc_windows: GcWindows | None = None,
        others: OtherThreads | None = None,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        cpu_clock_ns: Callable[[], int] = time.thread_time_ns,
    ) -> None:
        if not (period_s > 0.0 and threshold_periods > 0.0):
            raise ValueError(f"period_s = {period_s}, threshold_periods = {threshold_periods}; allowed: > 0")
        self.period_ns = round(period_s * NS_PER_S)
        self.threshold_ns = round(threshold_periods * period_s * NS_PER_S)
        self._schedstat = ThreadSchedstat() if schedstat is None else schedstat
        self._own_gc = gc_windows is None
        self.gc_windows = GcWindows() if gc_windows is None else gc_windows
        if self._own_gc:
            self.gc_windows.install()
        self.trace = PhaseTrace()
        self.others = OtherThreads() if others is None else others
        self._clock_ns = clock_ns
        self._cpu_clock_ns = cpu_clock_ns
        self._woke_ns = clock_ns()  # the first interval starts here
        self._refreshed_ns = self._woke_ns
        self._stat: tuple[int, int, int] | None = self._schedstat.read()
        self._woke_cpu_ns = self._cpu_now_ns(self._stat)  # the loop's CPU clock then
        self._others_stat = self.others.read()
        self._missed_cycles = 0
        self._sleep_mark: tuple[int, int] | None = (self._woke_ns, self._woke_cpu_ns)
        """The last sleep mark: its monotonic stamp and the loop's CPU clock read right after it [ns]."""
        self.stalls: dict[str, int] = {}
        """Stalls by cause since the start."""
        self.missed: dict[str, int] = {}
        """Missed ticks by cause since the start (they add up to the loop's missed ticks)."""
        self.trace.restart(Phase.SLEEP, self._woke_ns)

    def woke(self, now_ns: int, tick: bool, late_s: float, missed_cycles: int) -> StallRecord | None:
        """The loop thread woke at ``now_ns`` [monotonic ns] for a tick (``tick``) or an event cycle.

        Args:
            now_ns: the wake-up [monotonic ns].
            tick: a tick (else an event cycle: never late).
            late_s: how late the tick came [s].
            missed_cycles: the loop's count of skipped ticks so far (what it grew by since the previous call was
                skipped at this tick).

        Returns:
            The stall record of a tick later than the threshold or that made the loop skip ticks, else None.
            Either way the next iteration's trace begins (phase ``read``).
        """
        stat = self._schedstat.read()
        cpu_now_ns = self._cpu_now_ns(stat)
        others_stat = self.others.read()
        sleep_cpu_ns = self._sleep_cpu_ns(cpu_now_ns)
        record = None
        missed, self._missed_cycles = max(0, missed_cycles - self._missed_cycles), missed_cycles
        late_ns = round(late_s * NS_PER_S)
        if tick and (missed > 0 or late_ns > self.threshold_ns):
            due_ns = now_ns - late_ns
            cpu_ns = runq_ns = timeslices = None
            if stat is not None and self._stat is not None:
                cpu_ns, runq_ns, timeslices = (now - then for now, then in zip(stat, self._stat, strict=True))
            sample = StallSample(
                late_ns=late_ns,
                period_ns=self.period_ns,
                interval_ns=now_ns - self._woke_ns,
                slept_ns=self.trace.slept_ns(due_ns),
                phase=PHASE_NAMES[self.trace.phase_at(due_ns)],
                gc_ns=self.gc_windows.within_ns(self._woke_ns, now_ns),
                cpu_ns=cpu_ns,
                runqueue_ns=runq_ns,
                timeslices=timeslices,
                others=self.others.between(self._others_stat, others_stat),
                sleep_cpu_ns=sleep_cpu_ns,
            )
            record = StallRecord(attribute(sample), missed, sample)
            self.stalls[record.cause] = self.stalls.get(record.cause, 0) + 1
            self.missed[record.cause] = self.missed.get(record.cause, 0) + record.missed
        if record is not None or now_ns - self._refreshed_ns >= OTHERS_REFRESH_NS:
            self.others.refresh()
            others_stat = self.others.read()
            self._refreshed_ns = now_ns
        self._woke_ns, self._woke_cpu_ns, self._stat, self._others_stat = now_ns, cpu_now_ns, stat, others_stat
        self._sleep_mark = None
        self.trace.restart(Phase.READ, now_ns)
        return record

    def enter(self, phase: Phase) -> None:
        """The loop thread enters ``phase`` now (at ``sleep``, its CPU clock is read too: 0.3 µs)."""
        mark_ns = self._clock_ns()
        self.trace.enter(phase, mark_ns)
        if phase is Phase.SLEEP:
            self._sleep_mark = (mark_ns, self._cpu_clock_ns())

    def _cpu_now_ns(self, stat: tuple[int, int, int] | None) -> int:
        """The loop thread's CPU clock now: the schedstat reading's, read a moment ago (one clock read per wake-up),
        else a read of its own."""
        return self._cpu_clock_ns() if stat is None else stat[0]

    def _sleep_cpu_ns(self, cpu_now_ns: int) -> int | None:
        """The loop thread's time on a CPU in its last ``sleep`` phase [ns], None if it did not sleep since the
        previous wake-up: its CPU clock from the sleep mark to now, and the CPU time its clock shows before the mark
        beyond the wall time there was before it (a thread is on a CPU at most as long as the time that passes: the
        excess ran between the mark's two clock reads, where our code takes a microsecond: the thread was held on its
        CPU there, by the kernel or a host that paused the machine, as in its sleep)."""
        if self._sleep_mark is None:
            return None
        mark_ns, mark_cpu_ns = self._sleep_mark
        before_mark_excess_ns = max(0, (mark_cpu_ns - self._woke_cpu_ns) - (mark_ns - self._woke_ns))
        return cpu_now_ns - mark_cpu_ns + before_mark_excess_ns

    def close(self) -> None:
        if self._own_gc:
            self.gc_windows.remove()
        self._schedstat.close()
        self.others.close()

    def __enter__(self) -> StallMonitor:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
