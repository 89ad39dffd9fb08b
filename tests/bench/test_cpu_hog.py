"""The CPU hog beside tests under load: it runs its processes for the time asked, and SIGTERM stops them all."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.paths import REPO_ROOT

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)


def _children(pid: int) -> set[int]:
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.add(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_the_hog_runs_its_time_and_exits() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "bench.cpu_hog", "--processes", "1", "--seconds", "0.3"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert "cpu_hog: 1 processes for 0.3 s" in done.stderr


def test_sigterm_stops_the_hog_and_its_processes() -> None:
    hog = subprocess.Popen(
        [sys.executable, "-m", "bench.cpu_hog", "--processes", "2", "--seconds", "600"],
        cwd=REPO_ROOT,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert hog.stderr is not None
        assert "cpu_hog: 2 processes" in hog.stderr.readline()
        deadline = time.monotonic() + 10.0
        while len(workers := _children(hog.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(workers) >= 2, workers
        os.kill(hog.pid, signal.SIGTERM)
        assert hog.wait(timeout=10) == 0
        deadline = time.monotonic() + 10.0
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(_alive(w) for w in workers), "a busy process outlived the hog"
    finally:
        if hog.poll() is None:
            hog.kill()
            hog.wait()


def test_nonsense_is_refused() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "bench.cpu_hog", "--processes", "0"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert "--processes 0" in done.stderr
