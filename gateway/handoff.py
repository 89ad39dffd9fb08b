"""A worker thread fed through a one-place slot: handing a job over never blocks, and the newest job wins.

    any thread ──offer(job)──▶ [one-place slot] ──eventfd──▶ worker thread: work(job)

Used off the safety loop by the status thread (:class:`gateway.main.StatusThread`), the ROS 2 face
(:class:`gateway.ros2_face.Ros2Face`) and the override senders (:class:`gateway.main.OverrideSenders`, one per
robot): the loop must never wait for any of them.
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
    exception raised by ``work`` is logged and counted (:attr:`errors`); the thread goes on. :meth:`offer_last`
    then :meth:`close` end it with one last job done, waiting a bounded time.

    Args:
        work: what to do with one job (called on this thread).
        name: the thread's name.
        what: what ``work`` does, for the log line of an error (``publishing a status document``).
        logger: where that line goes.
        on_start: called first on the thread (e.g. to set its scheduling); None: nothing.
    """

    JOIN_TIMEOUT_S = 5.0

    def __init__(
        self,
        work: Callable[[JobT], None],
        name: str,
        what: str,
        logger: logging.Logger,
        on_start: Callable[[], None] | None = None,
    ) -> None:
        self._work = work
        self._on_start = on_start
        self._what = what
        self._log = logger
        self._slot: deque[JobT] = deque(maxlen=1)
        self._doorbell = os.eventfd(0)
        self._closed = False
        self._last_offered = False
        self.published = 0
        """Jobs done without an error."""
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def offer(self, job: JobT) -> None:
        """Hand over the newest job (never blocks: an eventfd write cannot, below 2⁶⁴ − 1 unread)."""
        self._slot.append(job)
        os.eventfd_write(self._doorbell, 1)

    def offer_last(self, job: JobT) -> None:
        """Hand over the last job (never blocks): it replaces one not yet taken, is done after the job being done
        (if any), and the thread then stops; :meth:`close` waits for that. Offer nothing after it."""
        self._slot.append(job)
        self._last_offered = True  # after the job is in the slot: the thread never stops before taking it
        os.eventfd_write(self._doorbell, 1)

    def close(self, timeout_s: float = JOIN_TIMEOUT_S) -> bool:
        """Stop the thread and wait for it at most ``timeout_s`` [s]: a job being done is finished first, and
        after :meth:`offer_last` the last job too; idempotent.

        Returns:
            True if the thread has ended (after :meth:`offer_last`: the last job was done, or raised and was
            counted in :attr:`errors`); False if it was still at work after ``timeout_s`` (it is left to the
            process's end, a daemon).
        """
        if not self._closed:
            self._closed = True
            os.eventfd_write(self._doorbell, 1)
        self._thread.join(max(0.0, timeout_s))
        ended = not self._thread.is_alive()
        if ended and self._doorbell >= 0:  # else it still reads the descriptor: leave it to the process's end
            os.close(self._doorbell)
            self._doorbell = -1
        return ended

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _run(self) -> None:
        if self._on_start is not None:
            self._on_start()
        while True:
            os.eventfd_read(self._doorbell)  # blocks, without the interpreter lock, until an offer or close
            if self._closed and not self._last_offered:
                return
            try:
                job = self._slot.pop()
            except IndexError:  # taken at a previous wake-up (the last one too, if offered)
                if self._last_offered:
                    return
                continue
            try:
                self._work(job)
                self.published += 1
            except Exception:  # never take the gateway down: count it, the loop goes on
                self.errors += 1
                self._log.exception("error while %s (the loop goes on)", self._what)
            if self._last_offered and not self._slot:  # the last job was this one or one before it
                return
