"""Stopping on SIGINT/SIGTERM: a StopEvent the loops wait on."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


class StopEvent(threading.Event):
    """A ``threading.Event`` that also sets the wake-up events made from it by :meth:`wake_event`.

    A loop that waits for new data (``RateLoop.sleep(stop, wake)``) waits on its wake-up event, not on
    the stop event; setting the stop event sets every wake-up event too, so the wait ends at once.
    """

    def __init__(self) -> None:
        super().__init__()
        self._wakes: list[threading.Event] = []
        self._wakes_lock = threading.Lock()

    def wake_event(self) -> threading.Event:
        """A new event, set whenever this one is set (and already set if this one is)."""
        wake = threading.Event()
        with self._wakes_lock:
            self._wakes.append(wake)
        if self.is_set():
            wake.set()
        return wake

    def set(self) -> None:
        super().set()
        with self._wakes_lock:
            wakes = list(self._wakes)
        for wake in wakes:
            wake.set()


@contextmanager
def stop_on_signals() -> Iterator[StopEvent]:
    """An event set by SIGINT or SIGTERM, with the previous handlers restored afterwards.

    The handler sets the event from a short-lived thread: a handler runs in the main thread between two
    bytecodes, possibly while that thread holds the lock inside the very event (or a wake-up event) it
    is waiting on, and ``Event.set`` there would deadlock.
    """
    stop = StopEvent()

    def handler(signum: int, frame: FrameType | None) -> None:
        try:
            threading.Thread(target=stop.set, name="stop-on-signal", daemon=True).start()
        except RuntimeError:  # no new thread (interpreter shutting down): set it here
            stop.set()

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
