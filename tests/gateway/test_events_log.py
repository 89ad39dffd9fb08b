"""The event log (gateway/events.py): zone changes held in time, faults raised and cleared, start, stop, the
in-memory ring and the rotated JSON Lines file."""

from __future__ import annotations

import json
from pathlib import Path

from gateway.core import ClosestPair, Fault, RobotDecision
from gateway.delay import DelayBudget
from gateway.events import EventFile, EventLog, EventRing
from gateway.planner_worker import PlannerHealth, PlanView
from gateway.zones import ZoneThresholds
from hrc_contract.status_models import Event
from hrc_contract.vocabulary import Zone

MS = 1_000_000
STALE = Fault("tracker_stale", "tracker 'front' data is 0.300 s old (limit 0.2 s)")


def decision(zone: Zone, faults: tuple[Fault, ...] = ()) -> RobotDecision:
    return RobotDecision(
        "ur5",
        zone,
        0.5,
        0.5,
        1.2,
        ClosestPair("front/h1", "hand_r", "tool"),
        DelayBudget(0.04, 0.03, 0.004, 0.012, 0.004, 0.004),
        1.0,
        ZoneThresholds(1.0, 1.1, 1.9, 2.4),
        faults,
        {"joint_state": 0.004},
        "running",
    )


def run(log: EventLog, zones: list[tuple[int, Zone]]) -> list[Event]:
    """Feed ``(t_ms, zone)`` cycles; return every event."""
    events: list[Event] = []
    for t_ms, zone in zones:
        events += log.observe(t_ms * MS, 1_790_000_000_000_000_000 + t_ms * MS, {"ur5": decision(zone)})
    return events


def test_a_flickering_zone_is_not_logged_but_a_held_one_is_once() -> None:
    log = EventLog(hold_s=0.2)
    guarded, reduced = Zone.GUARDED_DISTANCE, Zone.REDUCED_SPEED
    flicker = [(t, reduced if (t // 20) % 2 else guarded) for t in range(0, 1000, 4)]  # 20 ms each, for 1 s
    events = run(log, flicker)
    assert [e.zone for e in events] == ["guarded_distance"], "the first zone at once, then nothing while flickering"
    held = run(log, [(t, reduced) for t in range(1000, 1400, 4)])
    changes = [e for e in held if e.kind == "zone_changed"]
    assert len(changes) == 1
    assert (changes[0].previous_zone, changes[0].zone, changes[0].robot) == ("guarded_distance", "reduced_speed", "ur5")
    # The last flicker (980–999 ms) was already reduced_speed: held 0.2 s at 1180 ms.
    assert changes[0].stamp_ns == 1_790_000_000_000_000_000 + 1180 * MS, "logged when it had held 0.2 s"


def test_a_zone_shorter_than_the_hold_is_never_logged() -> None:
    log = EventLog(hold_s=0.2)
    run(log, [(0, Zone.AUTONOMOUS)])
    events = run(log, [(t, Zone.GUARDED_DISTANCE) for t in range(4, 180, 4)] + [(200, Zone.AUTONOMOUS)])
    events += run(log, [(t, Zone.AUTONOMOUS) for t in range(204, 800, 4)])
    assert events == []


def test_faults_are_logged_raised_with_their_reason_and_cleared_at_once() -> None:
    log = EventLog()
    assert [e.kind for e in log.observe(0, 1, {"ur5": decision(Zone.AUTONOMOUS)})] == ["zone_changed"]
    raised = log.observe(4 * MS, 2, {"ur5": decision(Zone.SAFETY_EXCEPTION, (STALE,))})
    assert [(e.kind, e.code, e.reason) for e in raised] == [("fault_raised", STALE.code, STALE.reason)]
    still = Fault("tracker_stale", "tracker 'front' data is 0.400 s old (limit 0.2 s)")  # same code, new reason
    assert log.observe(8 * MS, 3, {"ur5": decision(Zone.SAFETY_EXCEPTION, (still,))}) == []
    cleared = log.observe(12 * MS, 4, {"ur5": decision(Zone.SAFETY_EXCEPTION)})
    assert [(e.kind, e.code) for e in cleared] == [("fault_cleared", "tracker_stale")]


def test_start_stop_and_config_events_are_numbered_in_order() -> None:
    log = EventLog()
    events = log.started(5, "demo", "ab" * 32) + log.stopped(9, "stop requested")
    assert [(e.seq, e.kind) for e in events] == [(1, "start"), (2, "config_loaded"), (3, "stop")]
    assert events[1].config_sha256 == "ab" * 32
    assert "ab" * 32 in events[1].message


def test_the_ring_answers_after_a_seq_and_keeps_the_newest() -> None:
    ring = EventRing(size=3)
    log = EventLog()
    for event in log.started(1, "demo", "0" * 64) + log.stopped(2, "x") + log.stopped(3, "y"):
        ring.add(event)
    events, last = ring.since(0, 100)
    assert [e.seq for e in events] == [2, 3, 4], "the oldest fell out"
    assert last == 4
    assert [e.seq for e in ring.since(3, 100)[0]] == [4]
    assert [e.seq for e in ring.since(0, 1)[0]] == [2]


def test_the_file_is_json_lines_and_rotates_by_size(tmp_path: Path) -> None:
    path = tmp_path / "logs" / "events.jsonl"
    file = EventFile(path, max_bytes=400, backups=2)
    log = EventLog()
    written = [e for _ in range(10) for e in log.stopped(1, "a reason long enough to fill the file quickly")]
    for event in written:
        file.write(event)
    files = sorted(p.name for p in path.parent.iterdir())
    assert files == ["events.jsonl", "events.jsonl.1", "events.jsonl.2"], "two backups kept, no more"
    for p in path.parent.iterdir():
        assert p.stat().st_size <= 400
    kept = [json.loads(line) for p in (path.with_name("events.jsonl.1"), path) for line in p.read_text().splitlines()]
    seqs = [e["seq"] for e in kept]
    assert seqs == sorted(seqs)
    assert seqs[-1] == written[-1].seq, "the newest event is in the current file"
    assert Event.model_validate(kept[-1]) == written[-1]


def _plan(adopted: int, rejected: int, reason: str = "horizon") -> PlanView:
    return PlanView(True, 0.4, 3.2, 5, reason, {reason: adopted + rejected}, adopted, rejected, {}, 0.112)


def test_a_plan_taken_up_or_returned_too_late_is_logged_once() -> None:
    log = EventLog()
    stamp = 1_790_000_000_000_000_000

    def cycle(t_ms: int, plan: PlanView | None) -> list[Event]:
        d = decision(Zone.REDUCED_SPEED)._replace(plan=plan)
        return [e for e in log.observe(t_ms * MS, stamp + t_ms * MS, {"ur5": d}) if e.kind.startswith("plan_")]

    assert cycle(0, None) == []
    assert cycle(4, _plan(0, 0)) == []
    adopted = cycle(8, _plan(1, 0))
    assert [(e.kind, e.robot, e.cause) for e in adopted] == [("plan_adopted", "ur5", "horizon")]
    assert "a person ahead on the path, 3.2 s long, planned in 112 ms" in adopted[0].message
    assert cycle(12, _plan(1, 0)) == []  # the same plan: nothing new
    both = cycle(16, _plan(2, 1, "request"))
    assert [(e.kind, e.cause) for e in both] == [("plan_adopted", "request"), ("plan_rejected", None)]
    assert "request (16)" in both[0].message


def test_the_planner_s_death_and_restart_are_logged_once_for_the_gateway() -> None:
    log = EventLog()
    stamp = 1_790_000_000_000_000_000

    def cycle(t_ms: int, health: PlannerHealth) -> list[Event]:
        d = decision(Zone.REDUCED_SPEED)._replace(plan=_plan(0, 0)._replace(backend=health))
        decisions = {"ur5": d, "ur5b": d}  # two open robots, one planner
        return [e for e in log.observe(t_ms * MS, stamp + t_ms * MS, decisions) if e.kind.startswith("planner_")]

    assert cycle(0, PlannerHealth()) == []
    died = cycle(4, PlannerHealth(False, 1, 0, "signal SIGKILL"))
    assert [(e.kind, e.robot, e.cause) for e in died] == [("planner_died", None, "signal SIGKILL")]
    assert "signal SIGKILL" in died[0].message
    assert cycle(8, PlannerHealth(False, 1, 0, "signal SIGKILL")) == []
    restarted = cycle(12, PlannerHealth(True, 1, 1, "signal SIGKILL"))
    assert [(e.kind, e.robot) for e in restarted] == [("planner_restarted", None)]
    assert cycle(16, PlannerHealth(True, 1, 1, "signal SIGKILL")) == []
