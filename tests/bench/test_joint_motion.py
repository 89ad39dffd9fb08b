"""bench.joint_motion runs and reports every source (tiny run)."""

from __future__ import annotations

import pytest

from bench import joint_motion


def test_the_benchmark_reports_every_source_with_nothing_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert joint_motion.main(["--seeds", "1", "--duration-s", "6"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = {line.split()[0]: line.split() for line in lines[1:]}
    assert set(rows) == {
        "emulator", "emulator_late", "sim_zenoh", "sim_ur_rtde_500hz", "sim_ur_rtde_125hz", "sim_abb_rws",
    }  # fmt: skip
    for name, row in rows.items():
        assert int(row[1]) > 0, name
        assert float(row[2]) < 1.0, name  # no state used its whole tolerance
    assert "rejections 0" in " ".join(rows["emulator_late"])
