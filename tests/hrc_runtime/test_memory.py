"""The C heap's arenas (hrc_runtime/memory.py): limited in a program, counted by glibc's own ``malloc_info``."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap

import pytest

from hrc_runtime.memory import heap_figures, limit_malloc_arenas

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

# A child process: optionally limit the arenas, then eight threads allocate at the same time and hold their memory
# until all have allocated (so that glibc gives them arenas of their own), then print how many arenas the heap has
# (``<heap nr=`` elements of malloc_info's XML).
CHILD = textwrap.dedent(
    """
    import ctypes, sys, threading
    from hrc_runtime.memory import heap_figures, limit_malloc_arenas
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


# A child process: the heap report installed, then 80 MB in 4 kB blocks written to (resident), every block but each
# fiftieth freed again (so the heap's top stays in use and nothing shrinks by itself); it says "ready" and waits.
FRAGMENTED = textwrap.dedent(
    """
    import ctypes, logging, sys, time
    from hrc_runtime.memory import configure_heap
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(message)s")
    configure_heap(logging.getLogger("child"))
    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = (ctypes.c_size_t,)
    libc.free.argtypes = (ctypes.c_void_p,)
    blocks = [libc.malloc(4000) for _ in range(20000)]
    for b in blocks:
        ctypes.memset(b, 1, 4000)
    for i, b in enumerate(blocks):
        if i % 50:
            libc.free(b)
    print("ready", flush=True)
    time.sleep(60)
    """
)


def test_the_heap_report_tells_freed_memory_malloc_holds_and_releases_it_on_sigusr1() -> None:
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    child = subprocess.Popen(
        [sys.executable, "-c", FRAGMENTED], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout is not None
        assert child.stderr is not None
        assert child.stdout.readline().strip() == "ready"
        child.send_signal(signal.SIGUSR1)
        line = ""
        while not line.startswith("heap:"):
            line = child.stderr.readline()
            assert line, "the child ended without a heap report"
    finally:
        child.kill()
        child.wait(timeout=10)
    figures = re.search(
        r"in use ([\d.]+) MB .* free but held ([\d.]+) MB; malloc_trim\(0\) took the resident set from ([\d.]+) MB "
        r"to ([\d.]+) MB \(released ([\d.]+) MB\)",
        line,
    )
    assert figures is not None, line
    in_use, held, rss_before, rss_after, released = (float(x) for x in figures.groups())
    assert held > 70.0  # 49 of every 50 blocks of 80 MB were freed
    assert released > 60.0  # their pages went back to the kernel (each 4 kB block spans at most two pages)
    assert rss_after < rss_before - 60.0
    assert in_use < held


def test_heap_figures_of_this_process_are_plausible() -> None:
    figures = heap_figures()
    assert figures is not None  # Debian's glibc 2.36 has mallinfo2
    assert figures.in_use_b > 0
    assert figures.free_held_b >= 0
    assert figures.mmapped_b >= 0
    assert figures.rss_b > figures.in_use_b - figures.mmapped_b  # the interpreter's own memory is resident too
