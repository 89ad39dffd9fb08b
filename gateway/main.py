"""The gateway process: Zenoh in, :class:`~gateway.node.GatewayNode` cycles, override and status out, REST in a child.

    Zenoh callback ──node.on_joint_state / on_humans──▶ (stored)
    rate.sleep() ──▶ node.cycle(now) ──▶ publish overrides ──▶ status every ``status_rate_hz`` ──▶ rate.sleep()

Only Zenoh, timing, logging and the status live here; every decision is the node's.
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from gateway.core import RobotDecision
from gateway.events import EventLog
from gateway.http_server import HttpServerProcess
from gateway.node import GatewayCycle, GatewayNode, NodeRecorder, humans_summary
from gateway.status import effective_config, human_capsules, loop_status, robot_status, status_document
from hrc_common import keys
from hrc_common.clocks import read_clocks
from hrc_common.config import CellConfig, ConfigError, load_cell_config
from hrc_common.messages import Override, to_payload
from hrc_common.robot_model import load_robot_model
from hrc_common.sd_notify import LoopNotifier
from hrc_common.service import (
    RateLoop,
    StopEvent,
    add_config_argument,
    add_zenoh_arguments,
    configure_logging,
    freeze_startup_heap,
    logging_through_a_queue,
    stop_on_signals,
    use_realtime_scheduling,
)
from hrc_common.status_models import Event
from hrc_common.zenoh_session import DEFAULT_ENDPOINT, SessionOptions, options_from_args, session_config
from recorder.gateway_log import GatewayRecorder
from recorder.mcap_sink import RecordingError

log = logging.getLogger("hrc-gateway")

PROGRESS_EVERY_S = 5.0

MAX_EVENT_SEQS_PER_STATUS = 256
"""At most this many event-cycle seqs are listed in one status document (``loop.event_seqs``)."""


def _callback(node: GatewayNode, realtime_priority: int = 0) -> Callable[[zenoh.Sample], None]:
    """A Zenoh callback: the node judges and stores; an exception is logged, counted and faults the topic.

    ``realtime_priority`` > 0: each thread that calls it first puts itself under SCHED_FIFO at that priority
    (``gateway.io_realtime_priority``).
    """
    scheduled = threading.local()

    def on_sample(sample: zenoh.Sample) -> None:
        received = read_clocks()
        if realtime_priority and not getattr(scheduled, "done", False):
            scheduled.done = True
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


def _log_progress(decisions: dict[str, RobotDecision], missed_cycles: int) -> None:
    for name, d in decisions.items():
        log.info(
            "robot %s: %s δ=%.2f d_min=%s t_delay=%.3f s faults=%s missed_cycles=%d",
            name,
            d.zone.value,
            d.delta,
            "-" if d.min_distance_m is None else f"{d.min_distance_m:.2f} m",
            d.delay.total_s,
            ",".join(f.code for f in d.faults) or "none",
            missed_cycles,
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


@dataclass
class _Outputs:
    """The gateway's publishers, and what the status collects between two documents."""

    overrides: dict[str, Any]
    status: Any
    http: HttpServerProcess
    compute_max_s: float = 0.0
    event_seqs: list[int] = field(default_factory=list)
    events: EventLog = field(default_factory=EventLog)

    def publish_overrides(self, messages: dict[str, Override]) -> None:
        for name, message in messages.items():
            self.overrides[name].put(to_payload(message))

    def publish_status(self, config: CellConfig, cycle: GatewayCycle, rate: RateLoop, node: GatewayNode) -> None:
        rejected, received = node.inputs.counters()
        doc = status_document(
            config.cell,
            time.time_ns(),
            {
                name: robot_status(d, cycle.seq, node.robots[name].link_names, node.robots[name].link_radius_m)
                for name, d in cycle.decisions.items()
            },
            humans_summary(cycle.inputs),
            rejected,
            received,
            loop_status(rate, self.compute_max_s, config.gateway.event_driven, self.event_seqs),
            human_capsules(cycle.inputs),
        )
        line = doc.model_dump_json().encode()
        self.status.put(line)
        self.http.offer(line + b"\n")
        self.compute_max_s = 0.0
        self.event_seqs = []


def _declare_outputs(session: zenoh.Session, config: CellConfig, http: HttpServerProcess) -> _Outputs:
    overrides = {
        name: session.declare_publisher(
            keys.robot_override(config.cell, name),
            express=True,
            priority=zenoh.Priority.REAL_TIME,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        for name in config.robots
    }
    return _Outputs(overrides, session.declare_publisher(keys.gateway_status(config.cell)), http)


def _loop(config: CellConfig, node: GatewayNode, out: _Outputs, stop: StopEvent, wake: threading.Event | None) -> int:
    """Cycle until ``stop`` is set; returns the exit code (1 if the HTTP server died)."""
    gateway = config.gateway
    period_s = 1.0 / gateway.rate_hz
    status_every = max(1, round(gateway.rate_hz / gateway.status_rate_hz))
    next_progress_s = time.monotonic() + PROGRESS_EVERY_S
    freeze_startup_heap()
    rate = RateLoop(period_s, gateway.min_event_interval_s, gateway.event_guard_s)
    service = LoopNotifier.from_environment()  # READY=1, WATCHDOG=1 from this loop, STATUS=, STOPPING=1
    while rate.sleep(stop, wake):
        started_s = time.monotonic()
        # Until the next decision: at most the rest of this period plus the lateness of the next tick,
        # estimated by the last one; an event cycle only comes earlier.
        cycle = node.cycle(read_clocks(), period_s + rate.last_lateness_s)
        out.publish_overrides(cycle.overrides)
        service.cycle_done(started_s, functools.partial(service_status_line, cycle.decisions, rate.missed_cycles))
        service.stall_for_tests(stop)  # TEST ONLY (HRC_TEST_STALL_AFTER_CYCLES): a stalled loop stops the pings
        if rate.last_was_event and len(out.event_seqs) < MAX_EVENT_SEQS_PER_STATUS:
            out.event_seqs.append(cycle.seq)
        compute_s = time.monotonic() - started_s
        rate.cycle_took(compute_s)
        out.compute_max_s = max(out.compute_max_s, compute_s)
        events = out.events.observe(time.monotonic_ns(), time.time_ns(), cycle.decisions)
        if events:
            _log_events(events)
            out.http.offer_events(events)
        if not rate.last_was_event and rate.tick_cycles % status_every == 0:
            out.publish_status(config, cycle, rate, node)
            if out.http.exit_code() is not None:
                log.error("the HTTP server exited (code %s); is its port in use?", out.http.exit_code())
                service.stopping()
                return 1
        if started_s >= next_progress_s:
            next_progress_s = started_s + PROGRESS_EVERY_S
            _log_progress(cycle.decisions, rate.missed_cycles)
    service.stopping()
    log.info(
        "gateway stopped after %d cycles (%d ticks, %d missed; %d event cycles)",
        rate.tick_cycles + rate.event_cycles,
        rate.tick_cycles,
        rate.missed_cycles,
        rate.event_cycles,
    )
    return 0


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
) -> int:
    """Run the gateway until ``stop`` is set. Returns the process exit code.

    ``events_log``: a JSON Lines file of the event log (zone changes, faults, start, stop), rotated by size.

    The loop decides at every tick of ``gateway.rate_hz`` and, given ``wake`` (set by the node when a tracker
    frame arrives, see :class:`GatewayNode`), also at once between ticks (an event cycle, see :class:`RateLoop`).
    """
    with zenoh.open(session_config(listen, connect, zenoh_options)) as session:
        states_key, humans_key = keys.gateway_subscriptions(config.cell)
        on_sample = _callback(node, config.gateway.io_realtime_priority)
        subscribers = [session.declare_subscriber(k, on_sample) for k in (states_key, humans_key)]
        token = session.liveliness().declare_token(keys.alive(config.cell, "gateway"))
        effective = effective_config(config)
        out = _declare_outputs(
            session,
            config,
            HttpServerProcess(http_host, http_port, effective, events_log, config.gateway.io_realtime_priority),
        )
        out.http.offer_events(out.events.started(time.time_ns(), config.cell, effective.config_sha256))
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
        try:
            return _loop(config, node, out, stop, wake)
        finally:
            out.publish_overrides(node.stop_overrides(read_clocks()))  # last word to the controllers: stop
            out.http.offer_events(out.events.stopped(time.time_ns(), "stop requested" if stop.is_set() else "error"))
            out.http.close()
            del token, subscribers  # undeclared when the session closes


def build_node(config: CellConfig, wake: threading.Event | None, recorder: NodeRecorder | None = None) -> GatewayNode:
    """Load the robot models and build the node (compiles or loads the kernels); ``recorder``: see the node.

    Raises:
        ConfigError: a robot model or the safety configuration cannot be used.
    """
    robots = {name: load_robot_model(name, robot) for name, robot in config.robots.items()}
    if config.safety.unsafe_ignore_delay_for_tests:
        log.warning("UNSAFE: unsafe_ignore_delay_for_tests is set: the measured delay is ignored (t_delay = 0)")
    return GatewayNode(config, robots, on_tracker_change=None if wake is None else wake.set, recorder=recorder)


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
    configure_logging(args.log_level)
    with stop_on_signals() as stop:
        try:
            config = load_cell_config(args.config)
            zenoh_options = options_from_args(args, "gateway", config)  # mutual TLS + access control by default
            wake = stop.wake_event() if config.gateway.event_driven else None
            recorder = None if args.record is None else GatewayRecorder(args.record, config)
            node = build_node(config, wake, recorder)
        except RecordingError as exc:
            print(f"hrc-gateway: {exc}", file=sys.stderr)
            sys.exit(2)
        except ConfigError as exc:
            print(f"hrc-gateway: invalid configuration: {exc}", file=sys.stderr)
            sys.exit(2)
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
            )
        if recorder is not None:
            _close_recording(recorder)
    sys.exit(code)


if __name__ == "__main__":
    cli()
