"""The auditor's contact criterion (safety-math.md §12): every contact with its speed, acceptable only within its
body region's limit, never at the head or a body part of no region, never clamped; onsets counted per contact."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from support.known_cases import moving_links

from hrc_contract.config import BodyRegion, Box
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.link_motion import LinkMotion, link_motion
from hrc_devices.robots.model import RobotModel
from hrc_tools.audit.checks import AuditAccumulator, merge_summaries
from hrc_tools.audit.contact import ContactMass, ContactRules, audit_contacts, contact_limit_mps

REGIONS = {
    "hand": BodyRegion(capsules=["hand_r"], max_force_n=280.0, spring_constant_n_per_m=75_000.0, mass_kg=0.6),
    "head": BodyRegion(capsules=["head"], transient=False, mass_kg=4.4),
}


class FixedMass:
    """A stand-in for :class:`ContactMass` on the synthetic link: its axis point's speed and a fixed mass."""

    def __init__(self, mass_kg: float) -> None:
        self.mass_kg = mass_kg

    def at(self, q_rad: object, qd_radps: object, link: int, s: float, normal: object) -> tuple[float, float]:
        return 0.0, self.mass_kg


NINE_AND_A_HALF: ContactMass = FixedMass(9.5)  # type: ignore[assignment]
RULES = ContactRules(REGIONS, [], 0.1, NINE_AND_A_HALF)
HAND_LIMIT_MPS = 280.0 / (0.6 * 9.5 / 10.1 * 75_000.0) ** 0.5  # 1.3610 m/s
EPS = 0.01
NO_Q = np.zeros(0)


def _link_down(speed_mps: float) -> LinkMotion:
    """A horizontal link at z = 1.0 m moving down (−z) at ``speed_mps``, radius 0.05 m."""
    v = (0.0, 0.0, -speed_mps)
    return LinkMotion(*moving_links((0.0, 0.0, 1.0), (0.4, 0.0, 1.0), v, v))


def _capsule(name: str, z: float = 0.92) -> HumanCapsules:
    """A point capsule of radius 0.05 at (0.2, 0, z): at z = 0.92 its surface overlaps the link's by 2 cm."""
    p = np.array([[0.2, 0.0, z]])
    return HumanCapsules(p, p.copy(), np.array([0.05]), ("h1",), (name,))


def _audit(speed_mps: float, name: str, rules: ContactRules = RULES, z: float = 0.92) -> list[tuple[float, bool]]:
    contacts = audit_contacts(
        _link_down(speed_mps), np.array([0.05]), ("tool",), _capsule(name, z), rules, EPS, NO_Q, NO_Q
    )
    return [(round(c.speed_mps, 9), c.acceptable) for c in contacts]


def test_the_limit_is_iso_ts_15066s_force_form() -> None:
    assert contact_limit_mps(REGIONS["hand"], 9.5) == pytest.approx(HAND_LIMIT_MPS, rel=1e-12)
    assert contact_limit_mps(REGIONS["head"], 9.5) == 0.0
    assert contact_limit_mps(None, 9.5) == 0.0


def test_a_hand_touched_below_its_limit_is_acceptable_above_it_is_not() -> None:
    assert _audit(1.0, "hand_r") == [(1.0, True)]
    assert _audit(1.5, "hand_r") == [(1.5, False)]


def test_the_head_and_a_body_part_of_no_region_are_never_acceptable() -> None:
    assert _audit(0.1, "head") == [(0.1, False)]
    assert _audit(0.1, "elbow_pad") == [(0.1, False)]


def test_a_hand_pinned_against_a_clamping_surface_is_never_acceptable() -> None:
    table = Box(min_m=(-1.0, -1.0, 0.0), max_m=(1.0, 1.0, 0.86))  # 1 cm under the hand, the link moving toward it
    clamping = ContactRules(REGIONS, [table], 0.1, NINE_AND_A_HALF)
    assert _audit(0.2, "hand_r", clamping) == [(0.2, False)]
    below = Box(min_m=(-1.0, -1.0, 0.0), max_m=(1.0, 1.0, 0.5))  # 36 cm under it: not pinned
    assert _audit(0.2, "hand_r", ContactRules(REGIONS, [below], 0.1, NINE_AND_A_HALF)) == [(0.2, True)]


def test_no_contact_and_a_standing_robot_give_none() -> None:
    assert _audit(1.0, "hand_r", z=0.7) == []
    assert _audit(0.0, "head") == []


def test_the_accumulator_counts_onsets_and_unacceptable_cycles() -> None:
    acc = AuditAccumulator()
    fast = audit_contacts(_link_down(1.5), np.array([0.05]), ("tool",), _capsule("hand_r"), RULES, EPS, NO_Q, NO_Q)
    slow = audit_contacts(_link_down(0.5), np.array([0.05]), ("tool",), _capsule("hand_r"), RULES, EPS, NO_Q, NO_Q)
    for contacts in (slow, slow, (), fast, fast):  # two contacts: one onset at 0.5 m/s, one at 1.5 m/s
        acc.add_contacts(contacts, ["h1/hand_r"] * len(contacts))
    summary = acc.summary()
    assert summary.contact_cycles == 4
    assert summary.unacceptable_contacts == 2
    assert summary.contact_speeds_mps == pytest.approx((0.5, 1.5))
    assert summary.unacceptable_onsets == 1
    merged = merge_summaries([summary, summary])
    assert merged.unacceptable_contacts == 4
    assert len(merged.contact_speeds_mps) == 4
    assert summary.to_dict()["contact_speeds_mps"] == [0.5, 1.5]


def test_the_reflected_mass_at_the_contact_decides_not_the_simple_form(ur5: RobotModel) -> None:
    """The auditor's mass at a contact of the UR5's tool is its surface point's reflected mass along the normal,
    equal to an independent forward-dynamics measurement, and it changes the chest's limit from the simple form's."""
    mass = ContactMass(ur5, 1.0)
    q = np.array([0.3, -1.14, 1.25, -1.68, -1.571, 0.3])  # place_above of the shipped program
    qd = np.array([0.5, 0.2, -0.3, 0.1, 0.0, 0.0])
    links = link_motion(ur5, ur5.model.createData(), q, qd)
    tool = len(ur5.link_names) - 1
    normal = links.v_b_world[tool] / np.linalg.norm(links.v_b_world[tool])
    speed, m = mass.at(q, qd, tool, 1.0, normal)
    assert speed == pytest.approx(float(np.linalg.norm(links.v_b_world[tool])), rel=0.2)
    model = pin.Model(mass.model)
    model.gravity = pin.Motion.Zero()
    data = model.createData()
    frame = ur5.frame_b_ids[tool]
    pin.framesForwardKinematics(model, data, q)
    n_base = ur5.R_world_base.T @ normal
    joint = model.frames[frame].parentJoint
    p_joint = data.oMi[joint].actInv(data.oMf[frame].translation + ur5.link_radius_m[tool] * n_base)
    probe = model.addFrame(pin.Frame("probe", joint, 0, pin.SE3(np.eye(3), p_joint), pin.FrameType.OP_FRAME))
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    J = pin.getFrameJacobian(model, data, probe, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    measured = 1.0 / float(n_base @ J @ pin.aba(model, data, q, np.zeros(model.nv), J.T @ n_base))
    assert m == pytest.approx(measured, rel=1e-6)
    chest = BodyRegion(capsules=["torso"], max_force_n=280.0, spring_constant_n_per_m=25_000.0, mass_kg=40.0)
    assert contact_limit_mps(chest, m) != pytest.approx(contact_limit_mps(chest, 9.5), rel=1e-3)
