"""Process plumbing shared by the three programs: command line, signals, fixed-rate loop."""

from __future__ import annotations

import argparse
import gc
import logging
import logging.handlers
import math
import os
import queue
import signal
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from types import FrameType


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """``--zenoh-listen``, ``--zenoh-connect``, ``--zenoh-mode``, and :func:`add_security_arguments`."""
    parser.add_argument(
        "--zenoh-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tls/127.0.0.1:7447 (repeatable)",
    )
    parser.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (repeatable)",
    )
    parser.add_argument(
        "--zenoh-mode",
        choices=["peer", "client"],
        default="peer",
        help="peer (default: programs meet directly) or client (through an hrc-router, e.g. across hosts)",
    )
    add_security_arguments(parser)


def add_security_arguments(parser: argparse.ArgumentParser) -> None:
    """``--pki-dir``, ``--tls-identity`` and ``--insecure-plain-tcp`` (read by ``zenoh_session.options_from_args``)."""
    parser.add_argument(
        "--pki-dir",
        default=None,
        metavar="DIR",
        help="the cell's CA and certificates (default $HRC_STATE_DIR/pki, else .state/pki of this project)",
    )
    parser.add_argument(
        "--tls-identity",
        default=None,
        metavar="CN",
        help="certificate to use, by common name (default: the program's own, e.g. gateway, controller-<robot>)",
    )
    parser.add_argument(
        "--insecure-plain-tcp",
        action="store_true",
        help="DEVELOPMENT ONLY (also HRC_INSECURE_PLAIN_TCP=1): allow tcp/ endpoints on loopback, without "
        "authentication, encryption or access control (anyone on this machine can command the robot); refused on "
        "any other address",
    )


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        default=None,
        metavar="PATH",
        help="cell configuration (TOML); default: configs/cell.toml of this project",
    )
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])


TERMINAL_LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"
JOURNAL_LOG_FORMAT = "%(name)s %(levelname)s %(message)s"
"""No timestamp: the journal stamps every line itself."""

JOURNAL_STREAM_ENV_VAR = "JOURNAL_STREAM"

SYSLOG_PRIORITY_BY_LEVEL = {
    logging.CRITICAL: 2,
    logging.ERROR: 3,
    logging.WARNING: 4,
    logging.INFO: 6,
    logging.DEBUG: 7,
}
"""``<N>`` prefix of a line written to the journal (``sd-daemon(3)``: crit, err, warning, info, debug)."""


def syslog_priority(levelno: int) -> int:
    """The syslog priority of a logging level: the one of the nearest named level at or below it (debug below)."""
    named = [level for level in SYSLOG_PRIORITY_BY_LEVEL if level <= levelno]
    return SYSLOG_PRIORITY_BY_LEVEL[max(named)] if named else SYSLOG_PRIORITY_BY_LEVEL[logging.DEBUG]


class JournalFormatter(logging.Formatter):
    """Log lines for the journal: the syslog priority as ``<N>`` before every line (a traceback too), no timestamp."""

    def __init__(self) -> None:
        super().__init__(JOURNAL_LOG_FORMAT)

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{syslog_priority(record.levelno)}>"
        return "\n".join(prefix + line for line in super().format(record).splitlines())


def stderr_is_journal(environ: Mapping[str, str] | None = None, stderr_fd: int = 2) -> bool:
    """Whether standard error is the journal's stream: ``JOURNAL_STREAM`` (``<device>:<inode>``) names it.

    systemd sets ``JOURNAL_STREAM`` for a service whose output goes to the journal; a program started from
    such a service with its output redirected inherits the variable, hence the comparison with the descriptor.
    """
    value = (os.environ if environ is None else environ).get(JOURNAL_STREAM_ENV_VAR, "")
    device, _, inode = value.partition(":")
    if not (device.isdigit() and inode.isdigit()):
        return False
    try:
        stat = os.fstat(stderr_fd)
    except OSError:
        return False
    return (stat.st_dev, stat.st_ino) == (int(device), int(inode))


def configure_logging(level: str) -> None:
    """Log to standard error at ``level``: with timestamps on a terminal or a file, journal lines under systemd."""
    handler = logging.StreamHandler()
    handler.setFormatter(JournalFormatter() if stderr_is_journal() else logging.Formatter(TERMINAL_LOG_FORMAT))
    logging.basicConfig(level=level, handlers=[handler])


class StopEvent(threading.Event):
    """A ``threading.Event`` that also sets the wake-up events made from it by :meth:`wake_event`.

    A loop that waits for new data (``RateLoop.sleep(stop, wake)``) waits on its wake-up event, not on
    the stop event; setting the stop event sets every wake-up event too, so the wait ends at once.
    """

    def __init__(self) -> None:
        super().__init__()
        self._wakes: list[threading.Event] = []
        self._wakes_lock = threading.Lock()

    def wake_event(self) -> threading.Event:
        """A new event, set whenever this one is set (and already set if this one is)."""
        wake = threading.Event()
        with self._wakes_lock:
            self._wakes.append(wake)
        if self.is_set():
            wake.set()
        return wake

    def set(self) -> None:
        super().set()
        with self._wakes_lock:
            wakes = list(self._wakes)
        for wake in wakes:
            wake.set()


@contextmanager
def stop_on_signals() -> Iterator[StopEvent]:
    """An event set by SIGINT or SIGTERM, with the previous handlers restored afterwards.

    The handler sets the event from a short-lived thread: a handler runs in the main thread between two
    bytecodes, possibly while that thread holds the lock inside the very event (or a wake-up event) it
    is waiting on, and ``Event.set`` there would deadlock.
    """
    stop = StopEvent()

    def handler(signum: int, frame: FrameType | None) -> None:
        try:
            threading.Thread(target=stop.set, name="stop-on-signal", daemon=True).start()
        except RuntimeError:  # no new thread (interpreter shutting down): set it here
            stop.set()

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def use_realtime_scheduling(priority: int, thread: str, logger: logging.Logger) -> bool:
    """Run the calling thread under SCHED_FIFO at ``priority``; log a warning (and go on) if the OS refuses.

    Only this thread: on Linux the scheduling policy of pid 0 is the calling thread's.

    Returns:
        True if the thread now runs under SCHED_FIFO.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:  # not Linux, or no CAP_SYS_NICE
        logger.warning("could not run %s under SCHED_FIFO priority %d: %s", thread, priority, exc)
        return False
    logger.info("%s (thread %d) under SCHED_FIFO priority %d", thread, threading.get_native_id(), priority)
    return True


class _LogWriter(logging.handlers.QueueListener):
    """A queue listener whose thread first puts itself under SCHED_FIFO at ``realtime_priority`` (0: not)."""

    def __init__(
        self, records: queue.SimpleQueue[logging.LogRecord], realtime_priority: int, *handlers: logging.Handler
    ):
        super().__init__(records, *handlers, respect_handler_level=True)
        self.realtime_priority = realtime_priority

    def _monitor(self) -> None:
        if self.realtime_priority:
            use_realtime_scheduling(self.realtime_priority, "the log writer thread", logging.getLogger("hrc"))
        super()._monitor()  # type: ignore[misc]  # QueueListener's thread body


@contextmanager
def logging_through_a_queue(realtime_priority: int = 0) -> Iterator[None]:
    """Meanwhile, a thread that logs only puts the record in a queue; one writer thread formats and writes it.

    For a real-time loop: writing a line to a file or the journal can block for milliseconds, and the handler's
    lock is shared by every thread that logs. ``realtime_priority`` > 0: the writer runs under SCHED_FIFO (it
    shares Python's interpreter lock with the loop, see ``gateway.io_realtime_priority``). On exit every queued
    record is written and the handlers are put back.
    """
    root = logging.getLogger()
    handlers = root.handlers[:]
    records: queue.SimpleQueue[logging.LogRecord] = queue.SimpleQueue()
    writer = _LogWriter(records, realtime_priority, *handlers)
    root.handlers = [logging.handlers.QueueHandler(records)]
    writer.start()
    try:
        yield
    finally:
        writer.stop()
        root.handlers = handlers


def freeze_startup_heap() -> None:
    """Collect once and move every object alive now (modules, robot models, compiled kernels, configs) to the
    garbage collector's permanent generation, so that a full collection during the loop does not scan them.

    Call it right before a program's loop starts. Why: a full (generation 2) collection of the gateway's ~157 000
    start-up objects takes ~38 ms, ten periods at 250 Hz, and it happens at some allocation in the loop; after
    the freeze it scans only what the loop itself keeps (measured: see docs/benchmarks.md, "Many robots").
    Reference cycles created later are still collected.
    """
    gc.collect()
    gc.freeze()


@contextmanager
def collections_paused() -> Iterator[None]:
    """Meanwhile no automatic garbage collection in this process (any thread); as before afterwards.

    For a thread that builds and drops a large graph of objects next to a real-time loop (the gateway's status
    thread): a full collection while such a graph is alive scans all of it with the interpreter lock held
    (measured 5–10 ms for a status document of 4000 capsules, ``bench/crowded.py``), and the loop waits for the
    lock. Dropped, the graph is freed by reference counting (it holds no cycles), so the next collection finds
    little. The switch is process-wide: one thread at a time may use this.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


RECENT_CYCLE_DECAY = 0.98
"""Per cycle, the weight of the longest recent cycle in :attr:`RateLoop.guard_s` (halves in ~35 cycles)."""


MAX_TICK_PERIODS = 256
"""Tick periods kept between two status documents (25 Hz status at up to 1 kHz ticks needs 40)."""


class RateLoop:
    """Fixed-rate loop on the monotonic clock that measures its own lateness, with optional event cycles.

    ``sleep()`` waits until the next period boundary, a *tick*. A tick that overran skips the missed
    boundaries (counted in ``missed_cycles``) instead of bursting to catch up.

    Given a ``wake`` event, ``sleep()`` also returns as soon as it is set, for an *event cycle* (new data
    to act on at once), and the next ``sleep()`` waits for the same boundary as before: event cycles do
    not move the ticks, and are neither late nor missed ticks (``event_cycles`` counts them apart from
    ``tick_cycles``). Two limits keep a flood of wake-ups from starving the loop or delaying its ticks:

    - event cycles start at least ``min_event_interval_s`` apart (a wake-up meanwhile waits until then);
    - no event cycle starts when the next tick is due within :attr:`guard_s`: that tick serves the wake-up
      instead (a reaction later by at most that), and an event cycle shorter than the guard cannot make it
      late. The guard is ``event_guard_s`` or, if longer, the recent cycles' duration (reported by
      :meth:`cycle_took`; the longest recent one, its weight halving about every 35 cycles): with many robots
      a cycle takes longer than a fixed guard, and an event cycle started just before a tick made it late.

    ``wake`` is cleared when ``sleep()`` returns (a tick or an event cycle takes everything that arrived
    before), so a wake-up set during the cycle leads to one more event cycle.
    """

    def __init__(self, period_s: float, min_event_interval_s: float = 0.0, event_guard_s: float = 0.0) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s = {period_s}; allowed: > 0")
        if not (min_event_interval_s >= 0.0 and event_guard_s >= 0.0):
            raise ValueError(
                f"min_event_interval_s = {min_event_interval_s}, event_guard_s = {event_guard_s}; allowed: >= 0"
            )
        self.period_s = period_s
        self.min_event_interval_s = min_event_interval_s
        self.event_guard_s = event_guard_s
        self._next_s = time.monotonic() + period_s
        self._last_event_s = -math.inf
        self.missed_cycles = 0
        self.last_lateness_s = 0.0
        """Lateness of the last tick [s] (event cycles leave it as it is)."""
        self.tick_cycles = 0
        self.tick_periods_s: list[float] = []
        """Each tick's interval from the previous tick [s], since :meth:`take_tick_periods` (at most
        :data:`MAX_TICK_PERIODS` kept; the Prometheus histogram observes each)."""
        self._last_tick_s: float | None = None
        self.event_cycles = 0
        self.wakes_served_by_tick = 0
        """Wake-ups left to the next tick because it was due within ``event_guard_s``."""
        self.last_was_event = False
        """Whether the cycle ``sleep()`` last returned for is an event cycle (else a tick)."""
        self._recent_cycle_s = 0.0

    @property
    def guard_s(self) -> float:
        """No event cycle starts when the next tick is due within this [s] (at most one period)."""
        return min(self.period_s, max(self.event_guard_s, self._recent_cycle_s))

    def cycle_took(self, duration_s: float) -> None:
        """The cycle ``sleep()`` last returned for took ``duration_s`` of the loop's time [s]."""
        self._recent_cycle_s = max(duration_s, self._recent_cycle_s * RECENT_CYCLE_DECAY)

    @property
    def next_tick_s(self) -> float:
        """When the next tick is due [monotonic s]."""
        return self._next_s

    def sleep(self, stop: threading.Event, wake: threading.Event | None = None) -> bool:
        """Wait for the next tick or, given ``wake``, until it is set (within the limits above).

        ``stop`` must wake the wait too: with ``wake``, pass a :class:`StopEvent` and its
        :meth:`StopEvent.wake_event` (or set ``wake`` whenever ``stop`` is set).

        Returns:
            False when ``stop`` is set, else True (see ``last_was_event`` for which cycle it is).
        """
        while not stop.is_set():
            now_s = time.monotonic()
            to_tick_s = self._next_s - now_s
            if to_tick_s <= 0.0:
                self._tick(-to_tick_s, wake)
                return not stop.is_set()
            if wake is None:
                stop.wait(to_tick_s)
                continue
            if not wake.is_set():
                wake.wait(to_tick_s)  # set by new data, by stop, or times out at the tick
                continue
            to_event_s = max(0.0, self._last_event_s + self.min_event_interval_s - now_s)
            if to_tick_s - to_event_s <= self.guard_s:
                self.wakes_served_by_tick += 1
                stop.wait(to_tick_s)  # the tick comes first or soon after: it serves the wake-up
            elif to_event_s > 0.0:
                stop.wait(to_event_s)  # rate-limited
            else:
                wake.clear()
                self._last_event_s = now_s
                self.event_cycles += 1
                self.last_was_event = True
                return not stop.is_set()
        return False

    def take_tick_periods(self) -> list[float]:
        """The tick periods since the previous call [s], oldest first; the list starts empty again."""
        periods, self.tick_periods_s = self.tick_periods_s, []
        return periods

    def _tick(self, late_s: float, wake: threading.Event | None) -> None:
        if wake is not None:
            wake.clear()
        now_s = time.monotonic()
        if self._last_tick_s is not None and len(self.tick_periods_s) < MAX_TICK_PERIODS:
            self.tick_periods_s.append(now_s - self._last_tick_s)
        self._last_tick_s = now_s
        self.last_lateness_s = late_s
        missed = int(late_s // self.period_s)
        self.missed_cycles += missed
        self._next_s += (missed + 1) * self.period_s
        self.tick_cycles += 1
        self.last_was_event = False
