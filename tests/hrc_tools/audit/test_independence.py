"""The auditor computes its geometry on its own (safety-math.md §9): no gateway code in ``hrc_tools/audit/``,
its kinematics
and coal distances against independent references (finite differences, sampled points), its pruning of pairs
against evaluating every pair, and a gateway whose distances are wrong caught in the simulated cell."""

from __future__ import annotations

import ast
import math
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.paths import REPO_ROOT

import gateway.kernels
import hrc_devices.robots.segments
from hrc_contract.config import CellConfig
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.link_motion import LinkMotion, link_motion
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_tools.audit.checks import audit_links
from hrc_tools.audit.distance import LOWER_BOUND_SLACK_M, CapsulePairs, CapsuleSet
from hrc_tools.sim.cell import RunResult, simulate
from hrc_tools.sim.links import LinkFaults
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

AUDIT_DIR = REPO_ROOT / "hrc_tools" / "audit"
K = 1.6  # human approach speed [m/s]
T_B = 0.24  # controller braking time (δ 1 → 0) [s]

# -- no gateway code in the auditor ----------------------------------------------------------------------


def _imported_modules(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module is not None and node.level == 0:
            names.add(node.module)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute | ast.Name):
            # importlib.import_module("gateway...") / __import__("gateway...")
            func = node.func.attr if isinstance(node.func, ast.Attribute) else node.func.id
            if func in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant):
                names.add(str(node.args[0].value))
    return names


def test_no_module_of_the_auditor_imports_the_gateway() -> None:
    modules = sorted(AUDIT_DIR.glob("*.py"))
    assert {p.name for p in modules} >= {"__init__.py", "checks.py", "distance.py", "main.py"}
    for path in modules:
        gateway_imports = {m for m in _imported_modules(path) if m == "gateway" or m.startswith("gateway.")}
        assert not gateway_imports, f"{path.name} imports {gateway_imports}"
    # The AST check covers the audit modules themselves; this one also what the packages they use import in turn.
    probe = (
        "import sys, hrc_tools.audit, hrc_tools.audit.checks, hrc_tools.audit.main\n"
        "print(hrc_tools.audit.__file__)\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'gateway'))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", probe], cwd=REPO_ROOT, capture_output=True, text=True, check=True, timeout=120
    )
    audit_file, gateway_modules = loaded.stdout.splitlines()
    assert Path(audit_file).resolve() == AUDIT_DIR / "__init__.py"
    assert gateway_modules == "[]"


def test_the_import_check_would_see_a_gateway_import(tmp_path: Path) -> None:
    source = tmp_path / "m.py"
    source.write_text(
        "import numpy\nfrom gateway.geometry import x\nimport importlib\nimportlib.import_module('gateway.kernels')\n"
    )
    assert _imported_modules(source) == {"numpy", "gateway.geometry", "importlib", "gateway.kernels"}


# -- kinematics: Pinocchio's frame Jacobians against finite differences of its positions ----------------


def test_link_motion_matches_finite_differences(ur5: RobotModel) -> None:
    rng = np.random.default_rng(7)
    data = ur5.model.createData()
    h = 1e-6
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, ur5.n_joints)
        qd = rng.uniform(-2.0, 2.0, ur5.n_joints)
        got = link_motion(ur5, data, q, qd)
        ahead = link_motion(ur5, data, q + h * qd, np.zeros(ur5.n_joints))
        behind = link_motion(ur5, data, q - h * qd, np.zeros(ur5.n_joints))
        np.testing.assert_allclose(got.v_a_world, (ahead.p_a_world - behind.p_a_world) / (2 * h), atol=1e-6)
        np.testing.assert_allclose(got.v_b_world, (ahead.p_b_world - behind.p_b_world) / (2 * h), atol=1e-6)
        # consecutive links share a frame; the base end of the first link sits on the pedestal, 0.8 m up
        np.testing.assert_array_equal(got.p_b_world[:-1], got.p_a_world[1:])
        np.testing.assert_allclose(got.p_a_world[0], ur5.p_world_base, atol=1e-12)
        # rigid links: the end points keep their distance
        np.testing.assert_allclose(
            np.linalg.norm(got.p_b_world - got.p_a_world, axis=1),
            np.linalg.norm(ahead.p_b_world - ahead.p_a_world, axis=1),
            atol=1e-9,
        )


# -- coal distances against sampled points ---------------------------------------------------------------

SAMPLES = 401


def _sampled_surface_distance(a1: Any, b1: Any, r1: float, a2: Any, b2: Any, r2: float) -> tuple[float, float]:
    """Brute force: the smallest distance between SAMPLES points on each axis, minus both radii, and its
    resolution: the true value lies in [brute − resolution, brute] (each closest point is within half a step of
    a sample) [m]."""
    f = np.linspace(0.0, 1.0, SAMPLES)[:, None]
    x = a1 + f * (b1 - a1)
    y = a2 + f * (b2 - a2)
    gaps = np.sqrt(((x[:, None, :] - y[None, :, :]) ** 2).sum(-1))
    step = (np.linalg.norm(b1 - a1) + np.linalg.norm(b2 - a2)) / (SAMPLES - 1)
    return float(gaps.min()) - r1 - r2, step / 2


def _random_pair(rng: np.random.Generator, kind: str) -> tuple[Any, Any, float, Any, Any, float]:
    a1 = rng.uniform(-0.5, 0.5, 3)
    b1 = a1 + rng.normal(size=3) * rng.uniform(0.0, 0.4)
    a2 = rng.uniform(-0.5, 0.5, 3)
    b2 = a2 + rng.normal(size=3) * rng.uniform(0.0, 0.4)
    if kind == "parallel":
        b2 = a2 + (b1 - a1) * rng.uniform(-2.0, 2.0)
    elif kind == "crossing":  # the axes intersect: no direction between them
        at = a1 + rng.uniform(0.0, 1.0) * (b1 - a1)
        direction = b2 - a2
        a2 = at - rng.uniform(0.1, 1.0) * direction
        b2 = at + rng.uniform(0.1, 1.0) * direction
    elif kind == "point":
        b2 = a2.copy()
    elif kind == "near":  # a few centimetres apart, possibly overlapping
        a2 = a1 + rng.uniform(0.0, 1.0) * (b1 - a1) + rng.normal(size=3) * 0.05
    return a1, b1, rng.uniform(0.02, 0.15), a2, b2, rng.uniform(0.0, 0.15)


@pytest.mark.parametrize("kind", ["random", "parallel", "crossing", "point", "near"])
def test_coal_distance_agrees_with_sampled_points(kind: str) -> None:
    rng = np.random.default_rng(["random", "parallel", "crossing", "point", "near"].index(kind))
    for _ in range(40):
        a1, b1, r1, a2, b2, r2 = _random_pair(rng, kind)
        pairs = CapsulePairs(
            CapsuleSet(a1[None], b1[None], np.array([r1])), CapsuleSet(a2[None], b2[None], np.array([r2]))
        )
        got = pairs.exact(0, 0)
        brute, resolution = _sampled_surface_distance(a1, b1, r1, a2, b2, r2)
        assert brute - resolution - 1e-12 <= got.surface_m <= brute + 1e-12, (kind, got, brute, resolution)
        # The closest point on the first axis, moved along the normal by the centre-line distance, lands on the
        # second axis. Where the axes touch, the normal is (0, 0, 0) (or, rounding, any unit vector).
        p1 = a1 + got.s_first * (b1 - a1)
        normal = np.asarray(got.normal)
        assert got.normal == (0.0, 0.0, 0.0) or np.linalg.norm(normal) == pytest.approx(1.0)
        p2 = p1 + normal * (got.surface_m + r1 + r2)
        assert _distance_to_segment(p2, a2, b2) < 1e-9
        if kind == "crossing":
            assert got.surface_m == pytest.approx(-r1 - r2, abs=1e-9)
        # The auditor's own check reports the same distance, clamped at 0.
        links = LinkMotion(a1[None], b1[None], np.zeros((1, 3)), np.zeros((1, 3)))
        humans = HumanCapsules(a2[None], b2[None], np.array([r2]), ("h",), ("c",))
        audited = audit_links(links, np.array([r1]), ("link",), 0.0, T_B, humans, K)
        assert audited.min_distance_m == max(0.0, got.surface_m)
        # and the lower bound never exceeds it
        assert pairs.lower_bounds_m()[0, 0] <= max(0.0, got.surface_m)


def test_coal_placements_are_rotations_taking_z_to_the_axis() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(200, 3))
    axis = rng.normal(size=(200, 3)) * rng.uniform(0.0, 0.5, (200, 1))
    axis[:4] = [[0, 0, 1], [0, 0, -1], [0, 0, -1e-3], [1e-9, 0, -1]]  # along ±z: where a naive basis divides by ~0
    axis[4] = 0.0  # a sphere
    capsules = CapsuleSet(a, a + axis, np.full(200, 0.1))
    for k in range(200):
        shape, placement = capsules.shape(k)
        rotation = placement.getRotation()
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        length = float(np.linalg.norm(axis[k]))
        assert shape.halfLength == pytest.approx(length / 2)
        if length > 0.0:
            np.testing.assert_allclose(rotation[:, 2], axis[k] / length, atol=1e-12)
        np.testing.assert_allclose(placement.getTranslation(), a[k] + axis[k] / 2, atol=1e-15)


def _distance_to_segment(p: Any, a: Any, b: Any) -> float:
    d = b - a
    length2 = float(d @ d)
    s = 0.0 if length2 == 0.0 else min(max(float((p - a) @ d) / length2, 0.0), 1.0)
    return float(np.linalg.norm(p - (a + s * d)))


# -- pruning: the same verdict as evaluating every pair -------------------------------------------------


def _random_humans(rng: np.random.Generator, n: int, centre: Any, spread_m: float) -> HumanCapsules:
    a = centre + rng.normal(size=(n, 3)) * spread_m
    b = a + rng.normal(size=(n, 3)) * rng.uniform(0.0, 0.25, (n, 1))
    point = rng.random(n) < 0.2  # some capsules are spheres
    b[point] = a[point]
    return HumanCapsules(a, b, rng.uniform(0.03, 0.15, n), tuple(f"h{k // 13}" for k in range(n)), ("c",) * n)


def _every_pair(
    links: LinkMotion, robot: RobotModel, delta: float, humans: HumanCapsules
) -> tuple[float, float, int, float]:
    """Reference: every pair with coal, the margin of safety-math.md §9 written out; (smallest margin, smallest
    distance, flat index of the first pair of smallest margin, that pair's distance)."""
    pairs = CapsulePairs(
        CapsuleSet(links.p_a_world, links.p_b_world, robot.link_radius_m),
        CapsuleSet(humans.h_a_world, humans.h_b_world, humans.radius_m),
    )
    t_stop = delta * T_B
    margins, distances = [], []
    for i in range(len(robot.link_names)):
        for j in range(humans.n_capsules):
            pair = pairs.exact(i, j)
            d = max(0.0, pair.surface_m)
            v = links.v_a_world[i] + pair.s_first * (links.v_b_world[i] - links.v_a_world[i])
            n = np.asarray(pair.normal)
            v_toward = float(np.linalg.norm(v)) if not n.any() else max(0.0, float(v @ n))
            margins.append(d - (v_toward * t_stop / 2 + K * t_stop))
            distances.append(d)
    worst = int(np.argmin(margins))
    return margins[worst], min(distances), worst, distances[worst]


def test_pruned_pairs_give_the_verdict_of_every_pair(ur5: RobotModel) -> None:
    rng = np.random.default_rng(11)
    data = ur5.model.createData()
    violations = closest_is_not_worst = 0
    for case in range(200):
        q = rng.uniform(-np.pi, np.pi, ur5.n_joints)
        qd = rng.uniform(-3.0, 3.0, ur5.n_joints)
        delta = float(rng.choice([0.0, 0.3, 1.0]))
        links = link_motion(ur5, data, q, delta * qd)
        centre = ur5.p_world_base + rng.normal(size=3) * 0.4
        spread = [0.1, 0.3, 1.0][case % 3]  # from tangled up with the arm to across the cell
        humans = _random_humans(rng, 13 * (1 + case % 3), centre, spread)
        got = audit_links(links, ur5.link_radius_m, ur5.link_names, delta, T_B, humans, K)
        margin, distance, worst, worst_distance = _every_pair(links, ur5, delta, humans)
        assert got.margin_m == pytest.approx(margin, abs=1e-12)  # the reference rounds its own way
        assert got.min_distance_m == distance
        assert (got.worst_link, got.worst_capsule) == (
            ur5.link_names[worst // humans.n_capsules],
            worst % humans.n_capsules,
        )
        assert got.violation == (margin < 0.0 or (distance <= 0.0 and got.speed_mps > 0.01))
        violations += got.violation
        closest_is_not_worst += distance < worst_distance  # the closest pair is not the one of smallest margin
    assert 10 < violations < 190  # both verdicts were exercised
    assert closest_is_not_worst > 5  # and the smallest distance needed pairs of its own


def test_lower_bounds_hold_on_random_sets() -> None:
    rng = np.random.default_rng(5)
    for _ in range(30):
        first = _random_humans(rng, 7, np.zeros(3), 0.4)
        second = _random_humans(rng, 26, np.zeros(3), 0.6)
        pairs = CapsulePairs(
            CapsuleSet(first.h_a_world, first.h_b_world, first.radius_m),
            CapsuleSet(second.h_a_world, second.h_b_world, second.radius_m),
        )
        low = pairs.lower_bounds_m()
        exact = np.array([[max(0.0, pairs.exact(i, j).surface_m) for j in range(26)] for i in range(7)])
        assert (low <= exact).all()
        assert (low >= 0.0).all()
        # and they are useful: most pairs apart are bounded within a few centimetres plus the half-lengths
        apart = exact > 0.0
        assert np.median((exact - low)[apart]) < 0.15
        assert LOWER_BOUND_SLACK_M < 1e-6


# -- teeth: a gateway whose distances are too large, caught by the auditor in the simulated cell -----------

ERROR_M = 0.5
"""How much too large the wrong gateway's distances are [m]."""
DURATION_S = 4.0


def _walk_at_the_robot(bearing_deg: float, speed_mps: float = 1.6, stop_m: float = 0.6) -> Scenario:
    """One person walking from 3 m straight at the robot base along ``bearing_deg``, then standing ``stop_m`` off."""
    bearing = math.radians(bearing_deg)
    facing = bearing + math.pi
    start = (3.0 * math.cos(bearing), 3.0 * math.sin(bearing))
    stop = (stop_m * math.cos(bearing), stop_m * math.sin(bearing))
    arrive_s = 0.2 + (3.0 - stop_m) / speed_mps
    keyframes = [
        Keyframe(t_s=0.2, xy_m=start, heading_rad=facing),
        Keyframe(t_s=arrive_s, xy_m=stop, heading_rad=facing),
        Keyframe(t_s=DURATION_S, xy_m=stop, heading_rad=facing),
    ]
    return Scenario(
        description="walks at the robot",
        duration_s=DURATION_S,
        loop=False,
        humans=[HumanScript(id="h1", keyframes=keyframes)],
    )


def _tight_cell(base: CellConfig) -> tuple[CellConfig, dict[str, RobotModel]]:
    """The default cell with one noiseless 30 Hz tracker, and the gateway assuming the controller's real braking
    time for every joint (no slack in the braking model that could hide a wrong distance)."""
    raw = base.model_dump()
    raw["trackers"] = {"front": {"rate_hz": 30.0, "noise_std_m": 0.0, "drop_probability": 0.0, "latency_s": 0.0}}
    for robot in raw["robots"].values():
        robot["model"]["braking_time_s"] = [robot["controller"]["braking_time_s"]] * len(robot["model"]["joints"])
    config = CellConfig.model_validate(raw)
    return config, {name: load_robot_model(name, r) for name, r in config.robots.items()}


def _run(config: CellConfig, robots: dict[str, RobotModel], bearing_deg: float, tau_s: float) -> RunResult:
    return simulate(
        config,
        robots,
        _walk_at_the_robot(bearing_deg),
        LinkFaults(),
        DURATION_S,
        seed=1,
        program_start_s={"ur5": tau_s},
    )


def _inflate_gateway_distances(monkeypatch: pytest.MonkeyPatch, by_m: float) -> Callable[..., Any]:
    """Make every distance of the gateway's code ``by_m`` too large; returns the real ``RobotKernels.cycle``.

    - What the gateway runs: :meth:`gateway.kernels.RobotKernels.cycle` (kinematics, distances and the rows of
      eq. (15) in one compiled call) is wrapped so that it sees every capsule radius ``by_m`` smaller, i.e. every
      surface distance ``by_m`` larger, consistently through d, Δ, f, the bounds and the closest pair.
    - Its numpy reference, :func:`hrc_devices.robots.segments.segment_distances`, wherever a module bound it by name, so
      that an auditor that used the gateway's distance code would be fooled as well.
    """
    real_cycle = gateway.kernels.RobotKernels.cycle

    def cycle(self: gateway.kernels.RobotKernels, q: Any, qd: Any, capsules: Any, t_delay_s: float) -> Any:
        shifted = capsules.copy()  # the caller's array is shared (computed once per tracker frame)
        shifted[-1] -= by_m  # the last row is the radius (gateway.kernels.capsule_columns)
        return real_cycle(self, q, qd, shifted, t_delay_s)

    monkeypatch.setattr(gateway.kernels.RobotKernels, "cycle", cycle)
    real_segments = hrc_devices.robots.segments.segment_distances

    def segment_distances(*args: Any) -> Any:
        found = real_segments(*args)
        return found._replace(distance_m=found.distance_m + by_m)

    for module in list(sys.modules.values()):
        if getattr(module, "segment_distances", None) is real_segments:
            monkeypatch.setattr(module, "segment_distances", segment_distances)
    return real_cycle


TEETH = [(0.0, 2.0), (-40.0, 0.0)]  # (bearing [deg], program start τ [s])


@pytest.mark.parametrize(("bearing_deg", "tau_s"), TEETH, ids=[f"bearing {b:g} deg, tau {t:g} s" for b, t in TEETH])
def test_the_auditor_catches_a_gateway_whose_distances_are_too_large(
    cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch, bearing_deg: float, tau_s: float
) -> None:
    config, robots = _tight_cell(cell_config)
    honest = _run(config, robots, bearing_deg, tau_s)
    assert honest.audit.violations == 0, honest.to_dict()["audit"]
    assert honest.audit.smallest_margin_moving_m > 0.1

    real_cycle = _inflate_gateway_distances(monkeypatch, ERROR_M)
    # The patch does what it says: the gateway's distances are ERROR_M too large, the auditor's are not.
    robot = robots["ur5"]
    kernels = gateway.kernels.RobotKernels(robot, config.safety)
    q = np.array([0.3, -1.14, 1.25, -1.68, -1.57, 0.3])
    hand = np.array([[0.6, 0.0, 1.2]])
    humans = HumanCapsules(hand, hand, np.array([0.05]), ("h",), ("hand",))
    columns = gateway.kernels.capsule_columns(humans)
    wrong = kernels.cycle(q, np.zeros(6), columns, 0.05)[3].distance_m
    right = real_cycle(kernels, q, np.zeros(6), columns, 0.05)[3].distance_m
    assert wrong - right == pytest.approx(ERROR_M)
    links = link_motion(robot, robot.model.createData(), q, np.zeros(6))
    assert audit_links(
        links, robot.link_radius_m, robot.link_names, 0.0, T_B, humans, K
    ).min_distance_m == pytest.approx(right)

    fooled = _run(config, robots, bearing_deg, tau_s)
    assert fooled.audit.violations > 50, fooled.to_dict()["audit"]
    assert fooled.audit.contacts_while_moving > 10
    assert fooled.audit.smallest_margin_moving_m < -0.1
