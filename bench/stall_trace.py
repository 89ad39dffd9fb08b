"""The kernel's own record around the gateway's loop stalls: scheduler and interrupt events from ftrace, kept for
each ``loop_stall`` event of the chosen causes, so that a stall the gateway cannot attribute (``unknown``:
``gateway/stalls.py``) can be read on what the CPUs really did.

    sudo .venv/bin/python -m bench.stall_trace --events DIR/events.jsonl --out DIR/stall-traces [--causes unknown]
    sudo .venv/bin/python -m bench.stall_trace --events-url http://127.0.0.1:8080/api/v1/events --out DIR ...
    .venv/bin/python -m bench.stall_trace --summarize --out DIR   # one line per capture (below)

Runs beside a cell or a soak (``bench/soak.py`` writes ``DIR/events.jsonl``) until SIGINT or SIGTERM. It keeps a
trace instance of its own (``/sys/kernel/tracing/instances/hrc-stalls``: the global trace is left alone) running
on the monotonic clock with the tasks' process ids, recording ``sched_switch``, ``sched_wakeup``,
``sched_migrate_task``, every interrupt and softirq, the local timer and IPI vectors, user page faults and every
system call's entry and exit (which call a task that held a CPU in the kernel was in), into
a ring buffer of ``--buffer-kb`` per CPU (the last few seconds). It follows the events file; for a stall of a chosen
cause it stops the buffer, writes every line from ``--before-ms`` before the stall's interval to the event's time
into ``OUT/stall-<stamp_ns>-<cause>.txt`` (the event itself first), and starts the buffer again. At most one
capture every ``--min-gap-s``, ``--max-per-cause`` of each cause and ``--max-captures`` in all: reading the buffer
costs CPU that would itself stall the loop. Needs root (tracefs); exit 2 without it.

``--summarize`` reads the captures: per stall, the longest time a CPU that was running a task recorded nothing
within the stall's interval (:func:`busy_cpu_silence`). A busy CPU takes a scheduler tick every 4 ms; a longer
silence means the virtual CPU did not run at all (the host did not schedule it, or paused the machine), time the
guest kernel charges to whichever task was current, as time on a CPU.

The event's ``stamp_ns`` is the gateway's wall clock when it noticed the stall (at the late wake-up); the trace's
times are the monotonic clock's, converted with this host's offset between the two (read at each capture: a step of
the wall clock between the stall and the capture shifts the window by the step, and the gateway reports a clock
step as a fault of its own).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

from hrc_runtime.signals import stop_on_signals

TRACEFS = Path("/sys/kernel/tracing")
INSTANCE = "hrc-stalls"
EVENTS = (
    "sched/sched_switch",
    "sched/sched_wakeup",
    "sched/sched_migrate_task",
    "irq/irq_handler_entry",
    "irq/irq_handler_exit",
    "irq/softirq_entry",
    "irq/softirq_exit",
    "irq_vectors/local_timer_entry",
    "irq_vectors/local_timer_exit",
    "irq_vectors/reschedule_entry",
    "irq_vectors/reschedule_exit",
    "irq_vectors/call_function_entry",
    "irq_vectors/call_function_exit",
    "irq_vectors/call_function_single_entry",
    "irq_vectors/call_function_single_exit",
    "exceptions/page_fault_user",
    "raw_syscalls/sys_enter",
    "raw_syscalls/sys_exit",
)
"""What is recorded (tracefs event paths); one missing on this kernel is left out with a note."""
_INTERVAL = re.compile(r"of ([\d.]+) ms since the previous wake-up")
_LATE = re.compile(r"tick ([\d.]+) ms late")
_TIME = re.compile(r"\s(\d+\.\d+):\s")
_RECORD = re.compile(r"^\s*(.+?)-(\d+)\s+\(\s*[-\d]+\)\s+\[(\d+)\]\s+(\S+)\s+(\d+\.\d+):\s+(\w+):\s*(.*)$")
_NEXT_PID = re.compile(r"next_pid=(\d+)")


def trace_line_time_s(line: str) -> float | None:
    """The time of one line of ftrace's text output [s, the trace clock], None for a header or comment line."""
    if line.startswith("#"):
        return None
    match = _TIME.search(line)
    return float(match.group(1)) if match else None


def capture_window_s(event: dict[str, Any], wall_minus_mono_ns: int, before_s: float) -> tuple[float, float]:
    """The monotonic window [s] to keep for a ``loop_stall`` event: from ``before_s`` before the interval between
    the loop's two wake-ups (named in the message; 50 ms if it is not) to 2 ms after the event."""
    end_s = (event["stamp_ns"] - wall_minus_mono_ns) / 1e9
    match = _INTERVAL.search(event.get("message", ""))
    interval_s = float(match.group(1)) / 1e3 if match else 0.05
    return end_s - interval_s - before_s, end_s + 0.002


def lines_within(lines: Iterator[str], start_s: float, end_s: float) -> list[str]:
    """The trace lines whose time lies in [start_s, end_s] (the buffer is in time order per CPU, not overall)."""
    kept = []
    for line in lines:
        t_s = trace_line_time_s(line)
        if t_s is not None and start_s <= t_s <= end_s:
            kept.append(line)
    kept.sort(key=lambda line: trace_line_time_s(line) or 0.0)
    return kept


class Record(NamedTuple):
    """One line of ftrace's text output (with ``record-tgid``)."""

    t_s: float
    cpu: int
    tid: int
    """The task current on the CPU when it was recorded (0: the idle task)."""
    flags: str
    """irqs-off, need-resched (``N``), hard/soft interrupt, preempt depth."""
    event: str
    rest: str


def parse_records(lines: list[str]) -> list[Record]:
    """The records of ftrace's text lines, in their order; header, comment and unparsable lines left out."""
    records = []
    for line in lines:
        match = _RECORD.match(line)
        if match is not None:
            _comm, tid, cpu, flags, t_s, event, rest = match.groups()
            records.append(Record(float(t_s), int(cpu), int(tid), flags, event, rest))
    return records


def _current_after(record: Record) -> int:
    """The task current on the record's CPU after it: a switch's next task, else the one recorded."""
    next_pid = _NEXT_PID.search(record.rest) if record.event == "sched_switch" else None
    return int(next_pid.group(1)) if next_pid else record.tid


def _loop_wakeup(records: list[Record], loop_tid: int, due_s: float, end_s: float) -> int | None:
    """The index of the loop thread's first wake-up in [due_s − 1 ms, end_s], None if there is none.

    ``due_s`` is estimated from the stall's lateness (up to ~0.5 ms late: the loop reads its clock after the
    wake-up), hence the tolerance.
    """
    return next(
        (
            i
            for i, r in enumerate(records)
            if r.event == "sched_wakeup" and f" pid={loop_tid} " in f" {r.rest} " and due_s - 1e-3 <= r.t_s <= end_s
        ),
        None,
    )


class Silence(NamedTuple):
    """The longest time one CPU recorded nothing while it had work (a task, or one woken for it), within a stall's
    interval."""

    duration_s: float
    cpu: int
    tid: int
    start_s: float


def busy_cpu_silence(records: list[Record], start_s: float, end_s: float) -> Silence | None:
    """The longest silence of a busy CPU in [start_s, end_s] (:class:`Silence`), None if no CPU was seen busy.

    A CPU's task is followed from its ``sched_switch`` events (or, before the first, the task its records name). A
    CPU is busy while it runs a task, or while idle with a task woken for it (the need-resched flag ``N`` in its last
    record: it must switch to that task at once). A busy CPU takes a scheduler tick every 4 ms here
    (``CONFIG_HZ_250``) and records it, and a woken task is switched in within microseconds, so a silence much
    longer means the CPU itself did not run: the host did not schedule the virtual CPU (steal), or paused the whole
    machine. The kernel charges such time to the task that was current, as time on a CPU.
    """
    current: dict[int, int] = {}
    last: dict[int, Record] = {}
    best: Silence | None = None
    for r in records:
        previous = last.get(r.cpu)
        running = current.get(r.cpu, r.tid)
        if previous is not None and (running != 0 or "N" in previous.flags):
            gap_start_s, gap_end_s = max(previous.t_s, start_s), min(r.t_s, end_s)
            if gap_end_s > gap_start_s and (best is None or gap_end_s - gap_start_s > best.duration_s):
                best = Silence(gap_end_s - gap_start_s, r.cpu, running, gap_start_s)
        last[r.cpu] = r
        current[r.cpu] = _current_after(r)
    return best


def idle_timer_delay_s(records: list[Record], loop_tid: int, due_s: float, end_s: float) -> float | None:
    """How long the CPU that woke the loop thread stayed silent after the loop's tick fell due, while idle [s];
    None if the loop was not woken in [due_s − 1 ms, end_s] or its CPU was running a task at ``due_s``.

    An idle virtual CPU waits in the host for its next timer; the loop's timer is due at ``due_s``, so the CPU
    must record that interrupt then. A CPU silent long after is the host's delay (it did not run the virtual CPU
    in time).
    """
    wake = _loop_wakeup(records, loop_tid, due_s, end_s)
    if wake is None:
        return None
    cpu = records[wake].cpu
    running: int | None = None
    for r in records:
        if r.cpu != cpu:
            continue
        if r.t_s >= due_s:
            idle = (r.tid if running is None else running) == 0
            return r.t_s - due_s if idle else None
        running = _current_after(r)
    return None


class WakeToRun(NamedTuple):
    """From the loop thread's wake-up (at or after its tick fell due) to its first record on that CPU [s]."""

    total_s: float
    in_interrupts_s: float
    """Inside interrupt handlers on that CPU (``*_entry`` to ``*_exit``): a timer interrupt takes ~10 µs on a CPU the
    host runs; longer is the host's (the virtual CPU exits to it and waits)."""
    silent_s: float
    """Woken on an idle CPU: gaps of more than :data:`SILENT_GAP_S` between that CPU's records outside handlers
    (nothing ran; 0 on a busy CPU, whose task runs on between its records)."""


SILENT_GAP_S = 1e-4
"""A gap between two records of a CPU that owes a woken task its switch longer than this is silence [s]."""


def wake_to_run(records: list[Record], loop_tid: int, due_s: float, end_s: float) -> WakeToRun | None:
    """:class:`WakeToRun` for the loop's first wake-up in [due_s − 1 ms, end_s], None if there is none (or it
    never ran on that CPU within the window)."""
    wake = _loop_wakeup(records, loop_tid, due_s, end_s)
    if wake is None:
        return None
    woken = records[wake]
    idle = woken.tid == 0  # woken on an idle CPU: it owes the loop its switch at once; a busy one runs its task on
    in_handler_since: float | None = None
    in_interrupts_s = silent_s = 0.0
    previous_s = woken.t_s
    for r in records[wake + 1 :]:
        if r.cpu != woken.cpu:
            continue
        if idle and in_handler_since is None and r.t_s - previous_s > SILENT_GAP_S:
            silent_s += r.t_s - previous_s
        hard_interrupt = not r.event.startswith("softirq")
        if r.event.endswith("_entry") and hard_interrupt:
            in_handler_since = r.t_s
        elif r.event.endswith("_exit") and hard_interrupt and in_handler_since is not None:
            in_interrupts_s += r.t_s - in_handler_since
            in_handler_since = None
        previous_s = r.t_s
        if r.tid == loop_tid:
            return WakeToRun(r.t_s - woken.t_s, in_interrupts_s, silent_s)
    return None


def _loop_tid(records: list[Record]) -> int | None:
    """The loop thread: the task woken at the loop's real-time priority (SCHED_FIFO 10: ftrace's prio 89)."""
    for r in records:
        if r.event == "sched_wakeup" and "prio=89 " in r.rest and (pid := re.search(r" pid=(\d+) ", f" {r.rest}")):
            return int(pid.group(1))
    return None


def summarize_capture(path: Path) -> dict[str, Any]:
    """One capture's stall (cause, lateness, interval) and the longest busy-CPU silence within the interval."""
    text = path.read_text().splitlines()
    event = json.loads(text[0][2:])
    message = event.get("message", "")
    window_end_s = float(text[1].split("..")[1].split()[0])
    event_s = window_end_s - 0.002
    interval = _INTERVAL.search(message)
    late = _LATE.search(message)
    interval_s = float(interval.group(1)) / 1e3 if interval else 0.05
    records = parse_records(text[2:])
    silence = busy_cpu_silence(records, event_s - interval_s, event_s)
    loop_tid = _loop_tid(records)
    late_s = float(late.group(1)) / 1e3 if late else 0.0
    timer_delay_s = None if loop_tid is None else idle_timer_delay_s(records, loop_tid, event_s - late_s, event_s)
    to_run = None if loop_tid is None else wake_to_run(records, loop_tid, event_s - late_s, event_s)
    return {
        "file": path.name,
        "cause": event.get("cause"),
        "late_ms": float(late.group(1)) if late else None,
        "interval_ms": round(interval_s * 1e3, 1),
        "busy_cpu_silence_ms": None if silence is None else round(silence.duration_s * 1e3, 2),
        "silent_cpu": None if silence is None else silence.cpu,
        "silent_cpu_task": None if silence is None else silence.tid,
        "loop_tid": loop_tid,
        "idle_timer_delay_ms": None if timer_delay_s is None else round(timer_delay_s * 1e3, 2),
        "wake_to_run_ms": None if to_run is None else round(to_run.total_s * 1e3, 2),
        "wake_to_run_host_ms": None if to_run is None else round((to_run.in_interrupts_s + to_run.silent_s) * 1e3, 2),
    }


class EventsFollower:
    """New lines of a JSON Lines file that may be rotated (renamed, a new file started) under it."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._inode: int | None = None
        self._offset = 0

    def new_events(self) -> list[dict[str, Any]]:
        try:
            stat = self.path.stat()
        except FileNotFoundError:
            return []
        if stat.st_ino != self._inode or stat.st_size < self._offset:
            self._inode, self._offset = stat.st_ino, 0
        with self.path.open("rb") as f:
            f.seek(self._offset)
            data = f.read()
        complete = data.rpartition(b"\n")[0]
        if not complete:
            return []
        self._offset += len(complete) + 1
        events = []
        for raw in complete.split(b"\n"):
            try:
                events.append(json.loads(raw))
            except ValueError:
                continue  # a line torn by a kill: not an event
        return events


class EventsPoller:
    """New events of a running gateway's ``GET /api/v1/events?since=<seq>`` (a cell without an events file, such
    as ``hrc-cell``'s); a restarted gateway (its ``last_seq`` below ours) is read from its start."""

    def __init__(self, url: str) -> None:
        self.url = url
        self._since = 0

    def new_events(self) -> list[dict[str, Any]]:
        try:
            with urllib.request.urlopen(f"{self.url}?since={self._since}", timeout=2.0) as response:
                doc = json.load(response)
        except (OSError, ValueError):
            return []  # the gateway is restarting, or not there yet
        if doc.get("last_seq", 0) < self._since:
            self._since = 0
            return []
        events = [e for e in doc.get("events", []) if e.get("seq", 0) > self._since]
        if events:
            self._since = max(e["seq"] for e in events)
        return events


@contextmanager
def trace_instance(buffer_kb: int) -> Iterator[Path]:
    """A tracefs instance of its own, recording :data:`EVENTS`; removed afterwards.

    Raises:
        PermissionError, OSError: no tracefs here, or not root.
    """
    if not (TRACEFS / "instances").is_dir():
        raise OSError(f"{TRACEFS} is not mounted (as root: mount -t tracefs nodev {TRACEFS})")
    inst = TRACEFS / "instances" / INSTANCE
    if not inst.exists():
        inst.mkdir()
    try:
        (inst / "tracing_on").write_text("0")
        (inst / "trace_clock").write_text("mono")
        (inst / "buffer_size_kb").write_text(str(buffer_kb))
        (inst / "options" / "record-tgid").write_text("1")
        for event in EVENTS:
            enable = inst / "events" / event / "enable"
            if enable.exists():
                enable.write_text("1")
            else:
                print(f"stall-trace: this kernel has no event {event}; left out", file=sys.stderr)
        (inst / "trace").write_text("")
        (inst / "tracing_on").write_text("1")
        yield inst
    finally:
        (inst / "tracing_on").write_text("0")
        for event in EVENTS:
            enable = inst / "events" / event / "enable"
            if enable.exists():
                enable.write_text("0")
        inst.rmdir()


def capture(inst: Path, event: dict[str, Any], before_s: float, out: Path) -> Path:
    """Stop the buffer, keep the event's window in ``out``, clear and restart the buffer; the file written."""
    (inst / "tracing_on").write_text("0")
    try:
        wall_minus_mono_ns = time.time_ns() - time.monotonic_ns()
        start_s, end_s = capture_window_s(event, wall_minus_mono_ns, before_s)
        with (inst / "trace").open() as f:
            kept = lines_within(iter(f), start_s, end_s)
        path = out / f"stall-{event['stamp_ns']}-{event.get('cause', 'unknown').replace(':', '-')}.txt"
        header = f"# {json.dumps(event)}\n# window {start_s:.6f} .. {end_s:.6f} s (monotonic)\n"
        path.write_text(header + "".join(kept))
        return path
    finally:
        (inst / "trace").write_text("")
        (inst / "tracing_on").write_text("1")


def print_summary(folder: Path) -> int:
    """Print :func:`summarize_capture` for every capture in ``folder``, and how many stalls the host's delay (a
    busy CPU's silence, or an idle CPU's late timer) explains (at least half the lateness); exit 2 without
    captures."""
    rows = [summarize_capture(path) for path in sorted(folder.glob("stall-*.txt"))]
    if not rows:
        print(f"stall-trace: no captures in {folder}", file=sys.stderr)
        return 2
    explained: dict[str, list[int]] = {}
    for row in rows:
        silence_ms, late_ms, timer_ms = row["busy_cpu_silence_ms"], row["late_ms"], row["idle_timer_delay_ms"]
        host_ms = max(silence_ms or 0.0, (timer_ms or 0.0) + (row["wake_to_run_host_ms"] or 0.0))
        covered = late_ms is not None and host_ms >= late_ms / 2
        explained.setdefault(row["cause"], [0, 0])[0 if covered else 1] += 1
        print(
            f"{row['file']:48s} {row['cause']:13s} late {row['late_ms']} ms of {row['interval_ms']} ms; longest "
            f"silence of a busy CPU {silence_ms} ms (cpu {row['silent_cpu']}, task {row['silent_cpu_task']}, loop "
            f"{row['loop_tid']}); idle CPU's timer late {timer_ms} ms; wake-up to running "
            f"{row['wake_to_run_ms']} ms, of it in interrupts or silent {row['wake_to_run_host_ms']} ms"
        )
    for cause, (yes, no) in sorted(explained.items()):
        print(
            f"{cause}: {yes} of {yes + no} with the host's delay (a busy CPU silent; or an idle CPU's timer late, plus "
            "the woken loop's idle CPU in interrupts or silent) at least half the lateness"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.stall_trace", description=__doc__.split("\n\n")[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--events", type=Path, help="the gateway's events file (JSON Lines)")
    source.add_argument("--events-url", help="or its events API, e.g. http://127.0.0.1:8080/api/v1/events")
    source.add_argument(
        "--summarize", action="store_true", help="instead: one line per capture in --out, and exit (no tracing)"
    )
    parser.add_argument("--out", type=Path, required=True, help="folder for the captures")
    parser.add_argument("--causes", default="unknown", help="comma-separated stall causes to capture")
    parser.add_argument("--buffer-kb", type=int, default=16384, help="ring buffer per CPU [kB]")
    parser.add_argument("--before-ms", type=float, default=20.0, help="kept before the stall's interval [ms]")
    parser.add_argument("--min-gap-s", type=float, default=10.0, help="at least this long between captures [s]")
    parser.add_argument("--max-captures", type=int, default=40, help="captures in all")
    parser.add_argument("--max-per-cause", type=int, default=15, help="captures of one cause")
    args = parser.parse_args(argv)
    causes = {c.strip() for c in args.causes.split(",") if c.strip()}
    if args.summarize:
        return print_summary(args.out)
    args.out.mkdir(parents=True, exist_ok=True)
    follower: EventsFollower | EventsPoller = (
        EventsFollower(args.events) if args.events is not None else EventsPoller(args.events_url)
    )
    follower.new_events()  # what is already there happened before the trace ran
    captured = 0
    per_cause: dict[str, int] = dict.fromkeys(causes, 0)
    last_s = -float("inf")
    with stop_on_signals() as stop:
        try:
            with trace_instance(args.buffer_kb) as inst:
                print(f"stall-trace: recording; capturing {sorted(causes)} from {args.events or args.events_url}")
                while not stop.wait(0.25) and captured < args.max_captures:
                    for event in follower.new_events():
                        cause = event.get("cause")
                        if event.get("kind") != "loop_stall" or cause not in per_cause:
                            continue
                        if time.monotonic() - last_s < args.min_gap_s or per_cause[cause] >= args.max_per_cause:
                            continue
                        path = capture(inst, event, args.before_ms / 1e3, args.out)
                        captured += 1
                        per_cause[cause] += 1
                        last_s = time.monotonic()
                        print(f"stall-trace: {event.get('cause')} stall → {path.name}", flush=True)
                        break  # the buffer was cleared: later events of this batch have no trace left
        except OSError as exc:
            print(f"stall-trace: cannot trace: {exc}", file=sys.stderr)
            return 2
    print(f"stall-trace: {captured} captures in {args.out}: {per_cause}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
