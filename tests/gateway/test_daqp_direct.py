"""DAQP called directly (gateway/daqp_direct.py): the same answers as ``daqp.solve``, and used only where its
structures are the installed library's."""

from __future__ import annotations

import daqp
import numpy as np
import pytest

from gateway import daqp_direct
from gateway.daqp_direct import DirectLp, direct_lp_or_none
from gateway.open_kernels import OpenLp


def test_the_pinned_daqp_is_called_directly_by_the_open_lps() -> None:
    assert direct_lp_or_none() is None
    lp = OpenLp()
    lp._buffers(7, 6, 100)
    assert isinstance(lp._direct9, DirectLp)
    assert isinstance(lp._direct13, DirectLp)


def test_the_answers_are_daqp_solves_to_the_bit_feasible_or_not() -> None:
    assert daqp_direct._same_answers(seed=1, problems=300) is None
    rng = np.random.default_rng(2)
    flags = set()
    for k in range(200):
        n, rows = 4, 30
        cost = rng.normal(size=n)
        a = rng.normal(size=(rows, n))
        low_m = 0.1 if k % 2 else -1.0  # z = 0 keeps every row of the odd ones: feasible
        upper = np.concatenate((np.ones(n), rng.uniform(low_m, 1.0, rows)))
        lower = np.concatenate((-np.ones(n), np.full(rows, -1e30)))
        sense = np.zeros(n + rows, dtype=np.intc)
        direct = DirectLp(cost, a, upper, lower, sense)
        flag = direct.solve(rows)
        z, _, want, _ = daqp.solve(None, cost, a, upper, lower, sense)
        assert flag == want
        if flag == 1:
            np.testing.assert_array_equal(direct.z, z)
        flags.add(flag)
    assert 1 in flags
    assert any(f < 0 for f in flags), "some of these LPs are infeasible: the failures agree too"


def test_fewer_rows_than_bound_solve_that_lp_alone() -> None:
    """The buffers hold more rows than a cycle uses: only the first ``rows`` count (the open LPs' kept rows)."""
    cost = np.array([0.0, -1.0])
    a = np.array([[0.0, 1.0], [0.0, 1.0]])
    upper = np.array([1.0, 1.0, 0.5, 0.25])
    lower = np.array([-1.0, -1.0, -1e30, -1e30])
    direct = DirectLp(cost, a, upper, lower, np.zeros(4, dtype=np.intc))
    assert direct.solve(0) == 1
    assert direct.z[1] == 1.0
    assert direct.solve(1) == 1
    assert direct.z[1] == 0.5
    assert direct.solve(2) == 1
    assert direct.z[1] == 0.25
    with pytest.raises(ValueError, match="the buffers hold 2"):
        direct.solve(3)


def test_buffers_it_cannot_hand_to_daqp_are_refused() -> None:
    cost, sense = np.zeros(2), np.zeros(4, dtype=np.intc)
    a, upper, lower = np.zeros((2, 2)), np.ones(4), -np.ones(4)
    with pytest.raises(ValueError, match="C-ordered"):
        DirectLp(cost, np.asfortranarray(np.zeros((2, 2)))[:, ::-1], upper, lower, sense)
    with pytest.raises(ValueError, match="sense"):
        DirectLp(cost, a, upper, lower, np.zeros(4, dtype=np.int64))
    with pytest.raises(ValueError, match="upper"):
        DirectLp(cost, a, np.ones(3), lower, sense)


def test_another_version_or_layout_keeps_daqp_solve(monkeypatch: pytest.MonkeyPatch) -> None:
    check = direct_lp_or_none.__wrapped__
    assert check() is None
    monkeypatch.setattr(daqp_direct, "_installed_version", lambda: "0.12.0")
    assert "daqp 0.12.0 installed" in (check() or "")
    monkeypatch.undo()
    monkeypatch.setitem(daqp_direct.DEFAULT_SETTINGS, "iter_limit", 5000)  # as if a field had moved
    assert "not where they are declared" in (check() or "")
    monkeypatch.undo()
    monkeypatch.setattr(daqp_direct, "_same_answers", lambda: "LP 3: exit 1 against -1")
    assert check() == "LP 3: exit 1 against -1"
