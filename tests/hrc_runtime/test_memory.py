"""The C heap's arenas (hrc_runtime/memory.py): limited in a program, counted by glibc's own ``malloc_info``."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from hrc_runtime.memory import limit_malloc_arenas

# A child process: optionally limit the arenas, then eight threads allocate at the same time and hold their memory
# until all have allocated (so that glibc gives them arenas of their own), then print how many arenas the heap has
# (``<heap nr=`` elements of malloc_info's XML).
CHILD = textwrap.dedent(
    """
    import ctypes, sys, threading
    from hrc_runtime.memory import limit_malloc_arenas
    if sys.argv[1] == "limit":
        assert limit_malloc_arenas()
    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = (ctypes.c_size_t,)
    libc.free.argtypes = (ctypes.c_void_p,)
    barrier = threading.Barrier(8)
    def work():
        blocks = [libc.malloc(1024) for _ in range(200)]
        barrier.wait()
        for b in blocks:
            libc.free(b)
    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads: t.start()
    for t in threads: t.join()
    buf, size = ctypes.c_char_p(), ctypes.c_size_t()
    libc.open_memstream.restype = ctypes.c_void_p
    stream = libc.open_memstream(ctypes.byref(buf), ctypes.byref(size))
    libc.malloc_info(0, ctypes.c_void_p(stream))
    libc.fclose(ctypes.c_void_p(stream))
    print(buf.value.decode().count("<heap nr="))
    """
)


def arenas_in_a_child(mode: str) -> int:
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    out = subprocess.run(
        [sys.executable, "-c", CHILD, mode], env=env, capture_output=True, text=True, timeout=60, check=True
    )
    return int(out.stdout.strip())


def test_a_program_that_limits_its_arenas_has_at_most_two_where_the_default_has_more() -> None:
    assert arenas_in_a_child("default") > 2  # the default: up to 8 per core for 8 threads allocating at once
    assert arenas_in_a_child("limit") <= 2


def test_the_environment_wins_and_nonsense_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MALLOC_ARENA_MAX", "4")
    assert limit_malloc_arenas() is False
    with pytest.raises(ValueError, match="allowed: >= 1"):
        limit_malloc_arenas(0)
