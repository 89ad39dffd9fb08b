"""People as tracks, end to end (issue 17): a person who vanishes from the tracker leaves the tool still until
re-seen, seen leaving or reset by an operator.

The real gateway and the real controller emulator over mutual TLS with the cell's access control; the test plays
the (only) tracker with the tracker emulator's certificate, watches the controller's ground truth and the gateway's
overrides, and runs ``hrc-reset-track`` as a real program with the operator's certificate. Every case starts with
nobody in the cell (the robot runs its program), then a person stands with a hand at the tool (δ = 0, the robot
brakes to a standstill):

(a) the tracker reports nobody for 2 frames, then the person again: the robot never moved;
(b) the tracker reports nobody for good: the tool stays still; the status shows the person lost with a growing
    reach and what to do; ``hrc-reset-track`` releases them and the robot resumes;
(c) the person "jumps" 3 m in one frame: the robot stays stopped (the jump is not believed);
(d) the person is re-seen far away, within the reach the lost track has grown to: the robot resumes.

Teeth: ``HRC_TRACKS_TEETH=forget`` runs the same tests against a gateway that forgets a person no longer reported
(``tracking.unsafe_forget_lost_for_tests``, the old behaviour); then every test fails.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import httpx
import numpy as np
import pytest
import zenoh
from support.paths import REPO_ROOT

from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import Capsule, Human, Humans, JointState, Override, parse_message, to_payload
from hrc_runtime.access_control import AUDITOR, OPERATOR, TRACKER_EMULATOR, CellPolicy
from hrc_runtime.config import load_cell_config
from hrc_runtime.pki import CellPki
from hrc_runtime.zenoh_session import SessionOptions, mutual_tls, session_config
from hrc_tools.cell.procs import (
    Program,
    free_port,
    program_env,
    start_program,
    stop_all,
    unsafe_test_settings,
    wait_or_fail,
    write_cell_config,
)
from hrc_tools.cert.main import provision_cell

pytestmark = pytest.mark.e2e

ROBOT = "ur5"
TRACKER = "front"
FORGET = os.environ.get("HRC_TRACKS_TEETH") == "forget"
FORGET_SETTING = "unsafe_forget_lost_for_tests"
BY_ID = os.environ.get("HRC_TRACKS_TEETH") == "by_id"
BY_ID_SETTING = "unsafe_release_by_id_for_tests"

FRAME_S = 1 / 30
"""The tracker's frame period, as the real trackers publish [s]."""
START_S = 90.0
"""Generous waits: a loaded machine may take long to start the programs and to reach a state [s]."""
WAIT_S = 30.0
STILL_Q_RAD = 1e-6
"""Joint positions of a robot at a standstill agree within this [rad] (the emulator has no noise)."""
STANDSTILL_STATES = 25
"""A robot is at a standstill when this many consecutive joint states (0.1 s at 250 Hz) show δ = 0, same q."""
JUMP_M = 3.0


# -- the cell ---------------------------------------------------------------------------------------------


@dataclass
class TracksCell:
    """Gateway and controller emulator over mutual TLS, one tracker (played by the test)."""

    config: CellConfig
    config_path: Path
    pki: CellPki
    gateway_endpoint: str
    http_port: int
    logs: list[Path]
    procs: list[Program] = field(default_factory=list)

    def options(self, common_name: str, mode: str) -> SessionOptions:
        tls = mutual_tls(self.pki.root, common_name, CellPolicy.from_config(self.config), create=False)
        return SessionOptions("peer" if mode == "peer" else "client", tls)

    def get(self, path: str) -> Any:
        return httpx.get(f"http://127.0.0.1:{self.http_port}{path}", timeout=10.0).json()

    def status(self) -> dict[str, Any] | None:
        """The gateway's status, or None while it has none (not started, or no fresh status: a 503)."""
        try:
            doc: dict[str, Any] = self.get("/api/v1/status")
        except (httpx.HTTPError, ValueError):
            return None
        return doc if "robots" in doc else None

    def events(self) -> list[dict[str, Any]]:
        events: list[dict[str, Any]] = self.get("/api/v1/events")["events"]
        return events

    def wait(self, condition: Callable[[], bool], what: str, timeout_s: float = WAIT_S) -> None:
        wait_or_fail(condition, timeout_s, what, self.logs, self.procs)


def _cell_config(trackers: Sequence[str] = (TRACKER,)) -> CellConfig:
    """The default cell with the given trackers (the test plays them), forgetting lost people in the teeth run, or
    releasing them by id in the persons' teeth run."""
    config = load_cell_config(None)
    update = {"unsafe_forget_lost_for_tests": FORGET, "unsafe_release_by_id_for_tests": BY_ID}
    tracking = config.tracking.model_copy(update=update)
    return config.model_copy(update={"trackers": {t: config.trackers[t] for t in trackers}, "tracking": tracking})


@pytest.fixture
def trackers(request: pytest.FixtureRequest) -> tuple[str, ...]:
    """The trackers the test plays (one; the persons' tests play two, as the parameter)."""
    return tuple(getattr(request, "param", (TRACKER,)))


@pytest.fixture
def cell(tmp_path: Path, trackers: tuple[str, ...]) -> Iterator[TracksCell]:
    with ExitStack() as stack:
        if FORGET:
            stack.enter_context(unsafe_test_settings(FORGET_SETTING))
        if BY_ID:
            stack.enter_context(unsafe_test_settings(BY_ID_SETTING))
        config = _cell_config(trackers)
        config_path = write_cell_config(config, tmp_path / "cell.toml")
        pki = CellPki(tmp_path / "pki")
        provision_cell(pki, CellPolicy.from_config(config))
        pki.identity(OPERATOR)  # issued now, not by two programs at once
        gw_ep, ctrl_ep, http_port = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}", free_port()
        common = ["--config", str(config_path), "--pki-dir", str(pki.root)]
        commands = {
            "gateway": ("gateway", [*common, "--zenoh-listen", gw_ep, "--http-port", str(http_port)]),
            "controller": ("controller_emu", [*common, "--zenoh-listen", ctrl_ep, "--zenoh-connect", gw_ep]),
        }
        tc = TracksCell(config, config_path, pki, gw_ep, http_port, [tmp_path / f"{name}.log" for name in commands])
        stack.callback(stop_all, tc.procs)
        for (module, args), log in zip(commands.values(), tc.logs, strict=True):
            tc.procs.append(start_program(module, args, log, program_env(plain_tcp=False)))
        tc.wait(lambda: tc.status() is not None, "the gateway's REST API", START_S)
        yield tc


# -- the test's own tracker, and what it watches ------------------------------------------------------------


class Sent(NamedTuple):
    """A frame the test's tracker published: its seq, capture stamp [ns since the epoch] and people."""

    seq: int
    stamp_ns: int
    people: int


class Tracker:
    """Publishes one tracker's frames at 30 Hz: a scene (the people it sees) held until changed, and one-shot
    frames played once each, in order, before the scene resumes."""

    def __init__(self, session: zenoh.Session, cell: str, name: str = TRACKER, late_s: float = 0.0) -> None:
        self.name = name
        self._late_ns = int(late_s * 1e9)
        self._publisher = session.declare_publisher(
            keys.tracker_humans(cell, name), congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )
        self._lock = threading.Lock()
        self._scene: list[Human] = []
        self._once: list[list[Human]] = []
        self.sent: list[Sent] = []
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="test-tracker", daemon=True)
        self._thread.start()

    def show(self, scene: list[Human], once: Sequence[list[Human]] = ()) -> int:
        """From the next frame: each of ``once`` once, then ``scene`` for good. Returns the seq of the first."""
        with self._lock:
            self._scene = scene
            self._once = list(once)
            return len(self.sent) + 1

    def frames_from(self, seq: int) -> list[Sent]:
        with self._lock:
            return self.sent[seq - 1 :]

    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._halt.is_set():
            with self._lock:
                people = self._once.pop(0) if self._once else self._scene
                stamp_ns = time.time_ns() - self._late_ns
                message = Humans(tracker=self.name, seq=len(self.sent) + 1, stamp_ns=stamp_ns, humans=people)
                self._publisher.put(to_payload(message))
                self.sent.append(Sent(message.seq, message.stamp_ns, len(people)))
            next_s += FRAME_S
            self._halt.wait(max(0.0, next_s - time.monotonic()))  # pacing the tracker, not synchronisation

    def close(self) -> None:
        self._halt.set()
        self._thread.join()


class Truth(NamedTuple):
    """A joint state of the controller's ground truth: its stamp [ns since the epoch], q [rad], applied δ."""

    stamp_ns: int
    q: tuple[float, ...]
    override: float


class Watch:
    """The controller's ground truth and the gateway's overrides, as received."""

    def __init__(self, session: zenoh.Session, cell: str) -> None:
        self._lock = threading.Lock()
        self.truth: list[Truth] = []
        self.overrides: list[Override] = []
        self._subscribers = [
            session.declare_subscriber(keys.truth_robot_state(cell, ROBOT), self._on_truth),
            session.declare_subscriber(keys.robot_override(cell, ROBOT), self._on_override),
        ]

    def _on_truth(self, sample: zenoh.Sample) -> None:
        state = parse_message(sample.payload.to_bytes(), JointState)
        with self._lock:
            self.truth.append(Truth(state.stamp_ns, tuple(state.q), state.override))

    def _on_override(self, sample: zenoh.Sample) -> None:
        override = parse_message(sample.payload.to_bytes(), Override)
        with self._lock:
            self.overrides.append(override)

    def truth_since(self, stamp_ns: int) -> list[Truth]:
        with self._lock:
            return [s for s in self.truth if s.stamp_ns >= stamp_ns]

    def overrides_since(self, stamp_ns: int) -> list[Override]:
        with self._lock:
            return [o for o in self.overrides if o.stamp_ns >= stamp_ns]

    def last_truth(self, n: int) -> list[Truth]:
        with self._lock:
            return self.truth[-n:]

    def standstill(self) -> bool:
        """The newest joint states all show δ = 0 applied and the same q."""
        recent = self.last_truth(STANDSTILL_STATES)
        return len(recent) == STANDSTILL_STATES and all(
            s.override == 0.0 and _moved_rad(recent[0].q, s.q) <= STILL_Q_RAD for s in recent
        )

    def moving(self) -> bool:
        """The newest joint states show δ > 0 applied and the joints moving."""
        recent = self.last_truth(STANDSTILL_STATES)
        return (
            len(recent) == STANDSTILL_STATES
            and recent[-1].override > 0.0
            and _moved_rad(recent[0].q, recent[-1].q) > STILL_Q_RAD
        )


def _moved_rad(q0: tuple[float, ...], q1: tuple[float, ...]) -> float:
    return max(abs(a - b) for a, b in zip(q0, q1, strict=True))


@dataclass
class Scene:
    """The test's view of the running cell: its tracker, what it watches, and where the person stands."""

    cell: TracksCell
    tracker: Tracker
    watch: Watch
    person: list[Human] = field(default_factory=list)
    away_xy: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0]))

    def robot(self) -> dict[str, Any] | None:
        status = self.cell.status()
        return None if status is None else status["robots"][ROBOT]

    def track(self, label: str) -> dict[str, Any] | None:
        status = self.cell.status()
        if status is None:
            return None
        return next((t for t in status["tracks"] if t["label"] == label), None)


def person_at(person_id: str, hand_m: np.ndarray, away_xy: np.ndarray, shift_m: float = 0.0) -> Human:
    """A person with a hand at ``hand_m`` and their torso 0.45 m beyond it (along ``away_xy``, away from the
    robot's base), the whole person shifted by ``shift_m`` along ``away_xy`` [m]."""
    shift = np.array([*away_xy, 0.0]) * shift_m
    hand = hand_m + shift
    torso_xy = hand[:2] + 0.45 * away_xy
    return Human(
        id=person_id,
        capsules=[
            Capsule(name="hand_r", a=tuple(hand), b=tuple(hand), radius=0.06),
            Capsule(name="torso", a=(*torso_xy, 0.95), b=(*torso_xy, 1.45), radius=0.18),
        ],
    )


@pytest.fixture
def scene(cell: TracksCell) -> Iterator[Scene]:
    """Nobody in the cell until the robot runs its program; then a person with a hand at the tool, until the
    robot stands still."""
    with (
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options(TRACKER_EMULATOR, "peer"))) as trk,
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options(AUDITOR, "client"))) as obs,
    ):
        watch = Watch(obs, cell.config.cell)
        tracker = Tracker(trk, cell.config.cell)
        try:
            cell.wait(watch.moving, "the robot running its program with nobody in the cell", START_S)
            s = Scene(cell, tracker, watch)
            robot = s.robot()
            assert robot is not None
            tool = next(link for link in robot["links"] if link["name"] == "tool")
            hand_m = np.array(tool["b_m"])
            radius_m = float(np.linalg.norm(hand_m[:2]))
            if radius_m > 0.1:  # else the tool is above the base: any direction leads away from it
                s.away_xy = hand_m[:2] / radius_m
            s.person = [person_at("h1", hand_m, s.away_xy)]
            tracker.show(s.person)
            cell.wait(watch.standstill, "the robot braked to a standstill for the hand at the tool")
            robot = s.robot()
            assert robot is not None
            assert robot["delta"] == 0.0, robot
            yield s
        finally:
            tracker.close()


def _assert_never_moved(watch: Watch, since_ns: int, until_ns: int, q_still: tuple[float, ...]) -> None:
    """Every override the gateway sent and every joint state of the ground truth between the stamps: δ = 0, q
    the standstill's."""
    overrides = [o for o in watch.overrides_since(since_ns) if o.stamp_ns <= until_ns]
    truth = [s for s in watch.truth_since(since_ns) if s.stamp_ns <= until_ns]
    assert len(overrides) >= 10, f"{len(overrides)} overrides seen"
    assert len(truth) >= 10, f"{len(truth)} joint states seen"
    raised = [o for o in overrides if o.delta > 0.0]
    assert not raised, f"the gateway raised δ: {raised[:5]}"
    moved = max(_moved_rad(q_still, s.q) for s in truth)
    assert moved <= STILL_Q_RAD, f"the robot moved {moved:.6f} rad"
    assert all(s.override == 0.0 for s in truth)


def _released(cell: TracksCell, label: str, cause: str) -> list[dict[str, Any]]:
    return [e for e in cell.events() if e["kind"] == "track_released" and e["track"] == label and e["cause"] == cause]


def test_a_two_frame_blink_does_not_move_the_robot(scene: Scene) -> None:
    """(a) The hand at the tool; the tracker reports nobody for 2 frames, then the hand again."""
    q_still = scene.watch.last_truth(1)[0].q
    first = scene.tracker.show(scene.person, once=[[], []])
    scene.cell.wait(lambda: len(scene.tracker.frames_from(first)) >= 2 + 30, "the blink and 1 s after it")
    frames = scene.tracker.frames_from(first)
    assert [f.people for f in frames[:3]] == [0, 0, 1]
    # The gateway took the empty frames: it lost the person ...
    scene.cell.wait(lambda: any(e["kind"] == "track_lost" for e in scene.cell.events()), "the person lost")
    # ... and found them again where they were: released by the person seen again (a new track of the same person).
    scene.cell.wait(lambda: bool(_released(scene.cell, "front/h1", "redetected")), "the person seen again")
    _assert_never_moved(scene.watch, frames[0].stamp_ns, frames[-1].stamp_ns, q_still)


def test_a_person_lost_for_good_holds_the_robot_until_an_operator_resets_them(scene: Scene) -> None:
    """(b) The tracker reports nobody for good: the tool stays still, the status says who is lost and what to do;
    ``hrc-reset-track`` (the operator's certificate) releases them and the robot resumes."""
    cell = scene.cell
    q_still = scene.watch.last_truth(1)[0].q
    first = scene.tracker.show([])
    cell.wait(lambda: bool(scene.tracker.frames_from(first)), "the first empty frame")
    vanished_ns = scene.tracker.frames_from(first)[0].stamp_ns
    reaches: list[float] = []

    def lost_and_growing() -> bool:
        track = scene.track("front/h1")
        if track is None or track["state"] != "lost":
            return False
        reaches.append(track["reach_m"])
        return bool(track["last_seen_age_s"] >= 2.0)

    cell.wait(lost_and_growing, "the person lost for 2 s")
    track = scene.track("front/h1")
    assert track is not None
    assert track["state"] == "lost", track
    assert reaches[0] < reaches[-1] <= track["reach_m"], reaches
    assert track["reach_m"] >= 0.99 * cell.config.safety.human_speed_mps * 2.0, track  # K · age
    assert ROBOT in track["holds"], track
    assert "reset" in (track["action"] or ""), track
    robot = scene.robot()
    assert robot is not None
    assert robot["delta"] == 0.0, robot
    assert robot["closest"]["human"] == "front/h1 (lost)", robot
    _assert_never_moved(scene.watch, vanished_ns, time.time_ns(), q_still)

    reset = subprocess.run(
        [
            sys.executable, "-m", "hrc_tools.reset_track", "--config", str(cell.config_path),
            "--pki-dir", str(cell.pki.root), "--zenoh-connect", cell.gateway_endpoint,
            "--track", "front/h1", "--operator", "test",
        ],
        cwd=REPO_ROOT, env=program_env(plain_tcp=False), capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert reset.returncode == 0, f"{reset.stdout}\n{reset.stderr}"
    cell.wait(scene.watch.moving, "the robot resuming after the reset")
    events = cell.events()
    assert any(e["kind"] == "track_lost" and e["track"] == "front/h1" for e in events), events
    (released,) = _released(cell, "front/h1", "reset")
    assert "test" in released["message"], released
    status = cell.status()
    assert status is not None
    assert status["inputs"]["received"].get("operator/track_reset", 0) >= 1, status["inputs"]


def test_a_three_metre_jump_in_one_frame_keeps_the_robot_stopped(scene: Scene) -> None:
    """(c) The person's next frame puts them 3 m away: not believed (250 m/s). The detection is someone else, followed
    from then on: when the lost person's reach covers it, it is still not evidence about the lost person (issue 32);
    the robot stays stopped until an operator resets them."""
    q_still = scene.watch.last_truth(1)[0].q
    (hand,) = [c for c in scene.person[0].capsules if c.name == "hand_r"]
    jumped = [person_at("h1", np.array(hand.a), scene.away_xy, JUMP_M)]
    first = scene.tracker.show(jumped)
    cell = scene.cell
    cell.wait(lambda: bool(scene.tracker.frames_from(first)), "the jump")
    jump_ns = scene.tracker.frames_from(first)[0].stamp_ns
    # A person at K needs (3 m − the association margin and noise) / K ≈ 1.8 s to get there: not believed before.
    believable_ns = jump_ns + int((JUMP_M - 0.5) / 1.6 * 1e9)
    cell.wait(lambda: bool(scene.watch.overrides_since(believable_ns)), "overrides after the jump")
    _assert_never_moved(scene.watch, jump_ns, believable_ns, q_still)
    # Meanwhile the status showed the one lost where they were and a new track where the detection is.
    assert any(e["kind"] == "track_lost" and e["track"] == "front/h1" for e in cell.events())
    # Once their reach covers it, the detection is still someone followed since the loss: nothing releases them.
    held_until_ns = believable_ns + 1_500_000_000
    cell.wait(lambda: bool(scene.watch.overrides_since(held_until_ns)), "overrides 1.5 s after the reach covered it")
    _assert_never_moved(scene.watch, jump_ns, held_until_ns, q_still)
    assert not _released(cell, "front/h1", "redetected")
    track = scene.track("front/h1")
    assert track is not None
    assert track["state"] == "lost", track


def test_a_person_seen_again_far_away_within_reach_lets_the_robot_resume(scene: Scene) -> None:
    """(d) Lost at the tool; re-seen (another id) 3 m away once their reach covers that: released, robot resumes."""
    cell = scene.cell
    q_still = scene.watch.last_truth(1)[0].q
    first = scene.tracker.show([])
    cell.wait(lambda: bool(scene.tracker.frames_from(first)), "the first empty frame")
    vanished_ns = scene.tracker.frames_from(first)[0].stamp_ns
    cell.wait(
        lambda: (t := scene.track("front/h1")) is not None and t["state"] == "lost" and t["reach_m"] >= JUMP_M + 0.5,
        "the lost person's reach beyond 3.5 m",
    )
    _assert_never_moved(scene.watch, vanished_ns, time.time_ns(), q_still)
    (hand,) = [c for c in scene.person[0].capsules if c.name == "hand_r"]
    scene.tracker.show([person_at("h2", np.array(hand.a), scene.away_xy, JUMP_M)])
    cell.wait(lambda: bool(_released(cell, "front/h1", "redetected")), "the lost person released")
    (released,) = _released(cell, "front/h1", "redetected")
    assert "front/h2" in released["message"], released
    cell.wait(scene.watch.moving, "the robot resuming")
    robot = scene.robot()
    assert robot is not None
    assert robot["closest"]["human"] == "front/h2", robot


# -- persons (issue 32): two trackers; nothing but A themselves releases A --------------------------------------------
#
# Teeth: HRC_TRACKS_TEETH=by_id runs these against a gateway that releases by the rule before persons
# (tracking.unsafe_release_by_id_for_tests); then each of them fails.

SIDE = "side"
FAR_M = 1.9
"""B stands this much farther out than A (along the direction away from the robot's base) [m]."""
HOLD_S = 2.5
"""How long each case watches the robot stay still after what used to release A [s]."""


@dataclass
class TwoTrackers:
    scene: Scene
    side: Tracker
    hand_m: np.ndarray


@pytest.fixture
def two(request: pytest.FixtureRequest, cell: TracksCell) -> Iterator[TwoTrackers]:
    """Front and side (side ``late_s`` behind, from the test's parameter); A with a hand at the tool, seen by front
    only, until the robot stands still."""
    late_s = getattr(request, "param", 0.0)
    with (
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options(TRACKER_EMULATOR, "peer"))) as trk,
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options(AUDITOR, "client"))) as obs,
    ):
        watch = Watch(obs, cell.config.cell)
        front, side = Tracker(trk, cell.config.cell), Tracker(trk, cell.config.cell, SIDE, late_s)
        try:
            cell.wait(watch.moving, "the robot running its program with nobody in the cell", START_S)
            s = Scene(cell, front, watch)
            robot = s.robot()
            assert robot is not None
            hand_m = np.array(next(link for link in robot["links"] if link["name"] == "tool")["b_m"])
            radius_m = float(np.linalg.norm(hand_m[:2]))
            if radius_m > 0.1:
                s.away_xy = hand_m[:2] / radius_m
            s.person = [person_at("a", hand_m, s.away_xy)]
            front.show(s.person)
            cell.wait(watch.standstill, "the robot braked to a standstill for A's hand at the tool")
            yield TwoTrackers(s, side, hand_m)
        finally:
            front.close()
            side.close()


def _held_still(two: TwoTrackers, since_ns: int, label: str = "front/a") -> None:
    """For HOLD_S from ``since_ns`` the robot never moved and A's track stays lost."""
    scene = two.scene
    until_ns = since_ns + int(HOLD_S * 1e9)
    q_still = scene.watch.last_truth(1)[0].q
    scene.cell.wait(lambda: bool(scene.watch.overrides_since(until_ns)), f"overrides {HOLD_S} s on")
    _assert_never_moved(scene.watch, since_ns, until_ns, q_still)
    documents: list[dict[str, Any]] = []
    scene.cell.wait(lambda: (d := scene.cell.status()) is not None and bool(documents.append(d) or True), "a status")
    status = documents[-1]
    track = next((t for t in status["tracks"] if t["label"] == label), None)
    assert track is not None, status["tracks"]
    assert track["state"] == "lost", track
    persons = {p["label"]: p for p in status["persons"]}
    assert label in persons[track["person"]]["lost_tracks"], persons


@pytest.mark.parametrize("trackers", [("front", SIDE)], indirect=True)
def test_persons_1_a_second_trackers_first_view_of_someone_followed_does_not_release_a(two: TwoTrackers) -> None:
    """A at the tool, B 1.9 m farther out, both followed by front. A is hidden; side then reports B for the first
    time (a new id for side): that is B, not someone who appeared; A keeps the robot still."""
    scene = two.scene
    b = person_at("b", two.hand_m, scene.away_xy, FAR_M)
    scene.tracker.show([*scene.person, b])
    scene.cell.wait(lambda: scene.track("front/b") is not None, "B followed by front")
    first = scene.tracker.show([b])  # A hidden
    scene.cell.wait(lambda: (t := scene.track("front/a")) is not None and t["state"] == "lost", "A lost")
    hidden_ns = scene.tracker.frames_from(first)[0].stamp_ns
    two.side.show([person_at("s9", two.hand_m, scene.away_xy, FAR_M + 0.02)])
    _held_still(two, hidden_ns)
    documents: list[dict[str, Any]] = []
    scene.cell.wait(lambda: (d := scene.cell.status()) is not None and bool(documents.append(d) or True), "a status")
    status = documents[-1]
    b_tracks = [t for t in status["tracks"] if t["label"] in ("front/b", "side/s9")]
    assert len({t["person"] for t in b_tracks}) == 1, (status["tracks"], status["persons"])  # one body, one person


@pytest.mark.parametrize("trackers", [("front", SIDE)], indirect=True)
def test_persons_2_a_tracker_renaming_someone_it_follows_does_not_release_a(two: TwoTrackers) -> None:
    """Same cell, side sees B all along; after A is hidden, front gives B a new id."""
    scene = two.scene
    b = person_at("b", two.hand_m, scene.away_xy, FAR_M)
    scene.tracker.show([*scene.person, b])
    two.side.show([person_at("s1", two.hand_m, scene.away_xy, FAR_M + 0.02)])
    scene.cell.wait(lambda: scene.track("side/s1") is not None, "B followed by side")
    first = scene.tracker.show([b])  # A hidden
    scene.cell.wait(lambda: (t := scene.track("front/a")) is not None and t["state"] == "lost", "A lost")
    hidden_ns = scene.tracker.frames_from(first)[0].stamp_ns
    scene.tracker.show([person_at("b2", two.hand_m, scene.away_xy, FAR_M)])  # front renames B
    _held_still(two, hidden_ns)


@pytest.mark.parametrize("trackers", [("front", SIDE)], indirect=True)
@pytest.mark.parametrize("two", [0.14], indirect=True)
def test_persons_3_a_neighbour_seen_by_a_late_tracker_does_not_release_a(two: TwoTrackers) -> None:
    """Side stamps its frames 140 ms late (inside the age limit). A and B in one posture, B 0.36 m farther out; both
    trackers see both. A is hidden from both; side keeps seeing B."""
    scene = two.scene
    b = person_at("b", two.hand_m, scene.away_xy, 0.36)
    scene.tracker.show([*scene.person, b])
    two.side.show([person_at("sa", two.hand_m, scene.away_xy, 0.01), person_at("sb", two.hand_m, scene.away_xy, 0.37)])
    scene.cell.wait(lambda: scene.track("side/sb") is not None, "both followed by side")
    time.sleep(0.5)
    first = scene.tracker.show([b])  # A hidden from front ...
    two.side.show([person_at("sb", two.hand_m, scene.away_xy, 0.37)])  # ... and from side
    scene.cell.wait(lambda: (t := scene.track("front/a")) is not None and t["state"] == "lost", "A lost")
    _held_still(two, scene.tracker.frames_from(first)[0].stamp_ns)


@pytest.mark.parametrize("trackers", [("front", SIDE)], indirect=True)
def test_persons_5_a_person_re_seen_without_the_reaching_hand_does_not_release_the_hand(two: TwoTrackers) -> None:
    """A reaches with the hand to the tool, is hidden for 0.6 s, and is re-seen (same id) without the hand."""
    scene = two.scene
    first = scene.tracker.show([], once=[[]] * 18)  # 0.6 s hidden
    scene.cell.wait(lambda: (t := scene.track("front/a")) is not None and t["state"] == "lost", "A lost")
    (torso,) = [c for c in scene.person[0].capsules if c.name == "torso"]
    scene.tracker.show([Human(id="a", capsules=[torso])], once=[[]] * 18)
    _held_still(two, scene.tracker.frames_from(first)[0].stamp_ns)


@pytest.mark.parametrize("trackers", [("front", SIDE)], indirect=True)
@pytest.mark.parametrize("what", ["merged", "duplicate_names"])
def test_persons_4_a_body_no_person_can_be_is_refused_and_holds_the_robot(two: TwoTrackers, what: str) -> None:
    """A tracker that merges people (one 'person' 4.5 m wide, a hand at the tool) or names parts by kind."""
    scene = two.scene
    (hand,) = [c for c in scene.person[0].capsules if c.name == "hand_r"]
    if what == "merged":
        far = person_at("m", two.hand_m, scene.away_xy, 4.0)
        body = Human(id="a", capsules=[hand, *(c.model_copy(update={"name": f"far_{c.name}"}) for c in far.capsules)])
        reason = "person_too_large"
    else:
        body = Human(id="a", capsules=[hand, hand.model_copy(update={"name": "hand_r"})])
        reason = "duplicate_part_name"
    first = scene.tracker.show([body])
    scene.cell.wait(
        lambda: (r := scene.robot()) is not None and any(reason in f["reason"] for f in r["faults"]),
        f"the fault for {reason}",
    )
    since_ns = scene.tracker.frames_from(first)[0].stamp_ns
    until_ns = since_ns + int(HOLD_S * 1e9)
    q_still = scene.watch.last_truth(1)[0].q
    scene.cell.wait(lambda: bool(scene.watch.overrides_since(until_ns)), "overrides")
    _assert_never_moved(scene.watch, since_ns, until_ns, q_still)
