"""The controller emulator process: the Zenoh, clock and logging shell around :class:`ControllerNode`.

override payload → node.on_override(payload, read_clocks())   (the subscriber's thread)
rate.sleep() → node.cycle(read_clocks()) → publish the joint state (state and ground truth) → log, stats

With a vendor face (:data:`controller_emu.faces.FACES`, one option each): ``--rtde HOST`` (Universal Robots RTDE on
HOST:30004, :mod:`controller_emu.rtde_face`) or ``--rws HOST:PORT`` (ABB Robot Web Services,
:mod:`controller_emu.rws_face`), the emulator plays a vendor's controller: overrides come
only from that face (the speed slider, the speed ratio), there is no override subscription, and nothing is
published on the cell's state key (the controller bridge publishes the joint state it reads back). Each face gets
the latest state every cycle; the ground-truth key and the stats are published as always.

A robot whose ``controller.control`` is ``"open"`` gets an open controller instead
(:class:`controller_emu.open_node.OpenControllerNode`): it subscribes to the robot's joint commands
(``hrc/<cell>/robot/<robot>/joint_command``, newest wins) instead of its overrides, runs no program (the gateway
does) and starts standing at the program's first waypoint. With ``--egm HOST:PORT`` it plays ABB EGM's controller
side instead (:mod:`controller_emu.egm_face`): references only from the PC's ``EgmSensor`` replies, no joint command
subscription and nothing on the cell's state key, as the closed controller's faces.

joint command payload → node.on_command(payload, read_clocks())   (the subscriber's thread)
rate.sleep() → node.cycle(read_clocks()) → publish the joint state (state and ground truth) → log, stats

The same joint state also goes out on the ground-truth key (``hrc/<cell>/truth/robot/<robot>/state``) for
the auditor: the emulator knows its true state exactly, so truth and report are the same message here. A
fault injector may delay or drop the report on its way to the gateway; the truth key is not for the gateway.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import zenoh

from controller_emu.faces import FACES, VendorFace, start_faces
from controller_emu.node import ControllerNode, ControllerOutput, ControllerStats, ModeChange
from controller_emu.open_follower import FollowerLimits, FollowerState, follower_limits
from controller_emu.open_node import OpenControllerNode, OpenControllerStats
from hrc_contract import keys
from hrc_contract.config import CellConfig, ConfigError, ControllerConfig
from hrc_contract.messages import to_payload
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import Trajectory, load_trajectory
from hrc_devices.robots.time_scaling import ControllerState, check_braking_time
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments, run_program
from hrc_runtime.clocks import read_clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.newest_wins import declare_newest_wins
from hrc_runtime.rate_loop import RateLoop
from hrc_runtime.realtime import freeze_startup_heap
from hrc_runtime.sd_notify import LoopNotifier
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import DEFAULT_ENDPOINT, SessionOptions, options_from_args, session_config

PROG = "hrc-controller-emu"

log = logging.getLogger(PROG)

STATS_EVERY_S = 1.0
PROGRESS_EVERY_S = 5.0


def _callback(node: ControllerNode) -> Callable[[zenoh.Sample], None]:
    """The override subscriber's callback: the payload and its arrival times to the node, nothing else."""

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            reason = node.on_override(sample.payload.to_bytes(), read_clocks())
        except Exception:  # a callback must never die: count it, the watchdog stops the robot
            log.exception("error while handling an override")
            node.count_rejected("internal_error")
            return
        if reason is not None:
            log.debug("override rejected: %s", reason)

    return on_sample


class _Publishers(NamedTuple):
    state: zenoh.Publisher | None  # None when a vendor face serves the state (the bridge publishes it)
    truth: zenoh.Publisher
    stats: zenoh.Publisher


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


def _log_mode_change(change: ModeChange, state: ControllerState, config: ControllerConfig) -> None:
    if change.after == "protective_stop":
        if change.silent_s is None:
            log.warning("protective stop: no valid override yet")
        else:
            log.warning(
                "protective stop: no valid override for %.2f s (watchdog %.2f s)", change.silent_s, config.watchdog_s
            )
    elif change.after == "stopped":
        log.info("stopped: override 0 reached (program time %.2f s)", state.tau_s)
    elif change.before == "protective_stop":
        log.info("running: valid overrides (override seq %d, δ → %.2f)", state.override_seq, state.delta_commanded)
    else:
        log.info("running: override %.2f", state.delta_commanded)


def _stats_doc(robot: str, stats: ControllerStats, missed_cycles: int) -> bytes:
    """The ``emu_stats`` payload."""
    doc = {
        "robot": robot,
        "cycles_completed": stats.cycles_completed,
        "mode": stats.mode,
        "override": stats.delta_applied,
        "rejected": dict(stats.rejected),
        "missed_cycles": missed_cycles,
    }
    return json.dumps(doc).encode()


def _log_progress(node: ControllerNode, missed_cycles: int) -> None:
    stats = node.stats()
    log.info(
        "%s: %s δ=%.2f τ=%.2f/%.2f s cycles=%d override_seq=%d rejected=%s missed_cycles=%d",
        node.robot,
        stats.mode,
        stats.delta_applied,
        stats.tau_s,
        node.trajectory.duration_s,
        stats.cycles_completed,
        stats.override_seq,
        dict(stats.rejected),
        missed_cycles,
    )


def service_status_line(robot: str, stats: ControllerStats) -> str:
    """One line for the service manager (``STATUS=``): mode, applied override, program cycles, rejections."""
    rejected = sum(stats.rejected.values())
    return f"{robot} {stats.mode} δ={stats.delta_applied:.2f} cycles={stats.cycles_completed} rejected={rejected}"


def _publish(output: ControllerOutput, publishers: _Publishers, config: ControllerConfig) -> None:
    payload = to_payload(output.joint_state)
    if publishers.state is not None:
        publishers.state.put(payload)
    publishers.truth.put(payload)
    if output.mode_change is not None:
        _log_mode_change(output.mode_change, output.state, config)


def _run_loop(
    node: ControllerNode, publishers: _Publishers, stop: threading.Event, faces: Sequence[VendorFace] = ()
) -> RateLoop:
    """Cycle the node at its rate until ``stop`` is set; stats every second, a progress line every 5 s."""
    freeze_startup_heap()
    rate = RateLoop(node.config.cycle_s)
    next_stats_s = time.monotonic() + STATS_EVERY_S
    next_progress_s = time.monotonic() + PROGRESS_EVERY_S
    service = LoopNotifier.from_environment()  # READY=1 after the first joint state, WATCHDOG=1, STATUS=
    while rate.sleep(stop):
        now = read_clocks()
        output = node.cycle(now)
        for face in faces:
            face.on_cycle(output)
        _publish(output, publishers, node.config)
        now_s = now.mono_ns / 1e9
        service.cycle_done(now_s, lambda: service_status_line(node.robot, node.stats()))
        if now_s >= next_stats_s:
            next_stats_s = now_s + STATS_EVERY_S
            publishers.stats.put(_stats_doc(node.robot, node.stats(), rate.missed_cycles))
        if now_s >= next_progress_s:
            next_progress_s = now_s + PROGRESS_EVERY_S
            _log_progress(node, rate.missed_cycles)
    service.stopping()
    return rate


def _open_session(listen: Sequence[str], connect: Sequence[str], options: SessionOptions) -> zenoh.Session:
    """Open the Zenoh session.

    Raises:
        ConfigError: an endpoint is malformed or cannot be listened on (e.g. the port is in use).
    """
    try:
        return zenoh.open(session_config(listen, connect, options))
    except zenoh.ZError as exc:
        # Zenoh appends the Rust source location (" at /path/file.rs:N."): not useful to a user.
        reason = str(exc).split(" at /", 1)[0]
        raise ConfigError(
            f"cannot open a Zenoh session (listen {list(listen)}, connect {list(connect)}): {reason}"
        ) from None


def _declare_publishers(session: zenoh.Session, cell: str, robot: str, *, state: bool = True) -> _Publishers:
    return _Publishers(
        state=session.declare_publisher(
            keys.robot_state(cell, robot),
            express=True,
            priority=zenoh.Priority.REAL_TIME,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        if state
        else None,
        truth=session.declare_publisher(
            keys.truth_robot_state(cell, robot),
            express=True,
            congestion_control=zenoh.CongestionControl.DROP,
        ),
        stats=session.declare_publisher(keys.robot_emu_stats(cell, robot)),
    )


def run_controller(
    cell: str,
    robot: str,
    trajectory: Trajectory,
    config: ControllerConfig,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
    *,
    zenoh_options: SessionOptions,
    model: RobotModel,
    faces: Mapping[str, Any] | None = None,
) -> ControllerState:
    """Run the controller loop until ``stop`` is set. Returns the final state.

    With ``faces`` (kind → address, :data:`controller_emu.faces.FACES`) the overrides come only from those faces
    (see the module docstring); ``model`` is the robot's (the RTDE face reports its TCP from it).

    Raises:
        ConfigError: the Zenoh session cannot be opened with these endpoints, or a face cannot listen.
    """
    node = ControllerNode(robot, trajectory, config)
    override_key = keys.robot_override(cell, robot)
    faces = faces or {}
    vendor = bool(faces)
    with _open_session(listen, connect, zenoh_options) as session:
        subscriber = (  # the newest overrides only: a burst after a freeze keeps 16 samples, not 256 (bounded memory)
            None if vendor else declare_newest_wins(session, override_key, _callback(node), name="overrides")
        )
        publishers = _declare_publishers(session, cell, robot, state=not vendor)
        token = session.liveliness().declare_token(keys.alive(cell, f"controller-{robot}"))
        served = start_faces(FACES, faces, node, model)
        log.info(
            "controller %s of cell %r: program %.2f s per cycle, %.0f Hz; waiting for overrides on %s "
            "(protective stop until the first valid one)",
            robot,
            cell,
            trajectory.duration_s,
            1.0 / config.cycle_s,
            ", ".join(FACES[kind].describe(address) for kind, address in faces.items()) or override_key,
        )
        try:
            rate = _run_loop(node, publishers, stop, served)
        finally:
            for face in served:
                face.close()
            del token, subscriber  # undeclared when the session closes
    stats = node.stats()
    log.info(
        "controller %s stopped: %d program cycles completed, %d joint states published, %d missed cycles, "
        "rejected overrides: %s",
        robot,
        stats.cycles_completed,
        stats.joint_states,
        rate.missed_cycles,
        dict(stats.rejected) or "none",
    )
    return node.state


def _open_callback(node: OpenControllerNode) -> Callable[[zenoh.Sample], None]:
    """The joint command subscriber's callback: the payload and its arrival times to the node, nothing else."""

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            reason = node.on_command(sample.payload.to_bytes(), read_clocks())
        except Exception:  # a callback must never die: count it, the watchdog stops the robot
            log.exception("error while handling a joint command")
            node.count_rejected("internal_error")
            return
        if reason is not None:
            log.debug("joint command rejected: %s", reason)

    return on_sample


def _log_open_mode_change(change: ModeChange, state: FollowerState, watchdog_s: float) -> None:
    if change.after == "protective_stop":
        if change.silent_s is None:
            log.warning("protective stop: no valid joint command yet")
        else:
            log.warning(
                "protective stop: the last valid joint command is %.2f s old (watchdog %.2f s)",
                change.silent_s,
                watchdog_s,
            )
    else:
        log.info("running: following joint commands (seq %d)", state.command_seq)


def _open_stats_doc(robot: str, stats: OpenControllerStats, missed_cycles: int) -> bytes:
    """The ``emu_stats`` payload of an open controller: the closed one's fields; it runs no program (0 cycles)."""
    doc = {
        "robot": robot,
        "cycles_completed": 0,
        "mode": stats.mode,
        "override": 1.0 if stats.mode == "running" else 0.0,
        "rejected": dict(stats.rejected),
        "missed_cycles": missed_cycles,
    }
    return json.dumps(doc).encode()


def open_status_line(robot: str, stats: OpenControllerStats) -> str:
    """One line for the service manager (``STATUS=``): mode, last command, rejections."""
    rejected = sum(stats.rejected.values())
    return f"{robot} open {stats.mode} command_seq={stats.command_seq} rejected={rejected}"


def _run_open_loop(
    node: OpenControllerNode, publishers: _Publishers, stop: threading.Event, faces: Sequence[VendorFace] = ()
) -> RateLoop:
    """Cycle the open node at its rate until ``stop`` is set (each cycle's state to the EGM face, if any); stats every
    second, a progress line every 5 s."""
    freeze_startup_heap()
    rate = RateLoop(node.config.cycle_s)
    next_stats_s = time.monotonic() + STATS_EVERY_S
    next_progress_s = time.monotonic() + PROGRESS_EVERY_S
    service = LoopNotifier.from_environment()  # READY=1 after the first joint state, WATCHDOG=1, STATUS=
    while rate.sleep(stop):
        now = read_clocks()
        output = node.cycle(now)
        for face in faces:
            face.on_cycle(output)
        payload = to_payload(output.joint_state)
        if publishers.state is not None:
            publishers.state.put(payload)
        publishers.truth.put(payload)
        if output.mode_change is not None:
            _log_open_mode_change(output.mode_change, output.state, node.limits.watchdog_s)
        now_s = now.mono_ns / 1e9
        service.cycle_done(now_s, lambda: open_status_line(node.robot, node.stats()))
        if now_s >= next_stats_s:
            next_stats_s = now_s + STATS_EVERY_S
            publishers.stats.put(_open_stats_doc(node.robot, node.stats(), rate.missed_cycles))
        if now_s >= next_progress_s:
            next_progress_s = now_s + PROGRESS_EVERY_S
            stats = node.stats()
            log.info(
                "%s: open %s command_seq=%d accepted=%d rejected=%s missed_cycles=%d%s",
                node.robot,
                stats.mode,
                stats.command_seq,
                stats.commands_accepted,
                dict(stats.rejected),
                rate.missed_cycles,
                "".join(f" {text}" for text in (face.progress() for face in faces) if text),
            )
    service.stopping()
    return rate


def run_open_controller(
    cell: str,
    robot: str,
    limits: FollowerLimits,
    q0_rad: Sequence[float],
    config: ControllerConfig,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
    *,
    zenoh_options: SessionOptions,
    model: RobotModel,
    faces: Mapping[str, Any] | None = None,
) -> FollowerState:
    """Run an open controller loop until ``stop`` is set. Returns the final state.

    With ``faces`` (kind → address: an open controller's, e.g. EGM toward the PC's UDP address) the references come
    only from those faces (:mod:`controller_emu.egm_face`): no joint command subscription, nothing on the cell's
    state key (the bridge publishes the state it reads); the ground truth and the stats are published as always.

    Raises:
        ConfigError: the Zenoh session cannot be opened with these endpoints, or a face cannot be opened.
    """
    node = OpenControllerNode(robot, limits, q0_rad, config)
    command_key = keys.robot_joint_command(cell, robot)
    with _open_session(listen, connect, zenoh_options) as session:
        # the newest commands only: a burst after a freeze keeps 16 samples, not 256 (bounded memory)
        faces = faces or {}
        subscriber = (
            None if faces else declare_newest_wins(session, command_key, _open_callback(node), name="joint-commands")
        )
        publishers = _declare_publishers(session, cell, robot, state=not faces)
        token = session.liveliness().declare_token(keys.alive(cell, f"controller-{robot}"))
        served = start_faces(FACES, faces, node, model)
        log.info(
            "open controller %s of cell %r: %.0f Hz, acceleration bound %s rad/s², watchdog %.2f s; waiting for joint "
            "commands on %s (protective stop until the first valid one)",
            robot,
            cell,
            1.0 / config.cycle_s,
            [round(float(a), 3) for a in limits.accel_limit_radps2],
            limits.watchdog_s,
            ", ".join(FACES[kind].describe(address) for kind, address in faces.items()) or command_key,
        )
        try:
            rate = _run_open_loop(node, publishers, stop, served)
        finally:
            for face in served:
                face.close()
            del token, subscriber  # undeclared when the session closes
    stats = node.stats()
    log.info(
        "open controller %s stopped: %d joint commands accepted, %d joint states published, %d missed cycles, "
        "rejected joint commands: %s",
        robot,
        stats.commands_accepted,
        stats.joint_states,
        rate.missed_cycles,
        dict(stats.rejected) or "none",
    )
    return node.state


def main(
    config: CellConfig,
    robot: str | None,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
    *,
    zenoh_options: SessionOptions,
    faces: Mapping[str, Any] | None = None,
) -> int:
    """Load the robot and its program, then run the controller until ``stop`` is set.

    Args:
        config: the cell.
        robot: the robot to emulate; None for the cell's only robot.
        listen, connect: Zenoh endpoints; with neither, connect to :data:`DEFAULT_ENDPOINT`.
        stop: set to end the loop (SIGINT, SIGTERM, or a test).
        zenoh_options: mutual TLS and access control (``zenoh_session.options_from_args``).
        faces: the vendor faces to serve, kind → address (:data:`controller_emu.faces.FACES`: UR RTDE and ABB RWS
            for a closed controller, their overrides only from the speed slider or ratio; ABB EGM for an open one,
            its references only from the PC's ``EgmSensor`` replies, EGM's position mode on silence).

    Returns:
        The process exit code (0).

    An open controller (``controller.control = "open"``) is run by :func:`run_open_controller`, standing at the
    program's first waypoint.

    Raises:
        ConfigError: unknown robot, invalid robot model or program, unsafe braking time, unusable
            Zenoh endpoints, a face of the other kind of controller.
    """
    faces = faces or {}
    name = select_robot(config, robot)
    robot_config = config.robots[name]
    model = load_robot_model(name, robot_config)
    control = robot_config.controller.control
    _check_faces_serve(name, control, faces)
    if not listen and not connect:
        connect = [DEFAULT_ENDPOINT]
    if control == "open":
        q0_rad, _ = load_trajectory(robot_config.program, model).sample(0.0)  # where the closed one starts
        face_silence = [FACES[kind].on_silence for kind in faces]  # one face at most (_check_faces_serve)
        on_silence = face_silence[0] if face_silence and face_silence[0] is not None else "keep_speed"
        run_open_controller(
            config.cell,
            name,
            follower_limits(
                model,
                robot_config.controller.watchdog_s,
                stop_time_s=robot_config.controller.braking_time_s,
                on_silence=on_silence,
            ),
            q0_rad.tolist(),
            robot_config.controller,
            listen,
            connect,
            stop,
            zenoh_options=zenoh_options,
            model=model,
            faces=faces,
        )
        return 0
    check_braking_time(robot_config.controller, model)
    trajectory = load_trajectory(robot_config.program, model)
    run_controller(
        config.cell,
        name,
        trajectory,
        robot_config.controller,
        listen,
        connect,
        stop,
        zenoh_options=zenoh_options,
        model=model,
        faces=faces,
    )
    return 0


def _a(control: str) -> str:
    """``a closed`` / ``an open``."""
    return f"an {control}" if control[:1] in "aeiou" else f"a {control}"


def _check_faces_serve(robot: str, control: str, faces: Mapping[str, Any]) -> None:
    """Every face asked for belongs to the robot's kind of controller, and an open one serves one face at most.

    Raises:
        ConfigError: a face of the other kind, or two open faces.
    """
    wrong = [FACES[kind] for kind in faces if FACES[kind].control != control]
    if wrong:
        fitting = [f.option for f in FACES.values() if f.control == control]
        raise ConfigError(
            f"robot {robot!r} has {_a(control)} controller (control = {control!r}): {wrong[0].option} serves "
            f"{_a(wrong[0].control)} one; allowed with control = {control!r}: {', '.join(fitting) or 'none'}"
        )
    if control == "open" and len(faces) > 1:
        raise ConfigError(f"robot {robot!r}: an open controller follows one face; got {', '.join(faces)}")


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Emulated robot controller: closed (a program, speed override δ) or open (follows joint commands)",
    )
    add_config_argument(parser)
    parser.add_argument("--robot", default=None, metavar="NAME", help="robot of the cell (default: its only robot)")
    for face in FACES.values():
        parser.add_argument(face.option, default=None, metavar=face.metavar, help=face.help)
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)

    def body(stop: StopEvent) -> int:
        config = load_cell_config(args.config)
        # the command line is checked before anything is created (a first run makes the cell's CA)
        faces = {
            kind: face.address(text)
            for kind, face in FACES.items()
            if (text := getattr(args, face.option.lstrip("-").replace("-", "_"))) is not None
        }
        zenoh_options = options_from_args(args, f"controller-{select_robot(config, args.robot)}", config)
        return main(
            config, args.robot, args.zenoh_listen, args.zenoh_connect, stop, zenoh_options=zenoh_options, faces=faces
        )

    run_program(PROG, args.log_level, body, log=log)


if __name__ == "__main__":
    cli()
