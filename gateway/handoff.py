"""A worker thread fed through a one-place slot: handing a job over never blocks, and the newest job wins.

    any thread ──offer(job)──▶ [one-place slot] ──eventfd──▶ worker thread: work(job)

Used off the safety loop by the status thread (:class:`gateway.main.StatusThread`) and the ROS 2 face
(:class:`gateway.ros2_face.Ros2Face`): the loop must never wait for either of them.
"""

from __future__ import annotations

import logging
import os
import threading
from collections import deque
from collections.abc import Callable
from types import TracebackType
from typing import Generic, Self, TypeVar

JobT = TypeVar("JobT")


class LatestJobThread(Generic[JobT]):
    """Runs ``work`` on each job offered, on a thread of its own; a job not yet taken is replaced by a newer one.

    :meth:`offer` never blocks its caller: the job goes into a one-place slot and a counter (an eventfd) wakes the
    thread; no lock is shared with the caller, so this thread being descheduled cannot hold the caller up. An
    exception raised by ``work`` is logged and counted (:attr:`errors`); the thread goes on.

    Args:
        work: what to do with one job (called on this thread).
        name: the thread's name.
        what: what ``work`` does, for the log line of an error (``publishing a status document``).
        logger: where that line goes.
    """

    JOIN_TIMEOUT_S = 5.0

    def __init__(self, work: Callable[[JobT], None], name: str, what: str, logger: logging.Logger) -> None:
        self._work = work
        self._what = what
        self._log = logger
        self._slot: deque[JobT] = deque(maxlen=1)
        self._doorbell = os.eventfd(0)
        self._closed = False
        self.published = 0
        """Jobs done without an error."""
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def offer(self, job: JobT) -> None:
        """Hand over the newest job (never blocks: an eventfd write cannot, below 2⁶⁴ − 1 unread)."""
        self._slot.append(job)
        os.eventfd_write(self._doorbell, 1)

    def close(self) -> None:
        """Stop the thread (a job being done is finished first); idempotent."""
        if self._closed:
            return
        self._closed = True
        os.eventfd_write(self._doorbell, 1)
        self._thread.join(self.JOIN_TIMEOUT_S)
        if not self._thread.is_alive():  # else it still reads the descriptor: leave it to the process's end
            os.close(self._doorbell)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _run(self) -> None:
        while True:
            os.eventfd_read(self._doorbell)  # blocks, without the interpreter lock, until an offer or close
            if self._closed:
                return
            try:
                job = self._slot.pop()
            except IndexError:  # taken at a previous wake-up
                continue
            try:
                self._work(job)
                self.published += 1
            except Exception:  # never take the gateway down: count it, the loop goes on
                self.errors += 1
                self._log.exception("error while %s (the loop goes on)", self._what)
