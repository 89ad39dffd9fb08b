"""The C heap of a long-running program: at most :data:`MALLOC_ARENAS` glibc malloc arenas.

glibc gives threads that allocate at once arenas of their own, up to eight per core; each arena keeps its own
high-water mark. Zenoh's threads and the subscriber callbacks allocate while the loop frees. One pair of 10-minute
soaks (``python -m bench.soak --minutes 10 --seed 5``, same schedule, one run each, noise not measured): the
auditor grew 4.42 % with glibc's default and 2.42 % with two arenas. What still grows over an hour of faults is
Zenoh's session while peers restart (docs/benchmarks.md, "Soak"), which this does not change.

A program calls :func:`limit_malloc_arenas` first thing in its entry point (the arenas of threads started later
are limited). ``MALLOC_ARENA_MAX`` in the environment, if set, wins: glibc reads it at start and this function
leaves it alone.
"""

from __future__ import annotations

import ctypes
import os

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
