"""deploy/systemd/: the units parse and load without a warning (``systemd-analyze verify``), and say what the
README promises (notify, watchdog, restart, sandbox, one configuration file, the state folder).

``verify`` also checks that every command exists: the units name the installed checkout /opt/hrc-gateway, so the
test verifies copies that name this project's virtual environment instead.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from support.paths import REPO_ROOT

UNITS_DIR = REPO_ROOT / "deploy" / "systemd"
INSTALLED_BIN = "/opt/hrc-gateway/.venv/bin/"
SERVICES = (
    "hrc-gateway.service",
    "hrc-controller-emu@.service",
    "hrc-controller-bridge@.service",
    "hrc-tracker-emu.service",
)


def _service_section(name: str) -> dict[str, list[str]]:
    """The [Service] section of a unit: every value of each key (a key may repeat)."""
    values: dict[str, list[str]] = {}
    section = ""
    for line in (UNITS_DIR / name).read_text().splitlines():
        line = line.strip()
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
        elif section == "Service" and line and not line.startswith("#") and "=" in line:
            key, _, value = line.partition("=")
            values.setdefault(key, []).append(value)
    return values


@pytest.mark.skipif(
    shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed (Debian: systemd)"
)
def test_systemd_analyze_verify_accepts_the_units(tmp_path: Path) -> None:
    venv_bin = f"{Path(sys.executable).parent}/"
    for name in SERVICES:
        text = (UNITS_DIR / name).read_text()
        assert INSTALLED_BIN in text
        (tmp_path / name).write_text(text.replace(INSTALLED_BIN, venv_bin))
    shutil.copy(tmp_path / "hrc-controller-emu@.service", tmp_path / "hrc-controller-emu@ur5.service")
    shutil.copy(tmp_path / "hrc-controller-bridge@.service", tmp_path / "hrc-controller-bridge@ur5.service")
    instances = ("hrc-controller-emu@ur5.service", "hrc-controller-bridge@ur5.service")
    units = [str(tmp_path / n) for n in ("hrc-gateway.service", *instances, "hrc-tracker-emu.service")]
    result = subprocess.run(
        ["systemd-analyze", "verify", *units], capture_output=True, text=True, timeout=60, check=False
    )
    # verify exits 0 on settings it ignores ("Failed to parse ..., ignoring"): any output is a failure too.
    assert result.returncode == 0, result.stderr + result.stdout
    assert result.stderr.strip() == "", result.stderr
    assert result.stdout.strip() == "", result.stdout


@pytest.mark.parametrize("name", SERVICES)
def test_every_service_is_a_sandboxed_notify_service_with_a_watchdog(name: str) -> None:
    service = _service_section(name)
    expected = {
        "Type": ["notify"],
        "Restart": ["on-failure"],
        "DynamicUser": ["yes"],
        "NoNewPrivileges": ["yes"],
        "ProtectSystem": ["strict"],
        "StateDirectory": ["hrc-gateway"],
        "ConfigurationDirectory": ["hrc-gateway"],
    }
    for key, value in expected.items():
        assert service.get(key) == value, f"{name}: {key}"
    assert service["WatchdogSec"]
    assert "HRC_STATE_DIR=%S/hrc-gateway" in service["Environment"]
    assert all("--config %E/hrc-gateway/cell.toml" in command for command in service["ExecStart"])


def test_only_the_gateway_may_raise_its_loop_to_real_time() -> None:
    gateway = _service_section("hrc-gateway.service")
    assert gateway["AmbientCapabilities"] == ["CAP_SYS_NICE"]
    assert gateway["CapabilityBoundingSet"] == ["CAP_SYS_NICE"]
    for name in ("hrc-controller-emu@.service", "hrc-controller-bridge@.service", "hrc-tracker-emu.service"):
        emulator = _service_section(name)
        assert emulator["CapabilityBoundingSet"] == [""]
        assert emulator["RestrictRealtime"] == ["yes"]
