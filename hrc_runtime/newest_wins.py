"""A subscriber for a stream where only the newest sample matters (a speed override): bounded under a burst.

Zenoh reads each batch from a link into a buffer of its own while the previous one is still held; a sample keeps its
buffer until it is dropped. A callback subscriber queues up to 256 samples for its callback thread (field notes), so
a process that was frozen or starved of the interpreter lock, and then reads what piled up in its socket, holds up to
256 buffers at once: the soak's controller emulator grew by 5.8 MB (and 8.9 MB in the hour before) after such a
burst, memory malloc kept afterwards. Here the samples go to a ring of :data:`RING_CAPACITY`: when it is full the
oldest is dropped (and its buffer freed) as the next arrives, and a thread of our own hands each sample still in the
ring to ``on_sample``, as a callback subscriber would. Fewer than ``capacity`` samples arriving at once are all
delivered, in order. The controller emulator and the controller bridge take their overrides this way.

The thread ends when the session closes (the ring is deleted: ``recv`` raises). It is not a daemon: the interpreter
waits for it at exit, as for Zenoh's own callback threads (close the session first: ``with zenoh.open(...)``); a
daemon thread still inside ``recv`` while the interpreter shut down aborted the process (SIGABRT, 1 exit in ~10 of
the controller's process test). No other I/O here.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import zenoh

log = logging.getLogger("hrc.zenoh")

RING_CAPACITY = 16
"""Samples kept for the intake thread: 64 ms of overrides at 250 Hz; older ones are dropped in a burst."""


def declare_newest_wins(
    session: zenoh.Session,
    key: str,
    on_sample: Callable[[zenoh.Sample], None],
    capacity: int = RING_CAPACITY,
    name: str = "newest-wins",
) -> zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]]:
    """Subscribe to ``key`` with a ring of ``capacity`` samples and hand each to ``on_sample`` on a thread named
    ``name`` (one at a time, in arrival order). An exception in ``on_sample`` is logged, not raised: the next sample
    is handed over as usual. Keep the returned subscriber as long as samples should arrive.

    Raises:
        ValueError: ``capacity`` < 1.
    """
    if capacity < 1:
        raise ValueError(f"capacity = {capacity}; allowed: >= 1")
    subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
    ring = subscriber.handler  # its own object: receiving from it never borrows the subscriber

    def intake() -> None:
        while True:
            try:
                sample = ring.recv()
            except zenoh.ZError:  # the session closed
                return
            try:
                on_sample(sample)
            except Exception:  # a subscriber must never stop receiving
                log.exception("error while handling a sample of %s", key)

    threading.Thread(target=intake, name=name, daemon=False).start()
    return subscriber
