"""gateway.joint_motion: q's change over the stamps against the velocities reported (known answers, then
invariants over seeded random chains)."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from gateway import joint_motion
from gateway.joint_motion import MotionEntry, contradiction, extend, judged_span_s, moving, tolerance_used

MS = 1_000_000
A = np.array([60.0])  # an acceleration bound [rad/s²]
ROOM = np.array([0.01])


def _chain(q: list[float], v: list[float], w: list[float] | None = None, dt_ms: float = 4.0) -> deque[MotionEntry]:
    history: deque[MotionEntry] = deque()
    for k, (qk, vk) in enumerate(zip(q, v, strict=True)):
        wk = vk if w is None else w[k]
        history.append(
            extend(
                history[-1] if history else None,
                round(k * dt_ms * MS),
                np.array([qk]),
                np.array([vk]),
                np.array([wk]),
                ROOM,
                A,
            )
        )
    return history


def test_the_trapezoid_of_a_constant_velocity_is_the_motion() -> None:
    history = _chain([0.0, 0.004, 0.008], [1.0, 1.0, 1.0])
    assert history[-1].moved_v_rad[0] == pytest.approx(0.008)
    assert history[-1].room_w_rad[0] == pytest.approx(0.01 * 0.008)
    assert history[-1].turn_rad[0] == pytest.approx(2 * 60.0 * 0.004**2 / 4)


def test_an_honest_chain_uses_little_of_its_tolerance() -> None:
    q = [0.001 * k**2 for k in range(20)]  # accelerating: v = 0.5 k rad/s at 4 ms steps
    v = [0.5 * k for k in range(20)]
    history = _chain(q[:-1], v[:-1])
    state = extend(history[-1], 19 * 4 * MS, np.array([q[-1]]), np.array([v[-1]]), np.array([v[-1]]), ROOM, A)
    assert contradiction(history, state) is None
    assert tolerance_used(history, state) < 0.05


def test_q_advancing_under_zero_velocities_is_a_contradiction_with_its_figures() -> None:
    history = _chain([0.004 * k for k in range(10)], [0.0] * 10)
    state = extend(history[-1], 40 * MS, np.array([0.04]), np.array([0.0]), np.array([0.0]), ROOM, A)
    found = contradiction(history, state)
    assert found is not None
    assert found.joints.tolist() == [True]
    assert found.detail.startswith("joint 0 moved +0.0400 rad in 40.0 ms, qd integrate to +0.0000 rad")


def test_the_newest_state_is_an_anchor_however_old() -> None:
    history = _chain([0.0], [0.0])
    state = extend(history[-1], 2_000 * MS, np.array([0.0]), np.array([0.0]), np.array([0.0]), ROOM, A)
    assert contradiction(history, state) is None
    assert judged_span_s(history, 2_000 * MS) == 0.0  # nothing within the window: nothing proven
    assert judged_span_s(_chain([0.0] * 30, [0.0] * 30), 29 * 4 * MS) == pytest.approx(0.116)


def test_moving_is_above_the_threshold_either_sign() -> None:
    assert moving(np.array([0.2, -0.2, 0.05]), np.array([0.1, 0.1, 0.1])).tolist() == [True, True, False]


def test_an_empty_history_judges_nothing() -> None:
    state = extend(None, 0, np.array([1.0]), np.array([5.0]), np.array([5.0]), ROOM, A)
    assert contradiction(deque(), state) is None
    assert tolerance_used(deque(), state) == 0.0


@pytest.mark.parametrize("seed", range(5))
def test_a_constant_stamp_offset_costs_at_most_the_ends(seed: int) -> None:
    """Invariant: every stamp late by the same ε ≤ STAMP_JITTER_S leaves a smooth chain consistent."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.002, 0.008, 80))
    amplitude, omega = rng.uniform(0.1, 0.6), rng.uniform(1.0, 4.0)
    eps = rng.uniform(0, joint_motion.STAMP_JITTER_S)
    history: deque[MotionEntry] = deque(maxlen=joint_motion.HISTORY_STATES)
    for tk in t:
        q, v = amplitude * np.sin(omega * tk), amplitude * omega * np.cos(omega * tk)
        state = extend(history[-1] if history else None, round((tk + eps) * 1e9), np.array([q]), np.array([v]),
                       np.array([v]), ROOM, A)  # fmt: skip
        assert contradiction(history, state) is None
        history.append(state)


def test_the_history_buffer_judges_as_the_plain_deque_through_wraps_and_clears() -> None:
    """:class:`MotionHistory` (the door's: views of one buffer) and a plain deque of the same entries give the same
    verdicts, state by state, over a chain long enough to wrap its buffer several times, with a lie and a restart."""
    rng = np.random.default_rng(5)
    plain: deque[MotionEntry] = deque(maxlen=joint_motion.HISTORY_STATES)
    buffered = joint_motion.MotionHistory()
    q, previous, verdicts = np.zeros(3), None, 0
    room, accel = np.full(3, 0.01), np.full(3, 60.0)
    for k in range(5 * joint_motion.HISTORY_STATES):
        v = np.array([1.0, -0.5, 0.2]) * np.sin(k / 40.0)
        q = q + v * 0.004 + rng.normal(0.0, 2e-4, 3)
        claimed = np.zeros(3) if 300 <= k < 330 else v  # a stretch that claims rest while moving
        state = extend(previous, k * 4 * MS + int(rng.integers(0, 500_000)), q.copy(), claimed, claimed, room, accel)
        ours, theirs = contradiction(buffered, state), contradiction(plain, state)
        assert (ours is None) == (theirs is None), k
        if ours is not None and theirs is not None:
            assert ours.detail == theirs.detail
            assert np.array_equal(ours.joints, theirs.joints)
            verdicts += 1
        assert tolerance_used(buffered, state) == tolerance_used(plain, state)
        if k == 400:  # a restart: both start a new chain
            buffered.clear()
            plain.clear()
            previous = None
            continue
        buffered.append(state)
        plain.append(state)
        previous = state
    assert verdicts > 0, "the lie was never found: the comparison judged nothing"
    assert len(buffered) == len(plain) == joint_motion.HISTORY_STATES
