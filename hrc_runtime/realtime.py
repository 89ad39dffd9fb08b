"""Real-time scheduling (SCHED_FIFO) and a frozen start-up heap (gc.freeze) for the safety loop."""

from __future__ import annotations

import gc
import logging
import logging.handlers
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager


def use_realtime_scheduling(priority: int, thread: str, logger: logging.Logger) -> bool:
    """Run the calling thread under SCHED_FIFO at ``priority``; log a warning (and go on) if the OS refuses.

    Only this thread: on Linux the scheduling policy of pid 0 is the calling thread's.

    Returns:
        True if the thread now runs under SCHED_FIFO.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:  # not Linux, or no CAP_SYS_NICE
        logger.warning("could not run %s under SCHED_FIFO priority %d: %s", thread, priority, exc)
        return False
    logger.info("%s (thread %d) under SCHED_FIFO priority %d", thread, threading.get_native_id(), priority)
    return True


def freeze_startup_heap() -> None:
    """Collect once and move every object alive now (modules, robot models, compiled kernels, configs) to the
    garbage collector's permanent generation, so that a full collection during the loop does not scan them.

    Call it right before a program's loop starts. Why: a full (generation 2) collection of the gateway's ~157 000
    start-up objects takes ~38 ms, ten periods at 250 Hz, and it happens at some allocation in the loop; after
    the freeze it scans only what the loop itself keeps (measured: see docs/benchmarks.md, "Many robots").
    Reference cycles created later are still collected.
    """
    gc.collect()
    gc.freeze()


@contextmanager
def collections_paused() -> Iterator[None]:
    """Meanwhile no automatic garbage collection in this process (any thread); as before afterwards.

    For a thread that builds and drops a large graph of objects next to a real-time loop (the gateway's status
    thread): a full collection while such a graph is alive scans all of it with the interpreter lock held
    (measured 5–10 ms for a status document of 4000 capsules, ``bench/crowded.py``), and the loop waits for the
    lock. Dropped, the graph is freed by reference counting (it holds no cycles), so the next collection finds
    little. The switch is process-wide: one thread at a time may use this.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
