"""A delay line: items handed to a callback at their due time by one thread, on the monotonic clock.

Producers (Zenoh callbacks) only ``push``; they never sleep. The thread sleeps until the earliest due
time (or until an earlier item is pushed) and then delivers every item that is due, in due-time order
and, for equal due times, in the order they were pushed.
"""

from __future__ import annotations

import heapq
import logging
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Generic, TypeVar

T = TypeVar("T")

log = logging.getLogger("hrc-fault-relay")


class DelayLine(Generic[T]):
    """Releases pushed items to ``deliver`` at their due time [monotonic s].

    Use as a context manager: the thread starts on entry; on exit it stops and the items not yet due
    are discarded (counted in :attr:`discarded`).

    Args:
        deliver: called on the delay line's thread with each item when it is due. Exceptions are logged
            and counted in :attr:`errors`; the line keeps running.
        name: thread name.
    """

    def __init__(self, deliver: Callable[[T], None], name: str = "delay-line") -> None:
        self._deliver = deliver
        self._heap: list[tuple[float, int, T]] = []
        self._order = 0
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.delivered = 0
        self.errors = 0
        self.discarded = 0
        self.max_lateness_s = 0.0
        """Largest delay between an item's due time and its delivery [s]."""

    def push(self, due_s: float, item: T) -> None:
        """Schedule ``item`` for ``due_s`` (monotonic seconds). Never blocks for long."""
        with self._cond:
            self._order += 1
            heapq.heappush(self._heap, (due_s, self._order, item))
            if self._heap[0][1] == self._order:  # the new item is the earliest: wake the thread
                self._cond.notify()

    def pending(self) -> int:
        with self._cond:
            return len(self._heap)

    def __enter__(self) -> DelayLine[T]:
        self._thread.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join()
        with self._cond:
            self.discarded += len(self._heap)
            self._heap.clear()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop:
                    now_s = time.monotonic()
                    if self._heap and self._heap[0][0] <= now_s:
                        break
                    self._cond.wait(None if not self._heap else self._heap[0][0] - now_s)
                if self._stop:
                    return
                due: list[tuple[float, T]] = []
                now_s = time.monotonic()
                while self._heap and self._heap[0][0] <= now_s:
                    due_s, _, item = heapq.heappop(self._heap)
                    due.append((due_s, item))
            for due_s, item in due:  # outside the lock: producers are never held up by a put
                self.max_lateness_s = max(self.max_lateness_s, time.monotonic() - due_s)
                try:
                    self._deliver(item)
                except Exception:
                    self.errors += 1
                    log.exception("error while delivering a delayed message")
                else:
                    self.delivered += 1
