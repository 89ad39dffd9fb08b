"""The gateway process: Zenoh in, :class:`~gateway.node.GatewayNode` cycles, override and status out, REST in a child.

    Zenoh callback ──node.on_joint_state / on_humans──▶ (stored)
    rate.sleep() ──▶ node.cycle(now, until next) ──▶ hand overrides over ──▶ hand the cycle over ──▶ rate.sleep()
                                                          │ one sender per robot  │ every ``status_rate_hz``
    override sender threads ◀─────────────────────────────┘                       │
        └──▶ Zenoh put (BLOCK)                                                     │
    status thread ◀────────────────────────────────────────────────────────────────┘
        └──▶ cycle_status ──▶ JSON ──▶ Zenoh status key and the HTTP child

The safety loop's thread decides and hands over (never waits for a put); nothing it does after that can delay the next
decision beyond what that decision budgeted (:class:`DecisionIntervals`). Only Zenoh, timing, logging and the
status live here; every decision is the node's.
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys
import threading
import time
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from gateway.bridge_view import BridgeView
from gateway.capsules_json import check_capsules_json
from gateway.cell_warnings import cell_warnings
from gateway.core import RobotDecision
from gateway.delay import NS_PER_S, WindowMax
from gateway.events import EventLog
from gateway.handoff import LatestJobThread
from gateway.http.server import HttpServerProcess
from gateway.node import GatewayCycle, GatewayNode, NodeRecorder
from gateway.open_robot import acceleration_warning
from gateway.recording import GatewayRecorder
from gateway.ros2_face import Ros2Face, ros2_session_options, running_ros2_face
from gateway.ros2_trackers import check_ros2_inputs, running_ros2_trackers
from gateway.stalls import STALL_SUMMARY_EVERY_S, Phase, StallMonitor, StallSummary
from gateway.status import (
    StatusJob,
    cycle_status,
    effective_config,
    loop_status,
    people_lists_json,
)
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import JointCommand, Override, to_payload
from hrc_contract.status_models import Event, GatewayStatus
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments, run_program
from hrc_runtime.clocks import read_clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.logs import logging_through_a_queue
from hrc_runtime.mcap_sink import RecordingError
from hrc_runtime.rate_loop import RateLoop
from hrc_runtime.realtime import collections_paused, freeze_startup_heap, use_realtime_scheduling
from hrc_runtime.sd_notify import LoopNotifier
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import (
    DEFAULT_ENDPOINT,
    SessionOptions,
    options_from_args,
    plain_tcp_allowed,
    session_config,
)

log = logging.getLogger("hrc-gateway")

PROGRESS_EVERY_S = 5.0

MAX_EVENT_SEQS_PER_STATUS = 256
"""At most this many event-cycle seqs are listed in one status document (``loop.event_seqs``)."""

DECISION_INTERVAL_WINDOW_S = 10.0
"""Each decision budgets the longest interval between consecutive decisions measured within this window [s]."""

GIL_SWITCH_INTERVAL_S = 0.0005
"""Python's switch interval in the gateway [s] (default 5 ms): a thread that waits for the interpreter lock asks
its holder to drop it after this long. At the default, the loop waking while the status thread built a document
waited ~5 ms for the lock (p50, measured with a probe thread under SCHED_FIFO); at 0.5 ms, ~0.6 ms."""


def _callback(node: GatewayNode, realtime_priority: int = 0) -> Callable[[zenoh.Sample], None]:
    """A Zenoh callback: the node judges and stores; an exception is logged, counted and faults the topic.

    ``realtime_priority`` > 0: each thread that calls it first puts itself under SCHED_FIFO at that priority
    (``gateway.io_realtime_priority``).
    """
    scheduled = threading.local()

    def on_sample(sample: zenoh.Sample) -> None:
        received = read_clocks()
        if not getattr(scheduled, "done", False):
            scheduled.done = True
            threading.current_thread().name = "zenoh-input"  # so that a stall record names it
            if realtime_priority:
                _use_realtime_scheduling(realtime_priority, "a Zenoh thread that receives inputs")
        key = str(sample.key_expr)
        try:
            node.on_message(key, sample.payload.to_bytes(), received)
        except Exception:  # a callback must never die: count it and fail closed
            log.exception("error while handling a message on %s", key)
            node.on_internal_error(key, received)

    return on_sample


def _log_events(events: list[Event]) -> None:
    """The event log's events as log lines: zone changes after their hold (not every flicker), faults raised
    (a warning: δ = 0) and cleared."""
    for event in events:
        robot = f"robot {event.robot}: " if event.robot else ""
        if event.kind == "fault_raised":
            log.warning("%s%s (δ = 0)", robot, event.message)
        elif event.kind in ("zone_changed", "fault_cleared"):
            log.info("%s%s", robot, event.message)
        elif event.kind == "loop_stall":  # one summary line per interval (StallSummary), each stall in full here
            log.debug("%s", event.message)


def _log_progress(decisions: dict[str, RobotDecision], missed_cycles: int, budget_overruns: int) -> None:
    for name, d in decisions.items():
        log.info(
            "robot %s: %s δ=%.2f d_min=%s t_delay=%.3f s faults=%s missed_cycles=%d budget_overruns=%d",
            name,
            d.zone.value,
            d.delta,
            "-" if d.min_distance_m is None else f"{d.min_distance_m:.2f} m",
            d.delay.total_s,
            ",".join(f.code for f in d.faults) or "none",
            missed_cycles,
            budget_overruns,
        )


def service_status_line(decisions: dict[str, RobotDecision], missed_cycles: int) -> str:
    """One line for the service manager (``STATUS=``, shown by ``systemctl status``): zone, δ, faults per robot."""
    robots = "; ".join(
        f"{name} {d.zone.value} δ={d.delta:.2f} faults={','.join(f.code for f in d.faults) or 'none'}"
        for name, d in decisions.items()
    )
    return f"{robots}; missed cycles {missed_cycles}"


def _use_realtime_scheduling(priority: int, thread: str = "the safety loop") -> None:
    """The calling thread under SCHED_FIFO at ``priority`` (a warning if refused); the other threads and the HTTP
    child keep their scheduling."""
    use_realtime_scheduling(priority, thread, log)


class DecisionIntervals:
    """The time from one decision to the next: budgeted by each decision, checked when the next one starts.

    A decision's delay budget counts the time until the next decision (``gateway_period_s``: its override is in
    force until then). Each decision budgets the longest start-to-start interval between consecutive decisions
    (ticks and event cycles alike) measured within the last ``window_s``, and at least the nominal period: what the
    loop really took lately, stalls included, not the period plus the previous tick's lateness. The next decision
    checks it: a decision that commanded motion (δ > 0 to some robot) whose successor started later than it
    budgeted is an overrun, counted in :attr:`overruns` (the status's ``loop.budget_overruns``); the decisions
    after it budget that longer interval.

    Args:
        period_s: the loop's nominal period [s].
        window_s: how long a measured interval is remembered [s].

    Raises:
        ValueError: ``period_s`` or ``window_s`` is not > 0.
    """

    def __init__(self, period_s: float, window_s: float = DECISION_INTERVAL_WINDOW_S) -> None:
        if not (period_s > 0.0 and window_s > 0.0):
            raise ValueError(f"period_s = {period_s}, window_s = {window_s}; allowed: > 0")
        self.period_s = period_s
        self._intervals_ns = WindowMax(round(window_s * NS_PER_S))
        self._previous_ns: int | None = None
        self._budget_s = period_s
        self._moving = False
        self.overruns = 0
        """Decisions that commanded δ > 0 and whose next decision started later than they budgeted."""
        self.worst_overrun_s = 0.0
        """The longest time by which a next decision came later than budgeted [s]."""

    def start(self, now_mono_ns: int) -> float:
        """A decision starts at ``now_mono_ns`` [monotonic ns]: check the previous decision's budget, give this one's.

        Returns:
            The time until the next decision this one must budget [s]: the longest interval within the window
            (the one that just ended included), at least the period.
        """
        if self._previous_ns is not None:
            interval_ns = max(0, now_mono_ns - self._previous_ns)
            late_s = interval_ns / NS_PER_S - self._budget_s
            if self._moving and late_s > 0.0:
                self.overruns += 1
                self.worst_overrun_s = max(self.worst_overrun_s, late_s)
            self._intervals_ns.push(now_mono_ns, interval_ns)
        self._previous_ns = now_mono_ns
        longest_ns = self._intervals_ns.max()
        self._budget_s = self.period_s if longest_ns is None else max(self.period_s, longest_ns / NS_PER_S)
        self._moving = False
        return self._budget_s

    def commanded(self, moving: bool) -> None:
        """What the decision started last commanded: ``moving`` when δ > 0 for some robot (its budget must hold)."""
        self._moving = moving


def status_json(doc: GatewayStatus, lists_json: Mapping[str, bytes] | None = None) -> bytes:
    """``doc.model_dump_json()``; with ``lists_json`` (:func:`gateway.status.people_lists_json`: top-level lists of
    the document as JSON arrays), a ``doc`` built without those lists gets them in their place: the same bytes as the
    whole document's, without a model per entry (the status thread's way: for a crowd, validating and dumping the
    models held the interpreter lock the loop needs for tens of ms per document).

    Raises:
        ValueError: a list given for a document that has entries of its own in it.
    """
    line = doc.model_dump_json().encode()
    if not lists_json:
        return line
    where: list[tuple[int, int, bytes]] = []
    for key, array in lists_json.items():
        empty = b'"' + key.encode() + b'":[]'
        if getattr(doc, key) or line.count(empty) != 1:  # the keys are unique in the contract's models
            raise ValueError(f"status_json: {key} given for a document that has its own")
        at = line.index(empty)
        where.append((at, at + len(empty), b'"' + key.encode() + b'":' + array))
    pieces, done = [], 0
    for start, end, text in sorted(where):  # by place in the line, each cut from the document as it was
        pieces += [line[done:start], text]
        done = end
    return b"".join([*pieces, line[done:]])


class StatusThread(LatestJobThread[StatusJob]):
    """Builds, serialises and publishes the status documents on a thread of their own, off the safety loop.

    :meth:`offer` never blocks its caller: the job goes into a one-place slot (the newest wins: one not yet taken
    is replaced) and a counter (an eventfd) wakes the thread; no lock is shared with the loop, so the status thread
    being descheduled cannot hold the loop up. What it cannot avoid is Python's interpreter lock: it builds the
    document under :func:`collections_paused` (a full collection while a document of thousands of capsules is alive
    held the lock 5–10 ms) and serialises the lists that grow with the people apart, without a model per entry
    (:func:`gateway.status.people_lists_json`; the capsules' text by a compiled pass that does not hold the lock), and
    it runs under SCHED_FIFO at ``realtime_priority`` (``gateway.io_realtime_priority``) like the other threads that
    take the lock: at normal scheduling another program could deschedule it while it held the lock, and the loop
    waited for the lock until it ran again (a priority inversion; measured on the default cell: each ``blocked`` stall
    at normal scheduling had this thread waiting 8–18 ms on a run queue meanwhile, none under SCHED_FIFO). An
    exception while publishing is logged and counted; the thread goes on.

    Args:
        publish: builds and publishes one job's document (called on the status thread).
        realtime_priority: > 0: the thread puts itself under SCHED_FIFO at it; 0: normal scheduling.
    """

    def __init__(self, publish: Callable[[StatusJob], None], realtime_priority: int = 0) -> None:
        super().__init__(
            publish,
            "hrc-status",
            "publishing a status document",
            log,
            on_start=None
            if not realtime_priority
            else functools.partial(_use_realtime_scheduling, realtime_priority, "the status thread"),
        )


@dataclass(frozen=True)
class _StatusSink:
    """Where the status thread puts each document: the Zenoh status key and the HTTP child."""

    config: CellConfig
    robots: Mapping[str, RobotModel]
    publisher: Any
    http: HttpServerProcess
    bridges: BridgeView | None = None
    """The controller bridges' statistics, shown in the status (never used for a decision)."""
    ros2: Ros2Face | None = None
    """The ROS 2 face (``[ros2]``): handed each document with its job, so that it builds none of its own."""

    def publish(self, job: StatusJob) -> None:
        line = self.line(job)
        self.publisher.put(line)
        self.http.offer(line + b"\n")

    def line(self, job: StatusJob) -> bytes:
        """The job's document as JSON (the document itself goes to the ROS 2 face); built and dropped with
        collections paused (see :class:`StatusThread`)."""
        with collections_paused():
            bridges = None if self.bridges is None else self.bridges.snapshot()
            arguments = (self.config, job.cycle, self.robots, job.counters, job.loop, job.stamp_ns, bridges)
            line = status_json(cycle_status(*arguments, with_lists=False), people_lists_json(self.config, job.cycle))
            if self.ros2 is not None:  # the whole document with its models, built only if the face wants it
                self.ros2.offer(job, lambda: cycle_status(*arguments))
            return line


class OverrideSenders:
    """One sender thread per robot: the loop hands each robot's newest override over and never waits for a put.

    Each robot's publisher puts with congestion control BLOCK (:func:`_declare_overrides`), which waits while that
    controller's link is congested (a frozen controller, a partition). On the loop's thread that wait held every
    robot's decisions (the 60-minute soak: 22,964 of 35,575 missed ticks in the publish phase); here each put waits
    on its robot's own thread (a :class:`~gateway.handoff.LatestJobThread`): an override not yet put is replaced by
    the newer one (the newest decision is the one to be in force), and the other robots' overrides go out on time.

    The send is recorded at decision time, before the put (:meth:`gateway.inputs.InputStore.on_override_sent`, from
    the node): a put that waits lengthens the measured override path (conservative); a replaced override is never
    echoed, which :class:`gateway.delay.OverridePath` takes as no news (no fault). The controller ignores an
    override stamped no later than one it accepted; one thread per robot keeps each robot's overrides in order.

    Args:
        publishers: the robots' override publishers (``put(bytes)``).
        realtime_priority: > 0: each sender thread puts itself under SCHED_FIFO at it
            (``gateway.io_realtime_priority``, like the receiving threads).
    """

    LAST_WORD_TIMEOUT_S = 2.0
    """How long the gateway waits on exit for its last override (δ = 0) to be put to every controller [s]; a link
    still congested after it is left to the controller's watchdog."""

    def __init__(self, publishers: Mapping[str, Any], realtime_priority: int = 0) -> None:
        self._threads = {
            name: LatestJobThread[bytes](
                publisher.put,
                f"hrc-override-{name}",
                f"publishing robot {name}'s override",
                log,
                on_start=None
                if not realtime_priority
                else functools.partial(_use_realtime_scheduling, realtime_priority, f"robot {name}'s override sender"),
            )
            for name, publisher in publishers.items()
        }

    def offer(self, messages: Mapping[str, Override | JointCommand]) -> None:
        """Hand each robot's override to its sender (never blocks; a newer one replaces one not yet put)."""
        for name, message in messages.items():
            self._threads[name].offer(to_payload(message))

    def last_word(
        self, messages: Mapping[str, Override | JointCommand], timeout_s: float = LAST_WORD_TIMEOUT_S
    ) -> list[str]:
        """Put these last overrides (δ = 0 on exit) after any put under way, and stop the senders; waits for all
        of them together at most ``timeout_s`` [s].

        Returns:
            The robots whose last override was not put within ``timeout_s`` (their link still congested).
        """
        for name, message in messages.items():
            self._threads[name].offer_last(to_payload(message))
        deadline_s = time.monotonic() + timeout_s
        return [name for name, thread in self._threads.items() if not thread.close(deadline_s - time.monotonic())]


@dataclass
class _Outputs:
    """The gateway's publishers, and what the status collects between two documents (loop thread only).

    ``overrides``: the robots' override publishers, each put on a sender thread of its own (:class:`OverrideSenders`,
    at ``io_realtime_priority``); :meth:`last_word` stops those threads.
    """

    overrides: dict[str, Any]
    http: HttpServerProcess
    status_thread: StatusThread
    io_realtime_priority: int = 0
    compute_max_s: float = 0.0
    event_seqs: list[int] = field(default_factory=list)
    events: EventLog = field(default_factory=EventLog)
    senders: OverrideSenders = field(init=False)

    def __post_init__(self) -> None:
        self.senders = OverrideSenders(self.overrides, self.io_realtime_priority)

    def offer_overrides(self, messages: Mapping[str, Override | JointCommand]) -> None:
        """Hand the overrides to the robots' senders (never waits for a put)."""
        self.senders.offer(messages)

    def last_word(self, messages: Mapping[str, Override | JointCommand]) -> None:
        """Put ``messages`` (δ = 0 on exit) to every controller, waiting a bounded time; a warning names those
        not reached."""
        late = self.senders.last_word(messages)
        if late:
            log.warning(
                "the last override (δ = 0) was not put to robot(s) %s within %.1f s (link congested); their "
                "controllers' watchdogs stop them",
                ", ".join(late),
                OverrideSenders.LAST_WORD_TIMEOUT_S,
            )

    def offer_status(
        self,
        config: CellConfig,
        cycle: GatewayCycle,
        rate: RateLoop,
        node: GatewayNode,
        intervals: DecisionIntervals,
        stalls: StallMonitor | None = None,
    ) -> None:
        """Hand ``cycle`` to the status thread with the loop's numbers now (a few µs on the loop thread)."""
        loop = loop_status(rate, self.compute_max_s, config.gateway.event_driven, self.event_seqs)
        update: dict[str, Any] = {"budget_overruns": intervals.overruns}
        if stalls is not None:
            update |= {"stalls": dict(stalls.stalls), "missed_by_cause": dict(stalls.missed)}
        loop = loop.model_copy(update=update)
        job = StatusJob(cycle, node.counters(), loop, time.time_ns())
        self.status_thread.offer(job)
        self.compute_max_s = 0.0
        self.event_seqs = []


def _declare_overrides(session: zenoh.Session, config: CellConfig) -> dict[str, Any]:
    """One publisher per robot. Congestion control BLOCK: an override that lowers δ is never dropped on the way
    (DROP would leave the controller at the higher δ until a later one, or its watchdog, arrived, beyond the
    budget). A put waits only while the link's queue is full; a silent peer's link is closed after the session's
    lease (1 s), a congested one after Zenoh's ``wait_before_close`` (5 s), which ends the wait; meanwhile that
    controller's watchdog stops its robot. Each put waits on its robot's sender thread (:class:`OverrideSenders`),
    never on the safety loop: the other robots' decisions stay on time."""
    return {
        name: session.declare_publisher(
            keys.robot_joint_command(config.cell, name)
            if robot.controller.control == "open"
            else keys.robot_override(config.cell, name),
            express=True,
            priority=zenoh.Priority.REAL_TIME,
            congestion_control=zenoh.CongestionControl.BLOCK,
        )
        for name, robot in config.robots.items()
    }


def _moving(overrides: Mapping[str, Override | JointCommand]) -> bool:
    return any(
        message.delta > 0.0 or (isinstance(message, JointCommand) and any(v != 0.0 for v in message.qd))
        for message in overrides.values()
    )


def _loop(config: CellConfig, node: GatewayNode, out: _Outputs, stop: StopEvent, wake: threading.Event | None) -> int:
    """Cycle until ``stop`` is set; returns the exit code (1 if the HTTP server died). Each tick later than a
    period is recorded with its cause (:mod:`gateway.stalls`): an event, and counted in the status."""
    with StallMonitor(1.0 / config.gateway.rate_hz) as stalls:  # on this thread: it reads this thread's schedstat
        return _cycle(config, node, out, stop, wake, stalls)


def _cycle(
    config: CellConfig,
    node: GatewayNode,
    out: _Outputs,
    stop: StopEvent,
    wake: threading.Event | None,
    stalls: StallMonitor,
) -> int:
    gateway = config.gateway
    period_s = 1.0 / gateway.rate_hz
    status_every = max(1, round(gateway.rate_hz / gateway.status_rate_hz))
    next_progress_s = time.monotonic() + PROGRESS_EVERY_S
    freeze_startup_heap()
    rate = RateLoop(period_s, gateway.min_event_interval_s, gateway.event_guard_s)
    intervals = DecisionIntervals(period_s)
    overruns_logged = 0
    stall_summary = StallSummary(round(STALL_SUMMARY_EVERY_S * 1e9), time.monotonic_ns())
    service = LoopNotifier.from_environment()  # READY=1, WATCHDOG=1 from this loop, STATUS=, STOPPING=1
    while rate.sleep(stop, wake):
        woke_s = time.monotonic()
        stall = stalls.woke(time.monotonic_ns(), not rate.last_was_event, rate.last_lateness_s, rate.missed_cycles)
        now = read_clocks()
        stalls.enter(Phase.DECIDE)
        cycle = node.cycle(now, intervals.start(now.mono_ns))
        stalls.enter(Phase.PUBLISH)
        out.offer_overrides(cycle.overrides)
        intervals.commanded(_moving(cycle.overrides))
        stalls.enter(Phase.EVENTS)
        service.cycle_done(woke_s, functools.partial(service_status_line, cycle.decisions, rate.missed_cycles))
        service.stall_for_tests(stop)  # TEST ONLY (HRC_TEST_STALL_AFTER_CYCLES): a stalled loop stops the pings
        if rate.last_was_event and len(out.event_seqs) < MAX_EVENT_SEQS_PER_STATUS:
            out.event_seqs.append(cycle.seq)
        events = out.events.observe(time.monotonic_ns(), time.time_ns(), cycle.decisions, cycle.track_events)
        if stall is not None:  # built after the decision is out; logged and written by other threads
            events += out.events.stalled(time.time_ns(), stall.cause, stall.message())
            stall_summary.add(stall)
        if events:
            _log_events(events)
            out.http.offer_events(events)
        if not rate.last_was_event and rate.tick_cycles % status_every == 0:
            stalls.enter(Phase.STATUS)
            out.offer_status(config, cycle, rate, node, intervals, stalls)
            if out.http.exit_code() is not None:
                log.error("the HTTP server exited (code %s); is its port in use?", out.http.exit_code())
                service.stopping()
                return 1
        overruns_logged = _log_overruns_and_stalls(intervals, overruns_logged, stall_summary)
        if woke_s >= next_progress_s:
            next_progress_s = woke_s + PROGRESS_EVERY_S
            _log_progress(cycle.decisions, rate.missed_cycles, intervals.overruns)
        # The whole iteration, from waking to going back to sleep: what can make the next tick late.
        compute_s = time.monotonic() - woke_s
        rate.cycle_took(compute_s)
        out.compute_max_s = max(out.compute_max_s, compute_s)
        stalls.enter(Phase.SLEEP)
    service.stopping()
    log.info(
        "gateway stopped after %d cycles (%d ticks, %d missed; %d event cycles; %d budget overruns)",
        rate.tick_cycles + rate.event_cycles,
        rate.tick_cycles,
        rate.missed_cycles,
        rate.event_cycles,
        intervals.overruns,
    )
    return 0


def _log_overruns_and_stalls(intervals: DecisionIntervals, overruns_logged: int, stall_summary: StallSummary) -> int:
    """The first budget overrun at once (a warning), then the stalls and overruns of each interval in one line:
    a warning if a budget was hurt in it, else info. Returns the overruns logged at once (0 or the first count)."""
    if intervals.overruns and not overruns_logged:
        overruns_logged = intervals.overruns
        log.warning(
            "a decision with δ > 0 was in force %.3f ms longer than its delay budget counted (the loop was "
            "held up); later decisions budget the longer interval (loop.budget_overruns)",
            1e3 * intervals.worst_overrun_s,
        )
    summary = stall_summary.due(time.monotonic_ns(), intervals.overruns)
    if summary is not None:
        budget_hurt, line = summary
        log.log(logging.WARNING if budget_hurt else logging.INFO, "%s", line)
    return overruns_logged


def run_gateway(
    config: CellConfig,
    node: GatewayNode,
    listen: list[str],
    connect: list[str],
    http_host: str,
    http_port: int,
    stop: StopEvent,
    wake: threading.Event | None = None,
    *,
    zenoh_options: SessionOptions,
    events_log: Path | None = None,
    ros2_options: SessionOptions | None = None,
) -> int:
    """Run the gateway until ``stop`` is set. Returns the process exit code.

    ``ros2_options``: the ROS 2 face's own session (:func:`gateway.ros2_face.ros2_session_options`), when enabled.

    ``events_log``: a JSON Lines file of the event log (zone changes, faults, start, stop), rotated by size.

    The loop decides at every tick of ``gateway.rate_hz`` and, given ``wake`` (set by the node when a tracker
    frame arrives, see :class:`GatewayNode`), also at once between ticks (an event cycle, see :class:`RateLoop`).
    A shell: its resources (:func:`_open_gateway`, closed in reverse order whatever happens) and the loop.
    """
    with ExitStack() as resources:
        out = _open_gateway(
            resources,
            config,
            node,
            session_config(listen, connect, zenoh_options),
            (http_host, http_port),
            stop,
            events_log=events_log,
            ros2_options=ros2_options,
        )
        log.info(
            "gateway for cell %r: %d robot(s), %d tracker(s), %.0f Hz%s; status: http://%s:%d/api/v1/status",
            config.cell,
            len(config.robots),
            len(config.trackers),
            config.gateway.rate_hz,
            " + a decision on each tracker frame" if wake is not None else "",
            http_host,
            http_port,
        )
        if config.gateway.loop_realtime_priority:
            _use_realtime_scheduling(config.gateway.loop_realtime_priority)
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)  # the loop gets the interpreter lock soon after it wakes
        return _loop(config, node, out, stop, wake)


def _open_gateway(
    resources: ExitStack,
    config: CellConfig,
    node: GatewayNode,
    zenoh_config: zenoh.Config,
    http_address: tuple[str, int],
    stop: StopEvent,
    *,
    events_log: Path | None,
    ros2_options: SessionOptions | None,
) -> _Outputs:
    """Open the gateway's resources on ``resources``, each closed in reverse order when it unwinds (also when a later
    one fails to open): the Zenoh session, the ROS 2 face and trackers, the subscriptions, the HTTP server process,
    the status thread; on the way out the controllers get the last word (δ = 0) first, the event log its "stopped"
    event before the HTTP server closes."""
    session = resources.enter_context(zenoh.open(zenoh_config))
    ros2 = resources.enter_context(running_ros2_face(config, node.robots, ros2_options))
    resources.enter_context(
        running_ros2_trackers(  # ROS 2 body trackers through the same door (gateway/ros2_trackers.py)
            config, None if ros2 is None else ros2.node.session, node.on_message, node.inputs.count_rejection
        )
    )
    states_key, humans_key = keys.gateway_subscriptions(config.cell)
    on_sample = _callback(node, config.gateway.io_realtime_priority)
    declared: list[Any] = [
        session.declare_subscriber(k, on_sample)
        for k in (states_key, humans_key, keys.operator_track_reset(config.cell))
    ]
    declared.append(session.liveliness().declare_token(keys.alive(config.cell, "gateway")))
    resources.callback(declared.clear)  # kept alive until here; undeclared when the session closes
    effective = effective_config(config)
    http = HttpServerProcess(*http_address, effective, events_log, config.gateway.io_realtime_priority)
    resources.callback(http.close)
    bridges = BridgeView(config)
    if bridges.interfaces:  # display only: the bridges' read-back figures (gateway/bridge_view.py)
        declared.append(session.declare_subscriber(bridges.key, bridges.on_sample))
    status_pub = session.declare_publisher(keys.gateway_status(config.cell))
    check_capsules_json()  # the status's compiled capsule text, held to its reference and compiled before a document
    sink = _StatusSink(config, node.robots, status_pub, http, bridges if bridges.interfaces else None, ros2)
    events = EventLog()
    http.offer_events(events.started(time.time_ns(), config.cell, effective.config_sha256))
    resources.callback(
        lambda: http.offer_events(events.stopped(time.time_ns(), "stop requested" if stop.is_set() else "error"))
    )
    resources.callback(node.core.close)  # the planner layer's thread, if any
    status_thread = StatusThread(sink.publish, config.gateway.io_realtime_priority)
    resources.callback(status_thread.close)
    out = _Outputs(
        _declare_overrides(session, config), http, status_thread, config.gateway.io_realtime_priority, events=events
    )
    resources.callback(lambda: out.last_word(node.stop_overrides(read_clocks())))  # to every controller: stop
    return out


def build_node(config: CellConfig, wake: threading.Event | None, recorder: NodeRecorder | None = None) -> GatewayNode:
    """Load the robot models and build the node (compiles or loads the kernels); ``recorder``: see the node.

    Raises:
        ConfigError: a robot model or the safety configuration cannot be used.
    """
    robots = {name: load_robot_model(name, robot) for name, robot in config.robots.items()}
    if config.safety.unsafe_ignore_delay_for_tests:
        log.warning("UNSAFE: unsafe_ignore_delay_for_tests is set: the measured delay is ignored (t_delay = 0)")
    for line in cell_warnings(config):
        log.warning("%s", line)
    node = GatewayNode(config, robots, on_tracker_change=None if wake is None else wake.set, recorder=recorder)
    for name, state in node.core.states.items():
        warning = None if state.open is None else acceleration_warning(name, state.open.accelerations_over_limit)
        if warning is not None:
            log.warning("%s", warning)
    return node


def _close_recording(recorder: GatewayRecorder) -> None:
    summary = recorder.close()
    how = "complete" if summary.complete else f"INCOMPLETE: {summary.dropped} dropped {summary.error or ''}".strip()
    log.info("recording %s: %d messages (%s)", summary.path, summary.records, how)


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="hrc-gateway", description="HRC safety gateway (speed override δ)")
    add_config_argument(parser)
    parser.add_argument("--http-host", default=None, help="default: gateway.http_host of the config")
    parser.add_argument("--http-port", type=int, default=None, help="default: gateway.http_port of the config")
    parser.add_argument("--events-log", type=Path, default=None, help="JSON Lines file of the event log (rotated)")
    parser.add_argument(
        "--record", type=Path, default=None, metavar="PATH", help="record inputs, cycles and config to PATH (MCAP)"
    )
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)

    def body(stop: StopEvent) -> int:
        config = load_cell_config(args.config)
        zenoh_options = options_from_args(args, "gateway", config)  # mutual TLS + access control by default
        ros2_options = ros2_session_options(args, config) if config.ros2.enabled else None
        check_ros2_inputs(config, ros2_options, plain_tcp_allowed(args))
        wake = stop.wake_event() if config.gateway.event_driven else None
        try:
            recorder = (
                None
                if args.record is None
                else GatewayRecorder(args.record, config, realtime_priority=config.gateway.io_realtime_priority)
            )
        except RecordingError as exc:
            print(f"hrc-gateway: {exc}", file=sys.stderr)
            return 2
        node = build_node(config, wake, recorder)
        listen = args.zenoh_listen or ([] if args.zenoh_connect else [DEFAULT_ENDPOINT])
        http_host = args.http_host or config.gateway.http_host
        http_port = args.http_port if args.http_port is not None else config.gateway.http_port
        with logging_through_a_queue(config.gateway.io_realtime_priority):  # the loop thread never writes a line
            code = run_gateway(
                config,
                node,
                listen,
                args.zenoh_connect,
                http_host,
                http_port,
                stop,
                wake,
                zenoh_options=zenoh_options,
                events_log=args.events_log,
                ros2_options=ros2_options,
            )
        if recorder is not None:
            _close_recording(recorder)
        return code

    run_program("hrc-gateway", args.log_level, body, log=log)


if __name__ == "__main__":
    cli()
