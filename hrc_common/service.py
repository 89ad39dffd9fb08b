"""Process plumbing shared by the three programs: command line, signals, fixed-rate loop."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--zenoh-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    parser.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (repeatable)",
    )


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        default=None,
        metavar="PATH",
        help="cell configuration (TOML); default: configs/cell.toml of this project",
    )
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])


def configure_logging(level: str) -> None:
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event set by SIGINT or SIGTERM, with the previous handlers restored afterwards."""
    stop = threading.Event()

    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


class RateLoop:
    """Fixed-rate loop on the monotonic clock that measures its own lateness.

    ``sleep()`` waits until the next period boundary. A cycle that overran skips the missed
    boundaries (counted in ``missed_cycles``) instead of bursting to catch up.
    """

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._next_s = time.monotonic() + period_s
        self.missed_cycles = 0
        self.last_lateness_s = 0.0

    def sleep(self, stop: threading.Event) -> bool:
        """Wait for the next cycle. Returns False when ``stop`` is set."""
        now = time.monotonic()
        delay = self._next_s - now
        if delay > 0:
            if stop.wait(delay):
                return False
            self.last_lateness_s = max(0.0, time.monotonic() - self._next_s)
            self._next_s += self.period_s
        else:
            self.last_lateness_s = -delay
            missed = int(-delay // self.period_s)
            self.missed_cycles += missed
            self._next_s += (missed + 1) * self.period_s
        return not stop.is_set()
