"""Teeth: delayed scenarios that the auditor flags when the gateway ignores the delay or takes the maximum of
the bounds, and that the real gateway passes (safety-math.md §9). A test that could not fail proves nothing.

Most cases run in the default cell made *tight*: the gateway assumes for every joint the braking time
that the emulated controller really has (0.24 s) instead of the UR5 manual's up to 0.53 s, so that
nothing but the delay handling stands between the gateway and a violation. In the default cell that
slack (the robot stops in less than half the time the gateway plans for) absorbs most delays the data
age limit allows: a search over tracker delays 0.1–0.15 s, override delays up to 0.08 s, 1.6–2.0 m/s,
bearings 0 / ±40° and 6 program phases found violations of the delay-blind gateway only with both
delays at once and a person at 2.0 m/s (the last case below).

Each scenario: one person walks straight at the robot (floor position 3 m → 0.6 m from the base, along
the bearing given, facing it), seen by one 30 Hz tracker without noise; the tracker link and/or the
override link are delayed; the program starts at ``tau`` [s]. At 1.6 m/s the person stays within the
gateway's assumption (K = 1.6 m/s).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pytest

import gateway.methods
from gateway.separation import ConstraintRows
from hrc_contract.config import UNSAFE_ENV_VAR, CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_tools.sim.cell import RunResult, simulate
from hrc_tools.sim.links import LinkFault, LinkFaults
from hrc_tools.sim.sweep import CellVariant
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

DURATION_S = 4.0
SEED = 1


class Teeth(NamedTuple):
    name: str
    tracker_delay_s: float
    override_delay_s: float
    speed_mps: float
    bearing_deg: float
    tau_s: float


def approach(bearing_deg: float, speed_mps: float, stop_m: float = 0.6, start_m: float = 3.0) -> Scenario:
    """One person walking straight at the robot base along ``bearing_deg``, then standing."""
    bearing = math.radians(bearing_deg)
    x0, y0 = start_m * math.cos(bearing), start_m * math.sin(bearing)
    x1, y1 = stop_m * math.cos(bearing), stop_m * math.sin(bearing)
    facing = math.atan2(-y0, -x0)
    t0 = 0.2
    t1 = t0 + (start_m - stop_m) / speed_mps
    keyframes = [
        Keyframe(t_s=t0, xy_m=(x0, y0), heading_rad=facing),
        Keyframe(t_s=t1, xy_m=(x1, y1), heading_rad=facing),
        Keyframe(t_s=DURATION_S, xy_m=(x1, y1), heading_rad=facing),
    ]
    return Scenario(
        description="teeth: straight approach",
        duration_s=DURATION_S,
        loop=False,
        humans=[HumanScript(id="h1", keyframes=keyframes)],
    )


def cell(base: CellConfig, tight: bool, ignore_delay: bool) -> tuple[CellConfig, dict[str, RobotModel]]:
    """The default cell with one noiseless 30 Hz tracker, tight braking times or not, delay-blind or not."""
    raw = base.model_dump()
    raw["trackers"] = {"front": {"rate_hz": 30.0, "noise_std_m": 0.0, "drop_probability": 0.0, "latency_s": 0.0}}
    variant = CellVariant(unsafe_ignore_delay=ignore_delay, tight_braking=tight)
    config = variant.apply(CellConfig.model_validate(raw))
    return config, {name: load_robot_model(name, r) for name, r in config.robots.items()}


def run(config: CellConfig, robots: dict[str, RobotModel], teeth: Teeth) -> RunResult:
    links = LinkFaults(
        tracker_to_gateway=LinkFault(delay_s=teeth.tracker_delay_s),
        gateway_to_controller=LinkFault(delay_s=teeth.override_delay_s),
    )
    scenario = approach(teeth.bearing_deg, teeth.speed_mps)
    return simulate(config, robots, scenario, links, DURATION_S, SEED, program_start_s={"ur5": teeth.tau_s})


def max_of_bounds(rows: ConstraintRows) -> float:
    """The wrong reduction of paper 1's "δ = max_i δ^(i)": the farthest row decides (rows with e ≤ 0: none)."""
    finite = rows.bound[np.isfinite(rows.bound)]
    return 1.0 if finite.size == 0 else float(np.clip(finite.max(), 0.0, 1.0))


@pytest.fixture(scope="module")
def tight(cell_config: CellConfig) -> tuple[CellConfig, dict[str, RobotModel]]:
    return cell(cell_config, tight=True, ignore_delay=False)


IGNORE_DELAY_TEETH = [
    # 0.1 s on the tracker link: the person is 0.16 m closer than the gateway sees.
    (Teeth("tight, tracker link 0.1 s, head-on", 0.1, 0.0, 1.6, 0.0, 2.0), True),
    # 0.08 s on the override link (below the controller's 0.1 s watchdog): the stop arrives late.
    (Teeth("tight, override link 0.08 s, from the right", 0.0, 0.08, 1.6, -40.0, 0.0), True),
    # The default cell: both links delayed near their budget, a person at 2.0 m/s.
    (Teeth("default, tracker 0.15 s + override 0.08 s, 2 m/s from the left", 0.15, 0.08, 2.0, 40.0, 4.0), False),
]


@pytest.mark.parametrize(("teeth", "tight_cell"), IGNORE_DELAY_TEETH, ids=[t.name for t, _ in IGNORE_DELAY_TEETH])
def test_ignoring_the_delay_violates_where_the_real_gateway_does_not(
    cell_config: CellConfig, teeth: Teeth, tight_cell: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_ignore_delay_for_tests")  # the test-only setting is refused without
    unsafe = run(*cell(cell_config, tight=tight_cell, ignore_delay=True), teeth)
    assert unsafe.t_delay_max_s == 0.0
    assert unsafe.audit.violations > 10, unsafe.to_dict()["audit"]
    assert unsafe.audit.smallest_margin_m < 0.0
    real = run(*cell(cell_config, tight=tight_cell, ignore_delay=False), teeth)
    assert real.audit.violations == 0, real.to_dict()["audit"]
    assert real.audit.smallest_margin_moving_m > 0.1
    assert real.t_delay_min_s is not None
    assert real.t_delay_min_s > teeth.tracker_delay_s + teeth.override_delay_s


MAX_OF_BOUNDS_TEETH = [
    Teeth("override link 0.08 s, from the left", 0.0, 0.08, 1.6, 40.0, 2.0),
]


@pytest.mark.parametrize("teeth", MAX_OF_BOUNDS_TEETH, ids=lambda t: t.name)
def test_max_of_the_bounds_violates_where_the_min_does_not(
    tight: tuple[CellConfig, dict[str, RobotModel]],
    teeth: Teeth,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    real = run(*tight, teeth)
    assert real.audit.violations == 0, real.to_dict()["audit"]
    assert real.audit.smallest_margin_moving_m > 0.1
    monkeypatch.setattr(gateway.methods, "override_from_rows", max_of_bounds)
    wrong = run(*tight, teeth)
    assert wrong.audit.violations > 10, wrong.to_dict()["audit"]
    assert wrong.audit.smallest_margin_m < 0.0


# -- the speed-aware method (safety-math.md §10) --------------------------------------------------------

SPEED_AWARE = "zanchettin2016_speed_aware"


def speed_aware(base: CellConfig) -> CellConfig:
    return base.model_copy(update={"safety": base.safety.model_copy(update={"method": SPEED_AWARE})})


SPEED_AWARE_TEETH = [*IGNORE_DELAY_TEETH, *((t, True) for t in MAX_OF_BOUNDS_TEETH)]


@pytest.mark.parametrize(("teeth", "tight_cell"), SPEED_AWARE_TEETH, ids=[t.name for t, _ in SPEED_AWARE_TEETH])
def test_speed_aware_passes_where_its_delay_blind_twin_violates(
    cell_config: CellConfig, teeth: Teeth, tight_cell: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The speed-aware method stops from δ in δ t_b: it comes closer than eq. (15), so the same delayed scenarios
    must hold it too (0 violations, margin while moving > 0.1 m), and the delay must matter for it as well."""
    base = speed_aware(cell_config)
    real = run(*cell(base, tight=tight_cell, ignore_delay=False), teeth)
    assert real.audit.violations == 0, real.to_dict()["audit"]
    assert real.audit.smallest_margin_moving_m > 0.1
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_ignore_delay_for_tests")
    unsafe = run(*cell(base, tight=tight_cell, ignore_delay=True), teeth)
    assert unsafe.audit.violations > 10, unsafe.to_dict()["audit"]
    assert unsafe.audit.smallest_margin_m < 0.0
