"""The service manager's notify protocol (``sd_notify(3)``): readiness, watchdog, status and stopping.

Under systemd with ``Type=notify``, ``NOTIFY_SOCKET`` names a Unix datagram socket: a path, or ``@name`` for
the abstract namespace. A message is one datagram of ``KEY=value`` lines: ``READY=1``, ``WATCHDOG=1``,
``STATUS=<one line>``, ``STOPPING=1``. With ``WatchdogSec=`` the manager also sets ``WATCHDOG_USEC`` (the
timeout [µs]) and ``WATCHDOG_PID`` (the process that must ping); a service that does not send ``WATCHDOG=1``
within the timeout is killed and, with ``Restart=on-failure``, restarted.

Outside systemd (no ``NOTIFY_SOCKET``) every call is a no-op. A send never blocks, and one that fails is logged
once and never raises: the safety loop must not wait for, or die of, its service manager.

:class:`LoopNotifier` is what a program's main loop uses: ``cycle_done()`` after each cycle sends ``READY=1``
the first time the cycle did the program's job, ``WATCHDOG=1`` :data:`PINGS_PER_TIMEOUT` times per watchdog
timeout, and ``STATUS=`` every :data:`STATUS_EVERY_S`. The pings come from the loop itself, so a loop that
stalls stops them.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import threading
from collections.abc import Callable, Mapping
from types import TracebackType

log = logging.getLogger("hrc.sd_notify")

NOTIFY_SOCKET_ENV_VAR = "NOTIFY_SOCKET"
WATCHDOG_USEC_ENV_VAR = "WATCHDOG_USEC"
WATCHDOG_PID_ENV_VAR = "WATCHDOG_PID"

STALL_ENV_VAR = "HRC_TEST_STALL_AFTER_CYCLES"
"""TEST ONLY: a positive integer N makes the gateway's safety loop stall (block until stopped) after N cycles,
so a test can see the watchdog pings stop. Never set it on a real cell."""

PINGS_PER_TIMEOUT = 4
"""``WATCHDOG=1`` is sent this many times per watchdog timeout: a late cycle or two still leaves two pings in
every timeout window (systemd recommends at least two)."""

STATUS_EVERY_S = 1.0
"""How often ``STATUS=`` is refreshed [s]."""

MAX_STATUS_CHARS = 200
"""A ``STATUS=`` line is cut to this length (``systemctl status`` shows one line)."""


def socket_address(value: str) -> str | bytes | None:
    """The ``sendto`` address named by a ``NOTIFY_SOCKET`` value, None if it is not a Unix socket.

    ``/path`` is a socket in the file system; ``@name`` is ``name`` in the abstract namespace (a leading NUL).
    Other forms (e.g. ``vsock:``) are not supported: None.
    """
    if value.startswith("/"):
        return value
    if value.startswith("@") and len(value) > 1:
        return b"\0" + value[1:].encode()
    return None


def watchdog_timeout_s(environ: Mapping[str, str], pid: int) -> float | None:
    """The watchdog timeout asked of process ``pid`` [s], None when there is none (or it is another process's).

    Args:
        environ: the environment (``WATCHDOG_USEC`` [µs], and ``WATCHDOG_PID`` when set by the manager).
        pid: this process's id.
    """
    usec = environ.get(WATCHDOG_USEC_ENV_VAR, "")
    watchdog_pid = environ.get(WATCHDOG_PID_ENV_VAR, "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    if watchdog_pid and (not watchdog_pid.isdigit() or int(watchdog_pid) != pid):
        return None
    return int(usec) / 1e6


def stall_after_cycles(environ: Mapping[str, str]) -> int | None:
    """TEST ONLY: the cycle count after which the safety loop stalls (:data:`STALL_ENV_VAR`), None for never.

    A value that is not a positive integer is ignored with a warning (the loop never stalls).
    """
    value = environ.get(STALL_ENV_VAR, "")
    if not value:
        return None
    if not value.isdigit() or int(value) == 0:
        log.warning("%s = %r ignored; allowed: a positive number of cycles (test only)", STALL_ENV_VAR, value)
        return None
    return int(value)


def single_line(text: str) -> str:
    """``text`` on one line of at most :data:`MAX_STATUS_CHARS` characters (for ``STATUS=``)."""
    line = " ".join(text.split())
    return line if len(line) <= MAX_STATUS_CHARS else line[: MAX_STATUS_CHARS - 1] + "…"


class Notifier:
    """Sends notify messages to the service manager; a no-op without a socket address."""

    def __init__(self, address: str | bytes | None) -> None:
        self.address = address
        self._socket: socket.socket | None = None
        self._failed = False
        if address is not None:
            # Non-blocking: a busy service manager must never hold up the safety loop (a lost ping is one of four).
            self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK)

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> Notifier:
        """A notifier for ``NOTIFY_SOCKET`` (a no-op one when it is absent or not a Unix socket)."""
        value = (os.environ if environ is None else environ).get(NOTIFY_SOCKET_ENV_VAR, "")
        address = socket_address(value) if value else None
        if value and address is None:
            log.warning(
                "%s = %r is not supported (allowed: /path or @abstract); not notifying", NOTIFY_SOCKET_ENV_VAR, value
            )
        return cls(address)

    @property
    def enabled(self) -> bool:
        return self._socket is not None

    def send(self, *fields: str) -> bool:
        """Send ``fields`` (``KEY=value`` each) as one datagram. Returns whether it was sent (False when disabled).

        A failure is logged once (a warning) and never raises.
        """
        if self._socket is None or self.address is None:
            return False
        try:
            self._socket.sendto("\n".join(fields).encode(), self.address)
        except OSError as exc:
            if not self._failed:
                self._failed = True
                log.warning("cannot notify the service manager at %r: %s", self.address, exc)
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        return self.send("READY=1", *([f"STATUS={single_line(status)}"] if status else []))

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={single_line(text)}")

    def stopping(self, status: str | None = None) -> bool:
        return self.send("STOPPING=1", *([f"STATUS={single_line(status)}"] if status else []))

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def __enter__(self) -> Notifier:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()


class LoopNotifier:
    """What a program's main loop tells the service manager, from the loop itself.

    Call :meth:`cycle_done` after every cycle (with the monotonic time) and :meth:`stopping` when the loop has
    ended. Without ``NOTIFY_SOCKET`` it does nothing but count cycles.
    """

    def __init__(
        self,
        notifier: Notifier,
        watchdog_timeout_s: float | None,
        status_every_s: float = STATUS_EVERY_S,
        stall_after_cycles: int | None = None,
    ) -> None:
        self.notifier = notifier
        self.ping_every_s = math.inf if watchdog_timeout_s is None else watchdog_timeout_s / PINGS_PER_TIMEOUT
        self.status_every_s = status_every_s
        self.stall_after_cycles = stall_after_cycles
        self.cycles = 0
        self.is_ready = False
        self._next_ping_s = math.inf if watchdog_timeout_s is None else -math.inf  # no watchdog: no pings
        self._next_status_s = -math.inf

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> LoopNotifier:
        """From ``NOTIFY_SOCKET``, ``WATCHDOG_USEC``/``WATCHDOG_PID`` and the test-only :data:`STALL_ENV_VAR`."""
        env = os.environ if environ is None else environ
        stall = stall_after_cycles(env)
        if stall is not None:
            log.warning("TEST ONLY: %s is set: the loop stalls after %d cycles", STALL_ENV_VAR, stall)
        return cls(Notifier.from_environment(env), watchdog_timeout_s(env, os.getpid()), stall_after_cycles=stall)

    def cycle_done(self, now_s: float, status: Callable[[], str], *, ready: bool = True) -> None:
        """After a cycle: ``READY=1`` the first time ``ready`` holds, ``WATCHDOG=1`` and ``STATUS=`` when due.

        Args:
            now_s: monotonic time [s].
            status: the one-line summary; called only when a status is sent.
            ready: whether the program has done its job at least once (e.g. published its first output).
        """
        self.cycles += 1
        if not self.notifier.enabled:
            return
        if ready and not self.is_ready:
            self.is_ready = True
            self.notifier.ready(status())
            self._next_status_s = now_s + self.status_every_s
        elif now_s >= self._next_status_s:
            self.notifier.status(status())
            self._next_status_s = now_s + self.status_every_s
        if now_s >= self._next_ping_s:
            self.notifier.watchdog()
            self._next_ping_s = now_s + self.ping_every_s

    def stall_for_tests(self, stop: threading.Event) -> None:
        """TEST ONLY: block until ``stop`` is set once :attr:`stall_after_cycles` cycles are done (else return)."""
        if self.stall_after_cycles is not None and self.cycles >= self.stall_after_cycles:
            log.warning("TEST ONLY: the loop stalls after %d cycles (%s)", self.cycles, STALL_ENV_VAR)
            stop.wait()

    def stopping(self) -> None:
        """``STOPPING=1``, then close the socket."""
        self.notifier.stopping(f"stopping after {self.cycles} cycles")
        self.notifier.close()
