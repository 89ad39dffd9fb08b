"""The two-arm cell (configs/cell_two_arms.toml: a UR5 and a Panda facing each other), end to end.

The real gateway and one real controller emulator per robot run as processes over loopback TCP, each controller
behind its own ``hrc-fault-relay`` (forwarding at once until the test cuts its override direction); the test
plays both trackers itself (``front`` and ``side``, 50 Hz) so that it decides where the person is. Every status
document the gateway publishes is recorded, so that "the other robot kept moving" is checked on every one of
them while a fault lasted, not on one sample.

- Isolation: a fault of one robot (its controller frozen or killed, an invalid or an inconsistent joint state on
  its key, its override path lost) stops that robot only; an invalid frame of a tracker (a shared input) stops
  every robot.
- Zones per robot: a person beside the UR5 puts the UR5, not the Panda, into reduced speed / safety exception,
  and the other way round; the operator page (in a headless browser) shows both robots and follows the same.

The person walks (never jumps: a jump is not believed) and leaves by walking out of the covered volume: a person
who vanished inside it would be lost there, not gone, and keep the robots near them stopped (docs/contract.md
"Tracks").
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from typing import Any

import httpx
import pytest
import zenoh
from support.headless_browser import chromium
from support.paths import DEFAULT_CELL_PATH

from hrc_contract import keys
from hrc_contract.messages import Capsule, Human, Humans, JointState, to_payload
from hrc_contract.status_models import GatewayStatus
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import Cell, free_endpoint, free_port, stop_all

pytestmark = pytest.mark.e2e

CONFIG = DEFAULT_CELL_PATH.parent / "cell_two_arms.toml"
CELL = "twoarms"
ROBOTS = ("ur5", "panda")
TRACKERS = ("front", "side")
TRACKER_PERIOD_S = 1 / 50  # a late frame under load stays well inside max_data_age_s (0.2 s)
READY_S = 60.0  # the gateway loads two robots and checks their compiled kinematics; 5 programs; a shared machine
DETECT_S = 3.0
RECOVER_S = 10.0
ZONE_S = 10.0

AT_UR5 = (-0.5, -0.9)
"""Floor position beside the UR5 (base at the origin): about 0.8 m from its links, about 2 m from the Panda's."""
AT_PANDA = (2.7, -0.9)
"""Floor position beside the Panda (base at x = 2.2 m): about 0.8 m from its links, about 2 m from the UR5's."""
EXIT_Y_M = load_cell_config(CONFIG).tracking.coverage_min_m[1] - 0.7
"""Where the person walks out to: beyond the covered volume's -y face [m]."""
STEP_M = 0.03
"""How far the walking person moves per frame [m] (1.5 m/s at 50 Hz, within K): a step per frame, not per second,
so that a late frame never makes a jump."""
WALK_S = 30.0

Snapshot = dict[str, tuple[str, float, frozenset[str]]]
"""Per robot: zone, δ and the codes of its active faults, as one status document gave them."""


def _person(xy_m: tuple[float, float]) -> Human:
    x, y = xy_m
    return Human(
        id="p",
        capsules=[
            Capsule(name="torso", a=(x, y, 1.0), b=(x, y, 1.5), radius=0.17),
            Capsule(name="legs", a=(x, y, 0.1), b=(x, y, 0.95), radius=0.15),
        ],
    )


class _TrackerPlayer:
    """Publishes both trackers' frames at 50 Hz from a thread: nobody, or one person at a given floor position, who
    may walk (:meth:`walk_to`, :meth:`walk_out`) a step per frame."""

    def __init__(self, session: zenoh.Session) -> None:
        self.where: tuple[float, float] | None = None
        self._path: list[tuple[float, float] | None] = []
        self._lock = threading.Lock()
        self._pubs = {t: session.declare_publisher(keys.tracker_humans(CELL, t)) for t in TRACKERS}
        self._seq = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def walk_to(self, xy_m: tuple[float, float], then_gone: bool = False) -> None:
        """The person walks from where they are to ``xy_m`` (appears there if nobody is in the cell); ``then_gone``:
        and is no longer reported from there on."""
        with self._lock:
            if self.where is None:
                self._path = [xy_m]
            else:
                (x0, y0), (x1, y1) = self.where, xy_m
                steps = max(1, math.ceil(math.hypot(x1 - x0, y1 - y0) / STEP_M))
                self._path = [(x0 + (x1 - x0) * k / steps, y0 + (y1 - y0) * k / steps) for k in range(1, steps + 1)]
            if then_gone:
                self._path.append(None)

    def walk_out(self) -> None:
        """The person, if any, walks straight out of the covered volume (to -y) and is gone: seen leaving."""
        if self.where is not None:
            self.walk_to((self.where[0], EXIT_Y_M), then_gone=True)

    def walking(self) -> bool:
        with self._lock:
            return bool(self._path)

    def _run(self) -> None:
        while not self._stop.wait(TRACKER_PERIOD_S):
            self._seq += 1
            with self._lock:
                if self._path:
                    self.where = self._path.pop(0)
            humans = [] if self.where is None else [_person(self.where)]
            for tracker, pub in self._pubs.items():
                pub.put(to_payload(Humans(tracker=tracker, seq=self._seq, stamp_ns=time.time_ns(), humans=humans)))

    def put_raw(self, tracker: str, payload: bytes) -> None:
        self._pubs[tracker].put(payload)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


def _snapshot(doc: GatewayStatus) -> Snapshot:
    return {name: (r.zone, r.delta, frozenset(f.code for f in r.faults)) for name, r in doc.robots.items()}


class _StatusLog:
    """Every status document of the gateway (Zenoh, 25 Hz), reduced to a :data:`Snapshot` per document."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._log: list[Snapshot] = []

    def on_sample(self, sample: zenoh.Sample) -> None:
        snap = _snapshot(GatewayStatus.model_validate_json(sample.payload.to_bytes()))
        with self._lock:
            self._log.append(snap)

    def mark(self) -> int:
        with self._lock:
            return len(self._log)

    def since(self, mark: int) -> list[Snapshot]:
        with self._lock:
            return list(self._log[mark:])

    def last(self) -> Snapshot | None:
        with self._lock:
            return self._log[-1] if self._log else None


def _control_key(robot: str) -> str:
    """The run-time control key of the relay on ``robot``'s controller link (each relay its own)."""
    return f"hrc/{CELL}/faultinject/{robot}/control"


class TwoArms:
    """The running two-arm cell, what the test plays and what the gateway says.

    ``session`` is connected to the gateway; ``control[robot]`` to side A (the controller's side) of that robot's
    relay only, the way to reach its control key (Zenoh peers do not route for each other) without the other
    relay forwarding the control message.
    """

    def __init__(
        self,
        cell: Cell,
        player: _TrackerPlayer,
        status: _StatusLog,
        session: zenoh.Session,
        control: dict[str, zenoh.Session],
    ) -> None:
        self.cell = cell
        self.player = player
        self.status = status
        self.session = session
        self.control = control

    def cut_override_path(self, robot: str, for_s: float) -> None:
        """Cut the gateway → controller direction (b2a: the overrides) of ``robot``'s relay for ``for_s``."""
        self.control[robot].put(_control_key(robot), json.dumps({"partition_for_s": for_s, "dir": "b2a"}))

    def heal(self, robot: str) -> None:
        """End every cut of ``robot``'s relay."""
        self.control[robot].put(_control_key(robot), json.dumps({"heal": True}))

    def status_doc(self) -> GatewayStatus | None:
        """``GET /api/v1/status``, None while the gateway does not answer."""
        try:
            response = self.cell.get("/api/v1/status")
        except (httpx.HTTPError, OSError):
            return None
        return GatewayStatus.model_validate_json(response.content) if response.status_code == 200 else None

    def wait(self, predicate: Callable[[Snapshot], bool], timeout_s: float, what: str) -> int:
        """Wait until the newest status document satisfies ``predicate``; return the log's mark of it."""
        self.cell.wait(lambda: (s := self.status.last()) is not None and predicate(s), timeout_s, what)
        return self.status.mark()

    def wait_healthy(self, timeout_s: float = RECOVER_S) -> int:
        return self.wait(lambda s: all(_running(s, r) for r in ROBOTS), timeout_s, "both robots moving, no fault")

    def walk(self, xy_m: tuple[float, float]) -> None:
        """The person walks to ``xy_m`` (a step per frame); wait until they are there."""
        self.player.walk_to(xy_m)
        self.cell.wait(lambda: not self.player.walking(), WALK_S, f"the person walking to {xy_m}")

    def walk_out(self) -> None:
        """The person, if any, walks out of the covered volume; wait until they are gone."""
        self.player.walk_out()
        self.cell.wait(lambda: not self.player.walking(), WALK_S, "the person walking out of the covered volume")


def _running(snap: Snapshot, robot: str) -> bool:
    """The robot has no fault and a positive δ."""
    if robot not in snap:
        return False
    _, delta, faults = snap[robot]
    return not faults and delta > 0.0


def _stopped_with(robot: str, code: str) -> Callable[[Snapshot], bool]:
    def holds(snap: Snapshot) -> bool:
        zone, delta, faults = snap.get(robot, ("", 1.0, frozenset()))
        return code in faults and delta == 0.0 and zone == "safety_exception"

    return holds


def _commands(gw_ep: str, http_port: int, relay_eps: dict[str, str]) -> dict[str, tuple[str, list[str]]]:
    """The gateway and one controller emulator per robot, each reaching the gateway only through its own relay
    (side A listens at ``relay_eps[robot]``, side B connects to the gateway); no tracker emulator."""
    cfg = ["--config", str(CONFIG)]
    commands = {"gateway": ("gateway", [*cfg, "--zenoh-listen", gw_ep, "--http-port", str(http_port)])}
    for robot in ROBOTS:
        relay = [*cfg, "--a-listen", relay_eps[robot], "--b-connect", gw_ep, "--control-key", _control_key(robot)]
        commands[f"relay-{robot}"] = ("hrc_tools.faultinject", relay)
        args = [*cfg, "--robot", robot, "--zenoh-connect", relay_eps[robot]]
        commands[f"controller-{robot}"] = ("controller_emu", args)
    return commands


@pytest.fixture(scope="module")
def two_arms(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TwoArms]:
    tmp_path = tmp_path_factory.mktemp("two_arms")
    gw_ep, http_port = free_endpoint(), free_port()
    relay_eps = {robot: free_endpoint() for robot in ROBOTS}
    commands = _commands(gw_ep, http_port, relay_eps)
    logs = {name: tmp_path / f"{name}.log" for name in commands}
    cell = Cell({}, commands, http_port, gw_ep, "", logs, name=CELL)
    try:
        for name in commands:
            cell.start(name)
        with ExitStack() as sessions:
            session = sessions.enter_context(zenoh.open(session_config(connect=[gw_ep])))
            control = {
                r: sessions.enter_context(zenoh.open(session_config(connect=[ep]))) for r, ep in relay_eps.items()
            }
            status = _StatusLog()
            session.declare_subscriber(keys.gateway_status(CELL), status.on_sample)
            player = _TrackerPlayer(session)
            try:
                arms = TwoArms(cell, player, status, session, control)
                arms.wait_healthy(READY_S)
                cell.wait(lambda: arms.status_doc() is not None, READY_S, "the gateway's HTTP API answers")
                yield arms
            finally:
                player.close()
    finally:
        stop_all(cell.procs.values())


@pytest.fixture
def arms(two_arms: TwoArms) -> TwoArms:
    """The cell with nobody in it and both robots moving fault-free (whatever the previous test left)."""
    two_arms.walk_out()
    two_arms.wait_healthy()
    return two_arms


def _assert_kept_moving(snaps: list[Snapshot], robot: str, what: str) -> None:
    assert snaps, f"no status document while {what}"
    bad = [s[robot] for s in snaps if not _running(s, robot)]
    assert not bad, f"{robot} did not keep moving while {what}: {bad[:3]} (of {len(snaps)} documents)"


@pytest.mark.parametrize("how", ["freeze", "kill"])
@pytest.mark.parametrize("robot", ROBOTS)
def test_a_lost_controller_stops_its_robot_only(arms: TwoArms, robot: str, how: str) -> None:
    other = next(r for r in ROBOTS if r != robot)
    name = f"controller-{robot}"
    start = arms.status.mark()
    if how == "freeze":
        arms.cell.procs[name].send_signal(signal.SIGSTOP)
    else:
        arms.cell.procs[name].kill()
        arms.cell.procs[name].wait()
    arms.wait(_stopped_with(robot, "joint_state_stale"), DETECT_S, f"{robot} stopped on joint_state_stale")
    stopped = arms.status.mark()
    if how == "freeze":
        arms.cell.procs[name].send_signal(signal.SIGCONT)
    else:
        arms.cell.start(name)
    arms.wait_healthy()
    _assert_kept_moving(arms.status.since(start), other, f"{robot}'s controller was lost")
    assert stopped > start


@pytest.mark.parametrize("robot", ROBOTS)
def test_an_invalid_joint_state_stops_its_robot_only(arms: TwoArms, robot: str) -> None:
    other = next(r for r in ROBOTS if r != robot)
    start = arms.status.mark()
    key = keys.robot_state(CELL, robot)

    def bad_frames_seen(snap: Snapshot) -> bool:
        arms.session.put(key, b"{not json")  # repeated until seen: the first put may precede the route
        return _stopped_with(robot, "joint_state_invalid")(snap)

    arms.wait(bad_frames_seen, DETECT_S, f"{robot} stopped on joint_state_invalid")
    arms.wait_healthy()
    _assert_kept_moving(arms.status.since(start), other, f"{robot}'s joint state was invalid")


def test_an_invalid_tracker_frame_stops_every_robot(arms: TwoArms) -> None:
    def bad_frame_seen(snap: Snapshot) -> bool:
        arms.player.put_raw("side", b"{not json")
        return all(_stopped_with(r, "tracker_invalid")(snap) for r in ROBOTS)

    arms.wait(bad_frame_seen, DETECT_S, "every robot stopped on tracker_invalid")
    arms.wait_healthy()


@pytest.mark.parametrize(("where", "near", "far"), [(AT_UR5, "ur5", "panda"), (AT_PANDA, "panda", "ur5")])
def test_each_robot_zone_follows_the_person_near_it(
    arms: TwoArms, where: tuple[float, float], near: str, far: str
) -> None:
    arms.walk(where)
    slowed = ("reduced_speed", "safety_exception")
    start = arms.wait(lambda s: s[near][0] in slowed, ZONE_S, f"{near} slowed by the person beside it")
    # Then a second (25 status documents) of the person standing there: the robot near stays slowed, the far
    # one keeps full speed.
    arms.cell.wait(lambda: arms.status.mark() >= start + 25, ZONE_S, "one more second of status documents")
    snaps = arms.status.since(start)
    assert all(s[near][0] in slowed and not s[near][2] for s in snaps), [s[near] for s in snaps]
    far_seen = {(s[far][0], s[far][1], s[far][2]) for s in snaps}
    assert all(z in ("autonomous", "guarded_distance") and d == 1.0 and not f for z, d, f in far_seen), far_seen
    arms.walk_out()


# -- a joint state that contradicts the program ------------------------------------------------------------------


@pytest.fixture(scope="module")
def mid_range_q_rad() -> dict[str, list[float]]:
    """Per robot, every joint in the middle of its URDF range: a plausible position [rad]."""
    config = load_cell_config(CONFIG)
    mid = {}
    for robot in ROBOTS:
        model = load_robot_model(robot, config.robots[robot]).model
        mid[robot] = [(lo + hi) / 2 for lo, hi in zip(model.lowerPositionLimit, model.upperPositionLimit, strict=True)]
    return mid


def _inconsistent_state(robot: str, q_rad: list[float]) -> bytes:
    """A plausible joint state of ``robot`` whose first joint turns at 0.5 rad/s while its program stands still
    (qd_nominal = 0 at override 1): faster than override · qd_nominal allows (``streams.qd_tolerance_*``)."""
    n = len(q_rad)
    state = JointState(
        robot=robot,
        seq=1,
        stamp_ns=time.time_ns(),
        q=q_rad,
        qd=[0.5] + [0.0] * (n - 1),
        qd_nominal=[0.0] * n,
        override=1.0,
        override_seq=0,
        mode="running",
    )
    return to_payload(state)


@pytest.mark.parametrize("robot", ROBOTS)
def test_an_inconsistent_joint_state_stops_its_robot_only(
    arms: TwoArms, robot: str, mid_range_q_rad: dict[str, list[float]]
) -> None:
    other = next(r for r in ROBOTS if r != robot)
    before = arms.status_doc()
    assert before is not None
    other_counted = before.inputs.rejected.get(f"robot/{other}", {}).get("qd_inconsistent", 0)
    start = arms.status.mark()
    key = keys.robot_state(CELL, robot)
    shown: list[GatewayStatus] = []

    def fault_shown() -> bool:
        arms.session.put(key, _inconsistent_state(robot, mid_range_q_rad[robot]))  # repeated: see the invalid test
        doc = arms.status_doc()
        if doc is not None and _stopped_with(robot, "joint_state_inconsistent")(_snapshot(doc)):
            shown.append(doc)
        return bool(shown)

    arms.cell.wait(fault_shown, DETECT_S, f"/api/v1/status: {robot} stopped on joint_state_inconsistent")
    doc = shown[0]
    reasons = [f.reason for f in doc.robots[robot].faults if f.code == "joint_state_inconsistent"]
    assert reasons[0].startswith("qd_inconsistent: qd beyond override 1.000"), reasons
    assert doc.inputs.rejected[f"robot/{robot}"]["qd_inconsistent"] >= 1, doc.inputs.rejected
    assert _running(_snapshot(doc), other), doc.robots[other]
    assert doc.inputs.rejected.get(f"robot/{other}", {}).get("qd_inconsistent", 0) == other_counted
    arms.wait_healthy()
    _assert_kept_moving(arms.status.since(start), other, f"{robot}'s joint state was inconsistent")


# -- the override path lost ------------------------------------------------------------------------------------

CUT_S = 30.0
"""How long a cut of the override path lasts unless healed; the test heals it as soon as it has seen enough."""


def _codes(status: dict[str, Any]) -> set[str]:
    return {f["code"] for f in status["faults"]}


@pytest.mark.parametrize("robot", ROBOTS)
def test_a_lost_override_path_stops_its_robot_only(arms: TwoArms, robot: str) -> None:
    """The gateway's overrides no longer reach one controller (its relay drops gateway → controller) while its
    joint states still reach the gateway: the controller stops itself (watchdog), the gateway says why."""
    other = next(r for r in ROBOTS if r != robot)
    start = arms.status.mark()
    seen: list[dict[str, Any]] = []

    def stopped_by_its_watchdog() -> bool:
        arms.cut_override_path(robot, CUT_S)  # repeated until seen: the control session may still be connecting
        status = arms.cell.robot(robot)
        if status is not None and status["controller_mode"] == "protective_stop" and status["delta_applied"] == 0.0:
            seen.append(status)
        return bool(seen) and "override_path_stale" in _codes(seen[-1])

    def healed_and_healthy(snap: Snapshot) -> bool:
        arms.heal(robot)  # repeated until both robots run again
        return all(_running(snap, r) for r in ROBOTS)

    try:
        arms.cell.wait(stopped_by_its_watchdog, DETECT_S, f"{robot}'s controller in protective stop, path stale")
    finally:
        arms.wait(healed_and_healthy, RECOVER_S, "both robots moving again after the cut healed")
    status = seen[-1]
    assert status["delta"] == 0.0, status
    assert status["zone"] == "safety_exception", status
    reasons = [f["reason"] for f in status["faults"] if f["code"] == "override_path_stale"]
    assert reasons[0].startswith("newest override echoed was sent "), reasons
    # The joint states kept coming (only the gateway → controller direction was cut): not a lost controller.
    assert "joint_state_stale" not in _codes(status), status["faults"]
    assert status["data_age_s"]["joint_state"] < 0.2, status["data_age_s"]
    _assert_kept_moving(arms.status.since(start), other, f"{robot}'s override path was lost")


# -- the operator's view -----------------------------------------------------------------------------------------

FULL_SPEED = ("autonomous", "guarded distance")
SLOWED = ("reduced speed", "safety exception")
PAGE_JS = """
const page = {conn: document.getElementById('conn').textContent, cards: {}, links: {},
              humans: document.querySelectorAll('#top line.human').length,
              plot: [...document.querySelectorAll('#plot-robot option')].map(o => o.value)};
for (const card of document.querySelectorAll('#robots .robot[data-robot]'))
  page.cards[card.dataset.robot] = {name: card.querySelector('b').textContent,
                                    zone: card.querySelector('.zone').textContent};
for (const line of document.querySelectorAll('#top line.link[data-robot]'))
  page.links[line.dataset.robot] = (page.links[line.dataset.robot] || 0) + 1;
return page;
"""
"""What the operator page shows: LIVE/STALE, each robot's card (name, zone), its links drawn in the top view, the
robots the plot can show."""


def test_the_status_and_the_page_carry_both_robots(arms: TwoArms) -> None:
    page = arms.cell.get("/")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    assert "data-robot" in page.text
    doc = arms.status_doc()
    assert doc is not None
    assert set(doc.robots) == set(ROBOTS)
    config = load_cell_config(CONFIG)
    for robot in ROBOTS:
        base_x_m = config.robots[robot].base_pose_world.xyz[0]
        ends_x_m = [p[0] for link in doc.robots[robot].links for p in (link.a_m, link.b_m)]
        assert ends_x_m, f"no link capsules of {robot} in the status"
        assert all(abs(x - base_x_m) < 1.2 for x in ends_x_m), (robot, base_x_m, ends_x_m)  # within its reach


def test_the_operator_page_shows_both_robots_each_zone_following_its_person(arms: TwoArms) -> None:
    doc = arms.status_doc()
    assert doc is not None
    links = {robot: len(doc.robots[robot].links) for robot in ROBOTS}
    with chromium() as browser:
        browser.get(arms.cell.base_url + "/")
        seen: list[dict[str, Any]] = []

        def shows(zones: dict[str, tuple[str, ...]], someone: bool) -> Callable[[], bool]:
            def holds() -> bool:
                page: dict[str, Any] = browser.execute_script(PAGE_JS)
                seen.append(page)
                cards = page["cards"]
                return (
                    page["conn"] == "LIVE"
                    and sorted(cards) == sorted(ROBOTS)
                    and all(cards[r]["name"] == r and cards[r]["zone"] in zones[r] for r in ROBOTS)
                    and page["links"] == links
                    and sorted(page["plot"]) == sorted(ROBOTS)
                    and (page["humans"] > 0) == someone
                )

            return holds

        def wait_page(zones: dict[str, tuple[str, ...]], someone: bool, what: str) -> None:
            try:
                arms.cell.wait(shows(zones, someone), ZONE_S, what)
            except AssertionError as exc:
                raise AssertionError(f"the page showed {seen[-1] if seen else None}\n{exc}") from None

        wait_page({"ur5": ("autonomous",), "panda": ("autonomous",)}, False, "the page: both robots, nobody")
        arms.walk(AT_UR5)
        wait_page({"ur5": SLOWED, "panda": FULL_SPEED}, True, "the page: the UR5 slowed by the person beside it")
        arms.walk(AT_PANDA)
        wait_page({"ur5": FULL_SPEED, "panda": SLOWED}, True, "the page: the Panda slowed by the person beside it")
        arms.walk_out()
