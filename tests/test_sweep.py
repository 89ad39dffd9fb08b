"""The randomized sweep: a fast CI subset with the real gateway (0 violations), the table and the command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hrc_common.config import UNSAFE_ENV_VAR, CellConfig
from hrc_common.robot_model import load_robot_model
from sim.sweep import CaseResult, CellVariant, cli, format_table, run_case, summarize

CI_SEED = 2026
CI_SCENARIOS = 10
CI_DURATION_S = 8.0


def test_ci_subset_of_the_sweep_has_no_violations(cell_config: CellConfig) -> None:
    """10 generated cases (people, sensors, link faults, some delays beyond the data age limit), 8 s each, in
    the default cell with tight braking times (the gateway plans with the controller's real stopping time, so
    no slack hides a wrong delay handling; the same sweep with the delay ignored violates in ~1 case of 6)."""
    config = CellVariant(tight_braking=True).apply(cell_config)
    robots = {name: load_robot_model(name, r) for name, r in config.robots.items()}
    results = [run_case(config, robots, CI_SEED, i, CI_DURATION_S) for i in range(CI_SCENARIOS)]
    summary = summarize(results, wall_s=1.0)
    violating = [(r.index, r.seed, r.smallest_margin_m, r.params) for r in results if r.violations]
    assert summary.violations == 0, violating
    assert summary.contacts_while_moving == 0
    assert summary.smallest_margin_m is not None
    assert summary.smallest_margin_m >= 0.0
    # The subset really exercises the gateway: people come close, the robot slows and moves.
    assert summary.smallest_margin_m < 0.5
    assert 0.05 < summary.mean_delta < 0.95
    assert summary.program_cycles > 0
    assert summary.beyond_budget >= 1
    assert summary.beyond_budget_stopped == summary.beyond_budget
    assert "scenarios" in format_table(summary, workers=1)


def _case(index: int, violations: int, margin: float | None, beyond: str | None = None) -> CaseResult:
    return CaseResult(
        index=index,
        seed=index,
        violations=violations,
        contacts_while_moving=0,
        smallest_margin_m=margin,
        smallest_margin_moving_m=margin,
        min_distance_m=margin,
        first_violation_t_s=None,
        mean_delta=0.5,
        time_stopped_s=1.0,
        program_cycles=1,
        t_delay_mean_s=0.1,
        t_delay_min_s=0.1,
        t_delay_max_s=0.1,
        fault_decisions=100 if beyond else 0,
        decisions=100,
        faults={"tracker_stale": 100} if beyond else {},
        beyond_budget=beyond,
        params={},
        duration_s=10.0,
        wall_s=2.0,
    )


def test_summary_of_known_cases() -> None:
    results = [_case(0, 0, 0.3), _case(1, 4, -0.2), _case(2, 0, None, beyond="tracker_to_gateway")]
    summary = summarize(results, wall_s=3.0)
    assert summary.scenarios == 3
    assert summary.violations == 4
    assert summary.cases_with_violations == 1
    assert summary.smallest_margin_m == pytest.approx(-0.2)
    assert summary.smallest_margin_case == 1
    assert summary.mean_delta == pytest.approx(0.5)
    assert summary.program_cycles == 3
    assert (summary.beyond_budget, summary.beyond_budget_stopped) == (1, 1)
    assert summary.simulated_s == pytest.approx(30.0)


def test_command_writes_the_table_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sweep.json"
    with pytest.raises(SystemExit) as exit_info:
        cli(["--scenarios", "2", "--workers", "1", "--duration-s", "0.5", "--seed", "3", "--json", str(out), "--quiet"])
    assert exit_info.value.code == 0
    printed = capsys.readouterr().out
    assert "scenarios" in printed
    assert "wall time" in printed
    doc = json.loads(out.read_text())
    assert doc["summary"]["scenarios"] == 2
    assert [c["index"] for c in doc["cases"]] == [0, 1]


def test_cell_variant(cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    assert CellVariant().apply(cell_config) == cell_config
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_ignore_delay_for_tests")  # the test-only setting is refused without
    tight = CellVariant(unsafe_ignore_delay=True, tight_braking=True, human_speed_mps=2.2).apply(cell_config)
    controller_t_b = cell_config.robots["ur5"].controller.braking_time_s
    assert tight.robots["ur5"].model.braking_time_s == [controller_t_b] * 6
    assert tight.safety.unsafe_ignore_delay_for_tests
    assert tight.safety.human_speed_mps == 2.2
    assert tight.safety.human_speed_close_mps == 2.2
    assert not cell_config.safety.unsafe_ignore_delay_for_tests  # the original is untouched
