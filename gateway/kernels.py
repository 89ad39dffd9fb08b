"""The gateway's per-cycle math, compiled with numba: link kinematics, segment distances, the eq. (15) rows.

Two compiled calls per robot and cycle instead of ~100 numpy calls and ~20 Pinocchio accesses: at 7 links ×
30 capsules the cost of numpy was the calls (1–3 µs each), not the arithmetic.

- :func:`link_kinematics`: forward kinematics of the link-end frames and their world velocities from a
  :class:`gateway.kinematics.KinematicChain` (oMi = oMi[parent] · placement · motion(q); the velocity of a
  point p is Σ_j ω_j × (p − o_j) q̇_j over the revolute joints that move it and a_j q̇_j over the prismatic
  ones, safety-math.md §2).
- :func:`build_rows`: what :func:`gateway.reference.separation.build_rows` (the numpy reference)
  returns — segment distances
  (Ericson 2005, §5.1.9, the steps of :mod:`hrc_devices.robots.segments`), surface distance, clearance Δ (eq. (10)–(12),
  ISO 13855 close-speed switch), f = max(0, d − Δ)², e = (h − r)ᵀ v of the 4 corners and the bounds of
  eq. (15) (safety-math.md §2–§4) — with their minimum and the closest pair.
- :class:`RobotKernels`: both for one robot, as :class:`gateway.core.SafetyCore` calls them. Building it checks
  the compiled kinematics against Pinocchio (:func:`check_chain`) and compiles the kernels, or loads them from
  numba's on-disk cache (``cache=True``), so the first cycle is not slow.

The compiled code specialises on the argument types: the wrappers pass C-contiguous float64 arrays, the types
the kernels are compiled for at start-up. The kernels a tracker frame's capsules go through (the door's numbers, the
tracks' bodies and moves, the capsule columns) are compiled for one type instead, any layout and read only
(:data:`_POINTS`, :class:`_OneType`), and read the frame's views of one (H, 7) array without copying them.
"""

from __future__ import annotations

import functools
import operator
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple, TypeVar, cast

import numba
import numpy as np
import numpy.typing as npt

from gateway.kinematics import PRISMATIC, REVOLUTE, KinematicChain, LinkKinematics, kinematic_chain
from gateway.reference.kinematics import link_kinematics as pinocchio_link_kinematics
from gateway.separation import ConstraintRows
from hrc_contract.config import ConfigError, PlausibilityConfig, SafetyConfig
from hrc_contract.humans import FrameNumbers, HumanCapsules, merge_humans
from hrc_contract.humans import frame_numbers as reference_frame_numbers
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.segments import SegmentDistances

FloatArray = npt.NDArray[np.float64]

_EPS = 1e-12
_PARALLEL_SIN2 = 1e-14
"""As in :mod:`hrc_devices.robots.segments`: degenerate below a squared length of 1e-12 m², parallel below sin²
1e-14."""

CHECK_TOLERANCE = 1e-9
"""Largest difference to Pinocchio of a link-end position [m] or velocity [m/s] for the kinematics to be used."""
CHECK_CONFIGURATIONS = 8
CHECK_SEED = 20160415
CHECK_FRAMES = 32


def _use_writable_cache_dir() -> None:
    """numba caches next to this file (``__pycache__``); where that is read-only (an installed package) and no
    NUMBA_CACHE_DIR is given, cache in the temporary directory rather than fail at import."""
    config: Any = numba.config  # numba has no type hints
    if config.CACHE_DIR:
        return
    here = Path(__file__).parent
    cache = here / "__pycache__"
    if os.access(cache if cache.exists() else here, os.W_OK):
        return
    config.CACHE_DIR = str(Path(tempfile.gettempdir()) / f"hrc-gateway-numba-{os.getuid()}")


_use_writable_cache_dir()

_F = TypeVar("_F", bound=Callable[..., Any])


def compiled_with(*, nogil: bool = False, inline: bool = False) -> Callable[[_F], _F]:
    """``numba.njit(cache=True)``, typed for mypy; ``nogil``: the compiled function runs without the interpreter lock
    (a status thread's text beside the loop); ``inline``: inlined into its callers.

    ``error_model="numpy"``: a division by zero gives inf or nan as in numpy instead of raising, which also
    spares a test per division; no ``fastmath``: IEEE arithmetic, as the numpy reference.
    """

    def decorate(function: _F) -> _F:
        jit = numba.njit(cache=True, error_model="numpy", nogil=nogil, inline="always" if inline else "never")
        return cast(_F, jit(function))

    return decorate


def _compiled(function: _F) -> _F:
    """:func:`compiled_with` its defaults."""
    return compiled_with()(function)


def _inlined(function: _F) -> _F:
    """:func:`_compiled`, inlined into its callers (a called function costs twice the arithmetic of a pair)."""
    return compiled_with(inline=True)(function)


_POINTS = numba.types.Array(numba.types.float64, 2, "A", readonly=True)
"""A frame's capsule end points as the frame kernels take them: any layout, read only. A tracker frame's capsules are
views of one (H, 7) array (``hrc_contract.humans``): a kernel typed for them reads the views where one typed for
C-contiguous arrays needs three copies (~30 µs for 2000 capsules here, more than its arithmetic), and a C-contiguous
or read-only array converts to this type instead of compiling another version in the loop."""
_VALUES = numba.types.Array(numba.types.float64, 1, "A", readonly=True)
"""A frame's radii (the column of the (H, 7) array), or another float64 vector: any layout, read only."""
_INDICES = numba.types.Array(numba.types.int64, 1, "A", readonly=True)
"""Where each person's capsules start (int64), any layout, read only."""


class _OneType:
    """A kernel compiled for one signature, at its first call (from numba's cache; a process that imports the kernels
    without calling this one, the HTTP child, pays nothing), after which it compiles nothing more: a call of another
    layout converts to that signature instead of compiling a version of its own in the loop."""

    def __init__(self, function: Callable[..., Any], signature: Any) -> None:
        self._dispatcher: Any = numba.njit(cache=True, error_model="numpy")(function)
        self._signature = signature
        self._ready = False

    def __call__(self, *args: Any) -> Any:
        if not self._ready:  # compile, then refuse to compile more, before the first call (any thread; idempotent)
            self._dispatcher.compile(self._signature)
            self._dispatcher.disable_compile()
            self._ready = True
        return self._dispatcher(*args)

    @property
    def signatures(self) -> list[Any]:
        return list(self._dispatcher.signatures)


def _for_one_type(signature: Any) -> Callable[[Callable[..., Any]], _OneType]:
    """:class:`_OneType` as a decorator."""
    return functools.partial(_OneType, signature=signature)


_ARRAY_1D = numba.types.float64[::1]
_tuple: Any = numba.types.Tuple  # untyped in numba's stubs
_ARRAY_2D = numba.types.float64[:, ::1]
_FLAGS = numba.types.boolean[::1]


# -- forward kinematics ------------------------------------------------------------------------------


@_compiled
def _link_ends(
    parent: Any,
    kind: Any,
    index_v: Any,
    R_parent_joint: Any,
    p_parent_joint: Any,
    axis_joint: Any,
    frame_joint: Any,
    p_joint_frame: Any,
    link_end_frame: Any,
    q_rad: Any,
    qd_radps: Any,
    ends: Any,
) -> Any:
    """Link end points and velocities into ``ends`` (4, L, 3): p_a, p_b, v_a, v_b (world) [m, m/s]; returns the
    largest speed of a link end [m/s].

    oMi = oMi[parent] · placement · motion(q) (Pinocchio's forward kinematics; joint 0 carries the base pose).
    The outputs are allocated by the caller: an array handed back to Python costs more than the kinematics.
    """
    n_joints = parent.shape[0]
    R = np.empty((n_joints, 3, 3))  # joint frame → world
    o = np.empty((n_joints, 3))  # joint origin, world [m]
    w = np.zeros((n_joints, 3))  # joint axis, world
    R[0] = R_parent_joint[0]
    o[0] = p_parent_joint[0]
    M = np.empty((3, 3))  # placement · motion, in the parent joint's frame
    m = np.empty(3)
    for j in range(1, n_joints):
        i = parent[j]
        x, y, z = axis_joint[j, 0], axis_joint[j, 1], axis_joint[j, 2]
        angle_or_shift = q_rad[index_v[j]]
        for r in range(3):
            m[r] = p_parent_joint[j, r]
        if kind[j] == REVOLUTE:
            # Rodrigues: cos θ I + sin θ [a]× + (1 − cos θ) a aᵀ
            c, s = np.cos(angle_or_shift), np.sin(angle_or_shift)
            k = 1.0 - c
            rot = (
                (c + k * x * x, k * x * y - s * z, k * x * z + s * y),
                (k * y * x + s * z, c + k * y * y, k * y * z - s * x),
                (k * z * x - s * y, k * z * y + s * x, c + k * z * z),
            )
            for r in range(3):
                for col in range(3):
                    M[r, col] = (
                        R_parent_joint[j, r, 0] * rot[0][col]
                        + R_parent_joint[j, r, 1] * rot[1][col]
                        + R_parent_joint[j, r, 2] * rot[2][col]
                    )
        else:
            for r in range(3):
                for col in range(3):
                    M[r, col] = R_parent_joint[j, r, col]
            if kind[j] == PRISMATIC:
                for r in range(3):
                    m[r] += angle_or_shift * (
                        R_parent_joint[j, r, 0] * x + R_parent_joint[j, r, 1] * y + R_parent_joint[j, r, 2] * z
                    )
        for r in range(3):
            o[j, r] = R[i, r, 0] * m[0] + R[i, r, 1] * m[1] + R[i, r, 2] * m[2] + o[i, r]
            for col in range(3):
                R[j, r, col] = R[i, r, 0] * M[0, col] + R[i, r, 1] * M[1, col] + R[i, r, 2] * M[2, col]
        for r in range(3):
            w[j, r] = R[j, r, 0] * x + R[j, r, 1] * y + R[j, r, 2] * z

    n_frames = frame_joint.shape[0]
    p_frame = np.empty((n_frames, 3))
    v_frame = np.zeros((n_frames, 3))
    for f in range(n_frames):
        j = frame_joint[f]
        for r in range(3):
            p_frame[f, r] = (
                R[j, r, 0] * p_joint_frame[f, 0] + R[j, r, 1] * p_joint_frame[f, 1] + R[j, r, 2] * p_joint_frame[f, 2]
            ) + o[j, r]
        while j > 0:  # every joint that moves the frame: its ancestors
            rate = qd_radps[index_v[j]]
            if kind[j] == REVOLUTE:
                dx = p_frame[f, 0] - o[j, 0]
                dy = p_frame[f, 1] - o[j, 1]
                dz = p_frame[f, 2] - o[j, 2]
                v_frame[f, 0] += (w[j, 1] * dz - w[j, 2] * dy) * rate
                v_frame[f, 1] += (w[j, 2] * dx - w[j, 0] * dz) * rate
                v_frame[f, 2] += (w[j, 0] * dy - w[j, 1] * dx) * rate
            elif kind[j] == PRISMATIC:
                for r in range(3):
                    v_frame[f, r] += w[j, r] * rate
            j = parent[j]

    n_links = link_end_frame.shape[0]
    speed2 = 0.0
    for link in range(n_links):
        for end in range(2):
            f = link_end_frame[link, end]
            norm2 = 0.0
            for r in range(3):
                ends[end, link, r] = p_frame[f, r]
                ends[2 + end, link, r] = v_frame[f, r]
                norm2 += v_frame[f, r] * v_frame[f, r]
            speed2 = max(speed2, norm2)
    return np.sqrt(speed2)


def link_kinematics(chain: KinematicChain, q_rad: FloatArray, qd_radps: FloatArray) -> tuple[LinkKinematics, float]:
    """Link end points and their velocities J q̇ for ``q_rad``, ``qd_radps``, world frame (safety-math.md §2).

    Returns:
        The link kinematics [m, m/s] and the largest speed of a link end point [m/s].
    """
    ends = np.empty((4, len(chain.link_end_frame), 3))
    speed_mps = _link_ends(*chain, np.ascontiguousarray(q_rad, float), np.ascontiguousarray(qd_radps, float), ends)
    return LinkKinematics(ends[0], ends[1], ends[2], ends[3]), float(speed_mps)


# -- segment distances and the rows of eq. (15) --------------------------------------------------------


@_inlined
def _clip01(x: float) -> float:
    return min(max(x, 0.0), 1.0)


@_inlined
def _segment_pair(
    d1x: float,
    d1y: float,
    d1z: float,
    a: float,
    d2x: float,
    d2y: float,
    d2z: float,
    e: float,
    rx: float,
    ry: float,
    rz: float,
) -> Any:
    """Distance [m] and closest-point abscissas (s, t) of a link segment and a capsule segment.

    Args: the link's direction d1 = p_b − p_a and a = ‖d1‖², the capsule's d2 = h_b − h_a and e = ‖d2‖²,
    and r = p_a − h_a. The same steps as :func:`hrc_devices.robots.segments.segment_distances`, for one pair: the
    unclamped s (0 for parallel segments), then t clamped, then s from that t clamped; a point segment
    projects the other's point. Without branches (selects only), so that the loop over capsules vectorises.
    """
    b = d1x * d2x + d1y * d2y + d1z * d2z
    c = d1x * rx + d1y * ry + d1z * rz
    f = d2x * rx + d2y * ry + d2z * rz
    link_ok = a > _EPS
    capsule_ok = e > _EPS
    a = a if link_ok else 1.0
    e = e if capsule_ok else 1.0
    ae = a * e
    denom = ae - b * b
    s = (b * f - c * e) / (denom if denom > _PARALLEL_SIN2 * ae else np.inf)  # parallel: s = 0
    t = _clip01((b * _clip01(s) + f) / e)
    t = t if capsule_ok else 0.0
    s = _clip01((b * t - c) / a)
    point_link_t = _clip01(f / e)
    t = t if link_ok else (point_link_t if capsule_ok else 0.0)
    s = s if link_ok else 0.0
    gx = s * d1x + rx - t * d2x
    gy = s * d1y + ry - t * d2y
    gz = s * d1z + rz - t * d2z
    return np.sqrt(gx * gx + gy * gy + gz * gz), s, t


@_compiled
def _columns(p_a: Any, p_b: Any) -> Any:
    """Segments as columns, shape (11, N): a (x, y, z), b (x, y, z), d = b − a (x, y, z), ‖d‖², and a row for
    the radii (left unset)."""
    n = p_a.shape[0]
    columns = np.empty((11, n))
    for k in range(n):
        for r in range(3):
            columns[r, k] = p_a[k, r]
            columns[3 + r, k] = p_b[k, r]
            columns[6 + r, k] = p_b[k, r] - p_a[k, r]
        columns[9, k] = columns[6, k] * columns[6, k] + columns[7, k] * columns[7, k] + columns[8, k] * columns[8, k]
    return columns


@_compiled
def _segment_distances(p_a: Any, p_b: Any, h_a: Any, h_b: Any) -> Any:
    n_links, n_capsules = p_a.shape[0], h_a.shape[0]
    distance = np.empty((n_links, n_capsules))
    s_link = np.empty((n_links, n_capsules))
    t_capsule = np.empty((n_links, n_capsules))
    link = _columns(p_a, p_b)
    capsule = _columns(h_a, h_b)
    for i in range(n_links):
        for j in range(n_capsules):
            distance[i, j], s_link[i, j], t_capsule[i, j] = _segment_pair(
                link[6, i], link[7, i], link[8, i], link[9, i],
                capsule[6, j], capsule[7, j], capsule[8, j], capsule[9, j],
                link[0, i] - capsule[0, j], link[1, i] - capsule[1, j], link[2, i] - capsule[2, j],
            )  # fmt: skip
    return distance, s_link, t_capsule


def segment_distances(p_a: FloatArray, p_b: FloatArray, h_a: FloatArray, h_b: FloatArray) -> SegmentDistances:
    """Compiled :func:`hrc_devices.robots.segments.segment_distances`:

    L links ``[p_a, p_b]`` (L, 3) × H capsules (H, 3)."""
    distance, s, t = _segment_distances(*(np.ascontiguousarray(x, float) for x in (p_a, p_b, h_a, h_b)))
    return SegmentDistances(distance, s, t)


def _kernel_array(x: FloatArray) -> FloatArray:
    """``x`` as a C-contiguous, writable float64 array: the argument type the kernels are compiled for (another
    type would compile them anew, in the loop). ``np.require`` does the same at five times the cost."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return x if x.flags.writeable else x.copy()


@_for_one_type(_ARRAY_2D(_POINTS, _POINTS))
def _capsule_columns(h_a: Any, h_b: Any) -> Any:
    """:func:`_columns` of a frame's capsules, read where they are (:data:`_POINTS`)."""
    return _columns(h_a, h_b)


def _float64(x: FloatArray) -> FloatArray:
    """``x`` as a kernel typed with :data:`_POINTS` or :data:`_VALUES` takes it: itself if float64 (any layout, read
    only or not: no copy), else converted."""
    return x if x.dtype == np.float64 else np.asarray(x, dtype=np.float64)


def capsule_columns(humans: HumanCapsules) -> FloatArray:
    """The capsules as the compiled rows take them, shape (11, H): h_a, h_b, h_b − h_a (x, y, z each),
    ‖h_b − h_a‖² and the radius [m]. Computed once per tracker frame, not once per robot and cycle."""
    columns: FloatArray = _capsule_columns(_float64(humans.h_a_world), _float64(humans.h_b_world))
    columns[10] = humans.radius_m
    return columns


@_inlined
def _bound(f: float, lhs: float) -> float:
    """The largest δ a row allows: f / lhs, inf where the row bounds nothing (lhs ≤ 0)."""
    return f / lhs if lhs > 0.0 else np.inf


@_compiled
def _rows(
    p_a: Any,
    p_b: Any,
    v_a: Any,
    v_b: Any,
    h: Any,
    link_radius_m: Any,
    t_brake_link_s: Any,
    t_brake_max_s: float,
    t_delay_s: float,
    clearance_static_m: float,
    human_speed_mps: float,
    human_speed_close_mps: float,
    close_speed_below_m: float,
    pair: Any,
    corner: Any,
    horizon: Any,
) -> Any:
    """The arrays of :class:`gateway.separation.ConstraintRows` into the caller's ``pair``, ``corner`` and ``horizon``;
    returns the smallest bound (inf if none), the first (i, j) of smallest d and that d ((-1, -1, inf) if none).

    The capsules ``h`` are the columns of :func:`capsule_columns`: contiguous over capsules, so the loops over
    them vectorise. The outputs: pair (3, L, H): surface distance d [m], clearance Δ [m], f [m²]; corner
    (2, L, H, 2, 2): e [m²/s] and the bound; horizon (L,) [s]. Packed and allocated by the caller because an
    array handed back to Python costs more than the arithmetic of 30 pairs.
    """
    n_links, n_capsules = p_a.shape[0], h.shape[1]
    travel_s = t_brake_max_s + t_delay_s
    clearance_far = clearance_static_m + human_speed_mps * travel_s
    clearance_close = clearance_static_m + human_speed_close_mps * travel_s
    link = _columns(p_a, p_b)
    # corner[0] and corner[1] as (L, 4 H): [link end, capsule end] of capsule j at 4 j + 2 link end + capsule end
    e_flat = corner[0].reshape(n_links, 4 * n_capsules)
    bound_flat = corner[1].reshape(n_links, 4 * n_capsules)
    for i in range(n_links):
        horizon_s = t_brake_link_s[i] + t_delay_s
        horizon[i] = horizon_s
        pax, pay, paz, pbx, pby, pbz = link[0, i], link[1, i], link[2, i], link[3, i], link[4, i], link[5, i]
        vax, vay, vaz, vbx, vby, vbz = v_a[i, 0], v_a[i, 1], v_a[i, 2], v_b[i, 0], v_b[i, 1], v_b[i, 2]
        d1x, d1y, d1z, a, radius_m = link[6, i], link[7, i], link[8, i], link[9, i], link_radius_m[i]
        surface, clearance, f_m2 = pair[0, i], pair[1, i], pair[2, i]
        e, bound = e_flat[i], bound_flat[i]
        for j in range(n_capsules):
            distance, _, _ = _segment_pair(
                d1x, d1y, d1z, a, h[6, j], h[7, j], h[8, j], h[9, j], pax - h[0, j], pay - h[1, j], paz - h[2, j]
            )
            d = max(0.0, distance - radius_m - h[10, j])
            margin = clearance_close if d < close_speed_below_m else clearance_far
            gap = max(0.0, d - margin)
            surface[j] = d
            clearance[j] = margin
            f_m2[j] = gap * gap
        # e = (h − r)ᵀ v for r ∈ {p_a, p_b} (with its v) and h ∈ {h_a, h_b}
        for j in range(n_capsules):
            f = f_m2[j]
            e_aa = (h[0, j] - pax) * vax + (h[1, j] - pay) * vay + (h[2, j] - paz) * vaz
            e_ab = (h[3, j] - pax) * vax + (h[4, j] - pay) * vay + (h[5, j] - paz) * vaz
            e_ba = (h[0, j] - pbx) * vbx + (h[1, j] - pby) * vby + (h[2, j] - pbz) * vbz
            e_bb = (h[3, j] - pbx) * vbx + (h[4, j] - pby) * vby + (h[5, j] - pbz) * vbz
            e[4 * j] = e_aa
            e[4 * j + 1] = e_ab
            e[4 * j + 2] = e_ba
            e[4 * j + 3] = e_bb
            bound[4 * j] = _bound(f, horizon_s * e_aa)
            bound[4 * j + 1] = _bound(f, horizon_s * e_ab)
            bound[4 * j + 2] = _bound(f, horizon_s * e_ba)
            bound[4 * j + 3] = _bound(f, horizon_s * e_bb)
    closest_i, closest_j, closest_m = _first_closest(pair[0])
    return _lowest(bound_flat), closest_i, closest_j, closest_m


@_inlined
def _first_closest(surface_m: Any) -> Any:
    """(i, j, d) of the first smallest surface distance, or of the first nan (as numpy's argmin); (-1, -1, inf)
    when there is none. Nested loops: a division per pair to split a flat index costs more than the scan."""
    closest_i, closest_j, closest_m = -1, -1, np.inf
    for i in range(surface_m.shape[0]):
        for j in range(surface_m.shape[1]):
            d = surface_m[i, j]
            if d < closest_m or d != d:
                closest_i, closest_j, closest_m = i, j, d
                if d != d:
                    return closest_i, closest_j, closest_m
    return closest_i, closest_j, closest_m


@_inlined
def _lowest(bound: Any) -> float:
    """The smallest of the bounds (L, N), inf when there is none; a nan propagates, as in numpy's min."""
    lowest = np.inf
    for i in range(bound.shape[0]):
        for value in bound[i]:
            if value < lowest or value != value:
                lowest = value
    return lowest


@_inlined
def _all_finite(q_rad: Any, qd_radps: Any, h: Any, t_delay_s: float) -> bool:
    """Whether every input of a cycle is a finite number: x − x is 0 for a finite x and nan for a nan or an
    infinity (IEEE arithmetic: no ``fastmath``, so the compiler may not fold it to 0)."""
    check = t_delay_s - t_delay_s
    for k in range(q_rad.shape[0]):
        check += q_rad[k] - q_rad[k]
    for k in range(qd_radps.shape[0]):
        check += qd_radps[k] - qd_radps[k]
    for r in range(h.shape[0]):
        for j in range(h.shape[1]):
            check += h[r, j] - h[r, j]
    return check == 0.0


@_compiled
def _cycle(
    parent: Any,
    kind: Any,
    index_v: Any,
    R_parent_joint: Any,
    p_parent_joint: Any,
    axis_joint: Any,
    frame_joint: Any,
    p_joint_frame: Any,
    link_end_frame: Any,
    link_radius_m: Any,
    t_brake_link_s: Any,
    t_brake_max_s: float,
    clearance_static_m: float,
    human_speed_mps: float,
    human_speed_close_mps: float,
    close_speed_below_m: float,
    q_rad: Any,
    qd_radps: Any,
    h: Any,
    t_delay_s: float,
    ends: Any,
    pair: Any,
    corner: Any,
    horizon: Any,
) -> Any:
    """:func:`_link_ends` then :func:`_rows` of its link ends: one call from Python per robot and cycle.

    Returns the largest link-end speed [m/s], the smallest bound, the closest pair (i, j, d) and whether every
    input (q, q̇, the capsule columns, t_delay) is a finite number."""
    speed_mps = _link_ends(
        parent,
        kind,
        index_v,
        R_parent_joint,
        p_parent_joint,
        axis_joint,
        frame_joint,
        p_joint_frame,
        link_end_frame,
        q_rad,
        qd_radps,
        ends,
    )
    lowest, closest_i, closest_j, closest_m = _rows(
        ends[0],
        ends[1],
        ends[2],
        ends[3],
        h,
        link_radius_m,
        t_brake_link_s,
        t_brake_max_s,
        t_delay_s,
        clearance_static_m,
        human_speed_mps,
        human_speed_close_mps,
        close_speed_below_m,
        pair,
        corner,
        horizon,
    )
    return speed_mps, lowest, closest_i, closest_j, closest_m, _all_finite(q_rad, qd_radps, h, t_delay_s)


class Closest(NamedTuple):
    """The first (link, capsule) pair of smallest surface distance; (-1, -1, inf) with no capsule."""

    link: int
    capsule: int
    distance_m: float


class KernelCycle(NamedTuple):
    """What :meth:`RobotKernels.cycle` computed for one robot in one cycle.

    Attributes:
        links: link end points and their velocities at the programmed speed [m, m/s].
        speed_mps: the largest link-end speed [m/s].
        rows: the rows of eq. (15).
        closest: the pair of smallest surface distance, with that distance [m].
        inputs_finite: every input (q, q̇, capsules, t_delay) is a finite number; when not, the outputs mean
            nothing and the caller fails closed (:class:`gateway.core.SafetyCore` commands δ = 0).
    """

    links: LinkKinematics
    speed_mps: float
    rows: ConstraintRows
    closest: Closest
    inputs_finite: bool


def _row_outputs(n_links: int, n_capsules: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Fresh output arrays of :func:`_rows`: pair (3, L, H), corner (2, L, H, 2, 2), horizon (L,)."""
    return np.empty((3, n_links, n_capsules)), np.empty((2, n_links, n_capsules, 2, 2)), np.empty(n_links)


def _row_views(
    pair: FloatArray, corner: FloatArray, horizon: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The arrays of :class:`gateway.separation.ConstraintRows` (all but ``min_bound``) in the packed outputs."""
    return pair[0], pair[1], pair[2], corner[0], horizon, corner[1]


def _rows_from_packed(pair: FloatArray, corner: FloatArray, horizon: FloatArray, lowest: float) -> ConstraintRows:
    return ConstraintRows(*_row_views(pair, corner, horizon), float(lowest))


def build_rows(
    links: LinkKinematics,
    link_radius_m: FloatArray,
    t_brake_link_s: FloatArray,
    t_brake_max_s: float,
    humans: HumanCapsules,
    safety: SafetyConfig,
    t_delay_s: float,
) -> ConstraintRows:
    """Compiled :func:`gateway.reference.separation.build_rows` (same arguments, same rows; safety-math.md §2–§4)."""
    p_a, p_b, v_a, v_b = (np.ascontiguousarray(x, float) for x in links)
    capsules = capsule_columns(humans)
    pair, corner, horizon = _row_outputs(len(p_a), capsules.shape[1])
    lowest, _, _, _ = _rows(
        p_a,
        p_b,
        v_a,
        v_b,
        capsules,
        np.ascontiguousarray(link_radius_m, float),
        np.ascontiguousarray(t_brake_link_s, float),
        float(t_brake_max_s),
        float(t_delay_s),
        *_clearance_parameters(safety),
        pair,
        corner,
        horizon,
    )
    return _rows_from_packed(pair, corner, horizon, lowest)


def _clearance_parameters(safety: SafetyConfig) -> tuple[float, float, float, float]:
    """c, K, K close and the separation below which K close applies (eq. (11)–(12), ISO 13855)."""
    return (
        float(safety.clearance_static_m),
        float(safety.human_speed_mps),
        float(safety.human_speed_close_mps),
        float(safety.close_speed_below_m),
    )


# -- one robot: checked against Pinocchio and compiled at start-up, one call per cycle -----------------


# -- bodies: one set of human capsules inside another ------------------------------------------------------------


@_inlined
def _point_segment_m(px: float, py: float, pz: float, a: Any, d: Any, dd: float) -> float:
    """Distance of point p to the segment from ``a`` along ``d`` (``dd`` = ‖d‖², 1 for a point) [m]: the steps of
    :func:`gateway.bodies._point_segment_distance_m`."""
    rx, ry, rz = px - a[0], py - a[1], pz - a[2]
    t = _clip01((rx * d[0] + ry * d[1] + rz * d[2]) / dd)
    ox, oy, oz = rx - t * d[0], ry - t * d[1], rz - t * d[2]
    return float(np.sqrt(ox * ox + oy * oy + oz * oz))


@_compiled
def _within(s_a: Any, s_b: Any, s_r: Any, b_a: Any, b_b: Any, b_r: Any, grow_m: float) -> bool:
    n, m = s_a.shape[0], b_a.shape[0]
    if n == 0:
        return False
    d = b_b - b_a
    dd = np.empty(m)
    for j in range(m):
        norm2 = d[j, 0] * d[j, 0] + d[j, 1] * d[j, 1] + d[j, 2] * d[j, 2]
        dd[j] = norm2 if norm2 > 0.0 else 1.0
    for i in range(n):
        found = False
        for j in range(m):
            limit = b_r[j] + grow_m - s_r[i]
            if _point_segment_m(s_a[i, 0], s_a[i, 1], s_a[i, 2], b_a[j], d[j], dd[j]) > limit:
                continue
            if _point_segment_m(s_b[i, 0], s_b[i, 1], s_b[i, 2], b_a[j], d[j], dd[j]) <= limit:
                found = True
                break
        if not found:
            return False
    return True


@_compiled
def _near(x_a: Any, x_b: Any, x_r: Any, y_a: Any, y_b: Any, y_r: Any, grow_m: float) -> bool:
    return _within(x_a, x_b, x_r, y_a, y_b, y_r, grow_m) or _within(y_a, y_b, y_r, x_a, x_b, x_r, grow_m)


def capsules_near(x: HumanCapsules, y: HumanCapsules, grow_m: float) -> bool:
    """One of ``x`` and ``y`` lies inside the other grown by ``grow_m`` [m]: :func:`capsules_within` both ways in one
    compiled call."""
    if x.n_capsules == 0 or y.n_capsules == 0 or not np.isfinite(grow_m):
        return False
    return bool(
        _near(
            _kernel_array(x.h_a_world),
            _kernel_array(x.h_b_world),
            _kernel_array(x.radius_m),
            _kernel_array(y.h_a_world),
            _kernel_array(y.h_b_world),
            _kernel_array(y.radius_m),
            float(grow_m),
        )
    )


def capsules_within(small: HumanCapsules, big: HumanCapsules, grow_m: float) -> bool:
    """Every capsule of ``small`` lies inside some capsule of ``big`` grown by ``grow_m`` [m]: the compiled
    :func:`gateway.bodies.within_reference` (stops at the first capsule that fits nowhere; ~1 µs for two bodies of
    15 capsules against ~50 µs in numpy, and the tracks ask it for every pair of people whose boxes may nest)."""
    if small.n_capsules == 0 or big.n_capsules == 0 or not np.isfinite(grow_m):
        return False
    return bool(
        _within(
            _kernel_array(small.h_a_world),
            _kernel_array(small.h_b_world),
            _kernel_array(small.radius_m),
            _kernel_array(big.h_a_world),
            _kernel_array(big.h_b_world),
            _kernel_array(big.radius_m),
            float(grow_m),
        )
    )


@_for_one_type(numba.types.void(_POINTS, _POINTS, _VALUES, _INDICES, _INDICES, _INDICES, _INDICES, _VALUES, _FLAGS))
def _slices_near(
    h_a: Any, h_b: Any, radius: Any, starts: Any, ends: Any, first: Any, second: Any, grow_m: Any, out: Any
) -> None:
    for p in range(first.shape[0]):
        i, k = first[p], second[p]
        si, ei, sk, ek = starts[i], ends[i], starts[k], ends[k]
        g = grow_m[p]
        out[p] = (ei > si and ek > sk and np.isfinite(g)) and _near(
            h_a[si:ei], h_b[si:ei], radius[si:ei], h_a[sk:ek], h_b[sk:ek], radius[sk:ek], g
        )


def slices_near(
    capsules: HumanCapsules,
    starts: npt.NDArray[np.int64],
    ends: npt.NDArray[np.int64],
    first: npt.NDArray[np.intp],
    second: npt.NDArray[np.intp],
    grow_m: FloatArray,
) -> npt.NDArray[np.bool_]:
    """Per pair p: :func:`capsules_near` of the bodies ``capsules[starts[first[p]]:ends[first[p]]]`` and
    ``capsules[starts[second[p]]:ends[second[p]]]`` grown by ``grow_m[p]`` [m], all pairs in one compiled call that
    reads the capsules where they are (any layout: a tracker frame's views; the tracks ask it for every pair of
    people whose boxes may nest in a frame, their bodies slices of one or two frames).

    Raises:
        ValueError: a pair's body outside ``starts``/``ends``, a body's slice outside ``capsules``, or ``first``,
            ``second`` and ``grow_m`` (``starts`` and ``ends``) of different lengths.
    """
    out = np.zeros(len(first), dtype=np.bool_)
    if not len(first):
        return out
    if len(second) != len(first) or len(grow_m) != len(first) or len(ends) != len(starts):
        raise ValueError(
            f"slices_near: {len(first)} first, {len(second)} second, {len(grow_m)} grow (one per pair); "
            f"{len(starts)} starts, {len(ends)} ends (one per body)"
        )
    if min(first.min(), second.min()) < 0 or max(first.max(), second.max()) >= len(starts):
        raise ValueError(f"slices_near: a pair's body out of range (of {len(starts)})")  # read unchecked when compiled
    if len(starts) and (starts.min() < 0 or ends.max() > capsules.n_capsules or (ends < starts).any()):
        raise ValueError(f"slices_near: a body's capsules outside the {capsules.n_capsules} given")
    _slices_near(
        _float64(capsules.h_a_world),
        _float64(capsules.h_b_world),
        _float64(capsules.radius_m),
        np.asarray(starts, dtype=np.int64),
        np.asarray(ends, dtype=np.int64),
        np.asarray(first, dtype=np.int64),
        np.asarray(second, dtype=np.int64),
        _float64(grow_m),
        out,
    )
    return out


def bodies_near(
    bodies: Sequence[HumanCapsules], first: npt.NDArray[np.intp], second: npt.NDArray[np.intp], grow_m: FloatArray
) -> npt.NDArray[np.bool_]:
    """Per pair p: :func:`capsules_near` of ``bodies[first[p]]`` and ``bodies[second[p]]`` grown by ``grow_m[p]``
    [m], all pairs in one compiled call (:func:`slices_near` of the bodies joined).

    Raises:
        ValueError: a pair's index outside ``bodies``, or ``first``, ``second`` and ``grow_m`` of different lengths.
    """
    if not len(first):
        return np.zeros(0, dtype=np.bool_)
    counts = np.fromiter((b.n_capsules for b in bodies), np.int64, len(bodies))
    starts = np.zeros(len(bodies) + 1, dtype=np.int64)
    np.cumsum(counts, out=starts[1:])
    return slices_near(merge_humans(list(bodies)), starts[:-1], starts[1:], first, second, grow_m)


# -- the door: a tracker frame's numbers for the plausibility rules (hrc_contract.humans) --------------------------


@_for_one_type(
    _tuple((numba.types.boolean, numba.types.float64, numba.types.float64, _ARRAY_1D))(
        _POINTS, _POINTS, _VALUES, _INDICES, _VALUES, _VALUES
    )
)
def _frame_numbers(h_a: Any, h_b: Any, radius: Any, starts: Any, low: Any, high: Any) -> Any:
    n_people = starts.shape[0] - 1
    inside = True
    longest_sq = 0.0
    r_max = radius[0]
    extent = np.empty(n_people)
    for p in range(n_people):
        first, end = starts[p], starts[p + 1]
        r = radius[first]
        lo = np.empty(3)
        hi = np.empty(3)
        for axis in range(3):
            lo[axis] = min(h_a[first, axis], h_b[first, axis])
            hi[axis] = max(h_a[first, axis], h_b[first, axis])
        for i in range(first, end):
            r = max(r, radius[i])
            dx, dy, dz = h_b[i, 0] - h_a[i, 0], h_b[i, 1] - h_a[i, 1], h_b[i, 2] - h_a[i, 2]
            longest_sq = max(longest_sq, dx * dx + dy * dy + dz * dz)
            for axis in range(3):
                a, b = h_a[i, axis], h_b[i, axis]
                if not (a >= low[axis] and a <= high[axis] and b >= low[axis] and b <= high[axis]):
                    inside = False
                lo[axis] = min(lo[axis], min(a, b))
                hi[axis] = max(hi[axis], max(a, b))
        r_max = max(r_max, r)
        sx, sy, sz = hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]
        extent[p] = np.sqrt(sx * sx + sy * sy + sz * sz) + 2.0 * r
    return inside, longest_sq, r_max, extent


def frame_numbers(capsules: HumanCapsules, starts: Sequence[int], plausibility: PlausibilityConfig) -> FrameNumbers:
    """:func:`hrc_contract.humans.frame_numbers` in one compiled pass over the capsules (the door's numbers for a
    frame of 2000 capsules: ~0.2 ms of numpy calls, each holding the interpreter lock the safety loop needs). Its
    capsules finite, as the door admits them: held to the reference at start-up (:func:`check_frame_numbers`).

    Raises:
        ValueError: no capsule, or ``starts`` that do not run from the first capsule to the last (the compiled pass
            reads by them unchecked).
    """
    n = capsules.n_capsules
    if n == 0 or len(starts) < 2 or starts[0] != 0 or starts[-1] != n or not all(map(operator.lt, starts, starts[1:])):
        raise ValueError(f"frame_numbers: {n} capsules and starts {list(starts)[:8]}…; a person has a capsule")
    inside, longest_sq, r_max, extent = _frame_numbers(
        _float64(capsules.h_a_world),
        _float64(capsules.h_b_world),
        _float64(capsules.radius_m),
        np.array(starts, dtype=np.int64),
        np.array(plausibility.world_min_m, dtype=np.float64),
        np.array(plausibility.world_max_m, dtype=np.float64),
    )
    return FrameNumbers(bool(inside), float(longest_sq), float(r_max), extent)


@functools.cache  # once per process: the compiled code does not change in it
def check_frame_numbers(seed: int = CHECK_SEED) -> None:
    """Hold :func:`frame_numbers` to :func:`hrc_contract.humans.frame_numbers` on seeded random frames, bit for bit
    (and compile it, or load it from numba's cache, before the first frame).

    Raises:
        ConfigError: the two differ on a frame.
    """
    rng = np.random.default_rng(seed)
    plausibility = PlausibilityConfig(world_min_m=(-3.0, -3.0, -1.0), world_max_m=(3.0, 3.0, 2.5))
    for k in range(CHECK_FRAMES):
        sizes = rng.integers(1, 16, int(rng.integers(1, 12)))
        n = int(sizes.sum())
        a = rng.uniform(-3.2, 3.2, (n, 3)) * (1.0, 1.0, 0.6)
        rows = np.concatenate((a, a + rng.uniform(-0.5, 0.5, (n, 3)), rng.uniform(0.0, 0.3, (n, 1))), axis=1)
        ids = tuple(f"h{p}" for p, size in enumerate(sizes) for _ in range(size))
        capsules = HumanCapsules(rows[:, 0:3], rows[:, 3:6], rows[:, 6], ids, ("p",) * n)
        starts = [0, *np.cumsum(sizes).tolist()]
        got = frame_numbers(capsules, starts, plausibility)
        want = reference_frame_numbers(capsules, starts, plausibility)
        if got[:3] != want[:3] or not np.array_equal(got.extent_m, want.extent_m):
            raise ConfigError(f"the compiled frame numbers differ from their numpy reference on seeded frame {k}")


# -- the tracks' frame path (gateway/tracks.py): one compiled call where numpy took a dozen --------------


@_for_one_type(_tuple((_ARRAY_2D, _ARRAY_2D, _ARRAY_2D, _ARRAY_1D))(_POINTS, _POINTS, _VALUES, _INDICES))
def _frame_bodies(h_a: Any, h_b: Any, radius: Any, starts: Any) -> Any:
    n_people = starts.shape[0] - 1
    centres = np.empty((n_people, 3))
    low = np.empty((n_people, 3))
    high = np.empty((n_people, 3))
    r_max = np.empty(n_people)
    for p in range(n_people):
        first, end = starts[p], starts[p + 1]
        r = radius[first]
        for i in range(first + 1, end):
            r = max(r, radius[i])
        r_max[p] = r
        for axis in range(3):
            total = 0.0
            lo = min(h_a[first, axis], h_b[first, axis])
            hi = max(h_a[first, axis], h_b[first, axis])
            for i in range(first, end):
                a, b = h_a[i, axis], h_b[i, axis]
                total += a + b
                lo = min(lo, min(a, b))
                hi = max(hi, max(a, b))
            centres[p, axis] = total / (2.0 * (end - first))
            low[p, axis] = lo
            high[p, axis] = hi
    return centres, low, high, r_max


def frame_bodies(
    capsules: HumanCapsules, starts: npt.NDArray[np.int64]
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per person of a frame (``starts``: :func:`hrc_contract.humans.human_starts`, int64; every person has a capsule,
    the capsules finite as the door admits them): the mean of their capsules' end points [m], the box around those
    end points (lower, upper corner [m]) and their largest radius [m]. The compiled
    :func:`gateway.tracks.frame_bodies_reference`."""
    if starts.shape[0] < 2:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    return _frame_bodies(  # type: ignore[no-any-return]
        _float64(capsules.h_a_world), _float64(capsules.h_b_world), _float64(capsules.radius_m), starts
    )


@_for_one_type(_FLAGS(_POINTS, _POINTS, _VALUES, _POINTS, _POINTS, _VALUES, _INDICES, numba.types.float64))
def _moved_within(b_a: Any, b_b: Any, b_r: Any, a_a: Any, a_b: Any, a_r: Any, starts: Any, reach_m: float) -> Any:
    n_people = starts.shape[0] - 1
    out = np.empty(n_people, dtype=np.bool_)
    for p in range(n_people):
        ok = True
        for i in range(starts[p], starts[p + 1]):
            limit = reach_m - max(a_r[i] - b_r[i], 0.0)
            ax, ay, az = a_a[i, 0] - b_a[i, 0], a_a[i, 1] - b_a[i, 1], a_a[i, 2] - b_a[i, 2]
            bx, by, bz = a_b[i, 0] - b_b[i, 0], a_b[i, 1] - b_b[i, 1], a_b[i, 2] - b_b[i, 2]
            limit2 = limit * limit
            if not (limit >= 0.0 and ax * ax + ay * ay + az * az <= limit2 and bx * bx + by * by + bz * bz <= limit2):
                ok = False
                break
        out[p] = ok
    return out


def moved_within(
    before: HumanCapsules, after: HumanCapsules, starts: npt.NDArray[np.int64], reach_m: float
) -> npt.NDArray[np.bool_]:
    """Per person (``starts`` as :func:`frame_bodies`) of two frames listing the same capsules in the same order:
    whether every end point moved at most ``reach_m`` minus the growth of its radius [m] (False where that is
    negative or not a number). The compiled :func:`gateway.tracks.moved_within_reference`."""
    if starts.shape[0] < 2:
        return np.zeros(0, dtype=bool)
    return _moved_within(  # type: ignore[no-any-return]
        _float64(before.h_a_world),
        _float64(before.h_b_world),
        _float64(before.radius_m),
        _float64(after.h_a_world),
        _float64(after.h_b_world),
        _float64(after.radius_m),
        starts,
        float(reach_m),
    )


@_compiled
def _others_maybe_near(
    lo: Any,
    hi: Any,
    r_max: Any,
    stamp_ns: Any,
    noise_m: Any,
    person: Any,
    rows_lo: Any,
    rows_hi: Any,
    rows_r: Any,
    rows_stamp_ns: Any,
    rows_noise_m: Any,
    rows_person: Any,
    rows_seen: Any,
    reach_speed_mps: float,
    margin_m: float,
) -> Any:
    n, m = lo.shape[0], rows_r.shape[0]
    out = np.zeros((n, m), dtype=np.bool_)
    for i in range(n):
        for k in range(m):
            if not rows_seen[k] or rows_person[k] == person[i]:
                continue
            grow = reach_speed_mps * abs(rows_stamp_ns[k] - stamp_ns[i]) / 1e9 + margin_m + noise_m[i] + rows_noise_m[k]
            below, above = lo[i, 0] - rows_lo[k, 0], rows_hi[k, 0] - hi[i, 0]
            low_gap, high_gap = min(below, above), max(below, above)
            if low_gap + rows_r[k] + grow < 0.0 and r_max[i] + grow - high_gap < 0.0:
                continue  # apart along x already (most pairs): more axes only lower low_gap and raise high_gap
            for axis in range(1, 3):
                below, above = lo[i, axis] - rows_lo[k, axis], rows_hi[k, axis] - hi[i, axis]
                low_gap = min(low_gap, min(below, above))
                high_gap = max(high_gap, max(below, above))
            out[i, k] = low_gap + rows_r[k] + grow >= 0.0 or r_max[i] + grow - high_gap >= 0.0
    return out


BodyBoxes = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, npt.NDArray[np.int64]]
"""Bodies for :func:`others_maybe_near`: box lower, upper corner [m], largest radius [m], capture stamp [ns], tracker
noise [m], person."""
RowBoxes = tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, npt.NDArray[np.int64], npt.NDArray[np.bool_]
]
"""The live tracks for :func:`others_maybe_near`: as :data:`BodyBoxes`, and whether each is seen."""


def others_maybe_near(
    bodies: BodyBoxes,
    rows: RowBoxes,
    reach_speed_mps: float,
    margin_m: float,
) -> npt.NDArray[np.bool_]:
    """Per body (``bodies``: box lower, upper corner [m], largest radius [m], capture stamp [ns], tracker noise [m],
    person) × per row (``rows``: the same of the live tracks, and whether each is seen): whether the row is another
    person's seen track whose box could nest with the body's grown by ``K_reach · |Δt|``, ``margin_m`` and both
    noises. The compiled :func:`gateway.tracks.others_maybe_near_reference`."""
    return _others_maybe_near(*bodies, *rows, float(reach_speed_mps), float(margin_m))  # type: ignore[no-any-return]


def check_chain(robot: RobotModel, chain: KinematicChain, seed: int = CHECK_SEED) -> None:
    """Compare the compiled kinematics of ``chain`` with Pinocchio's on seeded random states of ``robot``.

    Raises:
        ConfigError: a link-end position or velocity differs by more than ``CHECK_TOLERANCE``.
    """
    rng = np.random.default_rng(seed)
    data = robot.model.createData()
    lower = np.where(np.isfinite(robot.model.lowerPositionLimit), robot.model.lowerPositionLimit, -np.pi)
    upper = np.where(np.isfinite(robot.model.upperPositionLimit), robot.model.upperPositionLimit, np.pi)
    lower, upper = np.maximum(lower, -2 * np.pi), np.minimum(upper, 2 * np.pi)
    for _ in range(CHECK_CONFIGURATIONS):
        q = rng.uniform(lower, upper)
        qd = rng.uniform(-2.0, 2.0, robot.model.nv)
        reference = pinocchio_link_kinematics(robot, data, q, qd)
        compiled, _ = link_kinematics(chain, q, qd)
        for name, got, expected in zip(LinkKinematics._fields, compiled, reference, strict=True):
            error = float(np.max(np.abs(got - expected), initial=0.0))
            if not error <= CHECK_TOLERANCE:
                raise ConfigError(
                    f"robot {robot.name!r}: the compiled kinematics differ from Pinocchio's by {error:.3g} in "
                    f"{name} at q = {np.round(q, 4).tolist()}; allowed: at most {CHECK_TOLERANCE}"
                )


class RobotKernels:
    """The compiled per-cycle math of one robot with what it needs prepared once (chain, radii, parameters).

    Building it extracts the chain, checks the compiled kinematics against Pinocchio and compiles the kernels
    (or loads them from numba's cache) with the argument types of the loop, so the first cycle is not slow.

    Raises:
        ConfigError: an unsupported joint, or compiled kinematics that differ from Pinocchio's.
    """

    def __init__(self, robot: RobotModel, safety: SafetyConfig) -> None:
        self.chain = kinematic_chain(robot)
        check_chain(robot, self.chain)
        self.link_radius_m = np.ascontiguousarray(robot.link_radius_m, dtype=np.float64)
        self.t_brake_link_s = np.ascontiguousarray(robot.t_brake_link_s, dtype=np.float64)
        self.t_brake_max_s = float(robot.braking_time_s.max())
        self._n_links = len(self.chain.link_end_frame)
        # The rows' arrays and their views, reused from cycle to cycle while the number of capsules stays the same
        # (three allocations and six views cost ~1.2 µs a cycle): see ``cycle``.
        self._row_buffers = _row_outputs(self._n_links, 0)
        self._row_views = _row_views(*self._row_buffers)
        # the arguments of the compiled call that do not change: one tuple, unpacked in one go every cycle
        self._robot_arguments = (
            *self.chain,
            self.link_radius_m,
            self.t_brake_link_s,
            self.t_brake_max_s,
            *_clearance_parameters(safety),
        )
        capsule = np.zeros((1, 3))
        self.cycle(
            np.zeros(robot.model.nq),
            np.zeros(robot.model.nv),
            capsule_columns(HumanCapsules(capsule, capsule, np.zeros(1), ("-",), ("-",))),
            0.0,
        )

    def cycle(self, q_rad: FloatArray, qd_radps: FloatArray, capsules: FloatArray, t_delay_s: float) -> KernelCycle:
        """:func:`link_kinematics` and :func:`build_rows` of this robot in one compiled call.

        Args:
            q_rad: joint positions [rad].
            qd_radps: joint velocities, the programmed ones at 100 % override [rad/s].
            capsules: the human capsules as :func:`capsule_columns` gives them.
            t_delay_s: the measured delay of the whole chain [s].

        ``q_rad`` and ``qd_radps`` are taken as they are, C-contiguous, writable float64 arrays as the input store
        makes them (converting costs ~1 µs a cycle): other array types work, but compile the kernel anew on their
        first call, in the loop (``tests/test_kernels.py`` checks that the loop never compiles).

        Returns:
            A :class:`KernelCycle`. Its ``links`` are fresh arrays (a decision keeps them); its ``rows`` are this
            robot's scratch space, overwritten by its next cycle: use them before (every method reduces them to
            its δ bound within the decision; nothing keeps them).
        """
        ends = np.empty((4, self._n_links, 3))
        if capsules.shape[1] != self._row_buffers[0].shape[2]:
            self._row_buffers = _row_outputs(self._n_links, capsules.shape[1])
            self._row_views = _row_views(*self._row_buffers)
        pair, corner, horizon = self._row_buffers
        speed_mps, lowest, i, j, distance_m, finite = _cycle(
            *self._robot_arguments,
            q_rad,
            qd_radps,
            capsules,
            float(t_delay_s),
            ends,
            pair,
            corner,
            horizon,
        )
        return KernelCycle(
            LinkKinematics(ends[0], ends[1], ends[2], ends[3]),
            speed_mps,
            ConstraintRows(*self._row_views, float(lowest)),
            Closest(i, j, distance_m),
            finite,
        )
