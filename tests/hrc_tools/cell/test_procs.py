"""The waits of the cell's programs stretch with the machine's load (issue 36: start-up waits scale with the load,
not fixed ones that fail on a busy machine)."""

from __future__ import annotations

import math
import time

import pytest

from hrc_tools.cell import procs
from hrc_tools.cell.procs import MAX_LOAD_SCALE, StartupError, late_data_only, load_scale, recovered, wait_for


@pytest.mark.parametrize(
    ("load_per_core", "scale"),
    [(0.0, 1.0), (0.5, 1.0), (1.0, 1.0), (2.5, 2.5), (4.0, 4.0), (9.0, MAX_LOAD_SCALE), (math.nan, MAX_LOAD_SCALE)],
)
def test_the_load_scale_is_the_load_per_core_between_one_and_its_cap(load_per_core: float, scale: float) -> None:
    assert load_scale(load_per_core) == scale


def test_this_machines_scale_is_within_its_bounds() -> None:
    assert 1.0 <= load_scale() <= MAX_LOAD_SCALE


def test_a_wait_that_holds_returns_at_once_and_one_in_vain_says_how_long_it_was_stretched(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    assert wait_for(lambda: True, 5.0, "nothing") < 5.0
    monkeypatch.setattr(procs, "load_scale", lambda: 3.0)
    start_s = time.monotonic()
    with pytest.raises(StartupError, match=r"waiting for the impossible \(0\.1 s on an idle machine, × 3\.00"):
        wait_for(lambda: False, 0.1, "the impossible")
    assert time.monotonic() - start_s >= 0.3  # the deadline was stretched to 3 × 0.1 s, never less


def _status(delta: float, *codes: str) -> dict[str, object]:
    return {"delta": delta, "faults": [{"code": c, "reason": f"{c} here"} for c in codes]}


def test_late_data_that_failed_closed_is_all_a_busy_machine_explains() -> None:
    assert late_data_only([_status(1.0), _status(0.0, "tracker_stale", "override_path_stale")]) == []
    assert late_data_only([_status(0.0, "joint_state_implausible")]) == [
        "joint_state_implausible: joint_state_implausible here"
    ]
    assert late_data_only([_status(0.3, "tracker_stale")]) == ["δ = 0.3 with faults ['tracker_stale']"]


def _robot(delta: float, zone: str, distance_m: float | None, resume_m: float = 1.2, *codes: str) -> dict[str, object]:
    return {
        **_status(delta, *codes),
        "controller_mode": "running",
        "zone": zone,
        "min_distance_m": distance_m,
        "thresholds_m": {"resume_m": resume_m},
    }


def test_recovered_is_moving_or_held_by_a_distance_the_status_shows() -> None:
    assert recovered(_robot(0.4, "reduced_speed", 1.5))
    assert recovered(_robot(0.0, "safety_exception", 1.18))  # the person stands inside the resume distance (1.2 m)
    assert not recovered(_robot(0.0, "safety_exception", 1.25))  # beyond it: the robot should have resumed
    assert not recovered(_robot(0.0, "safety_exception", None))  # nobody seen: nothing holds it
    assert not recovered(_robot(0.0, "reduced_speed", 1.0))  # stopped outside a safety exception
    assert not recovered(_robot(0.0, "safety_exception", 1.0, 1.2, "tracker_stale"))  # a fault still shown
    assert not recovered(_robot(0.5, "reduced_speed", 1.5, 1.2, "tracker_stale"))
    assert not recovered({**_robot(0.5, "reduced_speed", 1.5), "controller_mode": "protective_stop"})
    held = {**_robot(0.0, "safety_exception", 1.18), "controller_mode": "stopped"}  # δ = 0 applied: the robot stands
    assert recovered(held)
    assert not recovered({**held, "controller_mode": "protective_stop"})  # its watchdog: no overrides reach it
