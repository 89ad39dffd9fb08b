"""Transient contact (gateway/contact.py, safety-math.md §12): ISO/TS 15066 Annex A contact-safe speeds, the robot's
effective mass (simple form and reflected mass from Pinocchio, checked against an independent computation), the body
region table, and clamping.

Known answers: issue 21's worked figures for a UR5 with 1 kg payload (m_R = M/2 + 1 = 9.5 kg): hand ≈ 1.36 m/s,
chest ≈ 0.64 m/s, face ≈ 0.27 m/s, from ISO/TS 15066 Table A.2 (transient F = 2 × quasi-static) and Table A.3.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from gateway.contact import (
    NO_REGION,
    RegionTable,
    box_arrays,
    clamped_pairs,
    contact_delta,
    energy_contact_speed_mps,
    force_contact_speed_mps,
    reduced_mass_kg,
    region_contact_speed_mps,
    simple_robot_mass_kg,
)
from hrc_contract.config import BodyRegion, Box, CellConfig
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.effective_mass import moving_mass_kg, reflected_mass_kg, with_payload
from hrc_devices.robots.model import RobotModel

HAND = BodyRegion(capsules=["hand_r"], max_force_n=280.0, spring_constant_n_per_m=75_000.0, mass_kg=0.6)
CHEST = BodyRegion(capsules=["torso"], max_force_n=280.0, spring_constant_n_per_m=25_000.0, mass_kg=40.0)
FACE = BodyRegion(capsules=["face"], max_force_n=130.0, spring_constant_n_per_m=75_000.0, mass_kg=4.4)
HEAD = BodyRegion(capsules=["head"], transient=False, mass_kg=4.4)


# -- the formulas: known answers --------------------------------------------------------------------------------


def test_reduced_mass_known_answer() -> None:
    # 1 / (1/0.6 + 1/9.5) = 0.6 · 9.5 / 10.1 = 0.564356...
    assert reduced_mass_kg(0.6, 9.5) == pytest.approx(0.6 * 9.5 / 10.1, rel=1e-12)


def test_force_form_issue_21_worked_figures() -> None:
    """Hand: μ = 0.56436, sqrt(μ k) = sqrt(42327) = 205.74 N s/m, 280 / 205.74 = 1.361 m/s; chest: μ = 40·9.5/49.5 =
    7.6768, sqrt(191919) = 438.09, 280 / 438.09 = 0.639 m/s; face: μ = 4.4·9.5/13.9 = 3.0072, 130 / sqrt(225540)
    = 0.2737 m/s."""
    assert force_contact_speed_mps(280.0, 75_000.0, reduced_mass_kg(0.6, 9.5)) == pytest.approx(1.3610, abs=5e-4)
    assert force_contact_speed_mps(280.0, 25_000.0, reduced_mass_kg(40.0, 9.5)) == pytest.approx(0.6391, abs=5e-4)
    assert force_contact_speed_mps(130.0, 75_000.0, reduced_mass_kg(4.4, 9.5)) == pytest.approx(0.2737, abs=5e-4)


def test_energy_form_known_answer_and_agrees_with_the_force_form() -> None:
    # sqrt(2 · 0.49 / 0.564356) = sqrt(1.73648) = 1.31776 m/s
    assert energy_contact_speed_mps(0.49, reduced_mass_kg(0.6, 9.5)) == pytest.approx(1.31776, abs=1e-5)
    # E_max = F² / (2k) is the same limit: ½ μ v² = F² / (2k) at v = F / sqrt(μ k)
    for force, k, m_h in ((280.0, 75_000.0, 0.6), (280.0, 25_000.0, 40.0), (320.0, 40_000.0, 2.0)):
        mu = reduced_mass_kg(m_h, 9.5)
        energy = force * force / (2.0 * k)
        assert energy_contact_speed_mps(energy, mu) == pytest.approx(force_contact_speed_mps(force, k, mu), rel=1e-12)


def test_region_speed_takes_the_smaller_form_and_zero_without_transient_contact() -> None:
    both = HAND.model_copy(update={"max_energy_j": 0.49})
    mu = reduced_mass_kg(0.6, 9.5)
    assert region_contact_speed_mps(both, 9.5) == pytest.approx(energy_contact_speed_mps(0.49, mu))
    assert region_contact_speed_mps(HAND, 9.5) == pytest.approx(1.3610, abs=5e-4)
    assert region_contact_speed_mps(HEAD, 9.5) == 0.0


def test_a_transient_region_needs_a_limit() -> None:
    with pytest.raises(ValueError, match="needs max_force_n"):
        BodyRegion(capsules=["hand_r"], mass_kg=0.6)


# -- the robot's effective mass -----------------------------------------------------------------------------------


def test_simple_mass_of_the_ur5(ur5: RobotModel) -> None:
    """M = 3.7 + 8.393 + 2.275 + 1.219 + 1.219 + 0.1879 = 16.9939 kg (the fixed base's 4 kg not counted)."""
    assert moving_mass_kg(ur5.model) == pytest.approx(16.9939, abs=1e-9)
    assert simple_robot_mass_kg(ur5.model, 1.0) == pytest.approx(9.49695, abs=1e-9)
    # and the worked figures hold with it
    assert region_contact_speed_mps(HAND, simple_robot_mass_kg(ur5.model, 1.0)) == pytest.approx(1.36, abs=0.01)
    assert region_contact_speed_mps(CHEST, simple_robot_mass_kg(ur5.model, 1.0)) == pytest.approx(0.64, abs=0.01)


def _reflected_by_forward_dynamics(model: pin.Model, q: np.ndarray, frame_id: int, u_base: np.ndarray) -> float:
    """The reflected mass measured, not computed from M⁻¹: push the point with a unit force along u (τ = Jᵀ u), at
    rest and without gravity; ABA gives q̈, and the point's acceleration along u is 1 / m_u."""
    model = pin.Model(model)
    model.gravity = pin.Motion.Zero()
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    J = pin.getFrameJacobian(model, data, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    qdd = pin.aba(model, data, q, np.zeros(model.nv), J.T @ u_base)
    return 1.0 / float(u_base @ J @ qdd)


def test_reflected_mass_equals_forward_dynamics_and_crba(ur5: RobotModel) -> None:
    rng = np.random.default_rng(21)
    model = with_payload(ur5.model, 1.0, ur5.frame_b_ids[-1])
    data = model.createData()
    for _ in range(10):
        q = rng.uniform(-np.pi, np.pi, model.nq)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        M_inv_crba = np.linalg.inv(M)
        pin.computeMinverse(model, data, q)
        M_inv = np.triu(data.Minv) + np.triu(data.Minv, 1).T
        np.testing.assert_allclose(M_inv, M_inv_crba, rtol=1e-9, atol=1e-9)
        pin.computeJointJacobians(model, data, q)
        for frame_id in (ur5.frame_b_ids[2], ur5.frame_b_ids[-1]):
            J = pin.getFrameJacobian(model, data, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
            u = rng.normal(size=3)
            u /= np.linalg.norm(u)
            expected = _reflected_by_forward_dynamics(model, q, frame_id, u)
            assert reflected_mass_kg(J, M_inv_crba, u) == pytest.approx(expected, rel=1e-7)


def test_an_infinite_mass_is_the_regions_own_mass() -> None:
    """m_R = ∞ (a rigid direction): μ = m_H, v = F / sqrt(m_H k): hand 280 / sqrt(0.6 · 75000) = 1.3199 m/s."""
    assert region_contact_speed_mps(HAND, math.inf) == pytest.approx(280.0 / math.sqrt(0.6 * 75_000.0), rel=1e-12)
    assert region_contact_speed_mps(HAND, math.inf) < region_contact_speed_mps(HAND, 9.5)


# -- the region table ---------------------------------------------------------------------------------------------


def test_region_table_of_the_shipped_cell(cell_config: CellConfig) -> None:
    table = RegionTable(cell_config.safety.pfl_body_regions)
    names = ("head", "torso", "hand_r", "shin_l", "tail")
    assert table.region_names(names) == ("head", "chest", "hand", "lower_leg", NO_REGION)
    speeds = table.speeds_mps(names, np.array([9.5, 9.5]))
    assert speeds.shape == (2, 5)
    assert speeds[0, 0] == 0.0  # head
    assert speeds[0, 4] == 0.0  # a name of no region
    assert speeds[0, 1] == pytest.approx(0.639, abs=1e-3)
    assert speeds[0, 2] == pytest.approx(1.361, abs=1e-3)


# -- clamping -----------------------------------------------------------------------------------------------------

TABLE = Box(min_m=(0.2, -1.0, 0.0), max_m=(1.2, 1.0, 0.8))


def _hand(z: float) -> HumanCapsules:
    p = np.array([[0.6, 0.0, z]])
    return HumanCapsules(p, p + np.array([[0.08, 0.0, 0.0]]), np.array([0.05]), ("h1",), ("hand_r",))


def test_a_hand_on_the_table_under_a_link_moving_down_is_clamped() -> None:
    lo, hi = box_arrays([TABLE])
    down, up, sideways = np.array([[0.0, 0.0, -1.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 1.0, 0.0]])
    on_table = _hand(0.85)  # its surface 0 m above the table top
    assert clamped_pairs(down, down, on_table, lo, hi, 0.1).tolist() == [[True]]
    assert clamped_pairs(up, up, on_table, lo, hi, 0.1).tolist() == [[False]]
    assert clamped_pairs(sideways, sideways, on_table, lo, hi, 0.1).tolist() == [[False]]
    # 0.3 m above the table: not near it
    assert clamped_pairs(down, down, _hand(1.15), lo, hi, 0.1).tolist() == [[False]]
    # no boxes: nothing is clamped
    empty = box_arrays([])
    assert clamped_pairs(down, down, on_table, *empty, 0.1).tolist() == [[False]]


def test_contact_delta() -> None:
    # v_c = 1.0 m/s, link at 2 m/s: δ_c = 0.5; at 0.5 m/s: 1 (clipped); v_c = 0: 0; a link standing still: 1
    speeds = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    got = contact_delta(speeds, np.array([2.0, 0.5, 0.0]))
    assert got.tolist() == [[0.5, 0.0], [1.0, 0.0], [1.0, 0.0]]
    assert math.isnan(contact_delta(np.array([[math.nan]]), np.array([1.0]))[0, 0])
