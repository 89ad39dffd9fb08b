"""The C heap of a long-running program: at most :data:`MALLOC_ARENAS` glibc malloc arenas.

glibc gives threads that allocate at once arenas of their own, up to eight per core; each arena keeps its own
high-water mark. Zenoh's threads and the subscriber callbacks allocate while the loop frees. One pair of 10-minute
soaks (``python -m bench.soak --minutes 10 --seed 5``, same schedule, one run each, noise not measured): the
auditor grew 4.42 % with glibc's default and 2.42 % with two arenas. What still grows over an hour of faults is
Zenoh's session while peers restart (docs/benchmarks.md, "Soak"), which this does not change.

A program calls :func:`configure_heap` first thing in its entry point: it limits the arenas
(:func:`limit_malloc_arenas`; the arenas of threads started later are limited; ``MALLOC_ARENA_MAX`` in the
environment, if set, wins: glibc reads it at start and this leaves it alone) and installs the heap report on
``SIGUSR1`` (:func:`install_heap_report`).

**The heap report** (``kill -USR1 <pid>``) tells a program's live C heap from what malloc merely holds: a resident
set that grew is either memory in use (a leak, or state that grows) or freed memory the allocator keeps for reuse
(fragmentation, high-water marks). One log line gives glibc's own figures (``mallinfo2``: in use, free but held,
mmapped) and the resident set before and after ``malloc_trim(0)``, which hands every free page of the heap back to
the kernel. The soak sends it to every program at its end (``bench/soak.py``, ``rss_after_trim_kb``). The trim runs
on a thread of its own (never the signal's thread, which may be a safety loop) but takes malloc's arena locks for
its duration, a few milliseconds for a heap of 100 MB: a diagnostic, not something to run every cycle.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import threading
from pathlib import Path
from typing import NamedTuple

MALLOC_ARENAS = 2
"""Arenas of a program's C heap: the main one and one shared by every other thread."""

M_ARENA_MAX = -8
"""``mallopt``'s parameter number for the largest number of arenas (glibc's malloc.h)."""


def limit_malloc_arenas(arenas: int = MALLOC_ARENAS) -> bool:
    """Limit this process's glibc malloc arenas to ``arenas``; True if set (False: not glibc, or the environment's
    ``MALLOC_ARENA_MAX`` is set and wins).

    Raises:
        ValueError: ``arenas`` < 1.
    """
    if arenas < 1:
        raise ValueError(f"arenas = {arenas}; allowed: >= 1")
    if os.environ.get("MALLOC_ARENA_MAX"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt arenas)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_ARENA_MAX, arenas))


class HeapFigures(NamedTuple):
    """glibc's ``mallinfo2`` of every arena, and this process's resident set [bytes]."""

    in_use_b: int
    """Allocated and not freed (``uordblks``, plus the mmapped blocks ``hblkhd``)."""
    free_held_b: int
    """Freed chunks malloc keeps in its arenas (``fordblks``): resident once touched, until trimmed."""
    mmapped_b: int
    """Large blocks malloc took straight from the kernel (``hblkhd``); returned to it on free."""
    rss_b: int
    """This process's resident set (``/proc/self/statm``), every kind of page."""


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


def _libc() -> ctypes.CDLL | None:
    try:
        return ctypes.CDLL(None)
    except OSError:
        return None


def rss_bytes() -> int:
    """This process's resident set [bytes] (``/proc/self/statm``'s second field times the page size)."""
    resident_pages = int(Path("/proc/self/statm").read_text().split()[1])
    return resident_pages * os.sysconf("SC_PAGE_SIZE")


def heap_figures() -> HeapFigures | None:
    """The C heap's figures now; None without glibc's ``mallinfo2`` (glibc < 2.33, or another libc)."""
    libc = _libc()
    mallinfo2 = getattr(libc, "mallinfo2", None)
    if mallinfo2 is None:
        return None
    mallinfo2.restype = _MallInfo2
    mallinfo2.argtypes = ()
    info = mallinfo2()
    return HeapFigures(
        in_use_b=int(info.uordblks + info.hblkhd),
        free_held_b=int(info.fordblks),
        mmapped_b=int(info.hblkhd),
        rss_b=rss_bytes(),
    )


def release_free_heap() -> tuple[HeapFigures, HeapFigures] | None:
    """``malloc_trim(0)``: hand the heap's free pages back to the kernel; the figures before and after, or None
    without glibc."""
    libc = _libc()
    before = heap_figures()
    trim = getattr(libc, "malloc_trim", None)
    if before is None or trim is None:
        return None
    trim.argtypes = (ctypes.c_size_t,)
    trim.restype = ctypes.c_int
    trim(0)
    after = heap_figures()
    return None if after is None else (before, after)


def heap_report_line() -> str:
    """One line: the heap before ``malloc_trim(0)`` and the resident set it released (:func:`release_free_heap`)."""
    figures = release_free_heap()
    if figures is None:
        return "heap: no figures (not glibc >= 2.33)"
    before, after = figures
    mb = 1e-6
    return (
        f"heap: in use {before.in_use_b * mb:.1f} MB (mmapped {before.mmapped_b * mb:.1f} MB), free but held "
        f"{before.free_held_b * mb:.1f} MB; malloc_trim(0) took the resident set from {before.rss_b * mb:.1f} MB to "
        f"{after.rss_b * mb:.1f} MB (released {(before.rss_b - after.rss_b) * mb:.1f} MB)"
    )


def install_heap_report(log: logging.Logger, signum: int = signal.SIGUSR1) -> bool:
    """On ``signum``, log :func:`heap_report_line` from a thread of its own; True if installed (False: not the main
    thread, where Python installs signal handlers)."""

    def report() -> None:
        try:
            log.log(max(log.getEffectiveLevel(), logging.INFO), "%s", heap_report_line())  # asked for: shown
        except Exception:  # a diagnostic must never take a program down
            log.exception("heap report failed")

    def handler(signum: int, frame: object) -> None:
        with contextlib.suppress(RuntimeError):  # no new thread: the interpreter is shutting down
            threading.Thread(target=report, name="heap-report", daemon=True).start()

    if threading.current_thread() is not threading.main_thread():
        return False
    signal.signal(signum, handler)
    return True


def configure_heap(log: logging.Logger) -> None:
    """A long-running program's C heap: limited arenas (:func:`limit_malloc_arenas`) and the heap report on
    ``SIGUSR1`` (:func:`install_heap_report`). Call first thing in the entry point, on the main thread."""
    limit_malloc_arenas()
    install_heap_report(log)
