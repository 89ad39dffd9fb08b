"""The gateway's HTTP server, run as a child process of the gateway so it cannot stall the safety loop.

Protocol on standard input, one JSON document per line: the first line is the effective
configuration (:class:`~hrc_contract.status_models.EffectiveConfig`), every further line a status document
(:class:`~hrc_contract.status_models.GatewayStatus`) or, prefixed with ``E ``, an event of the log
(:class:`~hrc_contract.status_models.Event`), each validated once on arrival. Status documents may be dropped
when the child is slow (only the newest matters); events never are. End of input (the gateway exited or was
killed) ends the open streams and stops the server.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Iterable
from pathlib import Path
from typing import IO

import uvicorn
from pydantic import ValidationError

from gateway.events import EventFile
from gateway.http.api import StatusBoard, create_app
from hrc_contract.status_models import EffectiveConfig, Event
from hrc_runtime.logs import configure_logging
from hrc_runtime.memory import configure_heap
from hrc_runtime.realtime import use_realtime_scheduling

log = logging.getLogger("hrc-gateway.http")

NICENESS_INCREMENT = 10
"""The HTTP server lowers its own CPU priority by this much (no privilege needed), so that under HTTP load the
scheduler runs the safety loop (and the programs it talks to) first on a busy machine."""


EVENT_PREFIX = b"E "
"""Marks a line of the pipe as an event of the log."""
MAX_QUEUED_EVENTS = 10_000
"""Events waiting for the pipe beyond this are dropped (oldest first): a dead child never grows the gateway."""


def _take_event(board: StatusBoard, line: bytes, events_file: EventFile | None) -> None:
    event = Event.model_validate_json(line[len(EVENT_PREFIX) :])
    board.events.add(event)
    board.metrics.observe_event(event)
    if events_file is not None:
        try:
            events_file.write(event)
        except OSError as exc:
            log.warning("could not write the event log %s: %s", events_file.path, exc)


def _feed(board: StatusBoard, lines: IO[bytes], server: uvicorn.Server, events_file: EventFile | None = None) -> None:
    """Publish every line on the board until end of input, then stop the server.

    A line that is not a status document is skipped (the board keeps the previous one and goes stale, so the
    API answers 503 if no valid line follows); a warning is logged when valid lines turn invalid.
    """
    previous_valid = True
    for line in lines:
        try:
            if line.startswith(EVENT_PREFIX):
                _take_event(board, line, events_file)
                continue
            board.publish_json(line)
        except ValidationError as exc:
            if previous_valid:
                error = exc.errors()[0]
                where = ".".join(str(p) for p in error["loc"])
                log.warning("skipping status lines that are not a status document (%s: %s)", where, error["msg"])
            previous_valid = False
        else:
            previous_valid = True
    board.close()  # open streams end at once, so the shutdown below never waits on them
    server.should_exit = True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="HTTP server of hrc-gateway (started by hrc-gateway)")
    parser.add_argument("--http-host", default="127.0.0.1")
    parser.add_argument("--http-port", type=int, default=8080)
    parser.add_argument("--events-log", type=Path, default=None, help="JSON Lines file of the events (rotated)")
    args = parser.parse_args(argv)
    configure_logging("INFO")  # journal lines under systemd, timestamps otherwise
    configure_heap(log)  # before the program's threads start: arenas, heap report on SIGUSR1 (hrc_runtime/memory.py)
    try:
        os.nice(NICENESS_INCREMENT)
    except OSError as exc:  # never a reason not to serve
        log.warning("could not lower the HTTP server's CPU priority: %s", exc)
    stdin = sys.stdin.buffer
    first = stdin.readline()
    if not first:
        return 0
    board = StatusBoard(EffectiveConfig.model_validate_json(first))
    config = uvicorn.Config(
        create_app(board),
        host=args.http_host,
        port=args.http_port,
        log_level="warning",
        timeout_graceful_shutdown=2,
    )
    server = uvicorn.Server(config)
    events_file = None if args.events_log is None else EventFile(args.events_log)
    threading.Thread(target=_feed, args=(board, stdin, server, events_file), daemon=True).start()
    server.run()
    return 0 if server.started else 1


class HttpServerProcess:
    """The HTTP child process, fed with the newest status by a writer thread.

    ``offer()`` never blocks the caller: it replaces the pending document, and a writer thread does
    the (possibly blocking) pipe write. A slow or dead child only makes the API lag.

    ``feed_realtime_priority`` > 0: the writer thread runs under SCHED_FIFO at that priority (the gateway's
    ``io_realtime_priority``). It shares a lock with ``offer()`` and Python's interpreter lock with the safety
    loop; at normal priority any other program could deschedule it while it holds one, and the loop would wait.
    """

    def __init__(
        self,
        host: str,
        port: int,
        effective_config: EffectiveConfig,
        events_log: Path | None = None,
        feed_realtime_priority: int = 0,
    ) -> None:
        extra = [] if events_log is None else ["--events-log", str(events_log)]
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "gateway.http.server", "--http-host", host, "--http-port", str(port), *extra],
            stdin=subprocess.PIPE,
            start_new_session=True,  # Ctrl-C reaches the gateway only; it ends this child by closing stdin
        )
        if self._proc.stdin is not None:
            # A few kB into a fresh pipe: never blocks.
            self._proc.stdin.write(effective_config.model_dump_json().encode() + b"\n")
            self._proc.stdin.flush()
        self._pending: bytes | None = None
        self._events: deque[bytes] = deque(maxlen=MAX_QUEUED_EVENTS)
        self._cond = threading.Condition()
        self._closed = False
        self._feed_priority = feed_realtime_priority
        self._writer = threading.Thread(target=self._write_loop, name="http-feed", daemon=True)
        self._writer.start()

    def offer(self, status_line: bytes) -> None:
        """Hand over one status line (JSON + newline); replaces any line not yet written."""
        with self._cond:
            self._pending = status_line
            self._cond.notify()

    def offer_events(self, events: Iterable[Event]) -> None:
        """Hand over events of the log; written before the next status line, in order, never replaced."""
        lines = [EVENT_PREFIX + e.model_dump_json(exclude_none=True).encode() + b"\n" for e in events]
        if not lines:
            return
        with self._cond:
            self._events.extend(lines)
            self._cond.notify()

    def _write_loop(self) -> None:
        if self._feed_priority:
            use_realtime_scheduling(self._feed_priority, "the HTTP feed thread", log)
        stdin = self._proc.stdin
        if stdin is None:
            return
        while True:
            with self._cond:
                while self._pending is None and not self._events and not self._closed:
                    self._cond.wait()
                events, self._events = b"".join(self._events), deque(maxlen=MAX_QUEUED_EVENTS)
                data, self._pending = self._pending, None
                closing = self._closed
            data = events + (data or b"")
            if closing:  # the last events (the stop) still go out before the pipe closes
                with contextlib.suppress(OSError, ValueError):
                    stdin.write(data)
                    stdin.flush()
                break
            try:
                stdin.write(data)
                stdin.flush()
            except (BrokenPipeError, ValueError, OSError):
                return
        with contextlib.suppress(OSError):
            stdin.close()

    def exit_code(self) -> int | None:
        return self._proc.poll()

    def close(self, timeout_s: float = 5.0) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._writer.join(timeout_s)
        try:
            self._proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.terminate()
            self._proc.wait(timeout_s)


if __name__ == "__main__":
    sys.exit(main())
