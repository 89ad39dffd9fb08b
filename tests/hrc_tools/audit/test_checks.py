"""The auditor's checks (safety-math.md §9) on hand-built cases with answers worked out in the comments,
then on the real UR5, then the run summary."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from support.known_cases import LINK_UP, moving_links, point_hands

from hrc_contract.humans import NO_HUMANS
from hrc_devices.robots.link_motion import LinkMotion, link_motion
from hrc_devices.robots.model import RobotModel
from hrc_tools.audit.checks import (
    MAX_ONSET_SPEEDS,
    AuditAccumulator,
    CycleAudit,
    audit_cycle,
    audit_links,
    merge_summaries,
)
from hrc_tools.audit.contact import Contact

K = 1.6  # human approach speed [m/s]
T_B = 0.24  # controller braking time (δ 1 → 0) [s]
RADIUS = np.array([0.05])  # link radius [m]
NAMES = ("link",)


def _links(p_a, p_b, v_a, v_b) -> LinkMotion:  # type: ignore[no-untyped-def]
    """The auditor's own link type (it shares nothing with the gateway) for :func:`known_cases.moving_links`."""
    return LinkMotion(*moving_links(p_a, p_b, v_a, v_b))


def _audit(links, humans, delta, t_b=T_B) -> CycleAudit:
    return audit_links(links, RADIUS, NAMES, delta, t_b, humans, K)


# A 0.4 m link on the x axis, radius 0.05 m, translating along +y at 2 m/s (actual velocity).
TRANSLATING = LinkMotion(*LINK_UP)


def test_link_moving_straight_at_a_point_hand() -> None:
    # hand at (0.2, 1, 0), radius 0.05: d = 1.0 − 0.05 − 0.05 = 0.9
    # δ = 0.5: t_stop = 0.5 · 0.24 = 0.12 s; travel = 2 · 0.12 / 2 = 0.12 m; human: 1.6 · 0.12 = 0.192 m
    # margin = 0.9 − 0.12 − 0.192 = 0.588
    got = _audit(TRANSLATING, point_hands([(0.2, 1.0, 0.0)]), delta=0.5)
    assert got.margin_m == pytest.approx(0.588)
    assert got.min_distance_m == pytest.approx(0.9)
    assert not got.violation
    assert not got.contact_while_moving
    assert (got.worst_link, got.worst_capsule) == ("link", 0)
    assert got.speed_mps == pytest.approx(2.0)


def test_oblique_approach_counts_the_projection_only() -> None:
    # hand at (0.2, 0.6, 0.8): closest link point (0.2, 0, 0), direction (0, 0.6, 0.8), v_toward = 2 · 0.6 = 1.2
    # d = 1.0 − 0.1 = 0.9; margin = 0.9 − 1.2 · 0.12 / 2 − 0.192 = 0.9 − 0.072 − 0.192 = 0.636
    got = _audit(TRANSLATING, point_hands([(0.2, 0.6, 0.8)]), delta=0.5)
    assert got.margin_m == pytest.approx(0.636)


def test_rotating_link_uses_the_velocity_of_its_closest_point() -> None:
    # link rotating about end a: v_a = 0, v_b = (0, 2, 0); hand at (0.3, 1, 0): s = 0.75, v = 0.75 · 2 = 1.5
    # margin = 0.9 − 1.5 · 0.12 / 2 − 0.192 = 0.9 − 0.09 − 0.192 = 0.618
    rotating = _links((0, 0, 0), (0.4, 0, 0), (0, 0, 0), (0, 2, 0))
    got = _audit(rotating, point_hands([(0.3, 1.0, 0.0)]), delta=0.5)
    assert got.margin_m == pytest.approx(0.618)


def test_retreating_link_has_no_approach_term() -> None:
    # moving away at 2 m/s: only the human's approach counts: margin = 0.9 − 0.192 = 0.708
    away = _links((0, 0, 0), (0.4, 0, 0), (0, -2, 0), (0, -2, 0))
    got = _audit(away, point_hands([(0.2, 1.0, 0.0)]), delta=0.5)
    assert got.margin_m == pytest.approx(0.708)
    sideways = _links((0, 0, 0), (0.4, 0, 0), (0, 0, 2), (0, 0, 2))
    assert _audit(sideways, point_hands([(0.2, 1.0, 0.0)]), delta=0.5).margin_m == pytest.approx(0.708)


def test_too_close_at_full_speed_is_a_violation() -> None:
    # hand at (0.2, 0.35, 0): d = 0.25; δ = 1: t_stop = 0.24; travel 2 · 0.24 / 2 = 0.24; human 1.6 · 0.24 = 0.384
    # margin = 0.25 − 0.624 = −0.374
    got = _audit(TRANSLATING, point_hands([(0.2, 0.35, 0.0)]), delta=1.0)
    assert got.margin_m == pytest.approx(-0.374)
    assert got.violation
    assert not got.contact_while_moving


def test_contact_while_moving_and_contact_at_standstill() -> None:
    touching = point_hands([(0.2, 0.05, 0.0)])  # centre-line distance 0.05 < 0.05 + 0.05: surface distance 0
    moving = _audit(TRANSLATING, touching, delta=0.5)
    assert moving.contact_while_moving
    assert moving.violation
    assert moving.min_distance_m == 0.0
    # The same pose at standstill (δ_applied = 0, actual velocity 0): contact, but no violation.
    still = _links((0, 0, 0), (0.4, 0, 0), (0, 0, 0), (0, 0, 0))
    standing = _audit(still, touching, delta=0.0)
    assert not standing.contact_while_moving
    assert standing.margin_m == 0.0
    assert not standing.violation
    # Slower than ε counts as standing still.
    creeping = _links((0, 0, 0), (0.4, 0, 0), (0, 0.005, 0), (0, 0.005, 0))
    assert not audit_links(creeping, RADIUS, NAMES, 0.0, T_B, touching, K, moving_eps_mps=0.01).violation


def test_centre_lines_crossing_counts_the_full_speed() -> None:
    # hand on the link's axis: no direction to project on; the whole speed 2 m/s counts (d = 0).
    got = _audit(TRANSLATING, point_hands([(0.2, 0.0, 0.0)]), delta=0.5)
    assert got.margin_m == pytest.approx(0.0 - 2.0 * 0.12 / 2 - 0.192)


def test_no_humans_gives_an_infinite_margin() -> None:
    got = _audit(TRANSLATING, NO_HUMANS, delta=1.0)
    assert got.margin_m == math.inf
    assert got.min_distance_m is None
    assert not got.violation
    assert got.worst_link is None
    assert got.worst_capsule is None
    assert got.speed_mps is None


def test_the_worst_pair_is_named() -> None:
    two_links = _links(
        [(0, 0, 0), (0, 0, 1)], [(0.4, 0, 0), (0.4, 0, 1)], [(0, 2, 0), (0, 0, 0)], [(0, 2, 0), (0, 0, 0)]
    )
    # capsule 1 is in the moving link's way; capsule 0 sits near the still link, a bit farther
    humans = point_hands([(0.2, 0.0, 1.6), (0.2, 0.8, 0.0)])
    got = audit_links(two_links, np.array([0.05, 0.05]), ("low", "high"), 1.0, T_B, humans, K)
    # pair (low, 1): d = 0.7, margin = 0.7 − 0.24 − 0.384 = 0.076; pair (high, 0): d = 0.5, margin = 0.116
    assert (got.worst_link, got.worst_capsule) == ("low", 1)
    assert got.margin_m == pytest.approx(0.076)
    assert got.min_distance_m == pytest.approx(0.5)


def test_audit_cycle_on_the_ur5_is_audit_links_on_its_link_motion(ur5: RobotModel) -> None:
    data = ur5.model.createData()
    q = np.array([0.3, -1.14, 1.25, -1.68, -1.57, 0.3])
    qd = np.array([-1.0, 0.2, 0.4, -0.5, 0.0, -1.0])
    humans = point_hands([(0.9, 0.2, 1.1), (0.5, -0.6, 1.0)])
    got = audit_cycle(ur5, data, q, qd, 0.7, T_B, humans, K)
    links = link_motion(ur5, ur5.model.createData(), q, qd)
    expected = audit_links(links, ur5.link_radius_m, ur5.link_names, 0.7, T_B, humans, K)
    assert got.margin_m == pytest.approx(expected.margin_m)
    assert got.worst_link == expected.worst_link
    # At standstill only the human's own approach during the stop is left (δ = 0: nothing).
    still = audit_cycle(ur5, data, q, np.zeros(6), 0.0, T_B, humans, K)
    assert still.margin_m == pytest.approx(still.min_distance_m)
    assert still.speed_mps == 0.0


def test_accumulator_summary() -> None:
    acc = AuditAccumulator()
    empty = acc.summary()
    assert empty.cycles == 0
    assert empty.smallest_margin_m == math.inf
    assert json.loads(empty.to_json())["smallest_margin_m"] is None

    far = CycleAudit(False, 1.5, False, 2.0, "tool", 3, 1.0)
    close = CycleAudit(False, -0.1, True, 0.2, "forearm", 7, 1.0)
    free = CycleAudit(False, math.inf, False, None, None, None, 1.0)
    touch = CycleAudit(True, -0.3, True, 0.0, "tool", 8, 0.5)
    acc.add(free, t_s=0.0, dt_s=0.004, delta_applied=1.0, zone="autonomous", program_cycles_completed=0)
    acc.add(far, t_s=0.004, dt_s=0.004, delta_applied=1.0, zone="guarded_distance", program_cycles_completed=1)
    acc.add(close, t_s=0.008, dt_s=0.004, delta_applied=0.5, zone="reduced_speed", capsule_label="h1/hand_r")
    acc.add(touch, t_s=0.012, dt_s=0.004, delta_applied=0.0, zone=None, program_cycles_completed=1)
    got = acc.summary()
    assert got.cycles == 4
    assert got.duration_s == pytest.approx(0.016)
    assert got.violations == 2
    assert got.contacts_while_moving == 1
    assert got.smallest_margin_m == pytest.approx(-0.3)
    assert got.smallest_margin_t_s == pytest.approx(0.012)
    assert got.smallest_margin_pair == ("tool", "8")
    assert got.smallest_margin_moving_m == pytest.approx(-0.3)
    assert got.first_violation_t_s == pytest.approx(0.008)
    assert got.min_distance_m == 0.0
    assert dict(got.time_in_zone_s) == pytest.approx(
        {"autonomous": 0.004, "guarded_distance": 0.004, "reduced_speed": 0.004, "unknown": 0.004}
    )
    assert got.time_stopped_s == pytest.approx(0.004)
    assert got.mean_delta_applied == pytest.approx((1.0 + 1.0 + 0.5 + 0.0) / 4)
    assert got.program_cycles_completed == 1
    doc = json.loads(got.to_json(indent=2))
    assert doc["violations"] == 2
    assert doc["smallest_margin_pair"] == ["tool", "8"]
    assert doc["time_in_zone_s"]["unknown"] == pytest.approx(0.004)


def test_merging_summaries_adds_counts_and_keeps_the_smallest() -> None:
    a, b = AuditAccumulator(), AuditAccumulator()
    a.add(
        CycleAudit(False, 0.4, False, 0.5, "tool", 0, 1.0),
        t_s=1.0,
        dt_s=1.0,
        delta_applied=1.0,
        zone="guarded_distance",
    )
    a.add(
        CycleAudit(False, 0.0, False, 0.0, "tool", 1, 0.0),
        t_s=2.0,
        dt_s=1.0,
        delta_applied=0.0,
        zone="safety_exception",
    )
    b.add(
        CycleAudit(False, -0.1, True, 0.2, "forearm", 2, 1.0),
        t_s=0.5,
        dt_s=2.0,
        delta_applied=0.5,
        zone="reduced_speed",
        program_cycles_completed=3,
    )
    got = merge_summaries([a.summary(), b.summary()])
    assert got.cycles == 3
    assert got.duration_s == pytest.approx(4.0)
    assert got.violations == 1
    assert got.smallest_margin_m == pytest.approx(-0.1)
    assert got.smallest_margin_pair == ("forearm", "2")
    # a's standstill contact (margin 0 at speed 0) is not a moving margin; a's moving one is 0.4
    assert a.summary().smallest_margin_moving_m == pytest.approx(0.4)
    assert got.smallest_margin_moving_m == pytest.approx(-0.1)
    assert got.first_violation_t_s == pytest.approx(0.5)
    assert got.min_distance_m == 0.0
    assert got.mean_delta_applied == pytest.approx((1.0 + 0.0 + 0.5 * 2.0) / 4.0)
    assert got.time_stopped_s == pytest.approx(1.0)
    assert got.program_cycles_completed == 3
    assert set(got.time_in_zone_s) == {"guarded_distance", "safety_exception", "reduced_speed"}
    assert merge_summaries([]).cycles == 0


def test_100k_cycles_and_contact_onsets_keep_the_accumulator_bounded() -> None:
    """A run of weeks: the accumulator holds at most 2 × MAX_ONSET_SPEEDS onset speeds, the fastest, and counts
    every onset; below that it holds them all (what the sweep reports is unchanged)."""
    acc = AuditAccumulator()
    verdict = CycleAudit(False, 0.5, False, 0.3, "tool", 0, 0.2)
    for k in range(100_000):
        acc.add(verdict, t_s=k * 0.004, dt_s=0.004, delta_applied=1.0, zone="autonomous")
        speed_mps = (k * 7919 % 100_000) * 1e-5  # 0 … 1 m/s, all different
        # A contact every other cycle: each one is an onset (the cycle before had none).
        contacts = [Contact("tool", 0, "hand", speed_mps, 1.0, False, True)] if k % 2 else []
        acc.add_contacts(contacts, ["h1/hand_r"] * len(contacts))
    summary = acc.summary()
    assert summary.cycles == 100_000
    assert summary.contact_onsets == 50_000
    assert acc.n_items_stored <= 2 * MAX_ONSET_SPEEDS + 2  # a list held 50,000 speeds
    assert len(summary.contact_speeds_mps) == MAX_ONSET_SPEEDS
    assert (
        min(summary.contact_speeds_mps)
        >= sorted((k * 7919 % 100_000) * 1e-5 for k in range(1, 100_000, 2))[-MAX_ONSET_SPEEDS]
    )
    merged = merge_summaries([summary, summary])
    assert (merged.contact_onsets, len(merged.contact_speeds_mps)) == (100_000, MAX_ONSET_SPEEDS)
