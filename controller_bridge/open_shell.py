"""The open controller bridge's process shell: Zenoh, clocks and threads around
:class:`controller_bridge.open_bridge.OpenBridge` (an open controller's vendor: ABB EGM).

    joint command payload → bridge.on_command(payload, read_clocks())        (the subscriber's thread)
    reader thread: feedback = interface.read(timeout)                          (the controller speaks first)
                   reference = bridge.reference(now) → interface.send_reference → bridge.on_sent
                   state = bridge.on_feedback(feedback) → publish on the cell's joint state key
    main thread:   statistics every second, the progress line every 5 s, the service manager's watchdog

The reference is sent before the joint state is composed and published: EGM's controller waits for the answer
within its cycle. The reader opens the vendor's socket, and opens it again with a doubling backoff
(:data:`controller_bridge.shell.BACKOFF_MIN_S` … ``BACKOFF_MAX_S``) when it fails or no valid feedback came for
``read_timeout_s``; meanwhile nothing is published and the gateway's staleness check stops the robot.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack

import zenoh

from controller_bridge.open_bridge import OpenBridge, OpenBridgeStats
from controller_bridge.shell import (
    BACKOFF_MAX_S,
    BACKOFF_MIN_S,
    PROGRESS_EVERY_S,
    STATS_EVERY_S,
    open_bridge_io,
    open_session,
    start_reader,
)
from hrc_contract import keys
from hrc_contract.messages import JointState, to_payload
from hrc_devices.controllers.vendor import OpenVendorInterface, VendorError
from hrc_runtime.clocks import read_clocks
from hrc_runtime.sd_notify import LoopNotifier
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import SessionOptions

log = logging.getLogger("hrc-controller-bridge")

LOOP_S = 0.1
"""The main thread's loop: the service manager's watchdog and the statistics' schedule [s]."""
RECONNECT_ON = frozenset({"connect", "closed"})
"""VendorError reasons after which the socket is closed and opened again (a timeout: the next read may do)."""


def stats_doc(
    robot: str, kind: str, stats: OpenBridgeStats, readings_per_s: float, refused: Mapping[str, int]
) -> bytes:
    """The bridge's statistics payload (``hrc/<cell>/robot/<robot>/bridge_stats``; the gateway shows ``interface``,
    ``mode``, ``readings_per_s`` and the count of ``rejected``, which includes the interface's skipped datagrams
    as ``datagram_<reason>``; an open controller has no speed read-back)."""
    doc = {
        "robot": robot,
        "interface": kind,
        "control": "open",
        "mode": stats.mode,
        "readback": None,
        "readings_per_s": round(readings_per_s, 1),
        "command_seq": stats.command_seq,
        "echo_seq": stats.echo_seq,
        "echo_unproven": stats.echo_unproven,
        "commands_accepted": stats.commands_accepted,
        "published": stats.published,
        "references": dict(stats.references),
        "command_age_max_s": stats.command_age_max_s,
        "qd_sources": dict(stats.qd_sources),
        "watchdog_expired": stats.watchdog_expired,
        "rejected": {**stats.rejected, **{f"datagram_{reason}": n for reason, n in refused.items()}},
        "commands_rejected": dict(stats.commands_rejected),
    }
    return json.dumps(doc).encode()


class OpenReader:
    """The reader thread: open (with backoff), read, answer, compose, publish; open again when the link fails."""

    def __init__(
        self,
        bridge: OpenBridge,
        interface: OpenVendorInterface,
        publish: Callable[[JointState], None],
        stop: threading.Event,
        read_timeout_s: float,
    ) -> None:
        self.bridge = bridge
        self.interface = interface
        self.publish = publish
        self.stop = stop
        self.read_timeout_s = read_timeout_s
        self.thread = threading.Thread(target=self._run, name="open-bridge-reader", daemon=True)

    def _run(self) -> None:
        backoff_s = BACKOFF_MIN_S
        while not self.stop.is_set():
            try:
                self.interface.connect()
            except VendorError as exc:
                self.bridge.count_rejected(exc.reason)
                kind = self.interface.kind
                log.warning("%s: cannot open (%s): %s; retry in %.1f s", kind, exc.reason, exc, backoff_s)
                self.stop.wait(backoff_s)
                backoff_s = min(2 * backoff_s, BACKOFF_MAX_S)
                continue
            log.info("%s: listening for the controller", self.interface.kind)
            try:
                if self._exchange_until_failure():
                    backoff_s = BACKOFF_MIN_S
            finally:
                self.interface.close()
            if not self.stop.is_set():
                self.stop.wait(backoff_s)
                backoff_s = min(2 * backoff_s, BACKOFF_MAX_S)

    def _exchange_until_failure(self) -> bool:
        """Answer and publish until stopped or the link fails. Returns whether any joint state was published."""
        published = False
        last_valid_s = time.monotonic()
        while not self.stop.is_set():
            try:
                feedback = self.interface.read(self.read_timeout_s)
            except VendorError as exc:
                self.bridge.count_rejected(exc.reason)
                if exc.reason in RECONNECT_ON or time.monotonic() - last_valid_s > self.read_timeout_s:
                    log.warning("%s: %s (%s): not publishing; opening again", self.interface.kind, exc, exc.reason)
                    return published
                continue
            except Exception:  # a bug must not kill the thread silently: count it, open again
                log.exception("error while reading the controller")
                self.bridge.count_rejected("internal_error")
                return published
            last_valid_s = time.monotonic()
            try:
                reference = self.bridge.reference(read_clocks())
                if reference is not None:
                    try:
                        self.interface.send_reference(reference.q_rad, reference.qd_radps)
                    except VendorError as exc:
                        self.bridge.count_rejected(f"send_{exc.reason}")
                    else:
                        self.bridge.on_sent(reference, read_clocks())
                state = self.bridge.on_feedback(feedback)
            except Exception:
                log.exception("error while answering the controller")
                self.bridge.count_rejected("internal_error")
                return published
            if state is not None:
                self.publish(state)
                published = True
        return published


def _report_until_stopped(
    bridge: OpenBridge,
    interface: OpenVendorInterface,
    stats_pub: zenoh.Publisher,
    service: LoopNotifier,
    stop: StopEvent,
) -> None:
    """The main thread until ``stop``: the service manager's watchdog, the statistics and the progress line."""
    robot, kind = bridge.settings.robot, interface.kind
    last = (0, time.monotonic())
    next_stats_s = time.monotonic() + STATS_EVERY_S
    next_progress_s = time.monotonic() + PROGRESS_EVERY_S
    expired = True
    rate = 0.0
    while not stop.wait(LOOP_S):
        now_s = time.monotonic()
        stats = bridge.stats()
        line = f"{robot} {kind} {stats.mode}"
        service.cycle_done(now_s, line.__str__, ready=stats.published > 0)
        if now_s < next_stats_s:
            continue
        next_stats_s = now_s + STATS_EVERY_S
        rate = (stats.feedbacks - last[0]) / max(now_s - last[1], 1e-9)
        last = (stats.feedbacks, now_s)
        stats_pub.put(stats_doc(robot, kind, stats, rate, interface.refused))
        if stats.watchdog_expired != expired:
            expired = stats.watchdog_expired
            if expired:
                log.warning("no valid joint command within the watchdog: holding the last reference")
            else:
                log.info("valid joint commands again")
        if now_s >= next_progress_s:
            next_progress_s = now_s + PROGRESS_EVERY_S
            log.info(
                "%s via %s: %s command_seq=%d echo_seq=%d feedbacks=%d (%.0f/s) published=%d references=%s "
                "command_age_max_s=%s rejected=%s datagrams_refused=%s commands_rejected=%s",
                robot,
                kind,
                stats.mode,
                stats.command_seq,
                stats.echo_seq,
                stats.feedbacks,
                rate,
                stats.published,
                dict(stats.references),
                None if stats.command_age_max_s is None else round(stats.command_age_max_s, 4),
                dict(stats.rejected),
                dict(interface.refused),
                dict(stats.commands_rejected),
            )


def run_open_bridge(
    cell: str,
    bridge: OpenBridge,
    interface: OpenVendorInterface,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: StopEvent,
    *,
    zenoh_options: SessionOptions,
    read_timeout_s: float,
) -> OpenBridgeStats:
    """Run the open bridge until ``stop`` is set. Returns the final statistics.

    Raises:
        ConfigError: the Zenoh session cannot be opened with these endpoints.
    """
    robot, kind = bridge.settings.robot, interface.kind
    command_key = keys.robot_joint_command(cell, robot)
    with ExitStack() as resources:
        session = open_session(resources, listen, connect, zenoh_options)
        io = open_bridge_io(
            resources,
            cell,
            robot,
            session,
            command_key,
            lambda payload: bridge.on_command(payload, read_clocks()),
            bridge.count_command_rejected,  # the bridge holds the last reference
            inbound_name="joint-commands",
        )
        reader = OpenReader(bridge, interface, lambda state: io.state_pub.put(to_payload(state)), stop, read_timeout_s)
        log.info(
            "open bridge %s of cell %r via %s: joint commands from %s, joint states on %s",
            robot,
            cell,
            kind,
            command_key,
            keys.robot_state(cell, robot),
        )
        start_reader(resources, reader.thread, stop, io.service)
        _report_until_stopped(bridge, interface, io.stats_pub, io.service, stop)
    stats = bridge.stats()
    log.info(
        "open bridge %s stopped: %d feedbacks, %d joint states published, references %s, rejected %s, joint "
        "commands rejected %s",
        robot,
        stats.feedbacks,
        stats.published,
        dict(stats.references),
        dict(stats.rejected) or "none",
        dict(stats.commands_rejected) or "none",
    )
    return stats
