"""The per-link effective-mass bound (hrc_devices/robots/effective_mass.py, safety-math.md §12): it is never below the
reflected mass of any point of a link's capsule in any direction, computed independently (a frame added at the point,
forward dynamics under a unit force), at fresh random configurations of the program's box; the points that cannot move
in every direction get ∞; and the method's δ with the bound is never above δ with the simple form M/2 + m_payload."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hrc_contract.config import CellConfig
from hrc_devices.robots.effective_mass import (
    MASS_BOUND_MARGIN,
    cached_link_mass_bounds,
    path_samples,
    with_payload,
)
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import program_waypoints_rad

PAYLOAD_KG = 1.0


def _measured_mass_kg(model: pin.Model, q: np.ndarray, joint: int, p_joint: np.ndarray, u_base: np.ndarray) -> float:
    """The reflected mass measured at a point fixed on ``joint``'s body (``p_joint`` in that joint's frame): a frame
    added there, a unit force along u at rest without gravity, ABA's q̈, 1 / (the point's acceleration along u)."""
    model = pin.Model(model)
    model.gravity = pin.Motion.Zero()
    frame = model.addFrame(pin.Frame("probe", joint, 0, pin.SE3(np.eye(3), p_joint), pin.FrameType.OP_FRAME))
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    J = pin.getFrameJacobian(model, data, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    acceleration = float(u_base @ J @ pin.aba(model, data, q, np.zeros(model.nv), J.T @ u_base))
    return 1.0 / acceleration if acceleration > 1e-12 else math.inf


def test_the_bound_is_above_the_reflected_mass_at_random_points_configurations_and_directions(
    cell_config: CellConfig, ur5: RobotModel
) -> None:
    waypoints = program_waypoints_rad(cell_config.robots["ur5"].program)
    bounds = cached_link_mass_bounds(ur5, PAYLOAD_KG, waypoints)
    # the UR5's first links have points on a joint axis (rank J_v < 3): ∞; the wrist links finite, above M/2 + 1
    assert np.isinf(bounds.mass_kg[:4]).all()
    assert np.isfinite(bounds.mass_kg[4:]).all()
    assert (bounds.mass_kg[4:] > 9.5).all()
    np.testing.assert_allclose(bounds.mass_kg[4:], bounds.sampled_kg[4:] * (1.0 + MASS_BOUND_MARGIN))
    model = with_payload(ur5.model, PAYLOAD_KG, ur5.frame_b_ids[-1])
    data = model.createData()
    rng = np.random.default_rng(2020)
    worst = 0.0
    for _ in range(400):
        q = rng.uniform(bounds.q_min_rad, bounds.q_max_rad)
        assert bounds.covers(q)
        pin.framesForwardKinematics(model, data, q)
        for i in range(4, len(ur5.link_names)):
            fa, fb = ur5.frame_a_ids[i], ur5.frame_b_ids[i]
            s, offset = rng.uniform(), rng.normal(size=3)
            p = data.oMf[fa].translation + s * (data.oMf[fb].translation - data.oMf[fa].translation)
            p = p + ur5.link_radius_m[i] * offset / np.linalg.norm(offset)
            joint = model.frames[fa].parentJoint
            p_joint = data.oMi[joint].actInv(p)
            u = rng.normal(size=3)
            u /= np.linalg.norm(u)
            measured = _measured_mass_kg(model, q, joint, p_joint, u)
            assert measured <= bounds.mass_kg[i]
            worst = max(worst, measured / bounds.sampled_kg[i])
    assert worst <= 1.0 + MASS_BOUND_MARGIN


def test_the_program_path_is_inside_the_box(cell_config: CellConfig, ur5: RobotModel) -> None:
    waypoints = program_waypoints_rad(cell_config.robots["ur5"].program)
    bounds = cached_link_mass_bounds(ur5, PAYLOAD_KG, waypoints)
    assert all(bounds.covers(q) for q in path_samples(waypoints))
    assert not bounds.covers(bounds.q_max_rad + 0.01)
    assert not bounds.covers(np.full(6, math.nan))


def test_the_simple_mass_form_is_refused_unless_named(cell_config: CellConfig) -> None:
    with pytest.raises(ValueError, match="pfl_simple_mass_for_tests"):
        cell_config.safety.model_copy(update={"pfl_mass_model": "simple"}).model_validate(
            {**cell_config.safety.model_dump(), "pfl_mass_model": "simple"}
        )
