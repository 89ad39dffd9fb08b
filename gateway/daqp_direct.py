"""DAQP's C solver called directly: ``daqp_quadprog`` through ctypes, its structures kept between cycles.

``daqp.solve(None, cost, A, bupper, blower, sense)`` is DAQP's Cython wrapper around the same C call: per call it
parses ~20 keyword settings, takes five memoryviews, allocates the answer and the multipliers and builds a dict, ~3.5
µs of the ~15 µs a 60-row LP takes here (``bench.open_lp``'s LPs, 2026-12-07). :class:`DirectLp` calls
``daqp_quadprog(result, problem, settings)`` on buffers bound once (the LP buffers of
:class:`gateway.open_kernels.OpenLp`, kept between cycles): only the row count changes per call. The settings are
DAQP's own defaults (``daqp_default_settings``), the ones ``daqp.solve`` passes; the answers are the same to the bit
(``tests/gateway/test_daqp_direct.py``, and :func:`check_direct_lp` at start-up).

The structures are declared here from DAQP 0.11.0's headers (``csrc/include/types.h`` and ``api.h`` of its sdist):
``pyproject.toml`` pins that version. A structure that drifted from the installed library would be read wrong, so
:func:`direct_lp_or_none` uses this path only when the installed version is the one declared, the defaults the
library writes into the declared settings are its documented ones (a layout check), and seeded LPs solved both ways
give the same answers; otherwise the caller keeps ``daqp.solve``. Every answer is checked against every row by the
caller either way (a wrong answer commands the stop, never a motion).
"""

from __future__ import annotations

import ctypes
import functools
import importlib.metadata
import logging

import daqp
import numpy as np
import numpy.typing as npt

log = logging.getLogger(__name__)

DECLARED_VERSION = "0.11.0"
"""The DAQP version whose structures are declared below."""


class _Problem(ctypes.Structure):
    """``DAQPProblem`` (types.h): min ½ xᵀHx + fᵀx s.t. blower ≤ [x; A x] ≤ bupper, the first ``ms`` rows simple
    bounds."""

    _fields_ = (
        ("n", ctypes.c_int),
        ("m", ctypes.c_int),
        ("ms", ctypes.c_int),
        ("H", ctypes.c_void_p),
        ("f", ctypes.c_void_p),
        ("A", ctypes.c_void_p),
        ("bupper", ctypes.c_void_p),
        ("blower", ctypes.c_void_p),
        ("sense", ctypes.c_void_p),
        ("break_points", ctypes.c_void_p),
        ("nh", ctypes.c_int),
        ("problem_type", ctypes.c_int),
    )


class _Settings(ctypes.Structure):
    """``DAQPSettings`` (types.h)."""

    _fields_ = (
        ("primal_tol", ctypes.c_double),
        ("dual_tol", ctypes.c_double),
        ("zero_tol", ctypes.c_double),
        ("pivot_tol", ctypes.c_double),
        ("progress_tol", ctypes.c_double),
        ("cycle_tol", ctypes.c_int),
        ("iter_limit", ctypes.c_int),
        ("fval_bound", ctypes.c_double),
        ("eps_prox", ctypes.c_double),
        ("eta_prox", ctypes.c_double),
        ("rho_soft", ctypes.c_double),
        ("rel_subopt", ctypes.c_double),
        ("abs_subopt", ctypes.c_double),
        ("sing_tol", ctypes.c_double),
        ("refactor_tol", ctypes.c_double),
        ("time_limit", ctypes.c_double),
        ("w_soft", ctypes.c_double),
        ("eq_reduction", ctypes.c_int),
        ("presolve", ctypes.c_int),
    )


DEFAULT_SETTINGS = {
    "primal_tol": 1e-6,
    "dual_tol": 1e-12,
    "zero_tol": 1e-11,
    "pivot_tol": 1e-8,
    "progress_tol": 1e-14,
    "cycle_tol": 10,
    "iter_limit": 10000,
    "fval_bound": 1e30,
    "eps_prox": -1e-6,
    "eta_prox": -1.0,
    "rho_soft": 1e-6,
    "rel_subopt": 0.0,
    "abs_subopt": 0.0,
    "sing_tol": 3.7e-11,
    "refactor_tol": 1e-9,
    "time_limit": 0.0,
    "w_soft": 0.0,
    "eq_reduction": 0,
    "presolve": 1,
}
"""DAQP 0.11.0's defaults (constants.h ``DAQP_DEFAULT_*``), what ``daqp.solve`` passes: ``daqp_default_settings``
must write exactly these into :class:`_Settings`, or its fields are not where they are declared."""


class _Result(ctypes.Structure):
    """``DAQPResult`` (api.h)."""

    _fields_ = (
        ("x", ctypes.c_void_p),
        ("lam", ctypes.c_void_p),
        ("fval", ctypes.c_double),
        ("soft_slack", ctypes.c_double),
        ("exitflag", ctypes.c_int),
        ("iter", ctypes.c_int),
        ("nodes", ctypes.c_int),
        ("solve_time", ctypes.c_double),
        ("setup_time", ctypes.c_double),
    )


@functools.cache
def _library() -> ctypes.CDLL:
    """The loaded ``daqp`` extension (its C symbols are exported); ctypes releases the interpreter lock during a call,
    as ``daqp.solve`` does."""
    lib = ctypes.CDLL(daqp.__file__)
    lib.daqp_quadprog.argtypes = (ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)
    lib.daqp_quadprog.restype = None
    lib.daqp_default_settings.argtypes = (ctypes.c_void_p,)
    lib.daqp_default_settings.restype = None
    return lib


FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intc]


class DirectLp:
    """One LP's buffers bound to DAQP's structures: min costᵀz s.t. ``lower ≤ [z; A z] ≤ upper`` with ``sense``.

    The buffers are the caller's and must outlive this object and keep their memory (bind anew after growing them):
    ``cost`` (n,), ``a`` (rows, n) C-ordered, ``upper``, ``lower`` (n + rows,), ``sense`` (n + rows,) int32. The answer
    is written into :attr:`z`, owned here.
    """

    def __init__(self, cost: FloatArray, a: FloatArray, upper: FloatArray, lower: FloatArray, sense: IntArray) -> None:
        n = cost.shape[0]
        capacity = a.shape[0]
        if a.shape != (capacity, n) or not a.flags.c_contiguous or a.dtype != np.float64:
            raise ValueError(f"DirectLp: A must be C-ordered float64 of {n} columns, got {a.shape} {a.dtype}")
        for name, x, dtype in (("upper", upper, np.float64), ("lower", lower, np.float64), ("sense", sense, np.intc)):
            if x.shape != (n + capacity,) or not x.flags.c_contiguous or x.dtype != dtype:
                raise ValueError(f"DirectLp: {name} must be {n + capacity} contiguous {np.dtype(dtype)}, got {x.shape}")
        if not cost.flags.c_contiguous or cost.dtype != np.float64:
            raise ValueError("DirectLp: cost must be contiguous float64")
        self._buffers = (cost, a, upper, lower, sense)  # kept alive: DAQP reads them through the pointers below
        self._capacity = capacity
        self.z = np.zeros(n)
        self._lam = np.zeros(n + capacity)
        lib = _library()
        self._settings = _Settings()
        lib.daqp_default_settings(ctypes.byref(self._settings))
        self._problem = _Problem(
            n, n, n, None, cost.ctypes.data, a.ctypes.data, upper.ctypes.data, lower.ctypes.data, sense.ctypes.data
        )
        self._result = _Result(self.z.ctypes.data, self._lam.ctypes.data)
        self._call = functools.partial(
            lib.daqp_quadprog,
            ctypes.addressof(self._result),
            ctypes.addressof(self._problem),
            ctypes.addressof(self._settings),
        )

    def solve(self, rows: int) -> int:
        """Solve on the first ``rows`` rows of A (the first n + ``rows`` bounds); the answer in :attr:`z`. Returns
        DAQP's exit flag (1 optimal, 2 soft-optimal, negative: infeasible, unbounded, a failure).

        Raises:
            ValueError: ``rows`` beyond the bound buffers (DAQP would read past them).
        """
        if not 0 <= rows <= self._capacity:
            raise ValueError(f"DirectLp: {rows} rows, the buffers hold {self._capacity}")
        self._problem.m = self._problem.n + rows
        self._call()
        return int(self._result.exitflag)


def _installed_version() -> str:
    try:
        return importlib.metadata.version("daqp")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _same_answers(seed: int = 20161003, problems: int = 40) -> str | None:
    """Seeded LPs of the open mode's shapes solved by :class:`DirectLp` and by ``daqp.solve``: why they differ, or
    None when every exit flag and answer is the same to the bit."""
    rng = np.random.default_rng(seed)
    for k in range(problems):
        n, rows = int(rng.integers(2, 9)), int(rng.integers(0, 80))
        cost = rng.normal(size=n)
        a = np.ascontiguousarray(rng.normal(size=(rows + 5, n)))
        upper = np.concatenate((rng.uniform(0.1, 2.0, n), rng.uniform(-0.5, 2.0, rows + 5)))
        lower = np.concatenate((-rng.uniform(0.1, 2.0, n), np.full(rows + 5, -1e30)))
        sense = np.zeros(n + rows + 5, dtype=np.intc)
        if rows and k % 3 == 0:  # an equality row, as the task rows are
            sense[n] = 5
            lower[n] = upper[n]
        direct = DirectLp(cost, a, upper, lower, sense)
        flag = direct.solve(rows)
        z, _, want_flag, _ = daqp.solve(None, cost, a[:rows], upper[: n + rows], lower[: n + rows], sense[: n + rows])
        if flag != want_flag or (flag in (1, 2) and not np.array_equal(direct.z, z)):
            return f"LP {k} ({n} variables, {rows} rows): exit {flag} against {want_flag}"
    return None


@functools.cache
def direct_lp_or_none() -> str | None:
    """Whether :class:`DirectLp` may be used here: None if so, else why not (the caller keeps ``daqp.solve``)."""
    version = _installed_version()
    if version != DECLARED_VERSION:
        return f"daqp {version} installed, its structures are declared for {DECLARED_VERSION}"
    try:
        settings = _Settings()
        _library().daqp_default_settings(ctypes.byref(settings))
    except (OSError, AttributeError) as exc:  # no library, or no such symbol
        return f"daqp's C entry points not found: {exc}"
    found = {name: getattr(settings, name) for name, _ in _Settings._fields_}
    if found != DEFAULT_SETTINGS:
        return f"daqp's default settings are not where they are declared: {found}"
    return _same_answers()
