"""CPU scheduling of the gateway: the safety loop under SCHED_FIFO when allowed, the HTTP child niced; the loop's
timing (what each decision budgets until the next one) and the status built off the loop's thread."""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
import support.status_examples as ex
import zenoh
from pydantic import ValidationError
from support.paths import DEFAULT_CELL_PATH

from gateway import main as gateway_main
from gateway.capsules_json import human_capsules_json
from gateway.handoff import LatestJobThread
from gateway.http.server import NICENESS_INCREMENT, HttpServerProcess
from gateway.node import GatewayCycle, GatewayNode
from gateway.status import VALIDATE_CHUNK, effective_config, human_capsules
from hrc_contract import keys
from hrc_contract.config import CellConfig, GatewayConfig
from hrc_contract.humans import HumanCapsules
from hrc_contract.messages import Override, parse_message
from hrc_contract.status_models import GatewayStatus, HumanSeen
from hrc_runtime.clocks import Clocks, read_clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import PLAIN_TCP_LOOPBACK, session_config
from hrc_tools.cell.procs import free_port, load_scale, running_cell

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)


def _may_use_fifo() -> bool:
    try:
        os.sched_get_priority_max(os.SCHED_FIFO)
    except (AttributeError, OSError):
        return False
    return os.geteuid() == 0


def test_priority_range_is_validated() -> None:
    assert GatewayConfig().loop_realtime_priority == 0
    assert GatewayConfig(loop_realtime_priority=99).loop_realtime_priority == 99
    for bad in (-1, 100):
        with pytest.raises(ValidationError, match="loop_realtime_priority"):
            GatewayConfig(loop_realtime_priority=bad)


def test_refused_realtime_scheduling_warns_and_goes_on(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def refuse(pid: int, policy: int, param: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.WARNING, logger="hrc-gateway"):
        gateway_main._use_realtime_scheduling(10)
    assert "could not run the safety loop under SCHED_FIFO priority 10" in caplog.text


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_realtime_scheduling_applies_to_the_calling_thread_only() -> None:
    seen: dict[str, int] = {}

    def loop_thread() -> None:
        gateway_main._use_realtime_scheduling(7)
        seen["policy"] = os.sched_getscheduler(0)
        seen["priority"] = os.sched_getparam(0).sched_priority

    thread = threading.Thread(target=loop_thread)
    thread.start()
    thread.join()
    assert seen == {"policy": os.SCHED_FIFO, "priority": 7}
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # this (other) thread is unchanged


def test_http_child_lowers_its_cpu_priority(cell_config: CellConfig) -> None:
    http = HttpServerProcess("127.0.0.1", free_port(), effective_config(cell_config))
    try:
        pid = http._proc.pid
        expected = min(19, os.getpriority(os.PRIO_PROCESS, 0) + NICENESS_INCREMENT)
        deadline = time.monotonic() + 20.0 * load_scale()
        niceness = os.getpriority(os.PRIO_PROCESS, pid)
        while niceness != expected and time.monotonic() < deadline:
            time.sleep(0.05)
            niceness = os.getpriority(os.PRIO_PROCESS, pid)
        assert niceness == expected
    finally:
        http.close()


def test_input_priority_must_stay_below_the_loop() -> None:
    assert GatewayConfig(loop_realtime_priority=10, io_realtime_priority=9).io_realtime_priority == 9
    assert GatewayConfig(loop_realtime_priority=0, io_realtime_priority=0).io_realtime_priority == 0
    for loop, inputs in ((10, 10), (10, 11), (0, 5)):
        with pytest.raises(ValidationError, match="io_realtime_priority"):
            GatewayConfig(loop_realtime_priority=loop, io_realtime_priority=inputs)


class _Payload:
    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


class _Sample:
    def __init__(self, key: str, data: bytes) -> None:
        self.key_expr = key
        self.payload = _Payload(data)


class _RecordingNode:
    def __init__(self) -> None:
        self.messages: list[tuple[str, bytes, int, int]] = []

    def on_message(self, key: str, payload: bytes, received: object) -> None:
        self.messages.append((key, payload, os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_receiving_threads_put_themselves_under_fifo_below_the_loop() -> None:
    node = _RecordingNode()
    on_sample = gateway_main._callback(node, 4)  # type: ignore[arg-type]
    thread = threading.Thread(target=lambda: [on_sample(_Sample("k", b"m%d" % i)) for i in range(3)])  # type: ignore[arg-type]
    thread.start()
    thread.join()
    assert node.messages == [
        ("k", b"m0", os.SCHED_FIFO, 4),
        ("k", b"m1", os.SCHED_FIFO, 4),
        ("k", b"m2", os.SCHED_FIFO, 4),
    ]
    normal = gateway_main._callback(node, 0)  # type: ignore[arg-type]
    normal(_Sample("k", b"n"))  # type: ignore[arg-type]
    assert node.messages[-1] == ("k", b"n", os.SCHED_OTHER, 0)


def _thread_priorities(pid: int) -> list[tuple[int, int]]:
    """(policy, priority) of every thread of process ``pid``."""
    found = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            found.append((os.sched_getscheduler(int(task)), os.sched_getparam(int(task)).sched_priority))
        except OSError:  # the thread ended meanwhile
            continue
    return found


@pytest.mark.e2e
@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_running_gateway_has_its_loop_and_receiving_threads_under_fifo(tmp_path: Path) -> None:
    """The shipped cell: the loop at priority 10, the threads that received inputs and the HTTP feed thread at 5,
    every other at normal."""
    with running_cell(tmp_path) as cell:
        cell.wait_until(lambda s: s["delta"] > 0.0, 60.0, "the robot moving (inputs received)")
        priorities = _thread_priorities(cell.gateway.pid)
    fifo = sorted(p for policy, p in priorities if policy == os.SCHED_FIFO)
    assert fifo.count(10) == 1, priorities
    assert fifo.count(5) >= 2, priorities  # the HTTP feed thread and the receiving threads
    assert set(fifo) == {5, 10}, priorities
    assert any(policy == os.SCHED_OTHER for policy, _ in priorities), priorities


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_the_http_feed_thread_runs_under_fifo_when_asked(cell_config: CellConfig) -> None:
    for priority, policy in ((3, os.SCHED_FIFO), (0, os.SCHED_OTHER)):
        http = HttpServerProcess("127.0.0.1", free_port(), effective_config(cell_config), None, priority)
        try:
            native_id = http._writer.native_id
            assert native_id is not None
            deadline = time.monotonic() + 10.0 * load_scale()
            while os.sched_getscheduler(native_id) != policy and time.monotonic() < deadline:
                time.sleep(0.01)
            assert (os.sched_getscheduler(native_id), os.sched_getparam(native_id).sched_priority) == (policy, priority)
        finally:
            http.close()


# -- the loop's timing: the interval to the next decision, the status off the loop thread --------------------

MS = 1_000_000


def test_each_decision_budgets_the_longest_recent_interval_at_least_the_period() -> None:
    intervals = gateway_main.DecisionIntervals(0.004, window_s=1.0)
    starts_ms = [0, 4, 8, 20, 24, 28]  # a decision held up 8 ms (8 → 20)
    budgets_s = [intervals.start(t * MS) for t in starts_ms]
    assert budgets_s == pytest.approx([0.004, 0.004, 0.004, 0.012, 0.012, 0.012])
    # Shorter intervals (event cycles) never lower it below the worst within the window, nor below the period.
    assert intervals.start(29 * MS) == pytest.approx(0.012)
    # Once the 12 ms interval has left the window, the budget comes back down to what the loop takes now.
    t_ms = 29
    while t_ms < 20 + 1000 + 4:
        t_ms += 4
        budget_s = intervals.start(t_ms * MS)
    assert budget_s == pytest.approx(0.004)


def test_a_moving_decision_whose_successor_came_later_than_budgeted_is_an_overrun() -> None:
    intervals = gateway_main.DecisionIntervals(0.004)
    intervals.start(0)
    intervals.commanded(False)
    intervals.start(10 * MS)  # 10 ms after a decision with δ = 0 everywhere: late, but no motion was budgeted
    intervals.commanded(True)
    assert intervals.overruns == 0
    intervals.start(19 * MS)  # within the 10 ms budgeted
    intervals.commanded(True)
    assert intervals.overruns == 0
    intervals.start(33 * MS)  # 14 ms after a moving decision that budgeted 10 ms
    assert intervals.overruns == 1
    assert intervals.worst_overrun_s == pytest.approx(0.004)


def test_decision_intervals_refuse_a_period_or_window_that_is_not_positive() -> None:
    for period_s, window_s in ((0.0, 1.0), (0.004, 0.0), (-1.0, 1.0)):
        with pytest.raises(ValueError, match="allowed: > 0"):
            gateway_main.DecisionIntervals(period_s, window_s)


def _job(seq: int) -> gateway_main.StatusJob:
    return gateway_main.StatusJob(seq, ({}, {}), None, seq)  # type: ignore[arg-type]  # only carried through


def test_offering_a_status_never_waits_for_the_status_thread_and_the_newest_wins() -> None:
    started, release = threading.Event(), threading.Event()
    published: list[int] = []

    def publish(job: gateway_main.StatusJob) -> None:
        started.set()
        release.wait()
        published.append(job.stamp_ns)

    with gateway_main.StatusThread(publish) as status:
        status.offer(_job(1))
        assert started.wait(10.0)
        for seq in (2, 3, 4):  # the thread is stuck in publishing 1: each offer still returns
            status.offer(_job(seq))
        release.set()
        deadline = time.monotonic() + 10.0 * load_scale()
        while status.published < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert published == [1, 4]


def test_an_error_while_publishing_a_status_is_counted_and_the_thread_goes_on() -> None:
    published: list[int] = []

    def publish(job: gateway_main.StatusJob) -> None:
        if job.stamp_ns == 1:
            raise RuntimeError("boom")
        published.append(job.stamp_ns)

    with gateway_main.StatusThread(publish) as status:
        status.offer(_job(1))
        deadline = time.monotonic() + 10.0 * load_scale()
        while status.errors < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        status.offer(_job(2))
        while status.published < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert (status.errors, published) == (1, [2])


def awkward_capsules(count: int) -> HumanCapsules:
    """``count`` capsules with the values whose JSON could differ between serialisers: -0.0, 1e-4, whole numbers,
    large and tiny values rounded away, a number that is not finite, ids and names beyond ASCII and with quotes."""
    rng = np.random.default_rng(count)
    values = np.array([-0.0, 1e-4, 1.0, 12.3456789, -7.00004, 1e-9, 0.00015, np.nan, np.inf, 123456.78912])
    a = rng.choice(values, size=(count, 3))
    b = rng.uniform(-20.0, 20.0, size=(count, 3))
    radius = rng.choice(np.array([0.0, 0.06, 0.1234567, 2.5]), size=count)
    ids = tuple(f"front/h{k // 15}" if k % 7 else f'säde/"ß\\{k // 15}' for k in range(count))
    odd = ("käsi \u2603 \t", '","', '"', "\\", '\\"', "],[", "\x00")  # quotes, commas, brackets, escapes
    names = tuple(f"part{k % 15}" if k % 5 else f"{odd[k % len(odd)]}{k % 15}" for k in range(count))
    return HumanCapsules(a, b, radius, ids, names)


@pytest.mark.parametrize("count", [0, 1, 3, VALIDATE_CHUNK + 1, 4000])
def test_the_status_line_with_capsules_serialised_apart_is_the_documents_json(count: int) -> None:
    """The status thread's path (a document built without its capsules, the capsules serialised without models) gives
    the bytes of the whole document's ``model_dump_json`` with the capsules validated by the models."""
    capsules = awkward_capsules(count)
    doc = ex.gateway_status(ur5=ex.near_robot_status())
    whole = doc.model_copy(update={"human_capsules": human_capsules(capsules)})
    line = gateway_main.status_json(doc, {"human_capsules": human_capsules_json(capsules)})
    assert line == whole.model_dump_json().encode()
    assert len(GatewayStatus.model_validate_json(line).human_capsules) == count
    assert gateway_main.status_json(whole) == whole.model_dump_json().encode()
    if count:
        with pytest.raises(ValueError, match="has its own"):
            gateway_main.status_json(whole, {"human_capsules": human_capsules_json(capsules)})


def test_lists_serialised_apart_go_in_their_places_in_order_and_never_over_entries_of_the_document() -> None:
    capsules = awkward_capsules(3)
    doc = ex.gateway_status(ur5=ex.near_robot_status())
    humans = [{"id": 'front/"a"', "tracker": "front", "capsules": 3}]
    whole = doc.model_copy(update={"human_capsules": human_capsules(capsules), "humans": [HumanSeen(**humans[0])]})
    parts = {"human_capsules": human_capsules_json(capsules), "humans": msgspec.json.encode(humans)}
    assert gateway_main.status_json(doc, parts) == whole.model_dump_json().encode()
    with pytest.raises(ValueError, match="humans given for a document that has its own"):
        gateway_main.status_json(whole.model_copy(update={"human_capsules": []}), parts)


STALL_S = 0.05
"""One iteration of the loop is held up this long after its overrides went out."""

GIVE_UP_AFTER_CYCLES = 2500
"""The loop of the test stops after this many decisions (10 s at 250 Hz) if it has not seen its statuses by then."""


class _Publisher:
    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.payloads.append(payload)


class _Http:
    """The HTTP child's side the loop and the status thread use; the first exit check stalls (after publishing)."""

    def __init__(self) -> None:
        self.lines: list[bytes] = []
        self.checks = 0

    def offer(self, line: bytes) -> None:
        self.lines.append(line)

    def offer_events(self, events: object) -> None:
        pass

    def exit_code(self) -> int | None:
        self.checks += 1
        if self.checks == 1:
            time.sleep(STALL_S)
        return None


class _TimedNode:
    """A gateway node that records when each decision started and what it budgeted until the next one."""

    def __init__(self, node: GatewayNode) -> None:
        self._node = node
        self.starts_ns: list[int] = []
        self.budgets_s: list[float] = []

    def cycle(self, now: Clocks, period_s: float) -> GatewayCycle:
        self.starts_ns.append(now.mono_ns)
        self.budgets_s.append(period_s)
        return self._node.cycle(now, period_s)

    def __getattr__(self, name: str) -> object:
        return getattr(self._node, name)


class _RecordingStatusThread(gateway_main.StatusThread):
    def __init__(self, publish: Callable[[gateway_main.StatusJob], None]) -> None:
        self.offered: list[gateway_main.StatusJob] = []
        self.publishing_threads: set[str] = set()

        def recorded(job: gateway_main.StatusJob) -> None:
            self.publishing_threads.add(threading.current_thread().name)
            publish(job)

        super().__init__(recorded)

    def offer(self, job: gateway_main.StatusJob) -> None:
        self.offered.append(job)
        super().offer(job)


def test_the_loop_budgets_what_it_really_took_and_publishes_the_status_off_its_thread(cell_config: CellConfig) -> None:
    """The real loop and node, fake outputs: a hold-up after publishing (the first check of the HTTP child, at
    the first status) is budgeted by every later decision, counted in compute_max_s, and no document is built or
    serialised on the loop's thread."""
    node = _TimedNode(gateway_main.build_node(cell_config, None))
    http, status_key = _Http(), _Publisher()
    sink = gateway_main._StatusSink(cell_config, node.robots, status_key, http)  # type: ignore[arg-type]
    stop = StopEvent()
    status_thread = _RecordingStatusThread(sink.publish)

    class _StopAfterStatuses(_Publisher):
        def put(self, payload: bytes) -> None:
            super().put(payload)
            enough = len(status_thread.offered) >= 4 and status_thread.published >= 2
            if enough or len(self.payloads) >= GIVE_UP_AFTER_CYCLES:  # the assertions below tell which
                stop.set()

    out = gateway_main._Outputs({"ur5": _StopAfterStatuses()}, http, status_thread)  # type: ignore[arg-type]
    with status_thread:
        assert gateway_main._loop(cell_config, node, out, stop, None) == 0  # type: ignore[arg-type]

    starts_ns = np.array(node.starts_ns)
    intervals_s = np.diff(starts_ns) / 1e9
    assert intervals_s.max() >= STALL_S  # the hold-up happened between two decisions
    period_s = 1.0 / cell_config.gateway.rate_hz
    for k, budget_s in enumerate(node.budgets_s):
        worst_so_far_s = intervals_s[:k].max() if k else 0.0  # the run is shorter than the window
        assert budget_s >= max(period_s, worst_so_far_s) - 1e-9, k
    assert max(job.loop.compute_max_s for job in status_thread.offered) >= STALL_S
    assert status_thread.publishing_threads == {"hrc-status"}
    assert threading.current_thread().name != "hrc-status"
    docs = [json.loads(line) for line in status_key.payloads]
    assert len(docs) >= 2
    assert all(doc["loop"]["budget_overruns"] == 0 for doc in docs)
    assert http.lines == [line + b"\n" for line in status_key.payloads]


def test_overrides_are_published_with_congestion_control_block(cell_config: CellConfig) -> None:
    """An override that lowers δ must reach the controller: never dropped on a full queue."""
    with zenoh.open(session_config(listen=[f"tcp/127.0.0.1:{free_port()}"])) as session:
        publishers = gateway_main._declare_overrides(session, cell_config)
        assert set(publishers) == set(cell_config.robots)
        for publisher in publishers.values():
            assert publisher.congestion_control == zenoh.CongestionControl.BLOCK
            assert publisher.priority == zenoh.Priority.REAL_TIME


GIVE_UP_S = 10.0
"""A test's congested link gives up waiting after this long (only when the loop is held: the test then fails)."""

DECISIONS_WHILE_BLOCKED = 50
"""The free robot's overrides put while the other robot's put waits, before the test ends that wait."""


class _CongestedPublisher(_Publisher):
    """A congested link: the first put waits until :attr:`released` (at most :data:`GIVE_UP_S`)."""

    def __init__(self) -> None:
        super().__init__()
        self.waiting = False
        self.entered = threading.Event()
        self.released = threading.Event()

    def put(self, payload: bytes) -> None:
        super().put(payload)
        if len(self.payloads) == 1:
            self.waiting = True
            self.entered.set()
            self.released.wait(GIVE_UP_S)
            self.waiting = False


def _overrides(payloads: list[bytes]) -> list[Override]:
    return [parse_message(payload, Override) for payload in payloads]


def test_a_congested_robot_link_never_holds_the_loop_or_the_other_robots_overrides() -> None:
    """Two robots; the first one's put waits (its link congested): the loop goes on deciding and the second robot
    gets its overrides meanwhile; once the link clears, the first robot gets the newest override (the ones decided
    meanwhile were replaced, never queued); on stop both get δ = 0 as the last word."""
    config = load_cell_config(DEFAULT_CELL_PATH.parent / "cell_two_arms.toml")
    congested_name, free_name = list(config.robots)  # the congested robot's override is offered first
    node = gateway_main.build_node(config, None)
    stop = StopEvent()
    congested = _CongestedPublisher()

    class _Free(_Publisher):
        """Ends the congestion after DECISIONS_WHILE_BLOCKED puts meanwhile, stops the loop some puts later."""

        def __init__(self) -> None:
            super().__init__()
            self.while_blocked: list[bytes] = []

        def put(self, payload: bytes) -> None:
            super().put(payload)
            if congested.waiting:
                self.while_blocked.append(payload)
                if len(self.while_blocked) >= DECISIONS_WHILE_BLOCKED:
                    congested.released.set()
            if len(self.payloads) >= len(self.while_blocked) + DECISIONS_WHILE_BLOCKED or (
                len(self.payloads) >= GIVE_UP_AFTER_CYCLES  # the assertions below tell which
            ):
                stop.set()

    free = _Free()
    status_thread = gateway_main.StatusThread(lambda job: None)
    out = gateway_main._Outputs({congested_name: congested, free_name: free}, _Http(), status_thread)  # type: ignore[arg-type]
    with status_thread:
        assert gateway_main._loop(config, node, out, stop, None) == 0
        last = node.stop_overrides(read_clocks())
        out.last_word(last)

    assert congested.entered.is_set()
    held = _overrides(free.while_blocked)
    assert len(held) >= DECISIONS_WHILE_BLOCKED  # the free robot's overrides went on while the other put waited
    assert [o.seq for o in held] == sorted({o.seq for o in held})  # each from its own decision, in order
    first, *later = _overrides(congested.payloads)
    assert held[0].seq >= first.seq
    assert later[0].seq >= held[DECISIONS_WHILE_BLOCKED - 1].seq  # the newest at the release, not the next one
    assert [o.seq for o in later] == sorted({o.seq for o in later})
    for publisher, name in ((congested, congested_name), (free, free_name)):  # the last word: δ = 0, last seq
        assert _overrides(publisher.payloads)[-1] == last[name]
        assert last[name].delta == 0.0


def test_the_last_word_is_put_to_every_controller_and_waits_a_bounded_time_for_a_congested_one() -> None:
    congested, free = _CongestedPublisher(), _Publisher()
    senders = gateway_main.OverrideSenders({"a": congested, "b": free})
    stamp = time.time_ns()
    senders.offer({name: Override(robot=name, seq=1, stamp_ns=stamp, delta=0.5) for name in ("a", "b")})
    assert congested.entered.wait(GIVE_UP_S)
    last = {name: Override(robot=name, seq=2, stamp_ns=stamp + 1, delta=0.0) for name in ("a", "b")}
    late = senders.last_word(last)  # "a" still waits: its put of seq 1 holds its sender
    assert late == ["a"]
    assert _overrides(free.payloads)[-1] == last["b"]  # put before last_word returned
    congested.released.set()  # the link clears: the last word follows the put under way
    deadline = time.monotonic() + GIVE_UP_S * load_scale()
    while len(congested.payloads) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert _overrides(congested.payloads) == [
        Override(robot="a", seq=1, stamp_ns=stamp, delta=0.5),
        last["a"],
    ]


def test_the_last_job_replaces_one_not_taken_and_follows_the_one_under_way() -> None:
    started, release = threading.Event(), threading.Event()
    done: list[int] = []

    def work(job: int) -> None:
        if job == 1:
            started.set()
            release.wait(GIVE_UP_S)
        done.append(job)

    worker = LatestJobThread[int](work, "test-worker", "working", logging.getLogger("test"))
    worker.offer(1)
    assert started.wait(GIVE_UP_S)
    worker.offer(2)
    worker.offer_last(3)  # replaces 2, not yet taken
    assert not worker.close(0.0)  # 1 still under way
    release.set()
    assert worker.close(GIVE_UP_S)
    assert done == [1, 3]


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_override_senders_run_under_fifo_at_the_io_priority() -> None:
    seen: list[tuple[int, int]] = []

    class _Scheduling:
        def put(self, payload: bytes) -> None:
            seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

    senders = gateway_main.OverrideSenders({"a": _Scheduling()}, realtime_priority=4)
    assert senders.last_word({"a": Override(robot="a", seq=0, stamp_ns=1, delta=0.0)}) == []
    assert seen == [(os.SCHED_FIFO, 4)]


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_the_status_thread_runs_under_fifo_at_the_io_priority() -> None:
    """It takes the interpreter lock to build each document: at normal scheduling another program could deschedule
    it while it held the lock, and the loop waited (``blocked`` stalls on a quiet machine)."""
    for priority, policy in ((4, os.SCHED_FIFO), (0, os.SCHED_OTHER)):
        seen: list[tuple[int, int]] = []

        def publish(job: object, seen: list[tuple[int, int]] = seen) -> None:
            seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

        status = gateway_main.StatusThread(publish, priority)
        status.offer_last(object())  # type: ignore[arg-type]
        assert status.close(GIVE_UP_S)
        assert seen == [(policy, priority)]


@pytest.mark.e2e
def test_the_gateway_shell_opens_its_resources_runs_and_closes_them_with_the_last_word_first(
    tmp_path: Path, cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``run_gateway`` in process over a real Zenoh session: it serves the status on HTTP and publishes overrides
    (δ = 0: no inputs); on stop every robot gets a last override stamped after the stop, the event log ends with
    ``stop`` ("stop requested"), the HTTP server is gone and the exit code is 0; the closing order is the last word
    (δ = 0 to every robot), the status thread, the event, the HTTP server."""
    closed: list[str] = []
    for cls, name in (
        (gateway_main._Outputs, "last_word"),
        (gateway_main.StatusThread, "close"),
        (HttpServerProcess, "close"),
    ):
        original = getattr(cls, name)

        def spy(self: Any, *args: Any, _original: Any = original, _name: str = f"{cls.__name__}.{name}") -> Any:
            if _name == "_Outputs.last_word":
                _name += str(sorted((robot, m.delta) for robot, m in args[0].items()))
            closed.append(_name)
            return _original(self, *args)

        monkeypatch.setattr(cls, name, spy)
    endpoint, http_port = f"tcp/127.0.0.1:{_free_port()}", _free_port()
    events_log = tmp_path / "events.jsonl"
    node = gateway_main.build_node(cell_config, None)
    stop = StopEvent()
    code: list[int] = []
    gateway = threading.Thread(
        target=lambda: code.append(
            gateway_main.run_gateway(
                cell_config,
                node,
                [endpoint],
                [],
                "127.0.0.1",
                http_port,
                stop,
                zenoh_options=PLAIN_TCP_LOOPBACK,
                events_log=events_log,
            )
        ),
        daemon=True,
    )
    received: list[Override] = []
    with zenoh.open(session_config([], [endpoint], PLAIN_TCP_LOOPBACK)) as session:
        keys_of_robots = [keys.robot_override(cell_config.cell, name) for name in cell_config.robots]
        subscribers = [
            session.declare_subscriber(k, lambda s: received.append(parse_message(s.payload.to_bytes(), Override)))
            for k in keys_of_robots
        ]
        gateway.start()
        deadline_s = time.monotonic() + 30.0 * load_scale()
        while not (received and _http_answers(http_port)) and time.monotonic() < deadline_s:
            time.sleep(0.05)
        assert received, "no override published"
        assert _http_answers(http_port), "no status served"
        stopped_ns = time.time_ns()
        stop.set()
        gateway.join(30.0 * load_scale())
        assert not gateway.is_alive(), "the gateway did not stop"
        time.sleep(0.2)  # the last word's delivery
        del subscribers
    assert code == [0]
    last_words = {m.robot: m for m in received if m.stamp_ns >= stopped_ns}
    assert set(last_words) == set(cell_config.robots), [(m.robot, m.stamp_ns, m.delta) for m in received[-5:]]
    assert all(m.delta == 0.0 for m in last_words.values())
    events = [json.loads(line) for line in events_log.read_text().splitlines()]
    assert [e["kind"] for e in events[:2]] == ["start", "config_loaded"]
    assert events[-1]["kind"] == "stop", events[-1]
    assert "stop requested" in events[-1]["message"], events[-1]
    assert not _http_answers(http_port)
    assert closed == [
        "_Outputs.last_word" + str(sorted((robot, 0.0) for robot in cell_config.robots)),
        "StatusThread.close",
        "HttpServerProcess.close",
    ]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _http_answers(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/status", timeout=1.0) as response:
            return bool(response.status == 200)
    except OSError:
        return False
