"""The operator page as a browser renders it, served by the real app from a board fed in this process (no cell):
the labels' text as rendered (δ stays δ), the plot's axes, the drawing's scale with a person near and far, what the
first paint says before any status, and a lost person holding the robot: drawn as a growing outline, listed with
what to do and the command that resets them, named in the robot's panel and in the events; an open robot's plan
drawn as the tool's path, with its replans, the time spent planning and the planner's restarts.

Uses Debian's chromium through selenium (``tests/headless_browser.py``); without them these tests skip and say
why. Screenshots of the page with a person near the robot and with a lost person holding it are written to
``/tmp/hrc-operator-page-test.png`` and ``/tmp/hrc-operator-page-lost-test.png``; the page with a plan drawn to
``/tmp/hrc-operator-page-plan-test.png``.
"""

from __future__ import annotations

import itertools
import re
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import pytest
import support.status_examples as ex
import uvicorn
from support.headless_browser import chromium

from gateway.http.api import StatusBoard, create_app
from gateway.status import effective_config
from hrc_contract.config import CellConfig
from hrc_contract.status_models import (
    CapsuleStatus,
    ClosestPair,
    Event,
    GatewayStatus,
    HumanCapsuleStatus,
    PlanStatus,
    TrackStatus,
)
from hrc_tools.cell.procs import free_port, wait_for

SCREENSHOT = Path("/tmp/hrc-operator-page-test.png")
LOST_SCREENSHOT = Path("/tmp/hrc-operator-page-lost-test.png")
PLAN_SCREENSHOT = Path("/tmp/hrc-operator-page-plan-test.png")
PUBLISH_EVERY_S = 0.04
"""The feeder publishes the current document at the gateway's status rate (25 Hz)."""
WAIT_S = 15.0

ARM_LINKS = (
    CapsuleStatus(name="base", a_m=(0.0, 0.0, 0.0), b_m=(0.0, 0.0, 0.5), radius_m=0.08),
    CapsuleStatus(name="upper_arm", a_m=(0.0, 0.0, 0.5), b_m=(0.4, 0.0, 0.5), radius_m=0.06),
    CapsuleStatus(name="forearm", a_m=(0.4, 0.0, 0.5), b_m=(0.4, 0.0, 0.9), radius_m=0.05),
    CapsuleStatus(name="tool", a_m=(0.4, 0.0, 0.9), b_m=(0.55, 0.0, 0.9), radius_m=0.04),
)
"""A robot arm of about the UR5's size; ``upper_arm`` is 0.4 m long along x (the tests measure the scale on it)."""
UPPER_ARM_M = 0.4
READABLE_PX_PER_M = 100.0
"""A view of 400 px shows the robot and a person near it at least at this scale (a 0.4 m link ≥ 40 px)."""


def person_at(x_m: float, human: str = "front/h1", grown_m: float = 0.0) -> list[HumanCapsuleStatus]:
    """A standing person at ``x_m`` on the x axis, an arm reaching toward the robot (−x), each capsule's radius grown
    by ``grown_m`` (a lost person's reach) [m]."""
    capsules = (
        ("torso", (x_m, 0.0, 0.9), (x_m, 0.0, 1.45), 0.18),
        ("head", (x_m, 0.0, 1.65), (x_m, 0.0, 1.65), 0.12),
        ("legs", (x_m, 0.0, 0.1), (x_m, 0.0, 0.85), 0.14),
        ("hand_r", (x_m, 0.0, 1.3), (x_m - 0.5, 0.0, 1.1), 0.05),
    )
    return [HumanCapsuleStatus(human=human, name=n, a_m=a, b_m=b, radius_m=r + grown_m) for n, a, b, r in capsules]


PERSON_WIDTH_X_M = 0.18 + 0.5 + 0.05
"""The person of :func:`person_at` seen from above spans this along x: torso radius, arm and hand radius [m]."""


def document(person_x_m: float | None, stamp_ns: int) -> GatewayStatus:
    """The cell with the arm and, unless None, a person at ``person_x_m``."""
    if person_x_m is None:
        robot = ex.robot_status(links=list(ARM_LINKS))
        humans: list[HumanCapsuleStatus] = []
    else:
        distance_m = person_x_m - 0.5 - 0.55 - 0.09
        robot = ex.robot_status(
            delta=0.6,
            zone="reduced_speed",
            min_distance_m=distance_m,
            closest=ClosestPair(human="front/h1", capsule="hand_r", link="tool"),
            links=list(ARM_LINKS),
        )
        humans = person_at(person_x_m)
    return ex.gateway_status(stamp_ns, ur5=robot).model_copy(update={"human_capsules": humans})


K_REACH_MPS = 1.6
"""How fast a lost person's reach grows in :func:`lost_document` [m/s]."""
LOST_AT_X_M = 1.0
LOST_AGE_AT_START_S = 0.5
LOST_ACTION = "person front/h1 lost {age_s:.1f} s ago (holds ur5): clear the area and reset"
"""The gateway's action text (``gateway.status.track_entries``)."""


def lost_document(stamp_ns: int, age_s: float) -> GatewayStatus:
    """The cell after the person at the tool vanished from every tracker ``age_s`` ago: lost, grown by
    ``K_REACH_MPS · age_s``, holding ur5 at δ = 0; a released person and a seen one beside them."""
    reach_m = round(K_REACH_MPS * age_s, 4)
    robot = ex.robot_status(
        delta=0.0,
        zone="safety_exception",
        min_distance_m=0.0,
        closest=ClosestPair(human="front/h1 (lost)", capsule="hand_r", link="tool"),
        links=list(ARM_LINKS),
    )
    common = {"tracker": "front", "capsules": 4, "holds": [], "released_by": None, "action": None}
    tracks = [
        TrackStatus(
            **{**common, "holds": ["ur5"], "action": LOST_ACTION.format(age_s=age_s)},
            label="front/h1",
            human="front/h1 (lost)",
            state="lost",
            last_seen_age_s=age_s,
            reach_m=reach_m,
        ),
        TrackStatus(**common, label="front/h2", human="front/h2", state="seen", last_seen_age_s=0.03, reach_m=0.0),
        TrackStatus(
            **{**common, "released_by": "redetected by front/h2"},
            label="side/h7",
            human="side/h7 (lost)",
            state="released",
            last_seen_age_s=2.5,
            reach_m=0.0,
        ),
    ]
    humans = person_at(LOST_AT_X_M, "front/h1 (lost)", reach_m) + person_at(-1.4, "front/h2")
    return ex.gateway_status(stamp_ns, ur5=robot).model_copy(update={"human_capsules": humans, "tracks": tracks})


class Server(NamedTuple):
    url: str
    play: Callable[[Callable[[int], GatewayStatus]], None]
    """``play(scene)``: from now on the feeder publishes ``scene(n)``, ``n`` counting its documents from 0."""
    board: StatusBoard

    def show(self, person_x_m: float | None) -> None:
        """From now on the feeder publishes the cell with a person at ``person_x_m`` (None: nobody)."""
        self.play(lambda n: document(person_x_m, ex.STAMP_NS + n * 40_000_000))

    def show_lost(self) -> None:
        """From now on the feeder publishes the cell with a lost person holding the robot, lost longer each time."""
        self.play(lambda n: lost_document(ex.STAMP_NS + n * 40_000_000, LOST_AGE_AT_START_S + n * PUBLISH_EVERY_S))


@pytest.fixture
def server(cell_config: CellConfig) -> Iterator[Server]:
    """The app on a free port, fed (once :attr:`Server.show` is called) with a new document every 40 ms."""
    board = StatusBoard(effective_config(cell_config))
    port = free_port()
    uvi = uvicorn.Server(uvicorn.Config(create_app(board), host="127.0.0.1", port=port, log_level="warning"))
    serving = threading.Thread(target=uvi.run, daemon=True)
    serving.start()
    wait_for(lambda: uvi.started, WAIT_S, "the app listens")
    scenes: list[Callable[[int], GatewayStatus]] = []
    stop = threading.Event()

    def feed() -> None:
        playing, n = None, 0
        while not stop.wait(PUBLISH_EVERY_S):
            if not scenes:
                continue
            if scenes[-1] is not playing:
                playing, n = scenes[-1], 0
            board.publish(playing(n))
            n += 1

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    try:
        yield Server(f"http://127.0.0.1:{port}", scenes.append, board)
    finally:
        stop.set()
        feeder.join()
        board.close()
        uvi.should_exit = True
        serving.join(10.0)


@pytest.fixture
def browser() -> Iterator[Any]:
    with chromium() as driver:
        yield driver


CONN_JS = "return [document.getElementById('conn').textContent, document.body.className];"
CARD_JS = 'return document.querySelector(`.robot[data-robot="${arguments[0]}"]`)?.innerText ?? null;'

SCALE_JS = """
const view = document.getElementById(arguments[0]);
const links = [...view.querySelectorAll('line.link')].map(
  l => [l.textContent, +l.getAttribute('x1'), +l.getAttribute('x2'), +l.getAttribute('y1'), +l.getAttribute('y2')]);
const ends = sel => [...view.querySelectorAll(sel)].flatMap(l => [[+l.getAttribute('x1'), +l.getAttribute('y1')],
                                                                  [+l.getAttribute('x2'), +l.getAttribute('y2')]]);
return {links, humans: ends('line.human'), robot: ends('line.link'),
        beyond: view.querySelectorAll('.human-beyond').length};
"""

TEXTS_JS = """
return [...document.querySelectorAll(arguments[0])].map(t => {
  const r = t.getBoundingClientRect();
  return {text: t.textContent, left: r.left, right: r.right, top: r.top, bottom: r.bottom};
});
"""


def px_per_m(browser: Any, view: str) -> float:
    """The drawn scale of ``view``, measured on the upper arm (0.4 m along x) [px of the 400 px view per m]."""
    links = browser.execute_script(SCALE_JS, view)["links"]
    upper = next(link for link in links if "upper_arm" in link[0])
    return float(abs(upper[2] - upper[1])) / UPPER_ARM_M


def inside_view(points: list[list[float]]) -> bool:
    return bool(points) and all(0.0 <= x <= 400.0 and 0.0 <= y <= 400.0 for x, y in points)


def overlapping(texts: list[dict[str, Any]]) -> list[tuple[str, str]]:
    """Pairs of texts whose rendered boxes intersect."""
    pairs = []
    for a, b in itertools.combinations(texts, 2):
        if a["left"] < b["right"] and b["left"] < a["right"] and a["top"] < b["bottom"] and b["top"] < a["bottom"]:
            pairs.append((a["text"], b["text"]))
    return pairs


def test_the_first_paint_says_connecting_not_stale_then_live(server: Server, browser: Any) -> None:
    browser.get(server.url + "/")
    text, _ = browser.execute_script(CONN_JS)
    assert text in ("CONNECTING", "NO DATA"), "before any status the page has no old data to call STALE"
    server.show(None)
    wait_for(lambda: browser.execute_script(CONN_JS)[0] == "LIVE", WAIT_S, "the page says LIVE")
    assert "stale" not in browser.execute_script(CONN_JS)[1]


def test_labels_are_rendered_as_written_delta_is_not_the_clearance(server: Server, browser: Any) -> None:
    server.show(1.6)
    browser.get(server.url + "/")
    wait_for(lambda: browser.execute_script(CONN_JS)[0] == "LIVE", WAIT_S, "the page says LIVE")
    headings = [h.text for h in browser.find_elements("tag name", "h2")]  # as rendered (CSS text-transform applied)
    plot = next(h for h in headings if h.lower().startswith("last 30 s of"))
    assert "δ commanded" in plot, plot
    assert "δ applied" in plot, plot
    assert "minimum distance [m]" in plot, plot
    assert not [h for h in headings if "Δ" in h], headings
    card = browser.execute_script(CARD_JS, "ur5")  # read at once: the cards are rebuilt at every status
    assert "δ commanded / applied / bound" in card
    assert "Δ (protective)" in card, "the clearance keeps its capital Δ"


def test_the_plot_has_a_delta_axis_a_distance_axis_and_a_time_axis_none_overlapping(
    server: Server, browser: Any
) -> None:
    server.show(1.6)
    browser.get(server.url + "/")
    wait_for(lambda: browser.execute_script(CONN_JS)[0] == "LIVE", WAIT_S, "the page says LIVE")
    wait_for(lambda: bool(browser.find_elements("css selector", "#plot path.series.delta")), WAIT_S, "δ is plotted")
    texts = browser.execute_script(TEXTS_JS, "#plot text")
    by_class = {
        cls: [t["text"] for t in browser.execute_script(TEXTS_JS, f"#plot text.{cls}")]
        for cls in ("delta-tick", "distance-tick", "time-tick", "axis-title")
    }
    assert by_class["delta-tick"] == ["0", "0.25", "0.5", "0.75", "1"]
    assert by_class["distance-tick"] == ["0", "0.5", "1", "1.5", "2"], "2 m at the top for a person 0.46 m away"
    assert by_class["time-tick"] == ["now", "−5 s", "−10 s", "−15 s", "−20 s", "−25 s", "−30 s"]
    assert by_class["axis-title"] == ["δ", "distance [m]"]
    assert overlapping(texts) == []
    plot = browser.execute_script("return document.getElementById('plot').getBoundingClientRect().toJSON();")
    for t in texts:
        assert plot["left"] <= t["left"], t
        assert t["right"] <= plot["right"], t
        assert plot["top"] <= t["top"], t
        assert t["bottom"] <= plot["bottom"], t


def test_a_person_near_the_robot_and_the_robot_are_drawn_at_a_readable_scale(server: Server, browser: Any) -> None:
    server.show(1.6)
    browser.get(server.url + "/")

    def framed() -> bool:
        drawn = browser.execute_script(SCALE_JS, "top")
        return inside_view(drawn["humans"]) and inside_view(drawn["robot"])

    wait_for(framed, WAIT_S, "the person and the robot are both in the top view")
    wait_for(lambda: px_per_m(browser, "top") >= READABLE_PX_PER_M, WAIT_S, "a readable scale")
    side = browser.execute_script(SCALE_JS, "side")
    assert inside_view(side["humans"])
    assert inside_view(side["robot"])
    SCREENSHOT.write_bytes(browser.get_screenshot_as_png())


def test_a_person_far_away_is_marked_at_the_edge_and_the_scale_comes_back(server: Server, browser: Any) -> None:
    """Someone entering at 6 m does not shrink the robot to a few pixels, and the scale does not stay small."""
    browser.get(server.url + "/")
    server.show(6.0)
    wait_for(lambda: browser.execute_script(SCALE_JS, "top")["beyond"] == 1, WAIT_S, "the person is marked")
    assert px_per_m(browser, "top") >= READABLE_PX_PER_M
    server.show(1.6)
    wait_for(lambda: browser.execute_script(SCALE_JS, "top")["beyond"] == 0, WAIT_S, "the person is drawn")
    server.show(None)
    wait_for(lambda: not browser.execute_script(SCALE_JS, "top")["humans"], WAIT_S, "nobody is drawn")
    wait_for(lambda: px_per_m(browser, "top") >= 1.5 * READABLE_PX_PER_M, WAIT_S, "the robot alone fills the view")


LOST_JS = """
const view = document.getElementById(arguments[0]);
const lost = view.querySelector('g.lost');
if (!lost) return null;
const box = lost.getBBox();
return {reach_m: +lost.getAttribute('data-reach-m'), human: lost.getAttribute('data-human'),
        width_px: box.width, px_per_m: +view.getAttribute('data-px-per-m'),
        dashed: !!lost.querySelector('[stroke-dasharray] path.lost-outline'),
        label: lost.querySelector('text.lost-label')?.textContent,
        seen_drawn: [...view.querySelectorAll('line.human')].map(l => l.textContent)};
"""


def lost_outline(browser: Any) -> dict[str, Any] | None:
    """The lost person's outline in the top view, read in one go, with the reach and the scale it was drawn at."""
    drawn: dict[str, Any] | None = browser.execute_script(LOST_JS, "top")
    return drawn


def test_a_lost_person_is_drawn_as_a_dashed_outline_that_grows_with_the_reach(server: Server, browser: Any) -> None:
    browser.get(server.url + "/")
    server.show_lost()
    wait_for(lambda: lost_outline(browser) is not None, WAIT_S, "the lost person is drawn")
    first = lost_outline(browser)
    assert first is not None
    assert first["human"] == "front/h1 (lost)"
    assert first["dashed"], "an outline, dashed"
    assert first["label"].startswith("front/h1 lost "), first["label"]
    assert first["seen_drawn"], "the seen person is drawn as a person"
    assert not [h for h in first["seen_drawn"] if h.startswith("front/h1")], "the lost one only as an outline"
    # Seen from above the person spans PERSON_WIDTH_X_M along x; lost, every capsule grows by the reach on each side.
    assert first["reach_m"] > 0.0
    width_m = first["width_px"] / first["px_per_m"]
    assert width_m >= PERSON_WIDTH_X_M + 2.0 * first["reach_m"] - 0.01, (width_m, first)
    assert width_m > PERSON_WIDTH_X_M + 0.5, "bigger than the person as last seen"

    def grown() -> bool:
        now = lost_outline(browser)
        return now is not None and now["reach_m"] >= first["reach_m"] + 2.0

    wait_for(grown, WAIT_S, "the outline grows while the person stays lost")
    later = lost_outline(browser)
    assert later is not None
    assert later["width_px"] / later["px_per_m"] >= PERSON_WIDTH_X_M + 2.0 * later["reach_m"] - 0.01, later
    assert later["px_per_m"] >= READABLE_PX_PER_M, "framed where last seen: the growing outline shrinks nothing"


PANELS_JS = """
return {people: document.getElementById('people').innerText,
        lost: [...document.querySelectorAll('#people .track.lost')].map(t => t.innerText),
        command: [...document.querySelectorAll('#people .track.lost code.reset')].map(c => c.textContent),
        robot: document.querySelector('.robot[data-robot="ur5"]')?.innerText ?? '',
        events: [...document.querySelectorAll('#events .event')].map(e => e.innerText)};
"""


def test_the_panels_say_who_is_lost_what_holds_the_robot_and_how_to_reset(server: Server, browser: Any) -> None:
    log = [
        Event(seq=1, stamp_ns=ex.STAMP_NS, kind="track_lost", track="front/h1",
              message="person front/h1 lost: no longer reported"),
        Event(seq=2, stamp_ns=ex.STAMP_NS, kind="track_released", track="side/h7", cause="redetected",
              message="person side/h7 released: redetected by front/h2"),
    ]  # fmt: skip
    for event in log:
        server.board.events.add(event)
    browser.get(server.url + "/")
    server.show_lost()
    wait_for(lambda: browser.execute_script(PANELS_JS)["lost"], WAIT_S, "the lost person is listed")
    wait_for(lambda: len(browser.execute_script(PANELS_JS)["events"]) == 2, WAIT_S, "the events are listed")
    shown = browser.execute_script(PANELS_JS)
    [lost] = shown["lost"]
    assert lost.startswith("front/h1 LOST"), lost
    assert "holds ur5" in lost, lost
    assert re.search(r"person front/h1 lost \d+\.\d s ago \(holds ur5\): clear the area and reset", lost), lost
    assert shown["command"] == ["hrc-reset-track --track front/h1 --operator <you>"]
    assert "redetected by front/h2" in shown["people"], "a released person says by what"
    assert "front/h2 SEEN" in shown["people"], shown["people"]
    assert shown["people"].index("front/h1") < shown["people"].index("front/h2"), "the lost first"
    assert "Held by a lost person" in shown["robot"], shown["robot"]
    assert "person front/h1 lost" in shown["robot"]
    newest, oldest = shown["events"]
    assert "person released (redetected)" in newest, newest
    assert "redetected by front/h2" in newest, newest
    assert "person lost" in oldest, oldest
    assert "person front/h1 lost" in oldest, oldest
    wait_for(lambda: browser.execute_script(CONN_JS)[0] == "LIVE", WAIT_S, "the page says LIVE")
    LOST_SCREENSHOT.write_bytes(browser.get_screenshot_as_png())


PLAN_PATH_M = [[0.55 - 0.03 * k, 0.6 * (k / 31) ** 2, 0.9 + 0.01 * k] for k in range(32)]
"""A plan's tool path as the gateway sends it (32 points, world frame) [m]: from the tool (0.55, 0, 0.9) back over
the robot and to the side."""


def plan_document(stamp_ns: int, deaths: int) -> GatewayStatus:
    """The arm following a plan around a person (asked for by the horizon check), its planner process died
    ``deaths`` times (restarted as often), with an event saying it adopted the plan."""
    plan = PlanStatus(
        following=True,
        plan_time_s=0.4,
        plan_duration_s=2.1,
        path_waypoints=5,
        reason="horizon",
        requests={"horizon": 3, "request": 1},
        adopted=2,
        rejected=1,
        failures={"no_path": 1},
        planning_last_s=0.123,
        planning_total_s=0.5,
        path_tool_m=PLAN_PATH_M,
        planner_running=True,
        planner_deaths=deaths,
        planner_restarts=deaths,
        planner_last_exit="signal SIGKILL" if deaths else "",
    )
    robot = ex.robot_status(delta=0.7, zone="guarded_distance", links=list(ARM_LINKS), plan=plan)
    return ex.gateway_status(stamp_ns, ur5=robot).model_copy(update={"human_capsules": person_at(1.6)})


PLAN_JS = """
const view = id => [...document.querySelectorAll(`#${id} polyline.plan-path`)].map(
  l => l.getAttribute('points').trim().split(/\\s+/).map(p => p.split(',').map(Number)));
const card = document.querySelector('.robot[data-robot="ur5"]');
return {top: view('top'), side: view('side'), goals: document.querySelectorAll('#top circle.plan-goal').length,
        rows: card ? [...card.querySelectorAll('tr.plan')].map(r => r.innerText) : [],
        events: [...document.querySelectorAll('#events .event')].map(e => e.innerText)};
"""


def test_the_plan_is_drawn_as_the_tool_s_path_with_its_replans_time_planning_and_the_planner_s_restarts(
    server: Server, browser: Any
) -> None:
    server.board.events.add(
        Event(seq=1, stamp_ns=ex.STAMP_NS, kind="plan_adopted", robot="ur5", cause="horizon",
              message="plan adopted: a person ahead on the path, 2.1 s long, planned in 123 ms")
    )  # fmt: skip
    browser.get(server.url + "/")
    server.play(lambda n: plan_document(ex.STAMP_NS + n * 40_000_000, deaths=0))
    wait_for(lambda: browser.execute_script(PLAN_JS)["top"], WAIT_S, "the plan's path is drawn")
    wait_for(lambda: browser.execute_script(PLAN_JS)["events"], WAIT_S, "the events are listed")
    shown = browser.execute_script(PLAN_JS)
    [top], [side] = shown["top"], shown["side"]
    assert len(top) == len(side) == len(PLAN_PATH_M)
    assert inside_view(top)
    assert inside_view(side)
    # drawn where the tool goes: x falls along the path (right to left in both views), z rises (up in the side view)
    assert top[0][0] > top[-1][0]
    assert side[0][0] > side[-1][0]
    assert side[0][1] > side[-1][1]
    assert shown["goals"] == 1
    rows = "\n".join(shown["rows"])
    assert "a plan around people (a person ahead on the path), 0.4 of 2.1 s" in rows, rows
    assert "horizon 3, request 1; adopted 2, too late 1, failed: no_path 1" in rows, rows
    assert "last 123 ms, total 0.5 s" in rows, rows
    assert "running" in rows
    assert "died" not in rows
    PLAN_SCREENSHOT.write_bytes(browser.get_screenshot_as_png())
    [event] = shown["events"]
    assert "replanned (horizon)" in event, event
    assert "planned in 123 ms" in event, event
    server.play(lambda n: plan_document(ex.STAMP_NS + n * 40_000_000, deaths=1))
    wait_for(lambda: "died 1×" in "".join(browser.execute_script(PLAN_JS)["rows"]), WAIT_S, "the restart is shown")
    assert "restarted 1× (last: signal SIGKILL)" in "".join(browser.execute_script(PLAN_JS)["rows"])
    server.show(1.6)  # back on the program: no plan, nothing drawn
    wait_for(lambda: not browser.execute_script(PLAN_JS)["top"], WAIT_S, "the path is gone with the plan")
    assert browser.execute_script(PLAN_JS)["rows"] == []
