"""``hrc-audit``: the ground-truth auditor as a process (safety-math.md §9).

Zenoh callbacks only validate and store; the loop audits every controller cycle, in order:

    truth joint state (hrc/<cell>/truth/robot/<r>/state)  ─┐
    truth humans      (hrc/<cell>/truth/humans)           ─┼─► TruthAuditor.process() ─► audit_cycle ─► summary
    gateway status    (zone labels), emu_stats (cycles)   ─┘

Each joint state is judged against the true humans sample nearest in time. The two are not taken at
the same instant, so the humans are made conservatively bigger: every capsule radius grows by
``v_h · |age|``, with ``v_h`` the larger of the configured human speed and the speed the true capsule
end points were seen to move at around that sample. That is the same as subtracting ``v_h · |age|``
from every surface distance; with truth at 100 Hz, ``|age|`` is at most a few milliseconds. A joint
state with no true humans within :data:`MAX_HUMAN_TRUTH_GAP_S` (the tracker that plays them was killed, frozen, or
its clock stepped) is judged against the last sample before it, grown the same way by its age: a person no longer
seen is somewhere within ``v_h · age`` of where they were, not gone. Those cycles are counted as
``truth_gap_cycles`` (a person who enters the cell during the gap is not in that sample: across a gap the people
last seen are judged). A joint state waits up to :data:`TRUTH_SETTLE_S` for the true humans of its time (late on
their way is not a gap). A joint state older than every true humans sample is not audited and counted as
``unaudited_cycles`` (never silently passed).

Exit code: 0 when no cycle violated, 1 when any did, 2 on an invalid configuration, 3 when nothing
could be audited (no controller truth, or no human truth): a run that judged nothing proves nothing.
"""

from __future__ import annotations

import argparse
import bisect
import json
import logging
import math
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pinocchio as pin
import zenoh
from pydantic import ValidationError

from hrc_contract import keys
from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.humans import HumanCapsules, capsules_from_message
from hrc_contract.messages import Humans, JointState, MessageError, parse_message
from hrc_contract.status_models import GatewayStatus
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments
from hrc_runtime.config import load_cell_config
from hrc_runtime.logs import configure_logging
from hrc_runtime.memory import configure_heap
from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import DEFAULT_ENDPOINT, SessionOptions, options_from_args, session_config
from hrc_tools.audit.bounded import DelayHistogram
from hrc_tools.audit.checks import AuditAccumulator, AuditSummary, audit_cycle, open_stop_fraction

PROG = "hrc-audit"
log = logging.getLogger(PROG)

EXIT_OK, EXIT_VIOLATION, EXIT_CONFIG, EXIT_INCONCLUSIVE = 0, 1, 2, 3

MAX_HUMAN_TRUTH_GAP_S = 0.1
"""A joint state farther than this in time from every true humans sample is judged against the last one before it,
grown by its age (``truth_gap_cycles``) [s]."""
MAX_STATUS_AGE_S = 0.25
"""A gateway status older than this (relative to the joint state) gives the zone label ``unknown`` [s]."""
MAX_PLAUSIBLE_HUMAN_SPEED_MPS = 10.0
"""Capsule end point speeds above this (a person appearing elsewhere) are not used to grow the radii [m/s]."""
TRUTH_CLOCK_TOLERANCE_S = 0.5
"""Truth stamped farther than this from the auditor's own clock when it arrives is refused (``*/clock_off``): its
publisher's clock is off (a stepped host clock), so pairing it by stamp would judge the robot against where people
were seconds earlier; those cycles are judged across the gap. Truth travels on the host or a LAN: milliseconds, not
this [s]."""
TRUTH_SETTLE_S = 0.25
"""A joint state with no true humans sample at or after its stamp yet waits up to this long for one (truth that is
late on its way, not missing) before it is judged against the last sample before it, grown by its age [s]."""
HUMAN_HISTORY = 256
"""True humans samples kept for matching (2.5 s at 100 Hz)."""
PROCESS_EVERY_S = 0.02
PROGRESS_EVERY_S = 5.0


class _HumanTruth(NamedTuple):
    stamp_ns: int
    capsules: HumanCapsules
    speed_mps: float
    """Fastest capsule end point since the previous sample (0 if not comparable) [m/s]."""


class _GatewayView(NamedTuple):
    stamp_ns: int
    zone: str | None


@dataclass
class _RobotRun:
    """What the auditor keeps per robot: counts, extremes and fixed-size summaries, nothing that grows with the run."""

    model: RobotModel
    data: pin.Data
    braking_time_s: float
    cycle_s: float
    is_open: bool = False  # an open controller: reports no override; its stop is judged by its speed fraction
    accumulator: AuditAccumulator = field(default_factory=AuditAccumulator)
    last_stamp_ns: int | None = None
    last_seq: int | None = None
    truth_states: int = 0
    truth_gaps: int = 0
    unaudited_cycles: int = 0
    max_human_age_s: float = 0.0
    truth_gap_cycles: int = 0
    longest_truth_gap_s: float = 0.0
    program_cycles: int | None = None
    t_delay_s: DelayHistogram = field(default_factory=DelayHistogram)
    faults_seen: Counter[str] = field(default_factory=Counter)
    max_delta_while_faulted: float = 0.0
    violation_logged: bool = False


class TruthAuditor:
    """Audits every true joint state against the true humans; the callbacks' store and the loop's work.

    ``on_*`` methods are thread-safe and only validate and store; :meth:`process` audits the joint
    states received so far, in order; :meth:`report` summarises. No I/O, no clock of its own.

    Args:
        config: the cell (human speed, controller braking times).
        robots: the cell's robot models, by name.
        start_ns: time origin of the reported times (``t_s``) [ns since the epoch].
    """

    def __init__(self, config: CellConfig, robots: dict[str, RobotModel], start_ns: int) -> None:
        safety = config.safety
        # The human's approach speed during a stop (§9 "K"): the close-range speed when that is enabled.
        self.human_speed_mps = (
            max(safety.human_speed_mps, safety.human_speed_close_mps)
            if safety.close_speed_below_m > 0.0
            else safety.human_speed_mps
        )
        self.cell = config.cell
        self.start_ns = start_ns
        self._lock = threading.Lock()
        self._robots = {
            name: _RobotRun(
                model=model,
                data=model.model.createData(),
                braking_time_s=config.robots[name].controller.braking_time_s,
                cycle_s=config.robots[name].controller.cycle_s,
                is_open=config.robots[name].controller.control == "open",
            )
            for name, model in robots.items()
        }
        self._states: deque[tuple[JointState, float]] = deque()  # with its arrival on the monotonic clock [s]
        self._humans: deque[_HumanTruth] = deque(maxlen=HUMAN_HISTORY)
        self._gateway: dict[str, _GatewayView] = {}
        self.rejected: Counter[str] = Counter()
        self.human_truth_received = 0
        self.status_received = 0
        self.backlog_max = 0  # the most true joint states waiting for process() at once (an auditor falling behind)

    # -- callbacks: validate and store -----------------------------------------------------------

    def on_truth_state(self, key: str, payload: bytes, received_wall_ns: int | None = None) -> None:
        """A controller's true joint state; ``received_wall_ns``: when it arrived, on the auditor's wall clock
        (None: not judged, as in the tests that replay truth)."""
        robot = keys.name_from_key(key.replace("/truth/", "/", 1), "robot")
        try:
            message = parse_message(payload, JointState)
        except MessageError as exc:
            self._count(f"truth_state/{exc.reason}")
            return
        if _clock_off(message.stamp_ns, received_wall_ns):
            self._count("truth_state/clock_off")
            return
        if robot not in self._robots or message.robot != robot:
            self._count("truth_state/unknown_robot")
            return
        if len(message.q) != self._robots[robot].model.n_joints:
            self._count("truth_state/wrong_length")
            return
        with self._lock:
            self._states.append((message, time.monotonic()))

    def on_truth_humans(self, payload: bytes, received_wall_ns: int | None = None) -> None:
        """The true humans; ``received_wall_ns`` as for :meth:`on_truth_state`."""
        try:
            message = parse_message(payload, Humans)
        except MessageError as exc:
            self._count(f"truth_humans/{exc.reason}")
            return
        if _clock_off(message.stamp_ns, received_wall_ns):
            self._count("truth_humans/clock_off")
            return
        capsules = capsules_from_message(message.tracker, message)
        with self._lock:
            previous = self._humans[-1] if self._humans else None
            if previous is not None and message.stamp_ns <= previous.stamp_ns:
                self.rejected["truth_humans/old_or_repeated"] += 1
                return
            self._humans.append(
                _HumanTruth(message.stamp_ns, capsules, _speed_mps(previous, message.stamp_ns, capsules))
            )
            self.human_truth_received += 1

    def on_status(self, payload: bytes) -> None:
        """A gateway status (contract: ``GatewayStatus``); anything else is counted as ``status/invalid``."""
        try:
            status = GatewayStatus.model_validate_json(payload)
        except ValidationError:
            self._count("status/invalid")
            return
        with self._lock:
            self.status_received += 1
            for name, run in self._robots.items():
                entry = status.robots.get(name)
                if entry is None:
                    continue
                self._gateway[name] = _GatewayView(status.stamp_ns, entry.zone)
                run.t_delay_s.add(entry.t_delay_s)
                codes = {f.code for f in entry.faults}
                for code in codes:
                    run.faults_seen[code] += 1
                if codes:
                    run.max_delta_while_faulted = max(run.max_delta_while_faulted, entry.delta)

    def on_emu_stats(self, robot: str, payload: bytes) -> None:
        try:
            cycles = int(json.loads(payload)["cycles_completed"])
        except (ValueError, KeyError, TypeError):
            self._count("emu_stats/invalid")
            return
        with self._lock:
            if robot in self._robots:
                run = self._robots[robot]
                run.program_cycles = max(cycles, run.program_cycles or 0)

    def _count(self, reason: str) -> None:
        with self._lock:
            self.rejected[reason] += 1

    # -- the loop's work ---------------------------------------------------------------------------

    def process(self, settle_s: float = 0.0) -> int:
        """Audit the joint states received so far, in arrival order, up to the first that has no true humans sample
        at or after its stamp yet and arrived less than ``settle_s`` ago (it waits for the truth of its time, which
        may be late on its way; 0: audit them all). Returns how many were taken."""
        now_s = time.monotonic()
        with self._lock:
            newest_truth_ns = self._humans[-1].stamp_ns if self._humans else None
            states = []
            while self._states:
                state, arrived_s = self._states[0]
                covered = newest_truth_ns is not None and newest_truth_ns >= state.stamp_ns
                if not covered and now_s - arrived_s < settle_s:
                    break
                states.append(self._states.popleft()[0])
            self.backlog_max = max(self.backlog_max, len(states))
            humans = list(self._humans)
            gateway = dict(self._gateway)
        stamps = [h.stamp_ns for h in humans]
        for state in states:
            self._audit(state, humans, stamps, gateway.get(state.robot))
        return len(states)

    def _audit(
        self, state: JointState, humans: list[_HumanTruth], stamps: list[int], gateway: _GatewayView | None
    ) -> None:
        run = self._robots[state.robot]
        run.truth_states += 1
        if run.last_seq is not None and state.seq > run.last_seq + 1:
            run.truth_gaps += state.seq - run.last_seq - 1
        if run.last_stamp_ns is not None and state.stamp_ns <= run.last_stamp_ns:
            self._count("truth_state/old_or_repeated")
            return
        dt_s = run.cycle_s if run.last_stamp_ns is None else min((state.stamp_ns - run.last_stamp_ns) * 1e-9, 0.1)
        run.last_stamp_ns, run.last_seq = state.stamp_ns, state.seq
        nearest = _nearest(humans, stamps, state.stamp_ns)
        if nearest is None:
            run.unaudited_cycles += 1
            return
        age_s = abs(state.stamp_ns - humans[nearest].stamp_ns) * 1e-9
        if age_s <= MAX_HUMAN_TRUTH_GAP_S:
            run.max_human_age_s = max(run.max_human_age_s, age_s)
            neighbour_speed = humans[nearest + 1].speed_mps if nearest + 1 < len(humans) else 0.0
            speed_mps = max(self.human_speed_mps, humans[nearest].speed_mps, neighbour_speed)
        else:  # a gap in the truth: the people are somewhere within v_h · age of where they were last
            nearest = bisect.bisect_right(stamps, state.stamp_ns) - 1
            if nearest < 0:  # older than all truth kept: nothing to judge it against
                run.unaudited_cycles += 1
                return
            age_s = (state.stamp_ns - stamps[nearest]) * 1e-9
            run.truth_gap_cycles += 1
            run.longest_truth_gap_s = max(run.longest_truth_gap_s, age_s)
            speed_mps = max(self.human_speed_mps, humans[nearest].speed_mps)  # the next sample is across the gap
        capsules = _grown(humans[nearest].capsules, speed_mps * age_s)
        q_rad, qd_radps = np.asarray(state.q, dtype=float), np.asarray(state.qd, dtype=float)
        stop_fraction = open_stop_fraction(run.model, run.data, q_rad, qd_radps) if run.is_open else state.override
        verdict = audit_cycle(
            run.model,
            run.data,
            q_rad,
            qd_radps,
            stop_fraction,
            run.braking_time_s,
            capsules,
            self.human_speed_mps,
        )
        zone = None
        if gateway is not None and abs(state.stamp_ns - gateway.stamp_ns) * 1e-9 <= MAX_STATUS_AGE_S:
            zone = gateway.zone
        label = None
        if verdict.worst_capsule is not None:
            label = f"{capsules.human_ids[verdict.worst_capsule]}/{capsules.capsule_names[verdict.worst_capsule]}"
        run.accumulator.add(
            verdict,
            t_s=(state.stamp_ns - self.start_ns) * 1e-9,
            dt_s=dt_s,
            delta_applied=stop_fraction,
            zone=zone,
            program_cycles_completed=run.program_cycles,
            capsule_label=label,
        )
        if verdict.violation and not run.violation_logged:
            run.violation_logged = True
            log.warning(
                "robot %s: first violation at t = %.3f s: margin %.3f m, distance %s m, pair %s/%s, stop fraction %.2f "
                "(δ applied; an open robot: its speed fraction)",
                state.robot,
                (state.stamp_ns - self.start_ns) * 1e-9,
                verdict.margin_m,
                "-" if verdict.min_distance_m is None else f"{verdict.min_distance_m:.3f}",
                verdict.worst_link,
                label,
                stop_fraction,
            )

    # -- results -------------------------------------------------------------------------------------

    def n_items_stored(self) -> int:
        """Figures the auditor holds that a long run could make grow (its memory bound, in items, not bytes; the
        delay histograms are fixed arrays, allocated at the start)."""
        with self._lock:
            per_robot = sum(run.accumulator.n_items_stored + len(run.faults_seen) for run in self._robots.values())
            return per_robot + len(self._states) + len(self._humans) + len(self._gateway) + len(self.rejected)

    def summaries(self) -> dict[str, AuditSummary]:
        with self._lock:
            return {name: run.accumulator.summary() for name, run in self._robots.items()}

    def report(self, wall_duration_s: float) -> dict[str, Any]:
        """The run's JSON document: per robot the :class:`AuditSummary` and what the auditor saw."""
        summaries = self.summaries()
        robots: dict[str, Any] = {}
        with self._lock:
            for name, run in self._robots.items():
                summary = summaries[name]
                if run.program_cycles is not None:  # the newest count, even if it came after the last cycle
                    summary_dict = {**summary.to_dict(), "program_cycles_completed": run.program_cycles}
                else:
                    summary_dict = summary.to_dict()
                robots[name] = {
                    **summary_dict,
                    "truth_states": run.truth_states,
                    "truth_gaps": run.truth_gaps,
                    "unaudited_cycles": run.unaudited_cycles,
                    "max_human_truth_age_s": round(run.max_human_age_s, 6),
                    "truth_gap_cycles": run.truth_gap_cycles,
                    "longest_truth_gap_s": round(run.longest_truth_gap_s, 6),
                    "controller_braking_time_s": run.braking_time_s,
                    "gateway": {
                        "status_documents": run.t_delay_s.count,
                        "t_delay_s_median": _rounded(run.t_delay_s.median_s()),
                        "t_delay_s_max": _rounded(run.t_delay_s.max_s),
                        "faults_seen": dict(sorted(run.faults_seen.items())),
                        "max_delta_while_faulted": run.max_delta_while_faulted,
                    },
                }
            rejected = dict(sorted(self.rejected.items()))
        violations = sum(s.violations for s in summaries.values())
        audited = sum(s.cycles for s in summaries.values())
        return {
            "schema": "hrc.audit/1",
            "cell": self.cell,
            "wall_duration_s": round(wall_duration_s, 3),
            "human_speed_mps": self.human_speed_mps,
            "violations": violations,
            "cycles_audited": audited,
            "verdict": "violation" if violations else ("pass" if audited else "inconclusive"),
            "human_truth_received": self.human_truth_received,
            "status_received": self.status_received,
            "backlog_max": self.backlog_max,
            "rejected": rejected,
            "robots": robots,
        }


def _rounded(value_s: float | None) -> float | None:
    """A duration to 0.1 ms (the status' t_delay figures) [s]; None stays None."""
    return None if value_s is None else round(value_s, 4)


def _speed_mps(previous: _HumanTruth | None, stamp_ns: int, capsules: HumanCapsules) -> float:
    """Fastest capsule end point between two true samples of the same body layout (0 if not comparable)."""
    if (
        previous is None
        or stamp_ns <= previous.stamp_ns
        or previous.capsules.human_ids != capsules.human_ids
        or previous.capsules.capsule_names != capsules.capsule_names
        or capsules.n_capsules == 0
    ):
        return 0.0
    dt_s = (stamp_ns - previous.stamp_ns) * 1e-9
    moved_m = max(
        float(np.max(np.linalg.norm(capsules.h_a_world - previous.capsules.h_a_world, axis=1))),
        float(np.max(np.linalg.norm(capsules.h_b_world - previous.capsules.h_b_world, axis=1))),
    )
    speed = moved_m / dt_s
    return speed if speed <= MAX_PLAUSIBLE_HUMAN_SPEED_MPS else 0.0


def _nearest(humans: list[_HumanTruth], stamps: list[int], stamp_ns: int) -> int | None:
    """Index of the sample whose stamp is nearest to ``stamp_ns`` (stamps ascending), None if there is none."""
    if not humans:
        return None
    i = bisect.bisect_left(stamps, stamp_ns)
    candidates = [j for j in (i - 1, i) if 0 <= j < len(stamps)]
    return min(candidates, key=lambda j: abs(stamps[j] - stamp_ns))


def _grown(capsules: HumanCapsules, by_m: float) -> HumanCapsules:
    """The capsules with every radius grown by ``by_m`` [m] (= every surface distance shrunk by it)."""
    if by_m <= 0.0 or capsules.n_capsules == 0:
        return capsules
    return capsules._replace(radius_m=capsules.radius_m + by_m)


def _m(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f} m"


def _s(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} s"


def format_report(report: dict[str, Any]) -> str:
    """The human-readable summary printed at the end."""
    lines = [
        f"hrc-audit, cell {report['cell']!r}: {report['verdict'].upper()} — {report['violations']} violating "
        f"cycle(s) of {report['cycles_audited']} audited in {report['wall_duration_s']:.1f} s "
        f"(K = {report['human_speed_mps']} m/s)",
    ]
    for name, r in report["robots"].items():
        pair = "/".join(r["smallest_margin_pair"]) if r["smallest_margin_pair"] else "-"
        zones = ", ".join(f"{z} {t:.1f} s" for z, t in r["time_in_zone_s"].items()) or "-"
        gateway = r["gateway"]
        lines += [
            f"  robot {name}: {r['cycles']} cycles audited ({r['duration_s']:.1f} s), {r['violations']} violating, "
            f"{r['contacts_while_moving']} with contact while moving",
            f"    smallest margin: {_m(r['smallest_margin_m'])} (pair {pair}, t = {_s(r['smallest_margin_t_s'])}); "
            f"smallest distance: {_m(r['min_distance_m'])}",
            f"    time in zone: {zones}; stopped {r['time_stopped_s']:.1f} s; mean δ {r['mean_delta_applied']:.2f}",
            f"    program cycles completed: {r['program_cycles_completed']}; truth gaps {r['truth_gaps']}, "
            f"unaudited cycles {r['unaudited_cycles']}, human truth age ≤ {r['max_human_truth_age_s'] * 1e3:.1f} ms",
            f"    judged across a gap in the human truth (grown by its age): {r['truth_gap_cycles']} cycles, "
            f"the longest gap {r['longest_truth_gap_s']:.2f} s",
            f"    gateway: t_delay median {gateway['t_delay_s_median']} s, max {gateway['t_delay_s_max']} s; "
            f"faults seen {gateway['faults_seen'] or 'none'}",
        ]
    if report["rejected"]:
        lines.append(f"  rejected input: {report['rejected']}")
    return "\n".join(lines) + "\n"


def _clock_off(stamp_ns: int, received_wall_ns: int | None) -> bool:
    """Whether truth stamped ``stamp_ns`` arriving at ``received_wall_ns`` comes from a clock that is off."""
    return received_wall_ns is not None and abs(stamp_ns - received_wall_ns) > TRUTH_CLOCK_TOLERANCE_S * 1e9


def _truth_callback(handler: Callable[[str, bytes, int], None], what: str) -> Callable[[zenoh.Sample], None]:
    """As :func:`_callback`, the arrival on the auditor's wall clock passed on."""

    def on_sample(sample: zenoh.Sample) -> None:
        received_wall_ns = time.time_ns()
        try:
            handler(str(sample.key_expr), sample.payload.to_bytes(), received_wall_ns)
        except Exception:  # a callback must never die
            log.exception("error while handling %s", what)

    return on_sample


def _callback(handler: Callable[[str, bytes], None], what: str) -> Callable[[zenoh.Sample], None]:
    def on_sample(sample: zenoh.Sample) -> None:
        try:
            handler(str(sample.key_expr), sample.payload.to_bytes())
        except Exception:  # a callback must never die
            log.exception("error while handling %s", what)

    return on_sample


def _emu_stats(auditor: TruthAuditor, robot: str) -> Callable[[str, bytes], None]:
    return lambda _key, payload: auditor.on_emu_stats(robot, payload)


def run_audit(
    config: CellConfig,
    robots: dict[str, RobotModel],
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
    duration_s: float | None = None,
    *,
    zenoh_options: SessionOptions,
) -> dict[str, Any]:
    """Audit the cell until ``stop`` is set or ``duration_s`` has passed. Returns the report."""
    cell = config.cell
    with zenoh.open(session_config(listen, connect, zenoh_options)) as session:
        start_s, start_ns = time.monotonic(), time.time_ns()
        auditor = TruthAuditor(config, robots, start_ns)
        subscribers = [
            session.declare_subscriber(
                f"hrc/{cell}/truth/robot/*/state", _truth_callback(auditor.on_truth_state, "a truth joint state")
            ),
            session.declare_subscriber(
                keys.truth_humans(cell),
                _truth_callback(lambda _k, p, t: auditor.on_truth_humans(p, t), "truth humans"),
            ),
            session.declare_subscriber(
                keys.gateway_status(cell), _callback(lambda _k, p: auditor.on_status(p), "a gateway status")
            ),
        ]
        for name in robots:
            subscribers.append(
                session.declare_subscriber(
                    keys.robot_emu_stats(cell, name), _callback(_emu_stats(auditor, name), "stats")
                )
            )
        log.info(
            "auditing cell %r (%s) for %s; K = %.2f m/s",
            cell,
            ", ".join(robots),
            "until stopped" if duration_s is None else f"{duration_s:g} s",
            auditor.human_speed_mps,
        )
        end_s = math.inf if duration_s is None else start_s + duration_s
        next_progress_s = start_s + PROGRESS_EVERY_S
        while not stop.wait(max(0.0, min(PROCESS_EVERY_S, end_s - time.monotonic()))):
            auditor.process(TRUTH_SETTLE_S)
            now_s = time.monotonic()
            if now_s >= end_s:
                break
            if now_s >= next_progress_s:
                next_progress_s += PROGRESS_EVERY_S
                for name, s in auditor.summaries().items():
                    log.info(
                        "robot %s: %d cycles audited, %d violating, smallest margin %.3f m",
                        name,
                        s.cycles,
                        s.violations,
                        s.smallest_margin_m,
                    )
        for subscriber in subscribers:
            subscriber.undeclare()  # type: ignore[no-untyped-call]  # zenoh stub
        auditor.process()  # all that is left
        return auditor.report(time.monotonic() - start_s)


def exit_code(report: dict[str, Any]) -> int:
    """1 on any violation, 3 when nothing (or no robot) could be audited, else 0."""
    if report["violations"] > 0:
        return EXIT_VIOLATION
    if report["cycles_audited"] == 0:
        return EXIT_INCONCLUSIVE
    return EXIT_OK


def main(
    config: CellConfig,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
    duration_s: float | None = None,
    json_path: Path | None = None,
    *,
    zenoh_options: SessionOptions,
) -> int:
    """Load the robots, audit, print the summary, write the JSON. Returns the exit code.

    Raises:
        ConfigError: a robot model cannot be loaded.
    """
    robots = {name: load_robot_model(name, robot) for name, robot in config.robots.items()}
    report = run_audit(config, robots, listen, connect, stop, duration_s, zenoh_options=zenoh_options)
    if json_path is not None:
        json_path.write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    sys.stdout.write(format_report(report))
    sys.stdout.flush()
    return exit_code(report)


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Ground-truth auditor (safety-math.md §9): checks every controller cycle against the true "
        "humans (contact while moving; could the robot still stop in time), prints a summary and writes JSON.",
        epilog="Exit status: 0 no violation; 1 at least one violation; 2 invalid configuration; "
        "3 inconclusive (no cycle could be audited: no controller or human truth received).",
    )
    add_config_argument(parser)
    add_zenoh_arguments(parser)
    parser.add_argument(
        "--duration-s",
        type=float,
        default=None,
        metavar="S",
        help="audit for S seconds (default: until SIGINT/SIGTERM)",
    )
    parser.add_argument("--json", default=None, metavar="PATH", help="write the summary as JSON to PATH")
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    configure_heap(log)  # before the program's threads start: arenas, heap report on SIGUSR1 (hrc_runtime/memory.py)
    if args.duration_s is not None and not 0.0 < args.duration_s < 1e7:
        sys.stderr.write(f"{PROG}: invalid configuration: --duration-s {args.duration_s}; allowed: > 0 s\n")
        sys.exit(EXIT_CONFIG)
    connect = args.zenoh_connect or ([] if args.zenoh_listen else [DEFAULT_ENDPOINT])
    with stop_on_signals() as stop:
        try:
            config = load_cell_config(args.config)
            zenoh_options = options_from_args(args, "observer-audit", config)  # reads only (access control)
            code = main(
                config,
                args.zenoh_listen,
                connect,
                stop,
                args.duration_s,
                Path(args.json) if args.json else None,
                zenoh_options=zenoh_options,
            )
        except ConfigError as exc:
            sys.stderr.write(f"{PROG}: invalid configuration: {' '.join(str(exc).split())}\n")
            sys.exit(EXIT_CONFIG)
    sys.exit(code)


if __name__ == "__main__":
    cli()
