"""Logging of the services: terminal or journald format, and a queue so the loop never blocks on a write."""

from __future__ import annotations

import logging
import logging.handlers
import os
import queue
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

from hrc_runtime.realtime import use_realtime_scheduling

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
