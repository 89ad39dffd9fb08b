"""The controller emulator process: override in over Zenoh, program step, joint state out every cycle.

newest override (OverrideInbox.take) → accept_override → step(state, trajectory, config, now, dt)
→ joint_state → publish (state and ground truth) → rate.sleep()

The same joint state also goes out on the ground-truth key (``hrc/<cell>/truth/robot/<robot>/state``) for
the auditor: the emulator knows its true state exactly, so truth and report are the same message here. A
fault injector may delay or drop the report on its way to the gateway; the truth key is not for the gateway.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence

import zenoh

from controller_emu.controller import (
    ControllerState,
    accept_override,
    check_braking_time,
    joint_state,
    step,
)
from controller_emu.program import Trajectory, load_trajectory
from hrc_common import keys
from hrc_common.config import CellConfig, ConfigError, ControllerConfig, load_cell_config
from hrc_common.messages import MessageError, Override, parse_message, to_payload
from hrc_common.robot_model import load_robot_model
from hrc_common.service import (
    RateLoop,
    add_config_argument,
    add_zenoh_arguments,
    configure_logging,
    stop_on_signals,
)
from hrc_common.zenoh_session import DEFAULT_ENDPOINT, session_config

PROG = "hrc-controller-emu"

log = logging.getLogger(PROG)

STATS_EVERY_S = 1.0
PROGRESS_EVERY_S = 5.0


class OverrideInbox:
    """The newest valid override from the subscriber, and the payloads rejected while parsing.

    The subscriber callback only parses and stores (:meth:`on_payload`); the loop takes the newest
    message once (:meth:`take`), so an override is offered to the controller at most once.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._newest: Override | None = None
        self._rejected: Counter[str] = Counter()

    def on_payload(self, payload: bytes) -> None:
        """Parse a payload; keep it if valid, else count it by :attr:`MessageError.reason`."""
        try:
            message = parse_message(payload, Override)
        except MessageError as exc:
            with self._lock:
                self._rejected[exc.reason] += 1
            return
        with self._lock:
            self._newest = message

    def count(self, reason: str) -> None:
        with self._lock:
            self._rejected[reason] += 1

    def take(self) -> Override | None:
        """The newest valid override received since the last call, or None."""
        with self._lock:
            message, self._newest = self._newest, None
        return message

    def rejected(self) -> dict[str, int]:
        with self._lock:
            return dict(self._rejected)


def _callback(inbox: OverrideInbox) -> Callable[[zenoh.Sample], None]:
    def on_sample(sample: zenoh.Sample) -> None:
        try:
            inbox.on_payload(sample.payload.to_bytes())
        except Exception:  # a callback must never die: count it, the watchdog stops the robot
            log.exception("error while handling an override")
            inbox.count("internal_error")

    return on_sample


def select_robot(config: CellConfig, robot: str | None) -> str:
    """The robot to emulate: the given name, or the cell's only robot.

    Raises:
        ConfigError: unknown name, or no name for a cell with several robots.
    """
    names = ", ".join(sorted(config.robots))
    if robot is None:
        if len(config.robots) == 1:
            return next(iter(config.robots))
        raise ConfigError(f"cell {config.cell!r} has several robots; allowed: --robot with one of {names}")
    if robot not in config.robots:
        raise ConfigError(f"unknown robot {robot!r}; allowed: {names}")
    return robot


def _rejections(state: ControllerState, inbox: OverrideInbox) -> dict[str, int]:
    counts = Counter(inbox.rejected())
    counts.update(state.rejected)
    return dict(sorted(counts.items()))


def _log_mode_change(before: ControllerState, after: ControllerState, config: ControllerConfig, now_s: float) -> None:
    if after.mode == "protective_stop":
        if after.override_accepted_ns is None:
            log.warning("protective stop: no valid override yet")
        else:
            silent_s = now_s - after.override_accepted_ns * 1e-9
            log.warning("protective stop: no valid override for %.2f s (watchdog %.2f s)", silent_s, config.watchdog_s)
    elif after.mode == "stopped":
        log.info("stopped: override 0 reached (program time %.2f s)", after.tau_s)
    elif before.mode == "protective_stop":
        log.info("running: valid overrides (override seq %d, δ → %.2f)", after.override_seq, after.delta_commanded)
    else:
        log.info("running: override %.2f", after.delta_commanded)


def _open_session(listen: Sequence[str], connect: Sequence[str]) -> zenoh.Session:
    """Open the Zenoh session.

    Raises:
        ConfigError: an endpoint is malformed or cannot be listened on (e.g. the port is in use).
    """
    try:
        return zenoh.open(session_config(listen, connect))
    except zenoh.ZError as exc:
        # Zenoh appends the Rust source location (" at /path/file.rs:N."): not useful to a user.
        reason = str(exc).split(" at /", 1)[0]
        raise ConfigError(
            f"cannot open a Zenoh session (listen {list(listen)}, connect {list(connect)}): {reason}"
        ) from None


def run_controller(
    cell: str,
    robot: str,
    trajectory: Trajectory,
    config: ControllerConfig,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
) -> ControllerState:
    """Run the controller loop until ``stop`` is set. Returns the final state.

    Raises:
        ConfigError: the Zenoh session cannot be opened with these endpoints.
    """
    inbox = OverrideInbox()
    state = ControllerState()
    override_key = keys.robot_override(cell, robot)
    with _open_session(listen, connect) as session:
        subscriber = session.declare_subscriber(override_key, _callback(inbox))
        state_pub = session.declare_publisher(
            keys.robot_state(cell, robot),
            express=True,
            priority=zenoh.Priority.REAL_TIME,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        truth_pub = session.declare_publisher(
            keys.truth_robot_state(cell, robot),
            express=True,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        stats_pub = session.declare_publisher(keys.robot_emu_stats(cell, robot))
        token = session.liveliness().declare_token(keys.alive(cell, f"controller-{robot}"))
        log.info(
            "controller %s of cell %r: program %.2f s per cycle, %.0f Hz; waiting for overrides on %s "
            "(protective stop until the first valid one)",
            robot,
            cell,
            trajectory.duration_s,
            1.0 / config.cycle_s,
            override_key,
        )
        seq = 0
        rate = RateLoop(config.cycle_s)
        last_s = time.monotonic()
        next_stats_s = last_s + STATS_EVERY_S
        next_progress_s = last_s + PROGRESS_EVERY_S
        try:
            while rate.sleep(stop):
                now_mono_s = time.monotonic()
                dt_s, last_s = now_mono_s - last_s, now_mono_s
                now_ns = time.time_ns()
                before = state
                override = inbox.take()
                if override is not None:
                    state, reason = accept_override(state, override, robot, now_ns, config.watchdog_s)
                    if reason is not None:
                        log.debug("override seq %d rejected: %s", override.seq, reason)
                state = step(state, trajectory, config, now_ns * 1e-9, dt_s)
                payload = to_payload(joint_state(state, trajectory, robot, seq, now_ns))
                state_pub.put(payload)
                truth_pub.put(payload)
                seq += 1
                if state.mode != before.mode:
                    _log_mode_change(before, state, config, now_ns * 1e-9)
                if now_mono_s >= next_stats_s:
                    next_stats_s = now_mono_s + STATS_EVERY_S
                    stats = {
                        "robot": robot,
                        "cycles_completed": state.cycles_completed,
                        "mode": state.mode,
                        "override": state.delta_applied,
                        "rejected": _rejections(state, inbox),
                        "missed_cycles": rate.missed_cycles,
                    }
                    stats_pub.put(json.dumps(stats).encode())
                if now_mono_s >= next_progress_s:
                    next_progress_s = now_mono_s + PROGRESS_EVERY_S
                    log.info(
                        "%s: %s δ=%.2f τ=%.2f/%.2f s cycles=%d override_seq=%d rejected=%s missed_cycles=%d",
                        robot,
                        state.mode,
                        state.delta_applied,
                        state.tau_s,
                        trajectory.duration_s,
                        state.cycles_completed,
                        state.override_seq,
                        _rejections(state, inbox),
                        rate.missed_cycles,
                    )
        finally:
            del token, subscriber  # undeclared when the session closes
    log.info(
        "controller %s stopped: %d program cycles completed, %d joint states published, %d missed cycles, "
        "rejected overrides: %s",
        robot,
        state.cycles_completed,
        seq,
        rate.missed_cycles,
        _rejections(state, inbox) or "none",
    )
    return state


def main(
    config: CellConfig,
    robot: str | None,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
) -> int:
    """Load the robot and its program, then run the controller until ``stop`` is set.

    Args:
        config: the cell.
        robot: the robot to emulate; None for the cell's only robot.
        listen, connect: Zenoh endpoints; with neither, connect to :data:`DEFAULT_ENDPOINT`.
        stop: set to end the loop (SIGINT, SIGTERM, or a test).

    Returns:
        The process exit code (0).

    Raises:
        ConfigError: unknown robot, invalid robot model or program, unsafe braking time, unusable
            Zenoh endpoints.
    """
    name = select_robot(config, robot)
    robot_config = config.robots[name]
    model = load_robot_model(name, robot_config)
    check_braking_time(robot_config.controller, model)
    trajectory = load_trajectory(robot_config.program, model)
    if not listen and not connect:
        connect = [DEFAULT_ENDPOINT]
    run_controller(config.cell, name, trajectory, robot_config.controller, listen, connect, stop)
    return 0


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog=PROG, description="Emulated closed robot controller (speed override δ)")
    add_config_argument(parser)
    parser.add_argument("--robot", default=None, metavar="NAME", help="robot of the cell (default: its only robot)")
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    with stop_on_signals() as stop:
        try:
            config = load_cell_config(args.config)
            code = main(config, args.robot, args.zenoh_listen, args.zenoh_connect, stop)
        except ConfigError as exc:
            reason = " ".join(str(exc).split())
            sys.stderr.write(f"{PROG}: invalid configuration: {reason}\n")
            sys.exit(2)
    sys.exit(code)


if __name__ == "__main__":
    cli()
