"""The controller bridge process: Zenoh, clocks, threads and logging around :class:`controller_bridge.bridge.Bridge`.

    override payload → bridge.on_override(payload, read_clocks())    (the override intake thread; wakes the writer)
    writer loop (write_rate_hz, and at once on an override): bridge.next_write(now) → interface.write_speed_fraction
    reader thread: interface.read(timeout) → bridge.on_reading(reading) → publish the joint state

The writer writes what the core hands out, and the core decides when (stop-and-wait, ``controller_bridge/bridge.py``):
a value lower than the last written at once, on the wake of the override that asks for it; any other new value once
the previous write has been read back (on the next wake: an override, at the gateway's rate, or the heartbeat); while
a write awaits its read-back, the heartbeat repeats the last written value.

The vendor interface is the cell file's ``interface`` of ``--robot NAME`` (``ur_rtde`` or ``abb_rws``; a robot whose
interface is ``zenoh`` needs no bridge). An open controller's interface (``abb_egm``: joint references in, joint
feedback out) is run by :mod:`controller_bridge.open_shell` around :class:`controller_bridge.open_bridge.OpenBridge`
instead: the gateway's joint commands in, the controller's joint state out. The reader connects, and reconnects
with a doubling backoff (:data:`BACKOFF_MIN_S` … :data:`BACKOFF_MAX_S`) when the connection fails or no valid reading
came for ``read_timeout_s``; meanwhile nothing is published, and the gateway's staleness check stops the robot.

Overrides arrive through a ring of the newest 16 (:mod:`hrc_runtime.newest_wins`): after a freeze the bridge hands on
the newest, not 256 queued ones, and its memory stays bounded.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from controller_bridge.bridge import Bridge, BridgeSettings, BridgeStats, FloatArray, Locate
from controller_bridge.open_bridge import OpenBridge, OpenBridgeSettings
from controller_bridge.open_shell import run_open_bridge
from controller_bridge.program_model import load_model
from controller_bridge.shell import (
    BACKOFF_MAX_S,
    BACKOFF_MIN_S,
    PROGRESS_EVERY_S,
    STATS_EVERY_S,
    BridgeIo,
    open_bridge_io,
    open_session,
    start_reader,
)
from hrc_contract import keys
from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.messages import JointState, to_payload
from hrc_devices.controllers.descriptor import BridgedConfig, OpenBridgedConfig, OpenVendor, Vendor
from hrc_devices.controllers.registry import OPEN_VENDORS, VENDORS
from hrc_devices.controllers.vendor import VendorError, VendorInterface
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments, run_program
from hrc_runtime.clocks import read_clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.rate_loop import RateLoop
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import DEFAULT_ENDPOINT, SessionOptions, options_from_args

PROG = "hrc-controller-bridge"

log = logging.getLogger(PROG)

VELOCITY_WINDOW_CYCLES = 2
"""An open controller's q is differenced over at least this many of its cycles of its own time
(:mod:`controller_bridge.open_bridge`, "Velocities")."""
RECONNECT_ON = frozenset({"connect", "closed", "auth", "refused"})
"""VendorError reasons after which the connection is closed and opened again (others: the next read may do)."""


def _bridged(kind: str) -> bool:
    return kind in VENDORS or kind in OPEN_VENDORS


def select_robot(config: CellConfig, robot: str | None) -> str:
    """The robot to bridge: the given name, or the cell's only robot whose interface is a bridge (a closed
    controller's speed input or an open controller's joint references).

    Raises:
        ConfigError: unknown name; no name and not exactly one bridged robot; a robot on the ``zenoh`` interface.
    """
    bridged = sorted(name for name, r in config.robots.items() if _bridged(r.interface.kind))
    kinds = " or ".join(sorted([*VENDORS, *OPEN_VENDORS]))
    if robot is None:
        if len(bridged) == 1:
            return bridged[0]
        raise ConfigError(
            f"cell {config.cell!r} has {len(bridged)} robots with a bridged interface; allowed: --robot with one of "
            f"{', '.join(bridged) or f'(none: set [robots.<name>.interface] kind = {kinds})'}"
        )
    if robot not in config.robots:
        raise ConfigError(f"unknown robot {robot!r}; allowed: {', '.join(sorted(config.robots))}")
    if not _bridged(config.robots[robot].interface.kind):
        raise ConfigError(
            f"robot {robot!r} has interface kind {config.robots[robot].interface.kind!r} (its controller speaks the "
            f"cell's contract itself: no bridge); allowed: a robot with kind {kinds}: "
            f"{', '.join(bridged) or 'none in this cell'}"
        )
    return robot


def open_vendor_of(name: str, interface: object) -> tuple[OpenVendor[Any], OpenBridgedConfig] | None:
    """The registered open vendor of robot ``name``'s interface and the interface, or None for any other kind."""
    kind = getattr(interface, "kind", None)
    vendor = OPEN_VENDORS.get(kind) if isinstance(kind, str) else None
    if vendor is None or not isinstance(interface, vendor.config) or not isinstance(interface, OpenBridgedConfig):
        return None
    return vendor, interface


def open_bridge_settings(config: CellConfig, name: str, model: RobotModel) -> OpenBridgeSettings:
    """The open core's settings for robot ``name`` of the cell.

    Raises:
        ConfigError: the robot's interface is not an open controller's.
    """
    found = open_vendor_of(name, config.robots[name].interface)
    if found is None:
        raise ConfigError(f"robot {name!r}: interface {config.robots[name].interface.kind!r} is not an open one")
    _, interface = found
    cycle_s = config.robots[name].controller.cycle_s
    return OpenBridgeSettings(
        robot=name,
        n_joints=model.n_joints,
        watchdog_s=interface.watchdog_s,
        extrapolate_s=interface.extrapolate_s,
        cycle_s=cycle_s,
        velocity_window_s=VELOCITY_WINDOW_CYCLES * cycle_s,
        max_diff_gap_s=interface.read_timeout_s,
    )


def braking_time_of(model: RobotModel) -> float:
    """The smallest braking time the gateway plans with for a moving link [s] (t_b of the program model's
    envelope)."""
    moving = model.t_brake_link_s[model.t_brake_link_s > 0.0]
    return float(moving.min()) if moving.size else float(model.braking_time_s.max())


def bridge_settings(config: CellConfig, name: str, model: RobotModel) -> BridgeSettings:
    """The core's settings for robot ``name`` of the cell."""
    vendor, interface = vendor_of(name, config.robots[name].interface)
    return BridgeSettings(
        robot=name,
        speed_input=vendor.speed_input,
        velocity_limit_radps=tuple(float(v) for v in model.velocity_limit_radps),
        braking_time_s=braking_time_of(model),
        watchdog_s=interface.watchdog_s,
        heartbeat_s=1.0 / interface.write_rate_hz,
        min_scaling=max(config.streams.qd_tolerance_ratio, 1e-3),
        max_diff_gap_s=interface.read_timeout_s,
        rise_time_s=interface.rise_time_s,
        sample_jitter_s=vendor.sample_jitter_s(interface),
    )


def vendor_of(name: str, interface: object) -> tuple[Vendor[Any], BridgedConfig]:
    """The registered vendor of robot ``name``'s interface, and the interface.

    Raises:
        ConfigError: its kind is reached without a bridge (``zenoh``).
    """
    kind = getattr(interface, "kind", None)
    vendor = VENDORS.get(kind) if isinstance(kind, str) else None
    if vendor is None or not isinstance(interface, vendor.config) or not isinstance(interface, BridgedConfig):
        raise ConfigError(f"robot {name!r}: interface {kind!r} needs no bridge")
    return vendor, interface


def make_interface(interface: Any, n_joints: int, environ: Mapping[str, str] | None = None) -> VendorInterface:
    """The vendor interface the cell file asks for (not yet connected).

    Raises:
        ConfigError: not a bridged interface, the password variable is unset, or the URL is not served.
    """
    vendor = VENDORS.get(getattr(interface, "kind", ""))
    if vendor is None:
        raise ConfigError(f"interface {getattr(interface, 'kind', None)!r} needs no bridge")
    return vendor.interface(interface, n_joints, os.environ if environ is None else environ)


def model_locator(path: Path, robot: str, joint_names: Sequence[str]) -> Locate:
    """``locate`` of the recorded program model at ``path`` (it follows the robot along the program).

    Raises:
        ConfigError: the file is not a program model of this robot.
    """
    model = load_model(path, robot, list(joint_names))
    previous: list[int | None] = [None]

    def locate(q_rad: FloatArray, qd_radps: FloatArray) -> FloatArray | None:
        where = model.locate(q_rad, previous[0], qd_radps)
        previous[0] = None if where is None else where.index
        return None if where is None else np.asarray(where.qd_nominal_radps, dtype=float)

    log.info("program model %s: %s", path, model.summary())
    return locate


def _stats_doc(robot: str, kind: str, stats: BridgeStats, readings_per_s: float, latency_max_s: float | None) -> bytes:
    """The bridge's statistics payload (``hrc/<cell>/robot/<robot>/bridge_stats``)."""
    doc = {
        "robot": robot,
        "interface": kind,
        "mode": stats.mode,
        "override": stats.last_applied,
        "override_seq": stats.override_seq,
        "readback": stats.last_readback,
        "readback_latency_s": stats.readback_latency_s,
        "readback_latency_max_s": latency_max_s,
        "readings_per_s": round(readings_per_s, 1),
        "published": stats.published,
        "writes": stats.writes,
        "writes_awaiting_readback": stats.awaiting,
        "writes_dithered": stats.dithered,
        "writes_unprovable": stats.unprovable,
        "watchdog_expired": stats.watchdog_expired,
        "qd_nominal_sources": dict(stats.qd_nominal_sources),
        "rejected": dict(stats.rejected),
        "overrides_rejected": dict(stats.overrides_rejected),
    }
    return json.dumps(doc).encode()


def service_status_line(robot: str, kind: str, stats: BridgeStats) -> str:
    readback = "-" if stats.last_readback is None else f"{stats.last_readback:.2f}"
    return f"{robot} {kind} {stats.mode or 'no reading'} readback={readback} rejected={sum(stats.rejected.values())}"


class _Reader:
    """The reader thread: connect (with backoff), read, compose, publish; reconnect when the link fails."""

    def __init__(
        self,
        bridge: Bridge,
        interface: VendorInterface,
        publish: Callable[[JointState], None],
        stop: threading.Event,
        poll_interval_s: float = 0.0,
    ) -> None:
        self.bridge = bridge
        self.poll_interval_s = poll_interval_s
        """Readings at most this often [s] (a polled interface, ABB's ``poll_rate_hz``; 0: as they stream)."""
        self.interface = interface
        self.publish = publish
        self.stop = stop
        self.connected = threading.Event()
        self.read_timeout_s = bridge.settings.max_diff_gap_s
        self.thread = threading.Thread(target=self._run, name="bridge-reader", daemon=True)

    def _run(self) -> None:
        backoff_s = BACKOFF_MIN_S
        while not self.stop.is_set():
            try:
                self.interface.connect()
            except VendorError as exc:
                self.bridge.count_rejected(exc.reason)
                log.warning(
                    "%s: cannot connect (%s): %s; retry in %.1f s", self.interface.kind, exc.reason, exc, backoff_s
                )
                self.stop.wait(backoff_s)
                backoff_s = min(2 * backoff_s, BACKOFF_MAX_S)
                continue
            log.info("%s: connected", self.interface.kind)
            self.connected.set()
            try:
                if self._read_until_failure():
                    backoff_s = BACKOFF_MIN_S
            finally:
                self.connected.clear()
                self.interface.close()
            if not self.stop.is_set():
                self.stop.wait(backoff_s)
                backoff_s = min(2 * backoff_s, BACKOFF_MAX_S)

    def _read_until_failure(self) -> bool:
        """Read until stopped or the link fails. Returns whether any joint state was published."""
        published = False
        started_ns = time.monotonic_ns()
        next_read_s = time.monotonic()
        while not self.stop.is_set():
            if self.poll_interval_s > 0.0:  # a polled controller: q is differentiated over this interval, not less
                self.stop.wait(max(0.0, next_read_s - time.monotonic()))
                # From this read's start, never from the schedule: after a late read (this thread held off the CPU)
                # a catch-up read a few milliseconds later would difference q over less than the controller's cycle
                # and the request's jitter, and the velocity could come out above the joint's limit.
                next_read_s = time.monotonic() + self.poll_interval_s
            try:
                state = self.bridge.on_reading(self.interface.read(self.read_timeout_s))
            except VendorError as exc:
                self.bridge.count_rejected(exc.reason)
                if exc.reason in RECONNECT_ON:
                    log.warning("%s: %s (%s): not publishing; reconnecting", self.interface.kind, exc, exc.reason)
                    return published
                state = None
            except Exception:  # a bug must not kill the thread silently: count it, reconnect
                log.exception("error while reading the controller")
                self.bridge.count_rejected("internal_error")
                return published
            if state is not None:
                self.publish(state)
                published = True
                continue
            now_ns = time.monotonic_ns()
            silence_s = self.bridge.silence_s(now_ns)
            silent_s = (now_ns - started_ns) / 1e9 if silence_s is None else silence_s
            if silent_s > self.read_timeout_s:
                log.warning(
                    "%s: no valid reading for %.3f s (limit %.3f s): not publishing; reconnecting (rejected: %s)",
                    self.interface.kind,
                    silent_s,
                    self.read_timeout_s,
                    dict(self.bridge.stats().rejected),
                )
                return published
        return published


def _write_loop(
    bridge: Bridge,
    interface: VendorInterface,
    reader: _Reader,
    stop: StopEvent,
    wake: threading.Event,
    on_cycle: Callable[[float], None],
) -> None:
    """Write the speed input at the heartbeat rate and at once on a new override, until ``stop``."""
    rate = RateLoop(bridge.settings.heartbeat_s)
    expired = False
    while rate.sleep(stop, wake):
        now = read_clocks()
        value = bridge.next_write(now)
        stats_expired = bridge.stats().watchdog_expired
        if stats_expired != expired:
            expired = stats_expired
            if expired:
                log.warning("no valid override for %.2f s: writing 0", bridge.settings.watchdog_s)
            else:
                log.info("valid overrides again")
        if value is not None and reader.connected.is_set():
            try:
                written = interface.write_speed_fraction(value)
            except VendorError as exc:
                bridge.count_rejected(f"write_{exc.reason}")
            else:
                bridge.on_written(written, read_clocks())
        on_cycle(now.mono_ns / 1e9)


def run_bridge(
    cell: str,
    bridge: Bridge,
    interface: VendorInterface,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: StopEvent,
    *,
    zenoh_options: SessionOptions,
    poll_interval_s: float = 0.0,
) -> BridgeStats:
    """Run the bridge until ``stop`` is set. Returns the final statistics. A shell: its resources
    (:mod:`controller_bridge.shell`, closed in reverse order whatever happens) and the write loop.

    Raises:
        ConfigError: the Zenoh session cannot be opened with these endpoints.
    """
    robot, kind = bridge.settings.robot, interface.kind
    wake = stop.wake_event()
    with ExitStack() as resources:
        session = open_session(resources, listen, connect, zenoh_options)
        io = open_bridge_io(
            resources,
            cell,
            robot,
            session,
            keys.robot_override(cell, robot),
            lambda payload: bridge.on_override(payload, read_clocks()),
            bridge.count_override_rejected,
            inbound_name="overrides",
            on_accepted=wake.set,
        )
        reader = _Reader(bridge, interface, lambda state: io.state_pub.put(to_payload(state)), stop, poll_interval_s)
        log.info(
            "bridge %s of cell %r via %s: overrides from %s, joint states on %s",
            robot,
            cell,
            kind,
            keys.robot_override(cell, robot),
            keys.robot_state(cell, robot),
        )
        start_reader(resources, reader.thread, stop, io.service)
        _write_loop(bridge, interface, reader, stop, wake, _Reports(bridge, kind, io))
    stats = bridge.stats()
    log.info(
        "bridge %s stopped: %d readings, %d joint states published, %d writes, rejected %s, overrides rejected %s",
        robot,
        stats.readings,
        stats.published,
        stats.writes,
        dict(stats.rejected) or "none",
        dict(stats.overrides_rejected) or "none",
    )
    return stats


class _Reports:
    """Once per write-loop cycle: the service manager's watchdog; the statistics every :data:`STATS_EVERY_S`, the
    progress line every :data:`PROGRESS_EVERY_S`."""

    def __init__(self, bridge: Bridge, kind: str, io: BridgeIo) -> None:
        self.bridge, self.kind, self.io = bridge, kind, io
        now_s = time.monotonic()
        self.next_stats_s, self.next_progress_s = now_s + STATS_EVERY_S, now_s + PROGRESS_EVERY_S
        self.last_readings = (0, now_s)

    def __call__(self, now_s: float) -> None:
        robot, kind, stats = self.bridge.settings.robot, self.kind, self.bridge.stats()
        self.io.service.cycle_done(now_s, lambda: service_status_line(robot, kind, stats), ready=stats.published > 0)
        if now_s >= self.next_stats_s:
            self.next_stats_s = now_s + STATS_EVERY_S
            rate = (stats.readings - self.last_readings[0]) / max(now_s - self.last_readings[1], 1e-9)
            self.last_readings = (stats.readings, now_s)
            self.io.stats_pub.put(_stats_doc(robot, kind, stats, rate, self.bridge.take_latency_max()))
        if now_s >= self.next_progress_s:
            self.next_progress_s = now_s + PROGRESS_EVERY_S
            log.info(
                "%s via %s: %s override=%s readback=%s override_seq=%d latency=%s published=%d writes=%d "
                "(dithered %d, unprovable %d) rejected=%s overrides_rejected=%s",
                robot,
                kind,
                stats.mode,
                stats.last_applied,
                stats.last_readback,
                stats.override_seq,
                stats.readback_latency_s,
                stats.published,
                stats.writes,
                stats.dithered,
                stats.unprovable,
                dict(stats.rejected),
                dict(stats.overrides_rejected),
            )


def main(
    config: CellConfig,
    robot: str | None,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: StopEvent,
    *,
    zenoh_options: SessionOptions,
    program_model: Path | None = None,
) -> int:
    """Load the robot, build the bridge and its vendor interface, run until ``stop`` is set.

    Raises:
        ConfigError: unknown robot or one without a bridged interface, invalid robot model or program model, a
            missing password variable, unusable Zenoh endpoints.
    """
    name = select_robot(config, robot)
    robot_config = config.robots[name]
    model = load_robot_model(name, robot_config)
    if not listen and not connect:
        connect = [DEFAULT_ENDPOINT]
    found_open = open_vendor_of(name, robot_config.interface)
    if found_open is not None:
        if program_model is not None:
            raise ConfigError(
                f"robot {name!r} has an open controller ({robot_config.interface.kind}): the gateway runs its program, "
                "so --program-model has nothing to locate; allowed: without it"
            )
        open_vendor, open_interface = found_open
        run_open_bridge(
            config.cell,
            OpenBridge(open_bridge_settings(config, name, model)),
            open_vendor.interface(open_interface, model.n_joints),
            listen,
            connect,
            stop,
            zenoh_options=zenoh_options,
            read_timeout_s=open_interface.read_timeout_s,
        )
        return 0
    settings = bridge_settings(config, name, model)
    locate = None if program_model is None else model_locator(program_model, name, model.joint_names)
    interface_config = robot_config.interface
    vendor, _ = vendor_of(name, interface_config)
    interface = make_interface(interface_config, model.n_joints)
    poll_s = vendor.poll_interval_s(interface_config)
    run_bridge(
        config.cell,
        Bridge(settings, locate),
        interface,
        listen,
        connect,
        stop,
        zenoh_options=zenoh_options,
        poll_interval_s=poll_s,
    )
    return 0


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Controller bridge: the cell's Zenoh contract to a real controller (UR RTDE, ABB RWS; ABB EGM for "
        "an open one)",
    )
    add_config_argument(parser)
    parser.add_argument(
        "--robot", default=None, metavar="NAME", help="robot of the cell (default: its only bridged one)"
    )
    parser.add_argument(
        "--program-model", type=Path, default=None, metavar="PATH", help="recorded program model (qd_nominal source 1)"
    )
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)

    def body(stop: StopEvent) -> int:
        config = load_cell_config(args.config)
        zenoh_options = options_from_args(args, f"controller-{select_robot(config, args.robot)}", config)
        return main(
            config,
            args.robot,
            args.zenoh_listen,
            args.zenoh_connect,
            stop,
            zenoh_options=zenoh_options,
            program_model=args.program_model,
        )

    run_program(PROG, args.log_level, body, log=log)


if __name__ == "__main__":
    cli()
