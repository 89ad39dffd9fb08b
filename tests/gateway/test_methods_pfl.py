"""The contact-speed method ``lucci2020_pfl`` (safety-math.md §12): §10's form with the slow-down ending at a body
region's contact-safe speed δ_c instead of 0; the head and a body part that may be pinned fall back to separation.

Known answers, the closed form against a bisection of its inequality, equality with the speed-aware bounds at δ_c = 0,
monotonicity, fail-closed on nan, and the method inside :class:`gateway.core.SafetyCore` with the real UR5: a hand
pinned between the tool and a clamping surface stops the robot as separation monitoring does; the head is approached
as separation would; a free hand lets it move at the contact-safe speed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.known_cases import MS, NOW, QD_NOMINAL, Cell, Q

from gateway.contact import contact_bounds
from gateway.reference.kinematics import link_kinematics
from gateway.separation import speed_aware_bounds
from hrc_contract.config import Box, CellConfig
from hrc_devices.robots.model import RobotModel

K = 1.6
C = 0.05


def one_pair(d: float, e: float, t_b: float, t_delay: float, delta_c: float) -> float:
    bounds = contact_bounds(
        np.array([[d]]), np.full((1, 1, 2, 2), e), np.array([t_b]), t_delay, np.array([[K]]), C, np.array([[delta_c]])
    )
    return bounds.min_bound


def slack(delta: float, d: float, e: float, t_b: float, t_delay: float, delta_c: float) -> float:
    """Right minus left of ``δ (t_delay + (δ − δ_c) t_b) e ≤ max(0, d − Δ_c(δ))²`` with the human-alone bound; any
    δ ≤ δ_c is allowed."""
    if delta <= delta_c:
        return 1.0
    margin = d - (C + K * (t_delay + (delta - delta_c) * t_b))
    if margin < 0.0:
        return margin
    return margin * margin - delta * (t_delay + (delta - delta_c) * t_b) * max(e, 0.0)


def bisect(d: float, e: float, t_b: float, t_delay: float, delta_c: float) -> float:
    if slack(1.0, d, e, t_b, t_delay, delta_c) >= 0.0:
        return 1.0
    lo, hi = delta_c, 1.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if slack(mid, d, e, t_b, t_delay, delta_c) >= 0.0 else (lo, mid)
    return lo


# -- the bound ---------------------------------------------------------------------------------------------------


def test_known_answer_without_delay() -> None:
    # t_delay = 0: e (δ_c + y) t_b y ≤ (A − B y)², A = d − c = 0.95, B = K t_b = 0.8, e = 2, t_b = 0.5, δ_c = 0.2:
    # a = e t_b − B² = 1 − 0.64 = 0.36, b = e δ_c t_b + 2 A B = 0.2 + 1.52 = 1.72, c₀ = −A² = −0.9025
    # y = 2 · 0.9025 / (1.72 + sqrt(2.9584 + 1.2996)) = 1.805 / (1.72 + 2.06349) = 0.477074; δ = 0.677074
    assert one_pair(1.0, 2.0, 0.5, 0.0, 0.2) == pytest.approx(0.2 + 1.805 / (1.72 + math.sqrt(4.258)), rel=1e-12)


def test_contact_speed_is_always_allowed_and_separation_at_zero() -> None:
    # within c + K t_delay of the person: δ_c, not 0 (transient contact at that speed is acceptable)
    assert one_pair(0.1, 5.0, 0.5, 0.1, 0.4) == pytest.approx(0.4)
    assert one_pair(0.1, 5.0, 0.5, 0.1, 0.0) == 0.0
    # moving away: the human-alone bound shifted by δ_c: 0.3 + (1 − 0.05 − 0.16) / 0.8 = 1.2875 → δ = 1 allowed
    assert one_pair(1.0, -3.0, 0.5, 0.1, 0.3) == pytest.approx(1.2875)


def test_equals_the_speed_aware_bounds_at_zero_contact_speed() -> None:
    rng = np.random.default_rng(12)
    for _ in range(200):
        d = rng.uniform(0.0, 3.0, (3, 4))
        e = rng.uniform(-3.0, 5.0, (3, 4, 2, 2))
        t_b = rng.uniform(0.1, 0.6, 3)
        k = np.full((3, 4), K)
        t_delay = float(rng.uniform(0.0, 0.2))
        ours = contact_bounds(d, e, t_b, t_delay, k, C, np.zeros((3, 4)))
        theirs = speed_aware_bounds(d, e, t_b, t_delay, k, C)
        np.testing.assert_allclose(ours.human, theirs.human_m, rtol=1e-12)
        np.testing.assert_allclose(ours.row, theirs.row, rtol=1e-9, atol=1e-12)


def test_closed_form_equals_bisection_on_random_instances() -> None:
    rng = np.random.default_rng(2020)
    for _ in range(300):
        d, e = float(rng.uniform(0.0, 3.0)), float(rng.uniform(-2.0, 8.0))
        t_b, t_delay, delta_c = float(rng.uniform(0.05, 0.6)), float(rng.uniform(0.0, 0.25)), float(rng.uniform(0, 1))
        got = min(max(one_pair(d, e, t_b, t_delay, delta_c), 0.0), 1.0)
        assert got == pytest.approx(bisect(d, e, t_b, t_delay, delta_c), abs=1e-9)


def test_monotone_closer_older_or_slower_contact_never_raises_delta() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        d, e = float(rng.uniform(0.2, 3.0)), float(rng.uniform(0.0, 8.0))
        t_b, t_delay, delta_c = float(rng.uniform(0.05, 0.6)), float(rng.uniform(0.0, 0.2)), float(rng.uniform(0, 0.9))
        base = one_pair(d, e, t_b, t_delay, delta_c)
        assert one_pair(d * 0.8, e, t_b, t_delay, delta_c) <= base + 1e-12
        assert one_pair(d, e, t_b, t_delay + 0.05, delta_c) <= base + 1e-12
        assert one_pair(d, e, t_b, t_delay, delta_c * 0.5) <= base + 1e-12
        assert base >= delta_c


def test_nan_anywhere_gives_nan() -> None:
    assert math.isnan(one_pair(math.nan, 1.0, 0.5, 0.1, 0.2))
    assert math.isnan(one_pair(1.0, math.nan, 0.5, 0.1, 0.2))
    assert math.isnan(one_pair(1.0, 1.0, 0.5, 0.1, math.nan))


# -- in the gateway's core with the UR5 ----------------------------------------------------------------------------


def _pfl(config: CellConfig, **update: object) -> CellConfig:
    safety = config.safety.model_copy(update={"method": "lucci2020_pfl", **update})
    return config.model_copy(update={"safety": safety})


FAST = 4.0
"""The tests' programmed speed: QD_NOMINAL × 4 (tool0 at ~1.5 m/s, above a hand's contact-safe speed)."""


def _ahead_of_tool(
    ur5: RobotModel, distance_m: float, name: str, radius_m: float
) -> tuple[dict[str, object], list[np.ndarray]]:
    """A capsule ``distance_m`` from tool0's surface along its programmed velocity, and the unit direction."""
    links = link_kinematics(ur5, ur5.model.createData(), np.asarray(Q), FAST * np.asarray(QD_NOMINAL))
    u = links.v_b_world[-1] / np.linalg.norm(links.v_b_world[-1])
    p = links.p_b_world[-1] + (distance_m + 0.07 + radius_m) * u
    return {"name": name, "a": p.tolist(), "b": p.tolist(), "radius": radius_m}, [p, u]


def _box_behind(p: np.ndarray, u: np.ndarray, gap_m: float) -> Box:
    """A 0.4 m box whose nearest face is ``gap_m`` beyond ``p`` along the axis ``u`` is mostly along."""
    axis = int(np.argmax(np.abs(u)))
    centre = p.copy()
    centre[axis] += np.sign(u[axis]) * (gap_m + 0.2)
    return Box(min_m=tuple(centre - 0.2), max_m=tuple(centre + 0.2))


def _run(
    config: CellConfig,
    ur5: RobotModel,
    capsule: dict[str, object],
    cycles: int = 40,
    first: dict[str, object] | None = None,
) -> tuple[float, str | None]:
    """δ and what bounded it after ``cycles`` decisions with ``capsule`` seen (after as many with ``first``, if given:
    a person who came closer, so that the start-up safety exception has ended)."""
    cell = Cell(config, ur5)
    now, delta, by = NOW, 1.0, None
    for capsules in [first] * (cycles if first is not None else 0) + [capsule] * cycles:
        now += 4 * MS
        cell.joint(now, qd_nominal=[FAST * v for v in QD_NOMINAL])
        cell.humans(now, [capsules])
        d = cell.step(now)
        assert d.faults == ()
        assert 0.0 <= d.delta <= d.delta_bound <= 1.0
        delta, by = d.delta, d.bounded_by
    return delta, by


def _speed_aware(config: CellConfig) -> CellConfig:
    return config.model_copy(
        update={"safety": config.safety.model_copy(update={"method": "zanchettin2016_speed_aware"})}
    )


def test_a_free_hand_ahead_of_the_tool_lets_it_move_at_the_contact_speed(
    cell_config: CellConfig, ur5: RobotModel
) -> None:
    """A hand 0.5 m ahead of the tool: the speed-aware method crawls (δ ≈ 0.11), this one moves at a speed that can
    still slow to the hand's contact-safe speed (contact:hand); a hand that came to 0.2 m: it still moves."""
    pfl = _pfl(cell_config, pfl_clamping_surfaces=[])
    hand, _ = _ahead_of_tool(ur5, 0.5, "hand_r", 0.05)
    delta, by = _run(pfl, ur5, hand)
    assert delta > 0.4
    assert by == "contact:hand"
    assert _run(_speed_aware(cell_config), ur5, hand)[0] < 0.2
    close, _ = _ahead_of_tool(ur5, 0.2, "hand_r", 0.05)
    assert _run(pfl, ur5, close, first=hand)[0] > 0.3


def test_a_hand_pinned_between_the_tool_and_a_table_stops_the_robot(cell_config: CellConfig, ur5: RobotModel) -> None:
    """The same hand with a clamping surface 5 cm behind it, the tool moving toward it: contact-safe speed 0, exactly
    the speed-aware bound at 0.5 m, and stopped when it has come to 0.2 m (as separation monitoring stops)."""
    hand, (_, u) = _ahead_of_tool(ur5, 0.5, "hand_r", 0.05)
    close, (p_close, _) = _ahead_of_tool(ur5, 0.2, "hand_r", 0.05)
    pinned = _pfl(cell_config, pfl_clamping_surfaces=[_box_behind(p_close, u, 0.05 + 0.05)])
    away = _pfl(cell_config, pfl_clamping_surfaces=[_box_behind(p_close, -u, 0.6)])  # behind the robot: no pinning
    assert _run(pinned, ur5, close, first=hand) == (0.0, "clamping:hand")
    assert _run(_speed_aware(cell_config), ur5, close, first=hand)[0] == 0.0
    assert _run(away, ur5, close, first=hand)[0] > 0.3


def test_the_head_is_approached_as_separation_would(cell_config: CellConfig, ur5: RobotModel) -> None:
    """The head at 0.5 m and at 1.2 m: exactly the speed-aware method's bound (contact-safe speed 0); come to 0.2 m:
    stopped. The same capsule named a hand moves faster."""
    pfl = _pfl(cell_config, pfl_clamping_surfaces=[])
    for distance_m in (0.5, 1.2):
        head, _ = _ahead_of_tool(ur5, distance_m, "head", 0.11)
        delta, by = _run(pfl, ur5, head)
        assert 0.0 < delta < 1.0
        assert by == "separation:head"
        assert delta == pytest.approx(_run(_speed_aware(cell_config), ur5, head)[0], rel=1e-12)
        assert _run(pfl, ur5, {**head, "name": "hand_r"})[0] > delta
    far, _ = _ahead_of_tool(ur5, 0.5, "head", 0.11)
    near, _ = _ahead_of_tool(ur5, 0.2, "head", 0.11)
    assert _run(pfl, ur5, near, first=far) == (0.0, "separation:head")


def test_delta_with_the_mass_bound_is_never_above_delta_with_the_simple_form(
    cell_config: CellConfig, ur5: RobotModel, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A chest and a hand ahead of the tool at the known case's configuration (outside the program's box: every link
    counts as rigid, μ = m_H): never more than with M/2 + m_payload = 9.5 kg, and for the chest strictly less (its
    contact speed falls with the robot's mass). Inside the box the bound is ≥ 9.5 kg per link
    (tests/hrc_devices/robots/test_effective_mass.py), so the same order holds there."""
    monkeypatch.setenv("HRC_ALLOW_UNSAFE", "pfl_simple_mass_for_tests")
    pfl = _pfl(cell_config, pfl_clamping_surfaces=[])
    simple = _pfl(cell_config, pfl_clamping_surfaces=[], pfl_mass_model="simple")
    for name, radius_m in (("torso", 0.15), ("hand_r", 0.05)):
        for distance_m in (0.3, 0.6, 1.0):
            capsule, _ = _ahead_of_tool(ur5, distance_m, name, radius_m)
            bound, simple_delta = _run(pfl, ur5, capsule)[0], _run(simple, ur5, capsule)[0]
            assert bound <= simple_delta + 1e-12
            if name == "torso" and distance_m == 0.6:
                assert bound < simple_delta
