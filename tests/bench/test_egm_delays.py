"""``bench.egm_delays`` on one row: the EGM link delayed beyond ``max_data_age_s`` (0.3 s each way), the real cell
audited. The gateway must show the late data and command the stop (δ = 0 while a fault is shown), and the auditor
must find no violation; the report carries the row."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import egm_delays

pytestmark = pytest.mark.e2e


def test_a_link_beyond_the_age_limit_stops_the_open_robot_and_the_row_is_reported(tmp_path: Path) -> None:
    out = tmp_path / "egm_delays.json"
    assert egm_delays.main(["--links", "robot", "--delays-s", "0.3", "--run-s", "12", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    (row,) = doc["results"]["runs"]
    assert row["link"] == "robot"
    assert row["delay_s"] == 0.3
    assert row["violations"] == 0
    assert row["delta_above_bound"] == 0
    assert {"joint_state_stale", "override_path_stale"} & set(row["faults"]), row["faults"]
    assert row["max_delta_with_fault"] == 0.0, row


def test_delays_out_of_range_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        egm_delays.main(["--delays-s", "-0.1"])
    assert exit_info.value.code == 2
    assert "allowed: 0–5 s each" in capsys.readouterr().err
