"""The gateway's event log: zone changes held in time, faults raised and cleared, configuration, start and stop.

    loop ──EventLog.observe(decisions)──▶ new events ──HTTP child──▶ EventRing (GET /api/v1/events)
                                                                 └─▶ EventFile (JSON Lines, rotated by size)

:class:`EventLog` is pure (no I/O, no clock: every time is passed in) and cheap when nothing changes (one
comparison of zone and faults per robot), so the safety loop can feed it every cycle. A zone is logged as a
change only once it has held for ``hold_s``: a person standing on a threshold makes the zone flicker every
cycle, and the log then shows one change, not hundreds. Faults are logged at once (the input door already
holds them).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from gateway.core import Fault, RobotDecision
from gateway.planner_worker import PlannerHealth, PlanView
from gateway.tracks import TrackEvent
from hrc_contract.status_models import Event, EventKind
from hrc_contract.vocabulary import Zone

ZONE_HOLD_S = 0.2
"""A new zone must hold this long before it is logged as a change [s]."""
RING_EVENTS = 1000
"""Events kept in memory by the HTTP child for ``GET /api/v1/events``."""
FILE_MAX_BYTES = 1_000_000
"""The JSON Lines file is rotated when it would grow past this [bytes]."""
FILE_BACKUPS = 3
"""Rotated files kept (``events.jsonl.1`` … ``.3``)."""
NS_PER_S = 1_000_000_000


@dataclass
class _RobotLog:
    """What the log remembers of one robot: the zone logged, a candidate zone and since when, the faults."""

    logged: Zone | None = None
    candidate: Zone | None = None
    candidate_since_ns: int = 0
    faults: tuple[Fault, ...] = ()
    plans_adopted: int = 0
    plans_rejected: int = 0


class EventLog:
    """Turns the loop's decisions into events; numbers them 1, 2, 3, ...

    Args:
        hold_s: a zone must hold this long before it is logged as a change [s].
    """

    def __init__(self, hold_s: float = ZONE_HOLD_S) -> None:
        self.hold_ns = round(hold_s * NS_PER_S)
        self.seq = 0
        self._robots: dict[str, _RobotLog] = {}
        self._planner = PlannerHealth()
        """The planner's process as last logged (one planner for every open robot: logged once, for the gateway)."""

    def _event(self, stamp_ns: int, kind: EventKind, message: str, **fields: str | None) -> Event:
        self.seq += 1
        return Event(seq=self.seq, stamp_ns=stamp_ns, kind=kind, message=message, **fields)

    def started(self, stamp_ns: int, cell: str, config_sha256: str) -> list[Event]:
        """The gateway started with a configuration: ``start`` and ``config_loaded``."""
        return [
            self._event(stamp_ns, "start", f"gateway for cell {cell!r} started"),
            self._event(
                stamp_ns,
                "config_loaded",
                f"configuration loaded, sha256 {config_sha256}",
                config_sha256=config_sha256,
            ),
        ]

    def stopped(self, stamp_ns: int, why: str) -> list[Event]:
        """The gateway stops (``why``: e.g. ``"signal"``)."""
        return [self._event(stamp_ns, "stop", f"gateway stopped: {why}")]

    def stalled(self, stamp_ns: int, cause: str, message: str) -> list[Event]:
        """The loop stalled (:mod:`gateway.stalls`): ``loop_stall`` with its cause."""
        return [self._event(stamp_ns, "loop_stall", message, cause=cause)]

    def observe(
        self,
        mono_ns: int,
        stamp_ns: int,
        decisions: Mapping[str, RobotDecision],
        track_events: Sequence[TrackEvent] = (),
    ) -> list[Event]:
        """The events of one cycle's decisions (usually none).

        Args:
            mono_ns: the cycle's monotonic time, for the zone hold [ns].
            stamp_ns: the wall-clock time written in the events [ns since the Unix epoch].
            track_events: the cycle's track changes (a person lost, released and by what): logged at once.
        """
        events: list[Event] = [
            self._event(stamp_ns, e.kind, e.message, track=e.track, cause=e.cause)  # type: ignore[arg-type]
            for e in track_events
        ]
        for name, decision in decisions.items():
            robot = self._robots.get(name)
            if robot is None:
                robot = self._robots[name] = _RobotLog()
            if decision.faults != robot.faults:
                events += self._fault_events(name, stamp_ns, robot.faults, decision.faults)
                robot.faults = decision.faults
            if decision.zone is not robot.logged:
                events += self._zone_events(name, robot, decision.zone, mono_ns, stamp_ns)
            else:
                robot.candidate = None
            if decision.plan is not None:
                events += self._plan_events(name, robot, decision.plan, stamp_ns)
                events += self._planner_events(decision.plan.backend, stamp_ns)
        return events

    def _planner_events(self, health: PlannerHealth, stamp_ns: int) -> list[Event]:
        """The planner's process died, or was started again (its counts grew)."""
        events = []
        if health.deaths > self._planner.deaths:
            events.append(
                self._event(
                    stamp_ns,
                    "planner_died",
                    f"the planner's process died ({health.last_exit}; {health.deaths} so far): restarted after a "
                    "backoff; safety does not depend on it",
                    cause=health.last_exit or None,
                )
            )
        if health.restarts > self._planner.restarts:
            events.append(
                self._event(stamp_ns, "planner_restarted", f"the planner's process started again ({health.restarts})")
            )
        if health.deaths >= self._planner.deaths and health.restarts >= self._planner.restarts:
            self._planner = health
        return events

    def _plan_events(self, robot: str, log: _RobotLog, plan: PlanView, stamp_ns: int) -> list[Event]:
        """A plan the robot took up, or one that came back too late (the planner layer's counts grew)."""
        events = []
        if plan.adopted > log.plans_adopted:
            planned = "" if plan.planning_last_s is None else f", planned in {plan.planning_last_s * 1e3:.0f} ms"
            length = "" if plan.plan_duration_s is None else f", {plan.plan_duration_s:.1f} s long"
            why = {"horizon": "a person ahead on the path", "request": "δ held low (request (16))"}.get(
                plan.reason, plan.reason or "-"
            )
            events.append(
                self._event(
                    stamp_ns,
                    "plan_adopted",
                    f"plan adopted: {why}{length}{planned}",
                    robot=robot,
                    cause=plan.reason or None,
                )
            )
        if plan.rejected > log.plans_rejected:
            events.append(
                self._event(
                    stamp_ns,
                    "plan_rejected",
                    f"plan rejected: it came back after the robot had passed its join ({plan.rejected} so far)",
                    robot=robot,
                )
            )
        log.plans_adopted, log.plans_rejected = plan.adopted, plan.rejected
        return events

    def _fault_events(
        self, robot: str, stamp_ns: int, before: tuple[Fault, ...], now: tuple[Fault, ...]
    ) -> list[Event]:
        before_codes = {f.code for f in before}
        now_codes = {f.code for f in now}
        raised = [
            self._event(
                stamp_ns, "fault_raised", f"fault {f.code}: {f.reason}", robot=robot, code=f.code, reason=f.reason
            )
            for f in now
            if f.code not in before_codes
        ]
        cleared = [
            self._event(stamp_ns, "fault_cleared", f"fault {code} cleared", robot=robot, code=code)
            for code in sorted(before_codes - now_codes)
        ]
        return raised + cleared

    def _zone_events(self, robot: str, log: _RobotLog, zone: Zone, mono_ns: int, stamp_ns: int) -> list[Event]:
        """A zone other than the logged one: logged once it has held ``hold_ns`` (the first zone at once)."""
        if zone is not log.candidate:
            log.candidate, log.candidate_since_ns = zone, mono_ns
        if log.logged is not None and mono_ns - log.candidate_since_ns < self.hold_ns:
            return []
        previous, log.logged, log.candidate = log.logged, zone, None
        message = f"zone {zone.value}" if previous is None else f"zone {previous.value} → {zone.value}"
        return [
            self._event(
                stamp_ns,
                "zone_changed",
                message,
                robot=robot,
                zone=zone.value,
                previous_zone=None if previous is None else previous.value,
            )
        ]


class EventRing:
    """The newest events, for ``GET /api/v1/events?since=<seq>`` (thread-safe)."""

    def __init__(self, size: int = RING_EVENTS) -> None:
        self._events: deque[Event] = deque(maxlen=size)
        self._lock = threading.Lock()
        self.last_seq = 0

    def add(self, event: Event) -> None:
        with self._lock:
            self._events.append(event)
            self.last_seq = max(self.last_seq, event.seq)

    def since(self, seq: int, limit: int) -> tuple[list[Event], int]:
        """At most ``limit`` events with a seq above ``seq``, oldest first, and the newest seq logged."""
        with self._lock:
            return [e for e in self._events if e.seq > seq][:limit], self.last_seq


class EventFile:
    """Appends events as JSON Lines to ``path``; rotates by size (``path.1`` the newest rotated file).

    Args:
        path: the file; its directory is created.
        max_bytes: a file is rotated before it would grow past this [bytes].
        backups: rotated files kept.
    """

    def __init__(self, path: Path, max_bytes: int = FILE_MAX_BYTES, backups: int = FILE_BACKUPS) -> None:
        self.path = path
        self.max_bytes = max_bytes
        self.backups = backups
        path.parent.mkdir(parents=True, exist_ok=True)

    def write(self, event: Event) -> None:
        line = event.model_dump_json(exclude_none=True).encode() + b"\n"
        size = self.path.stat().st_size if self.path.exists() else 0
        if size and size + len(line) > self.max_bytes:
            self._rotate()
        with self.path.open("ab") as f:
            f.write(line)

    def _rotate(self) -> None:
        for i in range(self.backups - 1, 0, -1):
            older = self.path.with_name(f"{self.path.name}.{i}")
            if older.exists():
                older.replace(self.path.with_name(f"{self.path.name}.{i + 1}"))
        self.path.replace(self.path.with_name(f"{self.path.name}.1"))
