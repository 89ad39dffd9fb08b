"""What the operator sees over HTTP: the page at ``/``, the capsules in the status, the event log, the metrics,
and the status stream of the real HTTP child (which must end its streams when the gateway stops)."""

from __future__ import annotations

import io
import json
import re
import shutil
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import httpx
import numpy as np
import pytest
import support.status_examples as ex
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from gateway.core import ClosestPair, RobotDecision
from gateway.delay import DelayBudget
from gateway.events import EventLog
from gateway.http.api import StatusBoard, create_app
from gateway.http.server import EVENT_PREFIX, _feed
from gateway.link_ends import LinkEnds
from gateway.status import effective_config, human_capsules, robot_status
from gateway.tracks import TrackEvent
from gateway.zones import ZoneThresholds
from hrc_contract.config import CellConfig
from hrc_contract.humans import HumanCapsules
from hrc_contract.status_models import EventsResponse, Fault, GatewayStatus, LoopStatus, TrackStateName, TrackStatus
from hrc_contract.vocabulary import Zone
from hrc_tools.cell.procs import free_port, wait_for


@pytest.fixture
def board(cell_config: CellConfig) -> StatusBoard:
    return StatusBoard(effective_config(cell_config))


@pytest.fixture
def client(board: StatusBoard) -> TestClient:
    return TestClient(create_app(board))


def decision_with_links() -> RobotDecision:
    ends_a = np.array([[0.0, 0.0, 0.8], [0.0, 0.1, 1.2]])
    ends_b = np.array([[0.0, 0.1, 1.2], [0.4, 0.123456789, 1.2]])
    return RobotDecision(
        "ur5",
        Zone.REDUCED_SPEED,
        0.6,
        0.6,
        1.2,
        ClosestPair("front/h1", "hand_r", "tool"),
        DelayBudget(0.04, 0.03, 0.004, 0.012, 0.004, 0.004),
        1.0,
        ZoneThresholds(1.0, 1.1, 1.9, 2.4),
        (),
        {"joint_state": 0.004},
        "running",
        False,
        0.55,
        LinkEnds(ends_a, ends_b),
    )


def test_the_status_carries_the_link_capsules_of_the_decision() -> None:
    entry = robot_status(decision_with_links(), 7, ("upper_arm", "tool"), np.array([0.08, 0.07]))
    assert [(c.name, c.radius_m) for c in entry.links] == [("upper_arm", 0.08), ("tool", 0.07)]
    assert entry.links[1].a_m == [0.0, 0.1, 1.2]
    assert entry.links[1].b_m == [0.4, 0.1235, 1.2], "rounded to 0.1 mm"
    assert robot_status(decision_with_links(), 7).links == [], "no names: no capsules"
    assert robot_status(decision_with_links()._replace(links=None), 7, ("a", "b"), (0.1, 0.1)).links == []


def test_the_status_carries_every_human_capsule() -> None:
    capsules = HumanCapsules(
        np.array([[2.0, 0.0, 1.0], [2.0, 0.2, 1.0]]),
        np.array([[2.0, 0.0, 1.5], [2.3, 0.2, 1.0]]),
        np.array([0.15, 0.05]),
        ("front/h1", "front/h1"),
        ("torso", "hand_r"),
    )
    drawn = human_capsules(capsules)
    assert [(c.human, c.name, c.b_m, c.radius_m) for c in drawn] == [
        ("front/h1", "torso", [2.0, 0.0, 1.5], 0.15),
        ("front/h1", "hand_r", [2.3, 0.2, 1.0], 0.05),
    ]
    doc = ex.gateway_status(ur5=robot_status(decision_with_links(), 7, ("upper_arm", "tool"), (0.08, 0.07)))
    doc = doc.model_copy(update={"human_capsules": drawn})
    assert GatewayStatus.model_validate_json(doc.model_dump_json()) == doc, "the document round-trips"


def test_the_operator_page_is_served_whole_with_nothing_from_outside(client: TestClient) -> None:
    response = client.get("/")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/html")
    page = response.text
    assert "/api/v1/stream" in page
    assert "/api/v1/events" in page
    assert "STALE" in page
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", page), "no resource from another host"
    assert "<script src" not in page, "no script file to fetch: one file works offline"


def test_events_are_served_after_a_seq(board: StatusBoard, client: TestClient) -> None:
    log = EventLog()
    for event in log.started(1, "demo", "c" * 64) + log.stopped(2, "stop requested"):
        board.events.add(event)
    body = EventsResponse.model_validate_json(client.get("/api/v1/events").content)
    assert [e.kind for e in body.events] == ["start", "config_loaded", "stop"]
    assert body.last_seq == 3
    later = EventsResponse.model_validate_json(client.get("/api/v1/events", params={"since": 2}).content)
    assert [e.seq for e in later.events] == [3]
    assert client.get("/api/v1/events", params={"since": -1}).status_code == 422


def test_the_http_child_takes_event_lines_into_the_log(board: StatusBoard) -> None:
    events = EventLog().started(1, "demo", "d" * 64)
    lines = b"".join(EVENT_PREFIX + e.model_dump_json(exclude_none=True).encode() + b"\n" for e in events)
    status = ex.gateway_status(ur5=ex.robot_status(delta=0.5)).model_dump_json().encode() + b"\n"
    server = SimpleNamespace(should_exit=False)
    _feed(board, io.BytesIO(lines + status), server)  # type: ignore[arg-type]
    assert [e.seq for e in board.events.since(0, 10)[0]] == [1, 2]
    published, _ = board.latest()
    assert published is not None
    assert published.status.robots["ur5"].delta == 0.5
    assert board.closed, "end of input ends the streams"


def metric_samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def loop_after(previous: LoopStatus, ticks: int, compute_s: float, periods_s: list[float] | None = None) -> LoopStatus:
    return previous.model_copy(
        update={
            "tick_cycles": previous.tick_cycles + ticks,
            "cycles": previous.cycles + ticks,
            "compute_max_s": compute_s,
            "tick_periods_s": [0.004] * ticks if periods_s is None else periods_s,
        }
    )


def test_metrics_parse_and_show_the_status(board: StatusBoard, client: TestClient) -> None:
    first = ex.gateway_status(ur5=ex.near_robot_status(delta=0.62))
    stale = Fault(code="tracker_stale", reason="old")
    second = first.model_copy(
        update={
            "stamp_ns": first.stamp_ns + 40_000_000,
            "loop": loop_after(first.loop, 10, 0.0025),
            "robots": {"ur5": ex.robot_status(faults=[stale])},
            "inputs": first.inputs.model_copy(
                update={"received": {"robot/ur5": 279}, "rejected": {"tracker/front": {"stale": 3}}}
            ),
        }
    )
    board.publish(first)
    board.publish(second)
    response = client.get("/metrics")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain")
    samples = metric_samples(response.text)
    robot = (("robot", "ur5"),)
    assert samples[("hrc_robot_delta_ratio", robot)] == 0.0
    assert samples[("hrc_robot_zone", (("robot", "ur5"), ("zone", "safety_exception")))] == 1.0
    assert samples[("hrc_robot_zone", (("robot", "ur5"), ("zone", "autonomous")))] == 0.0
    assert samples[("hrc_robot_delay_part_seconds", (("part", "t_reaction"), ("robot", "ur5")))] == 0.04
    assert samples[("hrc_robot_faults_active", (("code", "tracker_stale"), ("robot", "ur5")))] == 1.0
    assert samples[("hrc_faults_raised_total", (("code", "tracker_stale"), ("robot", "ur5")))] == 1.0
    assert samples[("hrc_inputs_received_total", (("topic", "robot/ur5"),))] == 279
    assert samples[("hrc_inputs_rejected_total", (("reason", "stale"), ("topic", "tracker/front")))] == 3
    assert samples[("hrc_loop_missed_cycles_total", ())] == second.loop.missed_cycles
    # Each of the 10 tick periods observed: 4 ms, the configured period: within 1 % of it.
    assert samples[("hrc_loop_period_seconds_count", ())] == 10
    assert samples[("hrc_loop_period_seconds_bucket", (("le", "0.00404"),))] == 10
    assert samples[("hrc_loop_period_seconds_bucket", (("le", "0.00396"),))] == 0
    assert samples[("hrc_loop_compute_max_seconds_count", ())] == 2
    assert samples[("hrc_loop_compute_max_seconds_bucket", (("le", "0.002"),))] == 1, "2.5 ms is above 2 ms"


def test_faults_present_in_the_first_status_are_counted_as_raised(board: StatusBoard, client: TestClient) -> None:
    """The gateway starts with faults (no data yet): the child's first document already has them."""
    missing = [Fault(code="joint_state_missing", reason="none yet"), Fault(code="tracker_missing", reason="none")]
    first = ex.gateway_status(ur5=ex.robot_status(faults=missing))
    board.publish(first)
    board.publish(first.model_copy(update={"stamp_ns": first.stamp_ns + 40_000_000}))  # still active: not again
    cleared = ex.gateway_status(first.stamp_ns + 80_000_000, ur5=ex.robot_status())
    board.publish(cleared)
    board.publish(first.model_copy(update={"stamp_ns": first.stamp_ns + 120_000_000}))  # raised again
    samples = metric_samples(client.get("/metrics").text)
    for code in ("joint_state_missing", "tracker_missing"):
        assert samples[("hrc_faults_raised_total", (("code", code), ("robot", "ur5")))] == 2.0, code


def test_metric_names_are_in_base_units_and_the_period_buckets_lie_around_the_period(
    board: StatusBoard, client: TestClient
) -> None:
    first = ex.gateway_status()
    board.publish(first)
    board.publish(
        first.model_copy(
            update={
                "stamp_ns": first.stamp_ns + 41_000_000,
                "loop": loop_after(first.loop, 10, 0, [0.004] * 9 + [0.005]),
            }
        )
    )
    text = client.get("/metrics").text
    names = {family.name for family in text_string_to_metric_families(text)}
    assert not [n for n in names if n.endswith("_hz")], names
    samples = metric_samples(text)
    assert samples[("hrc_loop_nominal_period_seconds", ())] == 0.004  # gateway.rate_hz = 250
    edges = sorted(float(dict(labels)["le"]) for name, labels in samples if name == "hrc_loop_period_seconds_bucket")
    assert [e for e in edges if 0.0036 <= e <= 0.0044] == [
        0.0036,
        0.0038,
        0.00392,
        0.00396,
        0.00404,
        0.00408,
        0.0042,
        0.0044,
    ]
    # each tick's period is observed: the one late tick (5 ms) is a tail of its own, not hidden in a 4.1 ms mean
    assert samples[("hrc_loop_period_seconds_bucket", (("le", "0.00404"),))] == 9
    assert samples[("hrc_loop_period_seconds_bucket", (("le", "0.0042"),))] == 9
    assert samples[("hrc_loop_period_seconds_bucket", (("le", "0.005"),))] == 10


def track(label: str, state: TrackStateName, age_s: float, released_by: str | None = None) -> TrackStatus:
    """A track of tracker ``front`` as the status lists it (lost: reach at K = 1.6 m/s)."""
    lost = state == "lost"
    return TrackStatus(
        label=label,
        tracker="front",
        human=f"{label} (lost)" if lost else label,
        state=state,
        last_seen_age_s=age_s,
        reach_m=round(1.6 * age_s, 4) if lost else 0.0,
        capsules=13,
        holds=["ur5"] if lost else [],
        released_by=released_by,
        action=f"person {label} lost {age_s:.1f} s ago (holds ur5): clear the area and reset" if lost else None,
    )


TRACKS = [
    track("front/h1", "seen", 0.03),
    track("front/h2", "lost", 4.2),
    track("front/h3", "lost", 1.5),
    track("front/h4", "seen", 0.03),
    track("front/h5", "released", 3.0, "reset by operator 'alice'"),
]
"""Two people seen, two lost (the older 4.2 s ago), one released by an operator."""


def release_lines(log: EventLog, *releases: tuple[str, str]) -> bytes:
    """The event lines the gateway sends the child for a person lost and the ``(label, cause)`` releases, logged
    (numbered) by ``log``."""
    changes = [TrackEvent("track_lost", "front/h2", "person front/h2 lost")]
    changes += [TrackEvent("track_released", label, f"person {label} released", cause) for label, cause in releases]
    events = log.observe(0, ex.STAMP_NS, {}, changes)
    return b"".join(EVENT_PREFIX + e.model_dump_json(exclude_none=True).encode() + b"\n" for e in events)


def feed(board: StatusBoard, lines: bytes) -> None:
    """Lines of the gateway's pipe, taken by the HTTP child's reader."""
    _feed(board, io.BytesIO(lines), SimpleNamespace(should_exit=False))  # type: ignore[arg-type]


def test_metrics_show_the_people_by_state_and_count_each_release_once_by_cause(
    board: StatusBoard, client: TestClient
) -> None:
    status = ex.gateway_status().model_copy(update={"tracks": TRACKS})
    status_line = status.model_dump_json().encode() + b"\n"
    later = status.model_copy(update={"stamp_ns": status.stamp_ns + 40_000_000})
    later_line = later.model_dump_json().encode() + b"\n"
    # front/h5 is released twice (lost again in between: the same label); both documents list its newest release
    log = EventLog()
    feed(board, release_lines(log, ("front/h5", "redetected"), ("front/h9", "left")) + status_line)
    feed(board, release_lines(log, ("front/h5", "reset")) + later_line)
    samples = metric_samples(client.get("/metrics").text)
    assert samples[("hrc_tracks", (("state", "seen"),))] == 2
    assert samples[("hrc_tracks", (("state", "lost"),))] == 2
    assert samples[("hrc_track_lost_age_max_seconds", ())] == 4.2
    released = {dict(key[1])["cause"]: v for key, v in samples.items() if key[0] == "hrc_tracks_released_total"}
    assert released == {"redetected": 1.0, "left": 1.0, "reset": 1.0}


def test_an_event_seen_again_is_not_counted_again_and_nobody_lost_is_age_zero(
    board: StatusBoard, client: TestClient
) -> None:
    lines = release_lines(EventLog(), ("front/h5", "reset"))
    feed(board, lines + lines)
    board.publish(ex.gateway_status().model_copy(update={"tracks": [track("front/h1", "seen", 0.03)]}))
    samples = metric_samples(client.get("/metrics").text)
    assert samples[("hrc_tracks_released_total", (("cause", "reset"),))] == 1.0
    assert samples[("hrc_tracks_released_total", (("cause", "left"),))] == 0.0, "every cause exported from the start"
    assert samples[("hrc_track_lost_age_max_seconds", ())] == 0.0
    assert samples[("hrc_tracks", (("state", "lost"),))] == 0.0


PROMTOOL = shutil.which("promtool") or shutil.which("promtool", path=str(Path(sys.executable).parent))


@pytest.mark.skipif(PROMTOOL is None, reason="no promtool (Debian's prometheus; scripts/bootstrap.sh installs it)")
def test_promtool_finds_nothing_to_say_about_the_metrics(board: StatusBoard, client: TestClient) -> None:
    first = ex.gateway_status(ur5=ex.robot_status(faults=[ex.STALE_TRACKER]), ur10=ex.near_robot_status())
    first = first.model_copy(update={"tracks": TRACKS})
    feed(board, release_lines(EventLog(), ("front/h5", "reset")))
    board.publish(first)
    board.publish(
        first.model_copy(update={"stamp_ns": first.stamp_ns + 40_000_000, "loop": loop_after(first.loop, 10, 0)})
    )
    assert PROMTOOL is not None
    check = subprocess.run(
        [PROMTOOL, "check", "metrics"],
        input=client.get("/metrics").content,
        capture_output=True,
        timeout=60,
        check=False,
    )
    assert (check.returncode, check.stdout + check.stderr) == (0, b"")


def test_metrics_before_any_status_parse_and_are_empty_of_robots(client: TestClient) -> None:
    text = client.get("/metrics").text
    assert not [s for s in metric_samples(text) if s[0].startswith("hrc_robot_")]


# -- the real HTTP child ---------------------------------------------------------------------------


class Child:
    """``python -m gateway.http.server`` fed through its standard input, as the gateway feeds it."""

    def __init__(self, cell_config: CellConfig, events_log: Path, log: Path | None = None) -> None:
        self.port = free_port()
        self._log = None if log is None else log.open("ab")
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "gateway.http.server",
                "--http-port",
                str(self.port),
                "--events-log",
                str(events_log),
            ],
            stdin=subprocess.PIPE,
            stderr=self._log,
        )
        if self._log is not None:
            self._log.close()  # the child has its own descriptor
        self.url = f"http://127.0.0.1:{self.port}"
        self.send(effective_config(cell_config).model_dump_json().encode())

    def send(self, line: bytes) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + b"\n")
        self.proc.stdin.flush()

    def answers(self) -> bool:
        try:
            return httpx.get(self.url + "/healthz", timeout=1.0).status_code == 200
        except (httpx.HTTPError, OSError):
            return False


def read_stream(url: str, wanted: int, got: list[GatewayStatus], opened: threading.Event) -> None:
    """Read ``status`` events until ``wanted`` documents or the end of the stream."""
    with httpx.stream("GET", url + "/api/v1/stream", timeout=10.0) as response:
        opened.set()
        kind = ""
        for line in response.iter_lines():
            if line.startswith("event: "):
                kind = line.removeprefix("event: ")
            elif line.startswith("data: ") and kind == "status":
                got.append(GatewayStatus.model_validate_json(line.removeprefix("data: ")))
                if len(got) >= wanted:
                    return


def every_stream_has(results: list[list[GatewayStatus]], n: int) -> bool:
    return all(len(r) >= n for r in results)


@pytest.mark.e2e
def test_the_stream_delivers_each_status_and_ends_when_the_gateway_stops(
    cell_config: CellConfig, tmp_path: Path
) -> None:
    child_log = tmp_path / "child.log"
    child = Child(cell_config, tmp_path / "events.jsonl", child_log)
    try:
        wait_for(child.answers, 20.0, "the HTTP child answers")
        readers = []
        results: list[list[GatewayStatus]] = [[] for _ in range(3)]
        for got in results:
            opened = threading.Event()
            reader = threading.Thread(target=read_stream, args=(child.url, 10**6, got, opened), daemon=True)
            reader.start()
            assert opened.wait(10.0)
            readers.append(reader)
        for event in EventLog().started(time.time_ns(), "demo", "e" * 64):
            child.send(EVENT_PREFIX + event.model_dump_json(exclude_none=True).encode())
        for i in range(5):
            doc = ex.gateway_status(ur5=ex.robot_status(delta=i / 10)).model_copy(update={"stamp_ns": ex.STAMP_NS + i})
            child.send(doc.model_dump_json().encode())
            wait_for(partial(every_stream_has, results, i + 1), 10.0, f"every stream has document {i}")
        for got in results:
            assert [d.robots["ur5"].delta for d in got] == [0.0, 0.1, 0.2, 0.3, 0.4], "each document once, in order"
        events = EventsResponse.model_validate_json(httpx.get(child.url + "/api/v1/events").content).events
        assert [e.kind for e in events] == ["start", "config_loaded"]
        lines = (tmp_path / "events.jsonl").read_text().splitlines()
        assert [json.loads(line)["kind"] for line in lines] == ["start", "config_loaded"]
        # The gateway stops (its end of the pipe closes) while three streams are open: the child ends them.
        assert child.proc.stdin is not None
        child.proc.stdin.close()
        assert child.proc.wait(timeout=10.0) == 0
        # uvicorn cancels what still runs when its graceful time-out (2 s) is spent, and says so: the child ended
        # the streams itself instead (not a timing: a loaded machine may take longer to exit, never to say this)
        assert "graceful shutdown exceeded" not in child_log.read_text(errors="replace"), "open streams held it up"
        for reader in readers:
            reader.join(5.0)
            assert not reader.is_alive(), "the stream ended"
    finally:
        if child.proc.poll() is None:
            child.proc.kill()
            child.proc.wait()


@pytest.mark.e2e
def test_the_http_child_counts_the_faults_of_the_start(cell_config: CellConfig, tmp_path: Path) -> None:
    """As the gateway starts: its first status has faults (no data yet); a scrape of the child counts them."""
    child_log = tmp_path / "child.log"
    child = Child(cell_config, tmp_path / "events.jsonl", child_log)
    try:
        wait_for(child.answers, 20.0, "the HTTP child answers")
        faults = [Fault(code="joint_state_missing", reason="none yet"), Fault(code="tracker_missing", reason="none")]
        child.send(ex.gateway_status(ur5=ex.robot_status(faults=faults)).model_dump_json().encode())
        raised = ("hrc_faults_raised_total", (("code", "tracker_missing"), ("robot", "ur5")))
        wait_for(lambda: raised in metric_samples(httpx.get(child.url + "/metrics").text), 10.0, "a scrape counts")
        samples = metric_samples(httpx.get(child.url + "/metrics").text)
        assert samples[raised] == 1.0
        assert samples[("hrc_faults_raised_total", (("code", "joint_state_missing"), ("robot", "ur5")))] == 1.0
    finally:
        if child.proc.stdin is not None:
            child.proc.stdin.close()
        child.proc.wait(timeout=10.0)


def test_decisions_with_the_same_link_ends_are_equal_and_with_others_not() -> None:
    a, b = decision_with_links(), decision_with_links()
    assert a == b
    moved = a.links
    assert moved is not None
    other = a._replace(links=LinkEnds(moved.p_a_world + 1e-9, moved.p_b_world))
    assert a != other
