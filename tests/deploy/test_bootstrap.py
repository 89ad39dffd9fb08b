"""scripts/bootstrap.sh on a machine that already has everything: silent, and it installs nothing."""

from __future__ import annotations

import glob
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FAKETIME = (
    "/usr/lib/*/faketime/libfaketimeMT.so.1",
    "/usr/lib/faketime/libfaketimeMT.so.1",
    "/usr/local/lib/faketime/libfaketimeMT.so.1",
)


def test_a_second_bootstrap_says_nothing_and_installs_nothing() -> None:
    present = {
        "libfaketime": any(glob.glob(pattern) for pattern in FAKETIME),
        "chromium": shutil.which("chromium") is not None and shutil.which("chromedriver") is not None,
        "promtool": shutil.which("promtool") is not None or (ROOT / ".venv/bin/promtool").exists(),
    }
    missing = [name for name, there in present.items() if not there]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed here: the bootstrap would (rightly) try to install them")
    done = subprocess.run(
        ["bash", str(ROOT / "scripts/bootstrap.sh")], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    # libfaketime lies in one of three places; the check once demanded all three and reinstalled it on every run
    assert done.stderr == "", done.stderr
