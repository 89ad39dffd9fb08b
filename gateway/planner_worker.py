"""The planner beside the safety loop: when to ask for a plan, who plans it, when to adopt it (paper 2, Alg. 1–2, (16)).

- :class:`Replanner` (one per open robot, called by the core every loop, pure apart from the backend it is given):
  every ``planner.check_every_s`` it checks the horizon of the trajectory the robot follows against the people
  (:func:`gateway.plan.horizon_check`); an infeasible configuration ahead, or the request (16) (δ below
  ``safety.replan_delta_below`` for ``safety.replan_after_s``), sends a :class:`gateway.planner.PlanRequest`; a
  returned plan is handed to :meth:`gateway.open_robot.OpenRobot.adopt`, which follows it only from where the robot is.
- :class:`ProcessPlanner`: the gateway's backend, its own process (planning takes 10–400 ms; the 250 Hz loop only
  submits and polls, never waits, and does not share the interpreter lock with it);
- :class:`ThreadedPlanner`: the same on a thread of the gateway's process (it takes the interpreter lock from the loop
  while it plans: for tools and tests).
- :class:`SimulatedPlanner`: the same interface, synchronous and deterministic, for the simulated cell.

A planner that is late, fails, never answers or returns a path through a person changes only productivity: the LPs
(9)/(13) bound every command whatever the task follows (tests/hrc_tools/sim/test_planner_cell.py shows it).
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import multiprocessing.connection
import multiprocessing.context
import multiprocessing.process
import multiprocessing.queues
import queue
import signal
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import numpy as np
import pinocchio as pin

from gateway import plan as plan_math
from gateway.open_robot import OpenRobot
from gateway.planner import JointPlanner, PlanOutcome, PlanRequest, warm_up
from hrc_contract.config import PlannerConfig
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.program import Trajectory

NS_PER_S = 1_000_000_000
PENDING_TIMEOUT_FACTOR = 10.0
"""A request unanswered after this many planner time limits counts as lost (``timeout``)."""
HANG_AFTER_S = 20.0
"""A planner process that has not answered its oldest request for this long is hung (a library stuck in a loop, a
deadlock): it is killed and started again like a dead one [s]. Far above any plan (0.1–0.4 s) and the process's
start (its imports: seconds on a busy machine)."""
RESTART_BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0)
"""A dead planner process is started again after these waits, one more step per death in a row (the last one
repeats) [s]."""
RESTART_STEADY_S = 30.0
"""A planner process that has run this long since its start counts as healthy again: the next death waits the first
step of :data:`RESTART_BACKOFF_S` [s]."""
DIED = "planner_died"
"""The failure of a request that was in flight when the planner process died."""
GOALS_PER_REQUEST = 1
"""Program waypoints offered as goals: the next one beyond the obstruction only (a later one would skip a station of
the task, a pick or a place, and count as production that was not done)."""


class PlannerHealth(NamedTuple):
    """A backend's own state, for the status.

    Attributes:
        running: it can plan now (false: a dead process waiting for its restart).
        deaths: times its process was found dead since the start.
        restarts: times its process was started again.
        last_exit: how the last dead process ended (``exit code 1``, ``signal SIGKILL``; empty before any death).
    """

    running: bool = True
    deaths: int = 0
    restarts: int = 0
    last_exit: str = ""


class PlannerBackend(Protocol):
    """Plans requests somewhere else: ``submit`` never blocks the loop; ``poll`` returns the answers so far."""

    def submit(self, request: PlanRequest) -> bool: ...

    def poll(self) -> list[PlanOutcome]: ...

    def health(self) -> PlannerHealth: ...

    def close(self) -> None: ...


class SimulatedPlanner:
    """Plans each request at once, in the caller's thread (the simulated cell: simulated time does not pass while it
    plans; deterministic for a seed). Its answers are returned by the next :meth:`poll`."""

    def __init__(self, planners: dict[str, JointPlanner]) -> None:
        self.planners = planners
        self._done: list[PlanOutcome] = []
        warm_up()

    def submit(self, request: PlanRequest) -> bool:
        self._done.append(self.planners[request.robot].solve(request))
        return True

    def poll(self) -> list[PlanOutcome]:
        done, self._done = self._done, []
        return done

    def health(self) -> PlannerHealth:
        return PlannerHealth()

    def close(self) -> None:
        self._done = []


class ThreadedPlanner:
    """Plans requests on its own daemon thread, one at a time in order of arrival; the loop submits and polls without
    waiting (each :class:`Replanner` keeps at most one request in flight). The thread starts at once and imports the
    libraries; a planner that raises gives a failed plan (``error:<exception>``), never a dead thread."""

    def __init__(self, planners: dict[str, JointPlanner]) -> None:
        self.planners = planners
        self._queue: queue.Queue[PlanRequest | None] = queue.Queue()
        self._done: list[PlanOutcome] = []
        self._lock = threading.Lock()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="hrc-planner", daemon=True)
        self._thread.start()  # it imports the libraries first (warm_up), before any request

    def submit(self, request: PlanRequest) -> bool:
        if self._closed:
            return False
        self._queue.put(request)
        return True

    def poll(self) -> list[PlanOutcome]:
        with self._lock:
            done, self._done = self._done, []
        return done

    def health(self) -> PlannerHealth:
        return PlannerHealth(running=self._thread.is_alive())

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._queue.put(None)
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        warm_up()
        while True:
            request = self._queue.get()
            if request is None:
                return
            try:
                outcome = self.planners[request.robot].solve(request)
            except Exception as exc:  # a planner crash is a failed plan, never a dead loop
                outcome = PlanOutcome(request.robot, None, f"error:{type(exc).__name__}", 0.0, request.start_key)
            with self._lock:
                self._done.append(outcome)


class ProcessPlanner:
    """Plans requests in a child process (``spawn``: no fork of a process that may hold a Zenoh session), one at a
    time in order of arrival. The gateway's default: a planner thread would share Python's interpreter lock with the
    250 Hz loop (measured: 30–50 ms late ticks while it plans), a process does not. Requests and plans cross as
    pickles (a few ms, on the queue's feeder thread and in :meth:`poll`). A request the child cannot plan comes back
    as a failed plan (``error:<exception>``).

    A child that dies (killed, out of memory, a crash in a library) is found by :meth:`poll` (every loop): counted,
    its requests in flight answered as failed (:data:`DIED`), and a new child started after a backoff
    (:data:`RESTART_BACKOFF_S`) on a thread of its own (spawning and pickling the planners does not hold up the
    loop), with a new queue and pipe (the dead child may have held the queue's lock). Until then :meth:`submit`
    refuses: the robot follows what it follows, the LPs bound every command as always. A child alive but silent on
    its oldest request for ``hang_after_s`` is hung: :meth:`poll` kills it, and it is buried and restarted as a dead
    one (``last_exit`` says ``hung``).
    """

    def __init__(
        self,
        planners: dict[str, JointPlanner],
        clock: Callable[[], float] = time.monotonic,
        hang_after_s: float = HANG_AFTER_S,
    ) -> None:
        # the plans come back holding TOPP-RA's trajectories: unpickling the first one would import toppra in the
        # loop's thread (~0.5 s late, measured end to end); import it here, at start-up
        warm_up()
        self._planners = planners
        self._clock = clock
        self._context = multiprocessing.get_context("spawn")
        self._closed = False
        self._lock = threading.Lock()
        self._child: _Child | None = _Child.start(self._context, planners, clock())
        self._in_flight: list[tuple[str, tuple[object, ...]]] = []
        """(robot, start key) of the requests sent to the current child and not yet answered, in order."""
        self._deaths = 0
        self._restarts = 0
        self._deaths_in_a_row = 0
        self._last_exit = ""
        self._restart_at_s: float | None = None
        self._starting: threading.Thread | None = None
        self._hang_after_s = hang_after_s
        self._head_since_s: float | None = None
        """Since when the oldest request in flight has waited for its answer (the child plans in order) [s]."""
        self._killed_hung = False

    @property
    def pid(self) -> int | None:
        """The planner process's id (None while it is being restarted)."""
        child = self._child
        return None if child is None else child.process.pid

    def submit(self, request: PlanRequest) -> bool:
        child = self._child
        if self._closed or child is None or not child.process.is_alive():
            return False
        child.requests.put(request)
        if not self._in_flight:
            self._head_since_s = self._clock()
        self._in_flight.append((request.robot, request.start_key))
        return True

    def poll(self) -> list[PlanOutcome]:
        done: list[PlanOutcome] = []
        child = self._child
        if child is None:
            self._restart_when_due()
            return done
        while True:
            try:
                if not child.answers.poll():
                    break
                outcome = child.answers.recv()
            except (EOFError, OSError):  # the child is gone (its end of the pipe closed), maybe in mid-answer
                break
            done.append(outcome)
            key = (outcome.robot, outcome.start_key)
            if key in self._in_flight:
                self._in_flight.remove(key)
                self._head_since_s = self._clock() if self._in_flight else None
        if not self._closed and not child.process.is_alive():
            done += self._buried(child)
        elif self._hung():
            child.process.kill()  # a signal, not a wait: buried by a later poll once it is gone
            self._killed_hung = True
        return done

    def _hung(self) -> bool:
        """The oldest request in flight has waited longer than ``hang_after_s`` (not asked again once killed)."""
        since = self._head_since_s
        return not self._killed_hung and since is not None and self._clock() - since > self._hang_after_s

    def health(self) -> PlannerHealth:
        return PlannerHealth(self._child is not None, self._deaths, self._restarts, self._last_exit)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        starting = self._starting
        if starting is not None:
            starting.join(timeout=10.0)
        with self._lock:
            child, self._child = self._child, None
        if child is not None:
            child.stop()

    def _buried(self, child: _Child) -> list[PlanOutcome]:
        """A dead child: counted, its requests in flight answered as failed, its restart scheduled."""
        now_s = self._clock()
        code = child.process.exitcode
        self._last_exit = _exit_text(code)
        if self._killed_hung:
            self._last_exit = f"hung (no answer in {self._hang_after_s:g} s), {self._last_exit}"
            self._killed_hung = False
        self._head_since_s = None
        self._deaths += 1
        self._deaths_in_a_row = 1 if now_s - child.started_s >= RESTART_STEADY_S else self._deaths_in_a_row + 1
        self._restart_at_s = now_s + restart_backoff_s(self._deaths_in_a_row)
        with self._lock:
            self._child = None
        child.stop()
        lost = [PlanOutcome(robot, None, DIED, 0.0, key) for robot, key in self._in_flight]
        self._in_flight = []
        return lost

    def _restart_when_due(self) -> None:
        """Start a new child on a thread once the backoff has passed (one start at a time)."""
        if self._closed or self._starting is not None or self._restart_at_s is None:
            return
        if self._clock() < self._restart_at_s:
            return
        self._restart_at_s = None
        self._starting = threading.Thread(target=self._start_child, name="hrc-planner-restart", daemon=True)
        self._starting.start()

    def _start_child(self) -> None:
        try:
            child = _Child.start(self._context, self._planners, self._clock())
        except Exception:  # a start that fails is tried again after the next backoff step
            self._deaths_in_a_row += 1
            self._restart_at_s = self._clock() + restart_backoff_s(self._deaths_in_a_row)
            self._starting = None
            return
        with self._lock:
            if self._closed:
                child.stop()
            else:
                self._child = child
                self._restarts += 1
        self._starting = None


@dataclass
class _Child:
    """One planner process and its two queues."""

    process: multiprocessing.process.BaseProcess
    requests: multiprocessing.queues.Queue[PlanRequest | None]
    answers: multiprocessing.connection.Connection
    """The answers' pipe, read end. Not a queue: its write end lives only in the child, so a child that dies in the
    middle of an answer gives an end of file here, never a read that waits for the rest for ever."""
    started_s: float

    @classmethod
    def start(
        cls, context: multiprocessing.context.SpawnContext, planners: dict[str, JointPlanner], now_s: float
    ) -> _Child:
        requests: multiprocessing.queues.Queue[PlanRequest | None] = context.Queue()
        answers, child_end = context.Pipe(duplex=False)
        process = context.Process(target=_serve, args=(planners, requests, child_end), name="hrc-planner", daemon=True)
        try:
            process.start()
        finally:
            child_end.close()  # the child has its own copy
        return cls(process, requests, answers, now_s)

    def stop(self) -> None:
        """Ask it to end, then terminate it; close the queues without waiting for their feeders."""
        if self.process.is_alive():
            with contextlib.suppress(Exception):  # a broken queue: terminated below
                self.requests.put(None)
            self.process.join(timeout=5.0)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=1.0)
        self.requests.cancel_join_thread()
        self.requests.close()
        self.answers.close()


def restart_backoff_s(in_a_row: int) -> float:
    """The wait before starting a planner process again after ``in_a_row`` (≥ 1) deaths or failed starts in a row:
    :data:`RESTART_BACKOFF_S`, its last step repeated [s]."""
    return RESTART_BACKOFF_S[min(max(in_a_row, 1), len(RESTART_BACKOFF_S)) - 1]


def _exit_text(code: int | None) -> str:
    """How a process ended, for people: ``exit code 1``, ``signal SIGKILL``."""
    if code is None:
        return "unknown"
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


def _serve(
    planners: dict[str, JointPlanner],
    requests: multiprocessing.queues.Queue[PlanRequest | None],
    answers: multiprocessing.connection.Connection,
) -> None:
    """The planner process: import the libraries, then plan each request until ``None``."""
    warm_up()
    while True:
        request = requests.get()
        if request is None:
            return
        try:
            outcome = planners[request.robot].solve(request)
        except Exception as exc:  # a planner crash is a failed plan
            outcome = PlanOutcome(request.robot, None, f"error:{type(exc).__name__}", 0.0, request.start_key)
        answers.send(outcome)


ANSWERS_KEPT = 8
"""The planner's last answer times a robot's join is judged by (the longest of them)."""


def join_lead_s(lead_s: float, last_feasible_s: float, delta: float, answer_s: float) -> float:
    """How far ahead on the trajectory (task time) a new path joins it [s].

    ``lead_s`` (``planner.join_lead_s``), but not beyond the last feasible configuration ahead (``last_feasible_s``):
    a plan that starts there starts outside the people's clearance. Yet never less than the task time the robot
    covers while the planner works (``delta`` × ``answer_s``, the planner's recent answer time; at most
    ``lead_s``): a join the robot passes before the answer comes back is rejected, and a robot already inside the
    clearance (last feasible 0) that creeps on at a small δ would otherwise have every plan rejected until it stops,
    then stand in a protective stop that no plan can lift. A join inside the clearance is what the planner's
    start-inside inflation is for; the scaling layer bounds the robot on its way there as everywhere.
    """
    least_s = min(max(delta, 0.0) * answer_s, lead_s)
    return max(min(lead_s, max(last_feasible_s, 0.0)), least_s)


def goal_candidates(
    trajectory: Trajectory, after_tau_s: float, count: int = GOALS_PER_REQUEST
) -> tuple[tuple[np.ndarray, float], ...]:
    """The next ``count`` program waypoints reached after program time ``after_tau_s`` (not wrapped): their joints and
    their arrival times (not wrapped) [rad, s]."""
    duration = trajectory.duration_s
    cycle = math.floor(after_tau_s / duration)
    out: list[tuple[np.ndarray, float]] = []
    for c in (cycle, cycle + 1, cycle + 2):
        for k, arrival in enumerate(trajectory.arrival_s):
            tau = c * duration + float(arrival)
            if tau > after_tau_s + 1e-9:
                out.append((np.array(trajectory.waypoints_rad[k], dtype=float), tau))
    out.sort(key=lambda g: g[1])
    return tuple(out[:count])


class PlanView(NamedTuple):
    """The planner layer of one robot at one decision, for the status (plain values, frozen).

    Attributes:
        following: the robot follows a plan (not its program).
        plan_time_s, plan_duration_s: where it is along the plan and the plan's length (None on the program) [s].
        path_waypoints: the planned piece's waypoints (None on the program).
        reason: why the current or last adopted plan was asked for (``horizon``, ``request``; empty before any).
        requests, failures: per reason, since the start.
        adopted, rejected: plans adopted, and returned too late or for another trajectory.
        planning_last_s: the planner's time for the latest answer (wall clock; None before any) [s].
        planning_total_s: the planner's time for all answers since the start (wall clock) [s].
        path_tool_world_m: the tool's positions along the plan followed (its
            :attr:`gateway.plan.Plan.tool_path_world_m`: made by the planner, not per status), world frame, shape
            (N, 3) (None on the program) [m].
        backend: the planner's own state (its process: running, deaths, restarts).
    """

    following: bool
    plan_time_s: float | None
    plan_duration_s: float | None
    path_waypoints: int | None
    reason: str
    requests: dict[str, int]
    adopted: int
    rejected: int
    failures: dict[str, int]
    planning_last_s: float | None
    planning_total_s: float = 0.0
    path_tool_world_m: np.ndarray | None = None
    backend: PlannerHealth = PlannerHealth()


@dataclass
class ReplannerStats:
    """What the planner layer did for one robot (the status and the bench read it)."""

    requests: Counter[str] = field(default_factory=Counter)
    """Requests sent, per reason (``horizon``, ``request``)."""
    adopted: int = 0
    rejected: int = 0
    """Plans returned too late (the robot had passed the join) or for another trajectory."""
    failures: Counter[str] = field(default_factory=Counter)
    planning_s: list[float] = field(default_factory=list)
    planning_total_s: float = 0.0
    last_reason: str = ""

    def to_dict(self) -> dict[str, object]:
        """A JSON-ready summary: requests per reason, adopted, rejected, failures per reason, planning time p50/p99/max
        (wall clock; None without answers) [s]."""
        times = np.asarray(self.planning_s, dtype=float)
        quantiles = np.quantile(times, [0.5, 0.99]) if times.size else (None, None)
        return {
            "requests": dict(self.requests),
            "adopted": self.adopted,
            "rejected": self.rejected,
            "failures": dict(self.failures),
            "planning_p50_s": None if quantiles[0] is None else float(quantiles[0]),
            "planning_p99_s": None if quantiles[1] is None else float(quantiles[1]),
            "planning_max_s": float(times.max()) if times.size else None,
        }


@dataclass
class Replanner:
    """Decides for one open robot when to ask for a plan and adopts the answers (see the module's docstring)."""

    name: str
    config: PlannerConfig
    human_speed_mps: float
    open_robot: OpenRobot
    data: pin.Data = field(init=False)
    stats: ReplannerStats = field(default_factory=ReplannerStats)
    pending: tuple[object, ...] | None = None
    """The start key of the request in flight (one at a time per robot)."""
    next_check_ns: int = 0
    quiet_until_ns: int = 0
    """No new request before this (after a failure or an adoption) [ns]."""
    count: int = 0
    pending_deadline_ns: int = 0
    request_after_s: float = 1.0
    """After a plan is adopted, the request (16) replans again only after this (``safety.replan_after_s``: δ must
    have stayed low on the new path as long as on the old one) [s]."""
    request_quiet_until_ns: int = 0
    pending_since_ns: int = 0
    answer_s: deque[float] = field(default_factory=lambda: deque(maxlen=ANSWERS_KEPT))
    """How long the last answers took, request to answer, on the loop's clock (a simulated cell's too) [s]."""

    def __post_init__(self) -> None:
        self.data = self.open_robot.robot.model.createData()

    def answer_time_s(self) -> float:
        """The longest of the last answers' times (``join_lead_s`` before the first) [s]."""
        return max(self.answer_s) if self.answer_s else self.config.join_lead_s

    def view(self, backend: PlannerHealth | None = None) -> PlanView:
        """What the status shows of this robot's planner layer now (``backend``: the planner's own state)."""
        plan = self.open_robot.plan
        new = None if plan is None else plan.new_path
        stats = self.stats
        path = None if plan is None else plan.tool_path_world_m
        return PlanView(
            plan is not None,
            None if plan is None else self.open_robot.plan_t_s,
            None if plan is None else plan.duration_s,
            None if new is None else len(new.waypoints_rad),
            stats.last_reason,
            dict(stats.requests),
            stats.adopted,
            stats.rejected,
            dict(stats.failures),
            stats.planning_s[-1] if stats.planning_s else None,
            stats.planning_total_s,
            path,
            PlannerHealth() if backend is None else backend,
        )

    def take(self, outcome: PlanOutcome, now_ns: int) -> None:
        """An answer from the backend: adopt its plan if the robot can still follow it from where it is."""
        if self.pending is not None and outcome.start_key == self.pending:
            self.pending = None
            self.answer_s.append(max(now_ns - self.pending_since_ns, 0) / NS_PER_S)
        self.stats.planning_s.append(outcome.planning_s)
        self.stats.planning_total_s += outcome.planning_s
        if outcome.plan is None:
            self.stats.failures[outcome.failure] += 1
            self.quiet_until_ns = now_ns + int(self.config.retry_after_s * NS_PER_S)
            return
        if self.open_robot.adopt(outcome.plan):
            self.stats.adopted += 1
            self.stats.last_reason = outcome.plan.reason
            self.request_quiet_until_ns = now_ns + int(self.request_after_s * NS_PER_S)
        else:
            self.stats.rejected += 1

    def cycle(
        self,
        now_ns: int,
        humans: HumanCapsules,
        request_16: bool,
        faulted: bool,
        resume_m: float,
        backend: PlannerBackend,
    ) -> None:
        """After the loop's command: check the horizon (every ``check_every_s``) and ask when it is blocked or the
        request (16) stands. Nothing while faulted (blind: nothing to plan around), or while a request is in flight.

        ``resume_m`` is this decision's resume distance (the zones' protective distance plus hysteresis): a robot
        nearer than it to anyone is held at δ = 0 by the zones, so a path is feasible only beyond it plus
        ``planner.clearance_m`` (the protective separation of paper 2's check)."""
        if self.pending is not None and now_ns >= self.pending_deadline_ns:
            self.pending = None  # a planner that never answers: give up on it and ask again later
            self.stats.failures["timeout"] += 1
        if faulted or self.pending is not None or now_ns < self.next_check_ns:
            return
        self.next_check_ns = now_ns + int(self.config.check_every_s * NS_PER_S)
        if now_ns < self.quiet_until_ns:
            return
        path, t_now_s, key = self.open_robot.path_now()
        plan = self.open_robot.plan
        t_end_s = plan.duration_s if plan is not None else math.inf
        growth_m = self.human_speed_mps * self.config.plan_growth_s
        clearance_m = resume_m + self.config.clearance_m
        if plan is not None:  # held to no more than it was planned with (it may have had to start near someone)
            clearance_m = min(clearance_m, plan.clearance_m - growth_m)
        verdict = plan_math.horizon_check(
            self.open_robot.robot,
            self.data,
            path,
            t_now_s,
            self.config.horizon_s,
            self.config.horizon_step_s,
            humans,
            self.human_speed_mps,
            clearance_m,
            t_end_s,
            self.config.plan_growth_s,
        )
        lead_s = join_lead_s(
            self.config.join_lead_s, verdict.last_feasible_t_s, self.open_robot.delta_prev, self.answer_time_s()
        )
        if plan is not None:
            lead_s = min(lead_s, max(t_end_s - t_now_s, 0.0))
        if verdict.infeasible_t_s is not None:
            reason = "horizon"
            t_join_s = t_now_s + lead_s
            obstruction_s = t_now_s + verdict.infeasible_t_s
        elif request_16 and humans.n_capsules and now_ns >= self.request_quiet_until_ns:
            reason = "request"
            t_join_s = t_now_s + lead_s
            obstruction_s = t_join_s
        else:
            return
        after_tau_s = plan.goal_tau_s - 1e-6 if plan is not None else obstruction_s
        goals = goal_candidates(self.open_robot.trajectory, after_tau_s)
        self.count += 1
        request = PlanRequest(
            self.name,
            path,
            t_now_s,
            t_join_s,
            goals,
            humans,
            resume_m + self.config.clearance_m + growth_m,
            (*key, t_now_s),
            reason,
            self.config.seed + self.count,
            self.open_robot.delta_prev,
        )
        if backend.submit(request):
            self.pending = request.start_key
            self.pending_since_ns = now_ns
            self.pending_deadline_ns = now_ns + int(PENDING_TIMEOUT_FACTOR * self.config.time_limit_s * NS_PER_S)
            self.stats.requests[reason] += 1
            # after this request, wait before the next (a plan needs time to take the robot away)
            self.quiet_until_ns = now_ns + int(self.config.retry_after_s * NS_PER_S)
