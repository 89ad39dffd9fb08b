"""The compiled per-cycle math (gateway.kernels) against its references: Pinocchio for the kinematics, the numpy
geometry and rows for the rest, on seeded random inputs with the degenerate cases; then the start-up refusals."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pinocchio as pin
import pytest
from support.known_cases import FAR_TORSO, NEAR_HAND, NOW, Cell

from gateway import kernels, tracks
from gateway.core import SafetyCore
from gateway.kernels import CHECK_TOLERANCE, RobotKernels, check_chain
from gateway.kinematics import PRISMATIC, REVOLUTE, kinematic_chain
from gateway.reference import separation as reference_separation
from gateway.reference.kinematics import link_kinematics, link_speed_max_mps
from gateway.separation import ConstraintRows, override_from_rows
from hrc_contract.config import CellConfig, ConfigError, PlausibilityConfig, SafetyConfig
from hrc_contract.humans import NO_HUMANS, HumanCapsules
from hrc_devices.robots import segments as reference_geometry
from hrc_devices.robots.model import RobotModel

SAFETY_VARIANTS = (
    SafetyConfig(),
    SafetyConfig(close_speed_below_m=0.5),
    SafetyConfig(clearance_static_m=0.0, human_speed_mps=2.0),
)


def robot_from_model(model: pin.Model, frame_pairs: list[tuple[str, str]], name: str = "test") -> RobotModel:
    """A RobotModel around a Pinocchio model, one link per pair of frame names, base pose rotated and shifted."""
    n = len(frame_pairs)
    return RobotModel(
        name=name,
        model=model,
        joint_names=tuple(model.names[j] for j in range(1, model.njoints)),
        frame_a_ids=tuple(int(model.getFrameId(a)) for a, _ in frame_pairs),
        frame_b_ids=tuple(int(model.getFrameId(b)) for _, b in frame_pairs),
        link_names=tuple(f"{a}-{b}" for a, b in frame_pairs),
        link_radius_m=np.full(n, 0.05),
        t_brake_link_s=np.full(n, 0.3),
        braking_time_s=np.full(model.nv, 0.3),
        R_world_base=np.asarray(pin.rpy.rpyToMatrix(0.1, -0.2, 0.7)),
        p_world_base=np.array([0.4, -1.2, 0.8]),
        velocity_limit_radps=np.full(model.nv, 3.0),
    )


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def every_joint_type_tree() -> RobotModel:
    """A branching tree with every supported joint type, random placements, and frames off the joint origins."""
    rng = np.random.default_rng(5)
    model = pin.Model()
    joints = [
        pin.JointModelRX(),
        pin.JointModelRY(),
        pin.JointModelRZ(),
        pin.JointModelRevoluteUnaligned(_unit(rng.normal(size=3))),
        pin.JointModelPX(),
        pin.JointModelPY(),
        pin.JointModelPZ(),
        pin.JointModelPrismaticUnaligned(_unit(rng.normal(size=3))),
    ]
    parents = [0, 1, 2, 3, 4, 2, 6, 7]  # joint 6 branches off joint 2
    pairs = []
    for k, (joint, parent) in enumerate(zip(joints, parents, strict=True)):
        placement = pin.SE3(pin.exp3(rng.normal(size=3)), rng.uniform(-0.3, 0.3, 3))
        j = model.addJoint(parent, joint, placement, f"j{k}")
        model.addFrame(pin.Frame(f"j{k}_origin", j, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
        off = pin.SE3(pin.exp3(rng.normal(size=3)), rng.uniform(-0.2, 0.2, 3))
        model.addFrame(pin.Frame(f"j{k}_off", j, off, pin.FrameType.OP_FRAME))
        pairs.append((f"j{k}_origin", f"j{k}_off"))
    model.lowerPositionLimit = np.full(model.nq, -1.0)
    model.upperPositionLimit = np.full(model.nq, 1.0)
    return robot_from_model(model, pairs, "tree")


@pytest.fixture(scope="module")
def panda(cell_config: CellConfig) -> RobotModel:
    """example-robot-data's Panda: 7 revolute joints about z, two prismatic fingers (y and an unaligned axis)."""
    urdf = Path(cell_config.robots["ur5"].model.urdf).parents[2] / "panda_description" / "urdf" / "panda.urdf"
    model = pin.buildModelFromUrdf(str(urdf))
    links = [f"panda_link{k}" for k in range(9)]
    pairs = [*itertools.pairwise(links), ("panda_hand", "panda_leftfinger"), ("panda_hand", "panda_rightfinger")]
    return robot_from_model(model, pairs, "panda")


def _robot(request: pytest.FixtureRequest, which: str) -> RobotModel:
    if which == "tree":
        return every_joint_type_tree()
    robot: RobotModel = request.getfixturevalue(which)
    return robot


# -- kinematics: compiled against Pinocchio ---------------------------------------------------------


@pytest.mark.parametrize("which", ["ur5", "panda", "tree"])
def test_compiled_kinematics_equal_pinocchio(request: pytest.FixtureRequest, which: str) -> None:
    robot = _robot(request, which)
    chain = kinematic_chain(robot)
    data = robot.model.createData()
    rng = np.random.default_rng(8)
    lower, upper = np.maximum(robot.model.lowerPositionLimit, -4.0), np.minimum(robot.model.upperPositionLimit, 4.0)
    for _ in range(50):
        q, qd = rng.uniform(lower, upper), rng.uniform(-3.0, 3.0, robot.model.nv)
        expected = link_kinematics(robot, data, q, qd)
        got, speed_mps = kernels.link_kinematics(chain, q, qd)
        for a, b in zip(got, expected, strict=True):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-12)
        assert speed_mps == pytest.approx(link_speed_max_mps(expected), abs=1e-12)


def test_every_joint_type_moves_the_tree() -> None:
    """The tree really exercises both kinds of joint: each joint's rate moves the frames it carries."""
    robot = every_joint_type_tree()
    chain = kinematic_chain(robot)
    assert sorted(set(chain.kind[1:].tolist())) == [REVOLUTE, PRISMATIC]
    q = np.full(robot.model.nq, 0.3)
    for k in range(robot.model.nv):
        qd = np.zeros(robot.model.nv)
        qd[k] = 1.0
        links, speed_mps = kernels.link_kinematics(chain, q, qd)
        assert speed_mps > 0.05
        assert np.abs(links.v_b_world[k]).max() > 0.0


# -- start-up refusals ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("joint", "shortname"),
    [
        (pin.JointModelSpherical(), "JointModelSpherical"),
        (pin.JointModelFreeFlyer(), "JointModelFreeFlyer"),
        (pin.JointModelRUBZ(), "JointModelRUBZ"),
        (pin.JointModelPlanar(), "JointModelPlanar"),
    ],
)
def test_unsupported_joint_is_refused_with_the_allowed_types(joint: pin.JointModel, shortname: str) -> None:
    model = pin.Model()
    first = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "shoulder")
    second = model.addJoint(first, joint, pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.3])), "odd_joint")
    model.addFrame(pin.Frame("a", first, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    model.addFrame(pin.Frame("b", second, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    robot = robot_from_model(model, [("a", "b")])
    with pytest.raises(ConfigError, match=f"'odd_joint' is a {shortname}") as error:
        RobotKernels(robot, SafetyConfig())
    for allowed in ("JointModelRX", "JointModelRevoluteUnaligned", "JointModelPZ", "JointModelPrismaticUnaligned"):
        assert allowed in str(error.value)


@pytest.mark.parametrize("field", ["p_parent_joint", "R_parent_joint", "axis_joint", "p_joint_frame"])
def test_a_chain_that_disagrees_with_pinocchio_is_refused(ur5: RobotModel, field: str) -> None:
    chain = kinematic_chain(ur5)
    check_chain(ur5, chain)  # the extracted chain passes
    wrong = getattr(chain, field).copy()
    wrong[2] = wrong[2] + 1e-6 if field != "axis_joint" else -wrong[2]  # 1 µm or a flipped axis
    with pytest.raises(ConfigError, match=r"differ from Pinocchio's by .* allowed: at most 1e-09"):
        check_chain(ur5, chain._replace(**{field: wrong}))
    assert CHECK_TOLERANCE == 1e-9


def test_the_core_refuses_a_robot_it_cannot_compile(cell_config: CellConfig) -> None:
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), "ball")
    model.addFrame(pin.Frame("a", j, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    model.addFrame(pin.Frame("b", j, pin.SE3(np.eye(3), np.ones(3)), pin.FrameType.OP_FRAME))
    with pytest.raises(ConfigError, match="'ball' is a JointModelSpherical"):
        SafetyCore(cell_config, {"ur5": robot_from_model(model, [("a", "b")], "ur5")})


# -- segment distances: compiled against numpy -------------------------------------------------------


def random_segments(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n segments in a 2 m box; about a fifth are points, a fifth parallel copies of another segment."""
    a = rng.uniform(-1.0, 1.0, (n, 3))
    b = a + rng.normal(0.0, 0.5, (n, 3))
    kind = rng.integers(0, 5, n)
    b[kind == 0] = a[kind == 0]  # points
    b[kind == 1] = a[kind == 1] + 1e-7 * rng.normal(size=((kind == 1).sum(), 3))  # shorter than 1e-6 m: points
    return a, b


def assert_same_distances(p_a: np.ndarray, p_b: np.ndarray, h_a: np.ndarray, h_b: np.ndarray) -> None:
    expected = reference_geometry.segment_distances(p_a, p_b, h_a, h_b)
    got = kernels.segment_distances(p_a, p_b, h_a, h_b)
    for a, b in zip(got, expected, strict=True):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-12)


def test_random_segment_distances_equal_numpy() -> None:
    rng = np.random.default_rng(21)
    for _ in range(60):
        p_a, p_b = random_segments(rng, int(rng.integers(1, 9)))
        h_a, h_b = random_segments(rng, int(rng.integers(1, 31)))
        # parallel pairs: some capsules are shifted (and possibly reversed) copies of a link
        for j in range(0, len(h_a), 4):
            i = int(rng.integers(len(p_a)))
            shift = rng.uniform(-0.5, 0.5, 3)
            h_a[j], h_b[j] = (p_a[i] + shift, p_b[i] + shift) if j % 8 else (p_b[i] + shift, p_a[i] + shift)
        assert_same_distances(p_a, p_b, h_a, h_b)


def test_segment_distances_of_empty_and_coincident_sets() -> None:
    rng = np.random.default_rng(22)
    p_a, p_b = random_segments(rng, 5)
    none = np.zeros((0, 3))
    assert_same_distances(p_a, p_b, none, none)
    assert kernels.segment_distances(p_a, p_b, none, none).distance_m.shape == (5, 0)
    assert_same_distances(none, none, p_a, p_b)
    assert_same_distances(p_a, p_b, p_a, p_b)  # each link against itself: distance 0
    assert (np.diag(kernels.segment_distances(p_a, p_b, p_a, p_b).distance_m) == 0.0).all()


# -- the rows of eq. (15): compiled against numpy --------------------------------------------------------


def random_humans(rng: np.random.Generator, n: int, centre: np.ndarray) -> HumanCapsules:
    """n capsules 0–3 m around ``centre``; some are points, some have zero radius."""
    a, b = random_segments(rng, n)
    a, b = centre + 1.5 * a, centre + 1.5 * b
    radius = rng.uniform(0.0, 0.15, n)
    radius[rng.random(n) < 0.2] = 0.0
    return HumanCapsules(a, b, radius, tuple(f"h{j}" for j in range(n)), ("c",) * n)


def assert_same_rows(got: ConstraintRows, expected: ConstraintRows) -> None:
    for name in ("surface_distance_m", "clearance_m", "f_m2", "e_m2ps", "horizon_s"):
        a, b = getattr(got, name), getattr(expected, name)
        assert a.shape == b.shape, name
        np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-12, err_msg=name)
    # Each bound is f / (T e) of its own row; e is the difference of two ~1 m² products, so where e is tiny its
    # rounding (1e-15) shows in the bound: compare the bounds of well-conditioned rows only, and δ everywhere.
    lhs = got.horizon_s[:, None, None, None] * got.e_m2ps
    assert (np.isinf(got.bound) == (lhs <= 0.0)).all()
    approaching = lhs > 0.0
    np.testing.assert_array_equal(
        got.bound[approaching], (got.f_m2[:, :, None, None] / np.where(approaching, lhs, 1.0))[approaching]
    )
    conditioned = np.abs(expected.e_m2ps) > 1e-3
    np.testing.assert_allclose(got.bound[conditioned], expected.bound[conditioned], rtol=1e-12, atol=1e-12)
    assert got.min_bound == (float(got.bound.min()) if got.bound.size else np.inf)
    assert override_from_rows(got) == pytest.approx(override_from_rows(expected), abs=1e-12)


@pytest.mark.parametrize("where", ["q", "qd", "capsule", "radius", "t_delay"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_cycle_tells_a_non_finite_input(ur5: RobotModel, where: str, bad: float) -> None:
    """The loop's call says whether every input was a finite number (the core's guard for every method reads it)."""
    robot = RobotKernels(ur5, SafetyConfig())
    q, qd, t_delay = np.array([0.3, -1.2, 1.4, -0.5, 1.2, 0.0]), np.array([0.6, -0.4, 0.5, 0.3, 0.2, 0.1]), 0.1
    columns = kernels.capsule_columns(random_humans(np.random.default_rng(5), 4, ur5.p_world_base))
    assert robot.cycle(q, qd, columns, t_delay).inputs_finite
    if where == "q":
        q[3] = bad
    elif where == "qd":
        qd[5] = bad
    elif where == "capsule":
        columns[1, 2] = bad
    elif where == "radius":
        columns[10, 3] = bad
    else:
        t_delay = bad
    with np.errstate(invalid="ignore", over="ignore"):
        cycle = robot.cycle(q, qd, columns, t_delay)
    assert not cycle.inputs_finite
    assert (cycle.closest.link, cycle.closest.capsule) == _argmin(cycle.rows)  # the first nan, as numpy's argmin


def test_random_rows_equal_numpy(ur5: RobotModel) -> None:
    rng = np.random.default_rng(23)
    data = ur5.model.createData()
    t_brake_max = float(ur5.braking_time_s.max())
    per_robot = [RobotKernels(ur5, safety) for safety in SAFETY_VARIANTS]
    for k in range(200):
        q, qd = rng.uniform(-np.pi, np.pi, 6), rng.uniform(-2.5, 2.5, 6)
        links = link_kinematics(ur5, data, q, qd)
        humans = random_humans(rng, int(rng.integers(0, 31)), ur5.p_world_base)
        safety, t_delay = SAFETY_VARIANTS[k % 3], float(rng.uniform(0.0, 0.3))
        expected = reference_separation.build_rows(
            links, ur5.link_radius_m, ur5.t_brake_link_s, t_brake_max, humans, safety, t_delay
        )
        got = kernels.build_rows(links, ur5.link_radius_m, ur5.t_brake_link_s, t_brake_max, humans, safety, t_delay)
        assert_same_rows(got, expected)
        # the one call per robot of the loop: the same kinematics and rows, and the first closest pair
        cycle_links, speed_mps, rows, closest, finite = per_robot[k % 3].cycle(
            q, qd, kernels.capsule_columns(humans), t_delay
        )
        assert finite
        for a, b in zip(cycle_links, links, strict=True):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-12)
        assert_same_rows(rows, expected)
        separate = kernels.build_rows(
            cycle_links, ur5.link_radius_m, ur5.t_brake_link_s, t_brake_max, humans, safety, t_delay
        )
        for a, b in zip(rows, separate, strict=True):
            np.testing.assert_array_equal(a, b)  # the same compiled code: bit for bit
        assert speed_mps == kernels.link_kinematics(kinematic_chain(ur5), q, qd)[1]
        assert (closest.link, closest.capsule) == _argmin(rows)
        if humans.n_capsules:
            assert closest.distance_m == rows.surface_distance_m[closest.link, closest.capsule]
            assert closest.distance_m == pytest.approx(expected.surface_distance_m.min(), abs=1e-12)
        else:
            assert closest.distance_m == np.inf


def _argmin(rows: ConstraintRows) -> tuple[int, int]:
    d = rows.surface_distance_m
    if not d.size:
        return (-1, -1)
    i, j = np.unravel_index(int(np.argmin(d)), d.shape)
    return int(i), int(j)


def test_rows_of_degenerate_links_and_no_capsules(ur5: RobotModel) -> None:
    """Zero-length links (both ends on one frame), links on the base axis (not moving), and nobody seen."""
    rng = np.random.default_rng(24)
    data = ur5.model.createData()
    for _ in range(40):
        links = link_kinematics(ur5, data, rng.uniform(-np.pi, np.pi, 6), rng.uniform(-2.0, 2.0, 6))
        links = links._replace(p_b_world=links.p_b_world.copy(), v_b_world=links.v_b_world.copy())
        links.p_b_world[::2] = links.p_a_world[::2]
        links.v_b_world[::2] = links.v_a_world[::2]
        for humans in (random_humans(rng, 12, ur5.p_world_base), NO_HUMANS):
            args = (links, ur5.link_radius_m, ur5.t_brake_link_s, 0.53, humans, SAFETY_VARIANTS[1], 0.1)
            assert_same_rows(kernels.build_rows(*args), reference_separation.build_rows(*args))
    rows = kernels.build_rows(links, ur5.link_radius_m, ur5.t_brake_link_s, 0.53, NO_HUMANS, SafetyConfig(), 0.1)
    assert rows.bound.shape == (7, 0, 2, 2)
    assert override_from_rows(rows) == 1.0


# -- compiled once, at start-up ------------------------------------------------------------------------


def test_the_loop_never_compiles(cell_config: CellConfig, ur5: RobotModel) -> None:
    """Building the core compiles every kernel the loop calls; stepping it with real input adds no signature."""
    cell = Cell(cell_config, ur5)
    compiled = {name: len(getattr(kernels, name).signatures) for name in ("_cycle", "_capsule_columns")}
    assert all(compiled.values())
    for k, capsules in enumerate(([], [FAR_TORSO], [NEAR_HAND, FAR_TORSO])):
        now = NOW + k * 4_000_000
        cell.feed(now, capsules)
        cell.step(now)
    assert {name: len(getattr(kernels, name).signatures) for name in compiled} == compiled


def test_capsules_of_any_layout_use_the_compiled_columns(ur5: RobotModel) -> None:
    """Read-only or strided capsule arrays are converted, not compiled for (a compile in the loop takes seconds)."""
    RobotKernels(ur5, SafetyConfig())
    compiled = len(kernels._capsule_columns.signatures)
    points = np.arange(18.0).reshape(6, 3)
    points.flags.writeable = False
    strided = np.asfortranarray(points[::2])
    for h in (points, strided):
        humans = HumanCapsules(h, h, np.full(len(h), 0.1), ("h",) * len(h), ("c",) * len(h))
        columns = kernels.capsule_columns(humans)
        np.testing.assert_array_equal(columns[0:3], h.T)
        np.testing.assert_array_equal(columns[10], 0.1)
    assert len(kernels._capsule_columns.signatures) == compiled


def test_a_read_only_source_tree_caches_in_the_temp_dir(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(kernels.os, "access", lambda path, mode: False)
    kernels._use_writable_cache_dir()
    assert "hrc-gateway-numba" in numba.config.CACHE_DIR
    monkeypatch.setattr(numba.config, "CACHE_DIR", "/somewhere/chosen")
    kernels._use_writable_cache_dir()
    assert numba.config.CACHE_DIR == "/somewhere/chosen"


# -- the tracks' frame path: compiled against numpy ----------------------------------------------------


def _two_people(shift_m: float = 0.0, grow_m: float = 0.0) -> tuple[HumanCapsules, np.ndarray]:
    """Two people of 2 and 3 capsules; every end point moved by ``shift_m`` along x, each radius grown by ``grow_m``."""
    a = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.9], [2.0, 0.0, 0.0], [2.0, 0.0, 0.9], [2.0, 0.2, 1.2]])
    a[:, 0] += shift_m
    b = a + np.array([0.0, 0.0, 0.5])
    ids = ("t/a", "t/a", "t/b", "t/b", "t/b")
    return HumanCapsules(a, b, np.full(5, 0.1) + grow_m, ids, ("p",) * 5), np.array([0, 2, 5], dtype=np.int64)


@pytest.mark.parametrize(
    ("shift_m", "grow_m", "reach_m", "expected"),
    [
        (0.25, 0.0, 0.25, [True, True]),  # moved exactly the reach: within
        (0.25, 0.0, np.nextafter(0.25, 0.0), [False, False]),  # a hair less reach: not
        (0.0, 0.04, 0.05, [True, True]),  # grown less than the reach, not moved
        (0.0, 0.06, 0.05, [False, False]),  # grown more than the reach: never, not moved
        (0.1, 0.0, math.nan, [False, False]),  # no number: not (a new track, decided by the covering test)
    ],
)
def test_the_compiled_moved_within_equals_numpy_at_its_edges(
    shift_m: float, grow_m: float, reach_m: float, expected: list[bool]
) -> None:
    before, starts = _two_people()
    after, _ = _two_people(shift_m, grow_m)
    compiled = kernels.moved_within(before, after, starts, reach_m)
    assert compiled.tolist() == expected
    assert compiled.tolist() == tracks.moved_within_reference(before, after, list(starts), reach_m).tolist()


def test_one_person_moved_too_far_is_not_continued_the_other_is() -> None:
    before, starts = _two_people()
    after = before._replace(h_a_world=before.h_a_world + np.array([[0.0] * 3] * 4 + [[0.5, 0.0, 0.0]]))
    assert kernels.moved_within(before, after, starts, 0.3).tolist() == [True, False]


def test_the_compiled_frame_bodies_equal_numpy() -> None:
    frame, starts = _two_people()
    compiled = kernels.frame_bodies(frame, starts)
    reference = tracks.frame_bodies_reference(frame, list(starts))
    for got, expected in zip(compiled, reference, strict=True):
        np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(compiled[1][1], [2.0, 0.0, 0.0])  # lower corner of the second person
    np.testing.assert_array_equal(compiled[2][1], [2.0, 0.2, 1.7])  # upper corner


def _layouts(frame: HumanCapsules) -> dict[str, HumanCapsules]:
    """``frame`` as the door gives it (views of one (H, 7) array), read only, and as separate C- and F-ordered ones."""
    rows = np.concatenate((frame.h_a_world, frame.h_b_world, frame.radius_m[:, None]), axis=1)
    frozen = rows.copy()
    frozen.flags.writeable = False
    ids, names = frame.human_ids, frame.capsule_names
    return {
        "views of the rows": HumanCapsules(rows[:, 0:3], rows[:, 3:6], rows[:, 6], ids, names),
        "read only": HumanCapsules(frozen[:, 0:3], frozen[:, 3:6], frozen[:, 6], ids, names),
        "C": HumanCapsules(*(np.ascontiguousarray(x) for x in frame[:3]), ids, names),
        "Fortran": HumanCapsules(*(np.asfortranarray(x) for x in frame[:3]), ids, names),
    }


def test_the_frame_kernels_read_any_layout_without_copying_or_compiling() -> None:
    """A frame's capsules are views of one array: the frame kernels are typed for any layout, read only or not, so they
    read the views (no copy) and every layout converts to that one type (no compile in the loop), with the same
    numbers as numpy."""
    from hrc_contract.humans import frame_numbers

    names = ("_frame_numbers", "_frame_bodies", "_moved_within", "_capsule_columns")
    plausibility = PlausibilityConfig()
    frame, starts = _two_people()
    moved, _ = _two_people(shift_m=0.25)
    for layout, capsules in _layouts(frame).items():
        got = kernels.frame_numbers(capsules, list(starts), plausibility)
        want = frame_numbers(frame, list(starts), plausibility)
        assert got[:3] == want[:3], layout
        np.testing.assert_array_equal(got.extent_m, want.extent_m)
        for got_bodies, want_bodies in zip(
            kernels.frame_bodies(capsules, starts), tracks.frame_bodies_reference(frame, list(starts)), strict=True
        ):
            np.testing.assert_array_equal(got_bodies, want_bodies)
        assert kernels.moved_within(capsules, moved, starts, 0.25).tolist() == [True, True], layout
        assert kernels.moved_within(moved, capsules, starts, 0.2).tolist() == [False, False], layout
        np.testing.assert_array_equal(kernels.capsule_columns(capsules)[3:6], frame.h_b_world.T)
    assert {name: len(getattr(kernels, name).signatures) for name in names} == dict.fromkeys(names, 1)


def test_others_maybe_near_skips_the_same_person_and_every_track_not_seen() -> None:
    """Three rows at one body's box: another person's seen track (a candidate), the same person's, another person's
    lost one: only the first is a candidate, compiled and numpy alike."""
    frame, starts = _two_people()
    _, lo, hi, r_max = kernels.frame_bodies(frame, starts)
    bodies = (lo[:1], hi[:1], r_max[:1], np.zeros(1), np.zeros(1), np.array([1], dtype=np.int64))
    rows = (
        np.repeat(lo[:1], 3, axis=0),
        np.repeat(hi[:1], 3, axis=0),
        np.full(3, 0.1),
        np.zeros(3),
        np.zeros(3),
        np.array([2, 1, 3], dtype=np.int64),
        np.array([True, True, False]),
    )
    compiled = kernels.others_maybe_near(bodies, rows, 1.6, 0.1)
    assert compiled.tolist() == [[True, False, False]]
    assert compiled.tolist() == tracks.others_maybe_near_reference(bodies, rows, 1.6, 0.1).tolist()


def test_others_maybe_near_grows_with_the_time_between_the_stamps() -> None:
    """The second person 2 m away: not a candidate at equal stamps, a candidate 1.2 s apart at 1.6 m/s."""
    frame, starts = _two_people()
    _, lo, hi, r_max = kernels.frame_bodies(frame, starts)
    person = np.array([1, 2], dtype=np.int64)
    for dt_s, expected in ((0.0, False), (1.2, True)):
        bodies = (lo[:1], hi[:1], r_max[:1], np.zeros(1), np.zeros(1), person[:1])
        rows = (lo[1:], hi[1:], r_max[1:], np.array([dt_s * 1e9]), np.zeros(1), person[1:], np.array([True]))
        assert kernels.others_maybe_near(bodies, rows, 1.6, 0.1).tolist() == [[expected]]
        assert tracks.others_maybe_near_reference(bodies, rows, 1.6, 0.1).tolist() == [[expected]]


def test_the_frame_path_check_refuses_a_compiled_path_that_differs(monkeypatch: pytest.MonkeyPatch) -> None:
    tracks.check_frame_kernels.__wrapped__()  # the real one passes
    monkeypatch.setattr(tracks, "moved_within", lambda before, after, starts, reach_m: np.ones(len(starts) - 1, bool))
    with pytest.raises(ConfigError, match="compiled frame path differs"):
        tracks.check_frame_kernels.__wrapped__()


def test_a_frame_adds_no_compiled_signature(cell_config: CellConfig, ur5: RobotModel) -> None:
    """The start-up check compiles the frame path for the types the loop passes: frames in the loop add none."""
    cell = Cell(cell_config, ur5)
    names = ("_frame_bodies", "_moved_within", "_others_maybe_near")
    compiled = {name: len(getattr(kernels, name).signatures) for name in names}
    assert all(compiled.values())
    for k, capsules in enumerate(([FAR_TORSO], [NEAR_HAND, FAR_TORSO], [NEAR_HAND, FAR_TORSO])):
        now = NOW + k * 33_000_000
        cell.feed(now, capsules)
        cell.step(now)
    assert {name: len(getattr(kernels, name).signatures) for name in names} == compiled


def test_the_doors_compiled_numbers_are_the_references_to_the_bit_on_a_crowd_and_out_of_the_world() -> None:
    from bench.door import crowd_payload
    from hrc_contract.humans import frame_numbers, human_starts, humans_from_payload

    plausibility = PlausibilityConfig()
    _, crowd = humans_from_payload(crowd_payload())
    outside = crowd._replace(h_b_world=crowd.h_b_world + (0.0, 0.0, 9.0) * (np.arange(crowd.n_capsules) == 7)[:, None])
    for capsules in (crowd, outside):
        starts = human_starts(capsules)
        got, want = kernels.frame_numbers(capsules, starts, plausibility), frame_numbers(capsules, starts, plausibility)
        assert got[:3] == want[:3]
        assert got.extent_m.tobytes() == want.extent_m.tobytes()
    assert kernels.frame_numbers(crowd, human_starts(crowd), plausibility).inside_world
    assert not kernels.frame_numbers(outside, human_starts(outside), plausibility).inside_world


def test_the_door_numbers_check_refuses_compiled_numbers_that_differ(monkeypatch: pytest.MonkeyPatch) -> None:
    kernels.check_frame_numbers.__wrapped__()  # the real ones pass
    real = kernels.frame_numbers

    def one_ulp_more(capsules: HumanCapsules, starts: Any, plausibility: PlausibilityConfig) -> Any:
        found = real(capsules, starts, plausibility)
        return found._replace(extent_m=np.nextafter(found.extent_m, np.inf))

    monkeypatch.setattr(kernels, "frame_numbers", one_ulp_more)
    with pytest.raises(ConfigError, match="compiled frame numbers differ"):
        kernels.check_frame_numbers.__wrapped__()


@pytest.mark.parametrize("starts", [[0], [0, 3], [0, 2, 2, 4], [1, 4], [0, 5]])
def test_the_doors_compiled_numbers_refuse_starts_they_would_read_past(starts: list[int]) -> None:
    capsules = HumanCapsules(np.zeros((4, 3)), np.ones((4, 3)), np.full(4, 0.1), ("a",) * 4, ("p",) * 4)
    assert kernels.frame_numbers(capsules, [0, 2, 4], PlausibilityConfig()).extent_m.shape == (2,)
    with pytest.raises(ValueError, match="a person has a capsule"):
        kernels.frame_numbers(capsules, starts, PlausibilityConfig())
