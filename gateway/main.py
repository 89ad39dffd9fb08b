"""The gateway process: Zenoh in, safety loop, override and status out, REST in a child process.

observation (InputStore.snapshot) → SafetyCore.step(snapshot, now) → overrides → rate.sleep()
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import zenoh

from gateway.core import RobotDecision, SafetyCore
from gateway.http_server import HttpServerProcess
from gateway.inputs import InputSnapshot, InputStore
from gateway.status import effective_config, loop_status, robot_status, status_document
from hrc_common import keys
from hrc_common.config import CellConfig, ConfigError, load_cell_config
from hrc_common.messages import Override, to_payload
from hrc_common.robot_model import load_robot_model
from hrc_common.service import (
    RateLoop,
    StopEvent,
    add_config_argument,
    add_zenoh_arguments,
    configure_logging,
    stop_on_signals,
)
from hrc_common.zenoh_session import DEFAULT_ENDPOINT, session_config

log = logging.getLogger("hrc-gateway")

PROGRESS_EVERY_S = 5.0

MAX_EVENT_SEQS_PER_STATUS = 256
"""At most this many event-cycle seqs are listed in one status document (``loop.event_seqs``)."""


def _callback(store: InputStore, kind: str, wake: threading.Event | None = None) -> Callable[[zenoh.Sample], None]:
    """A Zenoh callback: validate and store (``store`` may set ``wake``, see ``on_tracker_change``)."""
    handler = store.on_joint_state if kind == "robot" else store.on_humans

    def on_sample(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            handler(key, sample.payload.to_bytes(), time.time_ns())
        except Exception:  # a callback must never die: count it and fail closed via the latch
            log.exception("error while handling a message on %s", key)
            store.count_rejection(f"{kind}/{keys.name_from_key(key, kind) or '?'}", "internal_error")
            if wake is not None:
                wake.set()  # decide on the latched fault at once

    return on_sample


def _humans_summary(inputs: InputSnapshot) -> list[dict[str, Any]]:
    humans: list[dict[str, Any]] = []
    for tracker, frame in inputs.humans.items():
        if frame is None:
            continue
        for human_id, count in Counter(frame.capsules.human_ids).items():
            humans.append({"id": human_id, "tracker": tracker, "capsules": count})
    return humans


def _log_changes(previous: dict[str, RobotDecision], decisions: dict[str, RobotDecision]) -> None:
    for name, decision in decisions.items():
        before = previous.get(name)
        if before is None or before.zone != decision.zone:
            log.info(
                "robot %s: zone %s (δ = %.2f, min distance %s m)",
                name,
                decision.zone.value,
                decision.delta,
                "-" if decision.min_distance_m is None else f"{decision.min_distance_m:.2f}",
            )
        codes = {f.code for f in decision.faults}
        before_codes = set() if before is None else {f.code for f in before.faults}
        for fault in decision.faults:
            if fault.code not in before_codes:
                log.warning("robot %s: fault %s: %s (δ = 0)", name, fault.code, fault.reason)
        if before_codes - codes and not codes:
            log.info("robot %s: all faults cleared", name)


def _use_realtime_scheduling(priority: int) -> None:
    """Run the calling thread (the safety loop) under SCHED_FIFO at ``priority``; warn if the OS refuses.

    Only this thread: on Linux the scheduling policy of pid 0 is the calling thread's, so Zenoh's threads and
    the HTTP child keep normal scheduling and cannot starve the machine.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:  # not Linux, or no CAP_SYS_NICE
        log.warning("could not run the safety loop under SCHED_FIFO priority %d: %s", priority, exc)
    else:
        log.info("safety loop thread under SCHED_FIFO priority %d", priority)


def run_gateway(
    config: CellConfig,
    core: SafetyCore,
    listen: list[str],
    connect: list[str],
    http_host: str,
    http_port: int,
    stop: StopEvent,
) -> int:
    """Run the gateway until ``stop`` is set. Returns the process exit code.

    The loop decides at every tick of ``gateway.rate_hz`` and, with ``gateway.event_driven``, also at
    once when a tracker frame arrives (an event cycle, see :class:`RateLoop`).
    """
    cell = config.cell
    robots = core.robots
    gateway = config.gateway
    wake = stop.wake_event() if gateway.event_driven else None
    store = InputStore(
        {name: r.n_joints for name, r in robots.items()},
        sorted(config.trackers),
        on_tracker_change=None if wake is None else wake.set,
    )
    if config.safety.unsafe_ignore_delay_for_tests:
        log.warning("UNSAFE: unsafe_ignore_delay_for_tests is set: the measured delay is ignored (t_delay = 0)")
    period_s = 1.0 / gateway.rate_hz
    status_every = max(1, round(gateway.rate_hz / gateway.status_rate_hz))
    with zenoh.open(session_config(listen, connect)) as session:
        states_key, humans_key = keys.gateway_subscriptions(cell)
        subscribers = [
            session.declare_subscriber(states_key, _callback(store, "robot")),
            session.declare_subscriber(humans_key, _callback(store, "tracker", wake)),
        ]
        override_pubs = {
            name: session.declare_publisher(
                keys.robot_override(cell, name),
                express=True,
                priority=zenoh.Priority.REAL_TIME,
                congestion_control=zenoh.CongestionControl.DROP,
            )
            for name in robots
        }
        status_pub = session.declare_publisher(keys.gateway_status(cell))
        token = session.liveliness().declare_token(keys.alive(cell, "gateway"))
        http = HttpServerProcess(http_host, http_port, effective_config(config))
        log.info(
            "gateway for cell %r: %d robot(s), %d tracker(s), %.0f Hz%s; status: http://%s:%d/api/v1/status",
            cell,
            len(robots),
            len(config.trackers),
            gateway.rate_hz,
            " + a decision on each tracker frame" if gateway.event_driven else "",
            http_host,
            http_port,
        )
        seq = 0
        compute_max_s = 0.0
        event_seqs: list[int] = []  # override seqs of the event cycles since the last status
        previous: dict[str, RobotDecision] = {}
        next_progress_s = time.monotonic() + PROGRESS_EVERY_S
        if gateway.loop_realtime_priority:
            _use_realtime_scheduling(gateway.loop_realtime_priority)
        rate = RateLoop(period_s, gateway.min_event_interval_s, gateway.event_guard_s)
        exit_code = 0
        try:
            while rate.sleep(stop, wake):
                started_s = time.monotonic()
                now_ns = time.time_ns()
                inputs = store.snapshot()
                # Until the next decision: at most the rest of this period plus the lateness of the next
                # tick, estimated by the last one; an event cycle only comes earlier.
                decisions = core.step(inputs, now_ns, period_s + rate.last_lateness_s)
                seq += 1
                if rate.last_was_event and len(event_seqs) < MAX_EVENT_SEQS_PER_STATUS:
                    event_seqs.append(seq)
                for name, decision in decisions.items():
                    message = Override(robot=name, seq=seq, stamp_ns=now_ns, delta=decision.delta)
                    override_pubs[name].put(to_payload(message))
                    store.on_override_sent(name, seq, time.time_ns())
                compute_max_s = max(compute_max_s, time.monotonic() - started_s)
                _log_changes(previous, decisions)
                previous = decisions
                if not rate.last_was_event and rate.tick_cycles % status_every == 0:
                    rejected, received = store.counters()
                    doc = status_document(
                        cell,
                        now_ns,
                        {name: robot_status(d, seq) for name, d in decisions.items()},
                        _humans_summary(inputs),
                        rejected,
                        received,
                        loop_status(rate, compute_max_s, gateway.event_driven, event_seqs),
                    )
                    line = json.dumps(doc).encode()
                    status_pub.put(line)
                    http.offer(line + b"\n")
                    compute_max_s = 0.0
                    event_seqs = []
                    if http.exit_code() is not None:
                        log.error(
                            "the HTTP server exited (code %s); is port %d in use?",
                            http.exit_code(),
                            http_port,
                        )
                        exit_code = 1
                        break
                if started_s >= next_progress_s:
                    next_progress_s = started_s + PROGRESS_EVERY_S
                    for name, d in decisions.items():
                        log.info(
                            "robot %s: %s δ=%.2f d_min=%s t_delay=%.3f s faults=%s missed_cycles=%d",
                            name,
                            d.zone.value,
                            d.delta,
                            "-" if d.min_distance_m is None else f"{d.min_distance_m:.2f} m",
                            d.delay.total_s,
                            ",".join(f.code for f in d.faults) or "none",
                            rate.missed_cycles,
                        )
        finally:
            # Last word to the controllers: stop. (Their watchdog would stop them anyway.)
            for name, pub in override_pubs.items():
                seq += 1
                pub.put(to_payload(Override(robot=name, seq=seq, stamp_ns=time.time_ns(), delta=0.0)))
            http.close()
            del token, subscribers  # undeclared when the session closes
    log.info(
        "gateway stopped after %d cycles (%d ticks, %d missed; %d event cycles)",
        rate.tick_cycles + rate.event_cycles,
        rate.tick_cycles,
        rate.missed_cycles,
        rate.event_cycles,
    )
    return exit_code


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="hrc-gateway", description="HRC safety gateway (speed override δ)")
    add_config_argument(parser)
    parser.add_argument("--http-host", default=None, help="default: gateway.http_host of the config")
    parser.add_argument("--http-port", type=int, default=None, help="default: gateway.http_port of the config")
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    try:
        config = load_cell_config(args.config)
        robots = {name: load_robot_model(name, robot) for name, robot in config.robots.items()}
        core = SafetyCore(config, robots)
    except ConfigError as exc:
        print(f"hrc-gateway: invalid configuration: {exc}", file=sys.stderr)
        sys.exit(2)
    listen = args.zenoh_listen or ([] if args.zenoh_connect else [DEFAULT_ENDPOINT])
    with stop_on_signals() as stop:
        code = run_gateway(
            config,
            core,
            listen,
            args.zenoh_connect,
            args.http_host or config.gateway.http_host,
            args.http_port if args.http_port is not None else config.gateway.http_port,
            stop,
        )
    sys.exit(code)


if __name__ == "__main__":
    cli()
