"""Line of sight: robot links, fixtures and other people hide people from a sensor; a person partly hidden is reported
with the capsules in sight only; the robots' link capsules from the true joint state (pure, no network)."""

from __future__ import annotations

import numpy as np
import pytest

from hrc_contract.messages import JointState, to_payload
from hrc_devices.robots.model import RobotModel
from tracker_emu.body import CAPSULE_NAMES, BodyPose, body_capsules
from tracker_emu.occlusion import NO_BLOCKERS, Blockers, fixture_blockers, human_blockers, occlude, visible_capsules
from tracker_emu.robot_links import RobotPoses, link_capsules
from tracker_emu.scenario import Fixture, TrackedHuman

SENSOR_M = np.array([3.5, 0.0, 2.2])
PERSON = TrackedHuman("h1", body_capsules(BodyPose(0.0, 0.0, 0.0)))
"""A person standing at the origin, facing the sensor (x), 3.5 m from it."""

Q_ARM_UP_RAD = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])
"""The UR5 with its upper arm and forearm straight up (world x = 0, z from 0.89 to 1.71 m)."""
Q_ARM_OUT_RAD = np.zeros(6)
NEAR_SENSOR_M = np.array([0.15, 0.0, 1.3])
"""A sensor 0.15 m in front of the raised arm: the arm fills its view like a finger in front of a lens."""
BEHIND_ARM = TrackedHuman("h1", body_capsules(BodyPose(-1.5, 0.0, 0.0)))


def column(x_m: float, y_m: float, radius_m: float, top_m: float = 2.0) -> Blockers:
    """A vertical blocker from the floor to ``top_m`` [m]."""
    return Blockers(np.array([[x_m, y_m, 0.0]]), np.array([[x_m, y_m, top_m]]), np.array([radius_m]))


def names(human: TrackedHuman) -> list[str]:
    return [c.name for c in human.capsules]


def test_nothing_in_the_way_everything_is_seen() -> None:
    assert occlude([PERSON], SENSOR_M, NO_BLOCKERS, [PERSON]) == [PERSON]
    assert visible_capsules(SENSOR_M, PERSON, column(0.0, 3.0, 0.3)).all()  # a blocker off the line of sight


def test_a_column_between_sensor_and_person_hides_them() -> None:
    # 0.7 m wide, 1.5 m in front of the person: the body's shadow is about 1.2 m wide there.
    assert occlude([PERSON], SENSOR_M, column(1.5, 0.0, 0.35, top_m=2.4), [PERSON]) == []


def test_a_link_capsule_between_sensor_and_person_hides_them(ur5: RobotModel) -> None:
    data = ur5.model.createData()
    raised = link_capsules(ur5, data, Q_ARM_UP_RAD)
    assert occlude([BEHIND_ARM], NEAR_SENSOR_M, raised, [BEHIND_ARM]) == []
    # The same robot with its arm stretched out along x hides nothing of them.
    stretched = link_capsules(ur5, data, Q_ARM_OUT_RAD)
    assert occlude([BEHIND_ARM], NEAR_SENSOR_M, stretched, [BEHIND_ARM]) == [BEHIND_ARM]


def test_link_capsules_are_the_robots_links(ur5: RobotModel) -> None:
    links = link_capsules(ur5, ur5.model.createData(), Q_ARM_UP_RAD)
    assert links.n_capsules == len(ur5.link_names)
    np.testing.assert_allclose(links.radius_m, ur5.link_radius_m)
    np.testing.assert_allclose(links.a_world[0], [0.0, 0.0, 0.8], atol=1e-9)  # the base on its 0.8 m pedestal
    forearm = ur5.link_names.index("forearm")
    assert links.b_world[forearm][2] == pytest.approx(1.706, abs=0.001)  # arm straight up


def test_another_person_hides_a_person_behind_them() -> None:
    front = TrackedHuman("h2", body_capsules(BodyPose(1.0, 0.0, np.pi)))
    # A low sensor (1.0 m): the person in front covers the whole body of the one behind.
    low_sensor_m = np.array([1.6, 0.0, 1.0])
    seen = occlude([PERSON, front], low_sensor_m, NO_BLOCKERS, [PERSON, front])
    assert [h.id for h in seen] == ["h2"]
    assert names(seen[0]) == list(CAPSULE_NAMES)  # a body does not hide itself
    # Whether or not the sensor reports the person in front, they block the view: only the one behind is asked for.
    assert occlude([PERSON], low_sensor_m, NO_BLOCKERS, [PERSON, front]) == []


def test_a_partly_hidden_person_is_reported_with_the_visible_capsules_only() -> None:
    # A bench 1.0 m high, 0.5 m in front of the person: the lower legs are hidden, the rest is seen over it.
    bench = Blockers(np.array([[0.5, -1.0, 0.5]]), np.array([[0.5, 1.0, 0.5]]), np.array([0.5]))
    (seen,) = occlude([PERSON], SENSOR_M, bench, [PERSON])
    assert set(names(seen)) == set(CAPSULE_NAMES) - {"shin_l", "shin_r"}
    assert names(seen) == [n for n in CAPSULE_NAMES if n in names(seen)]  # in the body's order
    for capsule in seen.capsules:  # the visible capsules are the true ones, untouched
        true = next(c for c in PERSON.capsules if c.name == capsule.name)
        np.testing.assert_array_equal(capsule.a, true.a)


def test_a_capsule_is_seen_when_any_of_its_three_axis_points_is_in_sight() -> None:
    shin = next(c for c in PERSON.capsules if c.name == "shin_r")
    one = TrackedHuman("h1", (shin,))
    # A thin blocker on the line of sight of the shin's middle only: its two ends are still in sight.
    middle_m = (shin.a + shin.b) / 2.0
    towards = (SENSOR_M - middle_m) / np.linalg.norm(SENSOR_M - middle_m)
    point_m = middle_m + 0.5 * towards
    across = np.cross(towards, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    thin = Blockers(np.array([point_m - 0.1 * across]), np.array([point_m + 0.1 * across]), np.array([0.02]))
    assert visible_capsules(SENSOR_M, one, thin).tolist() == [True]
    # Blockers on all three lines of sight hide it.
    points = [shin.a, middle_m, shin.b]
    ends = [p + 0.5 * (SENSOR_M - p) / np.linalg.norm(SENSOR_M - p) for p in points]
    three = Blockers(
        np.array([e - 0.1 * across for e in ends]), np.array([e + 0.1 * across for e in ends]), np.full(3, 0.02)
    )
    assert visible_capsules(SENSOR_M, one, three).tolist() == [False]


def test_fixtures_block_like_any_capsule() -> None:
    cabinet = Fixture(name="cabinet", a_m=(1.5, 0.0, 0.0), b_m=(1.5, 0.0, 2.4), radius_m=0.35)
    blockers = fixture_blockers([cabinet])
    np.testing.assert_array_equal(blockers.a_world, [[1.5, 0.0, 0.0]])
    assert occlude([PERSON], SENSOR_M, blockers, [PERSON]) == []
    assert fixture_blockers([]).n_capsules == 0


def test_human_blockers_are_the_bodys_capsules() -> None:
    blockers = human_blockers(PERSON)
    assert blockers.n_capsules == len(CAPSULE_NAMES)
    np.testing.assert_array_equal(blockers.radius_m, [c.radius_m for c in PERSON.capsules])


# -- the true joint states the process follows ------------------------------------------------------------------


def joint_state(q_rad: np.ndarray, stamp_ns: int, robot: str = "ur5") -> bytes:
    zeros = [0.0] * len(q_rad)
    return to_payload(
        JointState(
            robot=robot,
            seq=1,
            stamp_ns=stamp_ns,
            q=list(map(float, q_rad)),
            qd=zeros,
            qd_nominal=zeros,
            override=0.0,
            override_seq=-1,
            mode="stopped",
        )
    )


def test_robot_poses_follow_the_newest_truth_state(ur5: RobotModel) -> None:
    poses = RobotPoses("demo", {"ur5": ur5})
    assert poses.capsules().n_capsules == 0  # no state yet: the robot hides nothing
    key = "hrc/demo/truth/robot/ur5/state"
    poses.on_truth_state(key, joint_state(Q_ARM_UP_RAD, 2_000))
    assert poses.known() == ("ur5",)
    assert occlude([BEHIND_ARM], NEAR_SENSOR_M, poses.capsules(), [BEHIND_ARM]) == []
    poses.on_truth_state(key, joint_state(Q_ARM_OUT_RAD, 1_000))  # older: ignored
    assert occlude([BEHIND_ARM], NEAR_SENSOR_M, poses.capsules(), [BEHIND_ARM]) == []
    poses.on_truth_state(key, joint_state(Q_ARM_OUT_RAD, 3_000))
    assert occlude([BEHIND_ARM], NEAR_SENSOR_M, poses.capsules(), [BEHIND_ARM]) == [BEHIND_ARM]
    assert poses.rejected == {"old_or_repeated": 1}


def test_robot_poses_reject_what_is_not_a_state_of_a_robot_of_the_cell(ur5: RobotModel) -> None:
    poses = RobotPoses("demo", {"ur5": ur5})
    poses.on_truth_state("hrc/demo/truth/robot/ghost/state", joint_state(Q_ARM_UP_RAD, 1, robot="ghost"))
    poses.on_truth_state("hrc/demo/truth/robot/ur5/state", joint_state(Q_ARM_UP_RAD[:5], 1))
    poses.on_truth_state("hrc/demo/truth/robot/ur5/state", b"{not json")
    assert poses.known() == ()
    assert poses.rejected["unknown_robot"] == 1
    assert poses.rejected["wrong_length"] == 1
    assert sum(poses.rejected.values()) == 3
