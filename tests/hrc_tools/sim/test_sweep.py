"""The randomized sweep: a fast CI subset with the real gateway (0 violations), the table and the command."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from support.paths import REPO_ROOT

from hrc_contract.config import UNSAFE_ENV_VAR, CellConfig, ConfigError
from hrc_devices.robots.model import load_robot_model
from hrc_tools.sim.sweep import (
    CaseResult,
    CellVariant,
    cli,
    format_table,
    merge_sweeps,
    run_case,
    run_sweep,
    summarize,
    sweep_exit_code,
)

MEASURED_MODEL = REPO_ROOT / "configs" / "robots" / "ur5_measured.toml"

CI_SEED = 2030
CI_SCENARIOS = 10
CI_DURATION_S = 8.0


def test_ci_subset_of_the_sweep_has_no_violations(cell_config: CellConfig) -> None:
    """10 generated cases (people, sensors, link faults, some delays beyond the data age limit), 8 s each, in
    the default cell with tight braking times (the gateway plans with the controller's real stopping time, so
    no slack hides a wrong delay handling; the same sweep with the delay ignored violates in ~1 case of 6)."""
    config = CellVariant(tight_braking=True).apply(cell_config)
    robots = {name: load_robot_model(name, r) for name, r in config.robots.items()}
    results = [run_case(config, robots, CI_SEED, i, CI_DURATION_S) for i in range(CI_SCENARIOS)]
    summary = summarize(results, wall_s=1.0, human_speed_mps=config.safety.human_speed_mps)
    violating = [(r.index, r.seed, r.smallest_margin_m, r.beyond_k, r.params) for r in results if r.violations]
    assert summary.violations == 0, violating
    assert summary.within_k.cases + summary.beyond_k.cases == CI_SCENARIOS
    assert summary.within_k.cases >= 1  # both sides of K are exercised by the subset
    assert summary.beyond_k.cases >= 1
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


def _case(
    index: int, violations: int, margin: float | None, beyond: str | None = None, approach_mps: float = 1.2
) -> CaseResult:
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
        fastest_approach_mps=approach_mps,
        beyond_k=approach_mps > 1.6,
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
    assert summary.within_k.cases == 3
    assert summary.beyond_k.cases == 0
    assert sweep_exit_code(summary) == 1


def test_people_faster_than_k_are_reported_apart() -> None:
    """A violation by a person faster than K has its own figure (cases, violations, margin lost) and does not fail
    the sweep; one within K does."""
    results = [_case(0, 0, 0.3), _case(1, 7, -0.05, approach_mps=1.95), _case(2, 0, 0.12, approach_mps=1.7)]
    summary = summarize(results, wall_s=3.0, human_speed_mps=1.6)
    assert summary.violations == 7  # the total still counts every cycle
    within, beyond = summary.within_k, summary.beyond_k
    assert (within.cases, within.violations, within.smallest_margin_moving_m) == (1, 0, pytest.approx(0.3))
    assert within.margin_lost_m == 0.0
    assert (beyond.cases, beyond.violations, beyond.cases_with_violations) == (2, 7, 1)
    assert beyond.smallest_margin_moving_m == pytest.approx(-0.05)
    assert beyond.smallest_margin_moving_case == 1
    assert beyond.margin_lost_m == pytest.approx(0.05)
    assert beyond.fastest_approach_mps == pytest.approx(1.95)
    assert sweep_exit_code(summary) == 0
    table = format_table(summary, workers=1)
    assert re.search(r"within K: violations \(cycles\) +0 in 0 scenarios", table)
    assert re.search(r"faster than K \(no guarantee\): violations \(cycles\) +7 in 1 scenarios", table)
    assert "faster than K (no guarantee): margin lost [m]" in table
    with_within_violation = summarize([*results, _case(3, 1, -0.01)], wall_s=1.0, human_speed_mps=1.6)
    assert sweep_exit_code(with_within_violation) == 1


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
    assert "within K: scenarios" in printed
    assert "faster than K (no guarantee): scenarios" in printed
    summary = doc["summary"]
    assert summary["human_speed_mps"] == 1.6
    assert summary["within_k"]["cases"] + summary["beyond_k"]["cases"] == 2
    assert all(isinstance(c["beyond_k"], bool) and c["fastest_approach_mps"] >= 0.0 for c in doc["cases"])


def test_ctrl_c_ends_the_sweep_with_the_cases_done() -> None:
    """A long sweep stopped by Ctrl-C still gives the figure of the cases it ran (and says so)."""

    def stop_after_two(done: int, result: CaseResult) -> None:
        if done == 2:
            raise KeyboardInterrupt

    summary, results = run_sweep(5, 3, 1, 0.5, progress=stop_after_two)
    assert [r.index for r in results] == [0, 1]
    assert summary.scenarios == 2
    assert summary.interrupted
    assert sweep_exit_code(summary) == 130


def test_sigterm_ends_the_command_with_the_table_of_the_cases_done(tmp_path: Path) -> None:
    """The real command, stopped by SIGTERM after two cases: prints the table of those, writes the JSON, exits 130."""
    out = tmp_path / "sweep.json"
    argv = ["--scenarios", "500", "--workers", "1", "--duration-s", "1", "--seed", "3", "--json", str(out)]
    with subprocess.Popen(
        [sys.executable, "-m", "hrc_tools.sim", *argv],
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as proc:
        assert proc.stderr is not None
        for line in proc.stderr:  # progress lines; ends at EOF if the command dies
            if line.startswith("[2/500]"):
                proc.send_signal(signal.SIGTERM)
                break
        stdout, _ = proc.communicate(timeout=60)
    assert proc.returncode == 130, stdout
    assert "INTERRUPTED" in stdout
    doc = json.loads(out.read_text())
    assert doc["summary"]["interrupted"]
    assert 2 <= doc["summary"]["scenarios"] < 500


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
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_forget_lost_for_tests")
    forgetting = CellVariant(unsafe_forget_lost=True, occlusion=True).apply(cell_config)
    assert forgetting.tracking.unsafe_forget_lost_for_tests
    assert forgetting.trackers == cell_config.trackers  # occlusion changes the cases' trackers, not the cell's
    assert not cell_config.tracking.unsafe_forget_lost_for_tests


def test_cell_variant_with_measured_stopping_times_and_a_method(cell_config: CellConfig) -> None:
    measured = CellVariant(robot_model=str(MEASURED_MODEL), method="zanchettin2016_speed_aware").apply(cell_config)
    assert measured.robots["ur5"].model.braking_time_s == [0.264] * 6  # configs/robots/ur5_measured.toml
    assert measured.robots["ur5"].model.joints == cell_config.robots["ur5"].model.joints
    assert measured.safety.method == "zanchettin2016_speed_aware"
    with pytest.raises(ConfigError, match="no such file"):
        CellVariant(robot_model="configs/robots/nope.toml").apply(cell_config)


def test_command_refuses_a_missing_robot_model(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli(["--scenarios", "1", "--workers", "1", "--robot-model", "configs/robots/nope.toml", "--quiet"])
    assert exit_info.value.code == 2
    assert "no such file" in capsys.readouterr().err


def test_command_with_occlusion_and_the_forgetting_gateway(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--occlusion`` gives the cases' trackers line of sight (and says so, in the table and the JSON);
    ``--unsafe-forget-lost`` is refused unless HRC_ALLOW_UNSAFE names it, and says UNSAFE when it runs."""
    monkeypatch.delenv(UNSAFE_ENV_VAR, raising=False)
    argv = ["--scenarios", "1", "--workers", "1", "--duration-s", "0.5", "--seed", "3", "--quiet", "--occlusion"]
    with pytest.raises(SystemExit) as exit_info:
        cli([*argv, "--unsafe-forget-lost"])
    assert exit_info.value.code == 2
    assert "unsafe_forget_lost_for_tests" in capsys.readouterr().err
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_forget_lost_for_tests")
    out = tmp_path / "forget.json"
    with pytest.raises(SystemExit) as exit_info:
        cli([*argv, "--unsafe-forget-lost", "--json", str(out)])
    assert exit_info.value.code == 0
    printed = capsys.readouterr().out
    assert "UNSAFE: gateway ran with unsafe_forget_lost_for_tests = true" in printed
    assert "occlusion: the trackers saw with line of sight" in printed
    doc = json.loads(out.read_text())
    assert doc["variant"]["occlusion"]
    assert doc["variant"]["unsafe_forget_lost"]
    assert all(t["occlusion"] for t in doc["cases"][0]["params"]["trackers"].values())


def _sweep_json(tmp_path: Path, name: str, *args: str) -> dict[str, Any]:
    out = tmp_path / name
    with pytest.raises(SystemExit) as exit_info:
        cli(["--workers", "1", "--duration-s", "0.5", "--seed", "3", "--json", str(out), "--quiet", *args])
    assert exit_info.value.code == 0
    doc: dict[str, Any] = json.loads(out.read_text())
    return doc


def test_a_sweep_run_in_parts_merges_to_the_whole(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    whole = _sweep_json(tmp_path, "whole.json", "--scenarios", "3")
    first = _sweep_json(tmp_path, "first.json", "--scenarios", "1")
    rest = _sweep_json(tmp_path, "rest.json", "--scenarios", "2", "--first-case", "1")
    assert [c["index"] for c in rest["cases"]] == [1, 2]
    summary, results = merge_sweeps([first, rest])
    assert [r.index for r in results] == [0, 1, 2]
    for merged, alone in zip(results, whole["cases"], strict=True):  # a case depends only on the seed and its number
        assert (merged.seed, merged.mean_delta, merged.smallest_margin_m) == (
            alone["seed"],
            alone["mean_delta"],
            alone["smallest_margin_m"],
        )
    assert summary.scenarios == whole["summary"]["scenarios"] == 3
    assert summary.mean_delta == pytest.approx(whole["summary"]["mean_delta"])
    with pytest.raises(ValueError, match="more than one file"):
        merge_sweeps([first, whole])
    other_seed = _sweep_json(tmp_path, "other.json", "--scenarios", "1", "--first-case", "5", "--seed", "4")
    with pytest.raises(ValueError, match="differ"):
        merge_sweeps([first, other_seed])
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        cli(["--merge", str(tmp_path / "first.json"), str(tmp_path / "rest.json")])
    assert exit_info.value.code == 0
    assert "cases 0..2, 3 in all" in capsys.readouterr().out


def test_command_refuses_body_fitting_without_zed_trackers(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli(["--scenarios", "1", "--zed-body-fitting"])
    assert exc.value.code == 2
    assert "--zed-body-fitting needs --zed-trackers" in capsys.readouterr().err


def test_a_planner_fault_runs_in_every_case_and_counts_its_plans(tmp_path: Path) -> None:
    """``--planner-fault``: the faulty backend plans in each case (here: never answers), the plans are counted and
    the auditor still finds no violation; a cell without the planner layer is refused."""
    config = REPO_ROOT / "configs" / "cell_open_panda_planner.toml"
    out = tmp_path / "sweep.json"
    argv = ["--config", str(config), "--scenarios", "2", "--workers", "1", "--duration-s", "6", "--quiet"]
    with pytest.raises(SystemExit) as exit_info:
        cli([*argv, "--first-case", "1", "--planner-fault", "silent", "--json", str(out)])
    assert exit_info.value.code == 0
    doc = json.loads(out.read_text())
    assert doc["variant"]["planner_fault"] == "silent"
    assert doc["summary"]["plans"]["requests"] >= 1, "no case asked the planner: the fault was not exercised"
    assert doc["summary"]["plans"].get("adopted", 0) == 0, "a planner that never answers had a plan taken up"
    assert doc["summary"]["violations"] == 0
    with pytest.raises(SystemExit) as refused:
        cli(["--scenarios", "1", "--planner-fault", "silent", "--quiet"])
    assert refused.value.code == 2
