"""What both bridge shells open (a closed controller's, :func:`controller_bridge.main.run_bridge`, and an open one's,
:func:`controller_bridge.open_shell.run_open_bridge`): the Zenoh session, the joint state and statistics publishers,
the gateway's messages in through a ring of the newest (:mod:`hrc_runtime.newest_wins`), the liveliness token, the
service manager's notifier, and the reader thread. Each is put on an :class:`contextlib.ExitStack` and closed in
reverse order, also when a later one fails to open: a shell is these resources plus its loop.

On the way out: the service manager hears "stopping", the stop event is set (the reader ends), the reader is joined
(a bounded wait), then the subscription and the token go, then the session.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from typing import Any, NamedTuple

import zenoh

from hrc_contract import keys
from hrc_contract.config import ConfigError
from hrc_runtime.newest_wins import declare_newest_wins
from hrc_runtime.sd_notify import LoopNotifier
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import SessionOptions, session_config

log = logging.getLogger("hrc-controller-bridge")

STATS_EVERY_S = 1.0
"""The statistics on the cell's ``bridge_stats`` key, this often [s]."""
PROGRESS_EVERY_S = 5.0
"""The progress line in the log, this often [s]."""
BACKOFF_MIN_S = 0.1
BACKOFF_MAX_S = 2.0
"""Reconnection attempts start this far apart and double up to BACKOFF_MAX_S [s]."""
READER_JOIN_S = 2.0
"""How long the shell waits for its reader thread on the way out [s] (a read times out sooner)."""


class BridgeIo(NamedTuple):
    """The publishers and the notifier a shell's loop and reader use."""

    state_pub: Any
    """The cell's joint state key of the robot (express, real-time priority, dropped rather than queued)."""
    stats_pub: Any
    """The robot's ``bridge_stats`` key."""
    service: LoopNotifier


def open_session(resources: ExitStack, listen: Sequence[str], connect: Sequence[str], options: SessionOptions) -> Any:
    """A Zenoh session on ``resources``.

    Raises:
        ConfigError: it cannot be opened with these endpoints (one line, the library's reason).
    """
    try:
        session = zenoh.open(session_config(list(listen), list(connect), options))
    except zenoh.ZError as exc:
        reason = str(exc).split(" at /", 1)[0]
        raise ConfigError(
            f"cannot open a Zenoh session (listen {list(listen)}, connect {list(connect)}): {reason}"
        ) from None
    return resources.enter_context(session)


def open_bridge_io(
    resources: ExitStack,
    cell: str,
    robot: str,
    session: Any,
    inbound_key: str,
    on_payload: Callable[[bytes], str | None],
    count_error: Callable[[str], None],
    *,
    inbound_name: str,
    on_accepted: Callable[[], None] | None = None,
) -> BridgeIo:
    """The joint state and statistics publishers, the subscription to ``inbound_key`` and the liveliness token, on
    ``resources``.

    Each payload on ``inbound_key`` goes to ``on_payload`` (the bridge core's check: None if accepted, else the
    reason, counted by the core), then ``on_accepted`` if accepted. A callback never dies: an exception in it is
    logged and counted as ``internal_error`` by ``count_error``; the bridge's watchdog then does what silence does.
    """
    state_pub = session.declare_publisher(
        keys.robot_state(cell, robot),
        express=True,
        priority=zenoh.Priority.REAL_TIME,
        congestion_control=zenoh.CongestionControl.DROP,
    )
    stats_pub = session.declare_publisher(keys.robot_bridge_stats(cell, robot))

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            reason = on_payload(sample.payload.to_bytes())
        except Exception:
            log.exception("error while handling a message on %s", inbound_key)
            count_error("internal_error")
            return
        if reason is not None:
            log.debug("%s rejected: %s", inbound_name, reason)
        elif on_accepted is not None:
            on_accepted()

    # the newest messages only: a burst after a freeze keeps 16 samples, not 256 (bounded memory)
    declared = [
        declare_newest_wins(session, inbound_key, on_sample, name=inbound_name),
        session.liveliness().declare_token(keys.alive(cell, f"controller-{robot}")),
    ]
    resources.callback(declared.clear)  # kept alive until here; undeclared when the session closes
    return BridgeIo(state_pub, stats_pub, LoopNotifier.from_environment())


def start_reader(resources: ExitStack, reader: threading.Thread, stop: StopEvent, service: LoopNotifier) -> None:
    """Start the reader thread; on the way out: "stopping" to the service manager, ``stop`` set, the reader
    joined (at most :data:`READER_JOIN_S`)."""
    reader.start()
    resources.callback(reader.join, READER_JOIN_S)
    resources.callback(stop.set)
    resources.callback(service.stopping)
