"""The compiled LP (9)/(13) decision (gateway/open_kernels.py) against the numpy reference (gateway/open_control.py).

Same answers on seeded random problems: feasible ones, ones bounded by a row, infeasible ones (a robot too fast to
stop in one cycle, an empty velocity box), and ones with nan or inf anywhere; every cap (full, partial, zero, nan);
one buffer reused across problems of every size, in order and shuffled, so that nothing of an earlier cycle leaks.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import daqp
import numpy as np
import pytest

from gateway import open_control
from gateway.daqp_direct import DirectLp
from gateway.open_control import Limits, SafetyRows, Solution, Task
from gateway.open_kernels import OpenLp

# the reference's numpy warns on the poisoned problems (inf − inf in a row's reach); the answer is what is checked
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")

DT_S = 0.004
LINKS = ("l0", "l1", "l2", "l3")
CAPS = (1.0, 0.6, 0.0, float("nan"))
POISON = ("a_s", "f_m2", "jacobian", "x_rate", "correction", "qd_prev", "q_ref", "qd_self", "f_inf", "limits", "qd_max")


def _problem(seed: int) -> dict[str, Any]:
    """A random LP (9)/(13) of 1–9 joints and 0–200 rows: most rows far (dropped), some binding; a velocity from
    0.2 to 1.6 × the task's (above ~1: often infeasible in one cycle); every 7th problem poisoned with nan or inf."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 10))
    m = int(rng.choice([0, 1, 5, 40, 200]))
    k = int(rng.choice([0, 3, 6])) if n > 6 else int(rng.choice([0, min(n, 3)]))
    a = rng.normal(0.0, 0.3, (m, n))
    qd_task = rng.normal(0.0, 0.6, n)
    f = np.abs(a @ qd_task) * rng.choice([0.3, 0.9, 1.5, 20.0], m) * rng.uniform(0.8, 1.2, m)
    if m and rng.random() < 0.2:
        f[rng.integers(m)] = 0.0  # a pair already at its clearance
    jac = rng.normal(0.0, 0.5, (k, n))
    task = Task(jac, jac @ qd_task, jac @ rng.normal(0.0, 0.02, n))
    qd_max = rng.uniform(1.5, 2.5, n)
    t_brake = float(rng.choice([0.02, 0.2, 0.5]))
    q_lim = rng.uniform(1.0, 3.0, n)
    limits = Limits(qd_max, qd_max / t_brake, -q_lim, q_lim, t_brake)
    qd_prev = float(rng.uniform(0.2, 1.6)) * qd_task
    q_ref = rng.uniform(-1.05, 1.05, n) * q_lim  # sometimes beyond a limit
    qd_self = qd_prev + rng.normal(0.0, 0.2, n)
    rows = SafetyRows(a, f, rng.integers(0, len(LINKS), m), rng.integers(0, 30, m), 0)
    problem = {
        "rows": rows,
        "task": task,
        "qd_prev": qd_prev,
        "q_ref": q_ref,
        "limits": limits,
        "qd_self": qd_self,
        "cap": CAPS[seed % len(CAPS)],
    }
    if seed % 7 == 3:
        _poison(problem, POISON[(seed // 7) % len(POISON)], rng)
    return problem


def _poison(problem: dict[str, Any], what: str, rng: np.random.Generator, bad: float | None = None) -> None:
    bad = float(rng.choice([np.nan, np.inf, -np.inf])) if bad is None else bad
    rows, task = problem["rows"], problem["task"]
    if what in ("a_s", "f_m2", "f_inf") and rows.f_m2.size:
        a, f = rows.a_s.copy(), rows.f_m2.copy()
        i = rng.integers(f.size)
        if what == "a_s":
            a[i, rng.integers(a.shape[1])] = bad
        else:
            f[i] = np.inf if what == "f_inf" else bad
        problem["rows"] = rows._replace(a_s=a, f_m2=f)
    elif what in ("jacobian", "x_rate", "correction") and task.x_rate.size:
        x = getattr(task, what).copy()
        x.reshape(-1)[rng.integers(x.size)] = bad
        problem["task"] = task._replace(**{what: x})
    elif what in ("qd_prev", "q_ref", "qd_self"):
        x = problem[what].copy()
        x[rng.integers(x.size)] = bad
        problem[what] = x
    elif what in ("limits", "qd_max"):
        field = "q_max_rad" if what == "limits" else "qd_max_radps"
        x = getattr(problem["limits"], field).copy()
        x[rng.integers(x.size)] = bad
        problem["limits"] = problem["limits"]._replace(**{field: x})


def _decide(decide: Any, problem: dict[str, Any]) -> tuple[Solution, list[float]]:
    asked: list[float] = []

    def cap(delta_star: float) -> float:
        asked.append(delta_star)
        return float(problem["cap"])

    solution = decide(
        problem["rows"],
        problem["task"],
        problem["qd_prev"],
        problem["q_ref"],
        problem["limits"],
        DT_S,
        problem["qd_self"],
        cap,
        LINKS,
        0.8,
        0.3,
    )
    return solution, asked


def _same(ours: Solution, theirs: Solution, problem: dict[str, Any]) -> None:
    assert ours.how == theirs.how
    if ours.bounded_by != theirs.bounded_by:
        _both_active(ours, theirs, problem)
    np.testing.assert_array_equal(ours.qd_radps, theirs.qd_radps)  # bit for bit (nan where nan)
    assert ours.delta == theirs.delta or (np.isnan(ours.delta) and np.isnan(theirs.delta))
    assert ours.self_motion_gap_radps == theirs.self_motion_gap_radps


def _both_active(ours: Solution, theirs: Solution, problem: dict[str, Any]) -> None:
    """Several rows active at the optimum tie to ~1e-16 in their slack: the summation order (a loop here, BLAS in
    the reference) may name another of them. Then both must name a row of that tie."""
    assert ours.bounded_by.startswith("safety:")
    assert theirs.bounded_by.startswith("safety:")
    lower, upper = open_control.velocity_bounds(problem["qd_prev"], problem["q_ref"], problem["limits"], DT_S)
    rows = open_control.rows_within(problem["rows"], lower, upper)
    best = open_control.solve_lp9(rows, problem["task"], lower, upper)
    assert best is not None
    slack = rows.f_m2 - rows.a_s @ best[0]
    ratio = slack / (np.abs(rows.a_s) @ np.abs(best[0]) + np.abs(rows.f_m2) + 1e-12)
    tied = {
        f"safety:{LINKS[int(rows.link[i])]}/{int(rows.capsule[i])}"
        for i in np.flatnonzero(ratio <= ratio.min() + 1e-12)
    }
    assert {ours.bounded_by, theirs.bounded_by} <= tied


SEEDS = range(1200)


def test_the_compiled_decision_gives_the_reference_answer_on_seeded_random_problems() -> None:
    lp = OpenLp()  # one set of buffers for every size, as a robot's cycles reuse it
    hows: Counter[str] = Counter()
    for seed in SEEDS:
        problem = _problem(seed)
        ours, asked_ours = _decide(lp.decide, problem)
        theirs, asked_theirs = _decide(open_control.decide, problem)
        _same(ours, theirs, problem)
        assert asked_ours == asked_theirs  # cap called once, with the same δ*
        hows[theirs.how] += 1
    # the problems reach every path of the decision
    assert {
        "lp13",
        "ramp_stop:lp9_infeasible",
        "ramp_stop:commanded",
    } <= set(hows), hows
    assert hows["lp13"] >= 100
    assert hows["ramp_stop:lp9_infeasible"] >= 100


def test_the_buffers_carry_nothing_from_one_cycle_to_the_next() -> None:
    problems = [_problem(seed) for seed in range(300)]
    expected = [_decide(open_control.decide, p)[0] for p in problems]
    lp = OpenLp()
    order = np.random.default_rng(5).permutation(len(problems))
    for i in order:
        _same(_decide(lp.decide, problems[i])[0], expected[i], problems[i])


@pytest.mark.parametrize("seed", [0, 2, 9, 17])
def test_the_single_lps_match_the_reference(seed: int) -> None:
    """LP (9) and LP (13) alone, on the rows the reference keeps: the same q̇, δ and objective, bit for bit."""
    for s in range(seed, seed + 60):
        p = _problem(s)
        lower, upper = open_control.velocity_bounds(p["qd_prev"], p["q_ref"], p["limits"], DT_S)
        rows = open_control.rows_within(p["rows"], lower, upper)
        theirs9 = open_control.solve_lp9(rows, p["task"], lower, upper)
        lp = OpenLp()
        ours9 = lp.lp9(p["rows"], p["task"], p["qd_prev"], p["q_ref"], p["limits"], DT_S)
        assert (ours9 is None) == (theirs9 is None)
        if ours9 is None or theirs9 is None:
            continue
        np.testing.assert_array_equal(ours9[0], theirs9[0])
        assert ours9[1] == theirs9[1]
        for delta in (theirs9[1], 0.5 * theirs9[1]):
            theirs13 = open_control.solve_lp13(rows, p["task"], delta, lower, upper, p["qd_self"])
            ours13 = lp.lp13(p["task"], delta, p["qd_self"])
            assert (ours13 is None) == (theirs13 is None)
            if ours13 is not None and theirs13 is not None:
                np.testing.assert_array_equal(ours13[0], theirs13[0])
                assert ours13[1] == theirs13[1]


def test_a_robot_too_fast_to_stop_in_one_cycle_ramps_to_a_stop() -> None:
    """The known case of test_open_control: LP (9) infeasible → the ramp stop, δ scaled as the velocity."""
    n = 2
    rows = SafetyRows(np.array([[1.0, 0.0]]), np.array([0.0]), np.zeros(1, np.intp), np.zeros(1, np.intp), 0)
    task = Task(np.zeros((0, n)), np.zeros(0), np.zeros(0))
    limits = Limits(np.full(n, 2.0), np.full(n, 4.0), np.full(n, -3.0), np.full(n, 3.0), 0.5)
    qd_prev = np.array([1.5, 0.0])
    solution = OpenLp().decide(
        rows, task, qd_prev, np.zeros(n), limits, DT_S, np.zeros(n), open_control.fixed_cap(1.0), ("l0",), 1.0
    )
    assert solution.how == "ramp_stop:lp9_infeasible"
    assert solution.qd_radps == pytest.approx(qd_prev * (0.75 - 0.008) / 0.75)
    assert solution.delta == pytest.approx((0.75 - 0.008) / 0.75)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("what", POISON)
def test_nan_or_inf_in_any_input_gives_the_reference_answer_and_nan_fails_closed(what: str, bad: float) -> None:
    """Poisoned data gives the reference's answer; with nan in the rows, the task, the state or the limits the
    command is a ramp stop (an infinite right-hand side is a row that can never bind: dropped)."""
    rng = np.random.default_rng(11)
    for seed in range(40):
        problem = _problem(1000 * seed + 1)
        problem["cap"] = 1.0
        _poison(problem, what, rng, bad)
        ours = _decide(OpenLp().decide, problem)[0]
        theirs = _decide(open_control.decide, problem)[0]
        _same(ours, theirs, problem)
        if np.isnan(bad) and what not in ("f_inf", "qd_self"):
            assert ours.how.startswith("ramp_stop:") or not _was_poisoned(problem, what)


def _was_poisoned(problem: dict[str, Any], what: str) -> bool:
    if what in ("a_s", "f_m2"):
        return bool(problem["rows"].f_m2.size) and not (
            np.isfinite(problem["rows"].a_s).all() and np.isfinite(problem["rows"].f_m2).all()
        )
    if what in ("jacobian", "x_rate", "correction"):
        return bool(problem["task"].x_rate.size) and not np.isfinite(getattr(problem["task"], what)).all()
    if what in ("limits", "qd_max"):
        return not (
            np.isfinite(problem["limits"].q_max_rad).all() and np.isfinite(problem["limits"].qd_max_radps).all()
        )
    return not np.isfinite(problem[what]).all()


def _feasible_problem() -> dict[str, Any]:
    for seed in range(100):
        problem = _problem(seed)
        problem["cap"] = 1.0
        if _decide(open_control.decide, problem)[0].how == "lp13":
            return problem
    raise AssertionError("no feasible problem among the first 100 seeds")


@pytest.mark.parametrize(
    ("lies", "how"),
    [
        ((0,), "ramp_stop:lp9_breaks_a_row"),  # LP (9)'s answer breaks a row: never sent
        ((1,), "lp9"),  # LP (13)'s does: LP (9)'s q̇ stands (δ = δ*)
        ((), "ramp_stop:lp9_infeasible"),  # the solver fails
    ],
)
def test_a_solver_answer_that_breaks_a_row_or_fails_is_never_sent(
    monkeypatch: pytest.MonkeyPatch, lies: tuple[int, ...], how: str
) -> None:
    """Fail closed as the reference does, with the same fallbacks, when DAQP lies about or fails a solve."""
    problem = _feasible_problem()
    answers: dict[str, Solution] = {}
    for name, decide in (("ours", OpenLp().decide), ("theirs", open_control.decide)):
        monkeypatch.setattr("daqp.solve", _lying_solve(lies))
        monkeypatch.setattr(DirectLp, "solve", _lying_direct_solve(lies))
        answers[name] = _decide(decide, problem)[0]
        monkeypatch.undo()
    assert answers["ours"].how == how
    _same(answers["ours"], answers["theirs"], problem)


def _lying_direct_solve(lies: tuple[int, ...]) -> Any:
    """:meth:`DirectLp.solve` that lies or fails as :func:`_lying_solve` does (the path the loop takes where DAQP is
    called directly)."""
    real_solve = DirectLp.solve
    calls = [0]

    def solve(self: DirectLp, rows: int) -> int:
        calls[0] += 1
        if not lies:
            self.z[:] = 0.0
            return -1
        if calls[0] - 1 in lies:
            self.z[:] = 50.0
            return 1
        return real_solve(self, rows)

    return solve


def _lying_solve(lies: tuple[int, ...]) -> Any:
    """``daqp.solve`` that answers the calls numbered in ``lies`` with an "optimal" q̇ far beyond the rows; with
    none, every call fails."""
    real_solve = daqp.solve
    calls = [0]

    def solve(*args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        if not lies:
            return np.zeros(args[1].size), 0.0, -1, {}  # DAQP's "infeasible"
        if calls[0] - 1 in lies:
            return np.full(args[1].size, 50.0), -1.0, 1, {}
        return real_solve(*args, **kwargs)

    return solve
