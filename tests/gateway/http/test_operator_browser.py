"""The operator page in a real headless browser (Debian's chromium driven by selenium through chromedriver),
against the real cell: the zone text and the drawing change when the person of the default scenario walks in,
and the page says STALE within a second of the gateway being stopped. Saves ``docs/operator-page.png``.

The browser is installed by ``scripts/bootstrap.sh`` (as root with apt); without it this test skips and says why.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support.headless_browser import chromium
from support.paths import REPO_ROOT

from hrc_contract.status_models import EffectiveConfig, EventsResponse
from hrc_tools.cell.procs import running_cell, stop_program, wait_for

pytestmark = pytest.mark.e2e

SCREENSHOT = REPO_ROOT / "docs" / "operator-page.png"
"""The README's screenshot: rewritten only when HRC_UPDATE_SCREENSHOT=1 (a test run leaves the checkout clean)."""
SCENARIO_LOOP_S = 30.0
"""The default scenario (walk_in_reach_leave) repeats every 30 s: nobody for 3 s, then the person walks in."""

VIEW_JS = """
const robot = document.querySelector('.robot[data-robot="ur5"] .zone');
const ends = sel => [...document.querySelectorAll(sel)].flatMap(
  l => [[+l.getAttribute('x1'), +l.getAttribute('y1')], [+l.getAttribute('x2'), +l.getAttribute('y2')]]);
return {conn: document.getElementById('conn').textContent,
        zone: robot ? robot.textContent : null,
        humans: document.querySelectorAll('#top line.human').length,
        links: document.querySelectorAll('#top line.link').length,
        closest: document.querySelectorAll('#top line.closest').length,
        seen: [...document.querySelectorAll('#people .track.seen')].map(t => t.dataset.track),
        drawn: ends('#top line.human, #top line.link, #side line.human, #side line.link'),
        px_per_m: +document.getElementById('top').getAttribute('data-px-per-m'),
        headings: [...document.querySelectorAll('h2')].map(h => h.innerText)};
"""
READABLE_PX_PER_M = 70.0
"""A person close to the robot and the robot are drawn at least at this scale (the views are 400 px wide)."""


@pytest.fixture
def browser() -> Iterator[Any]:
    with chromium() as driver:
        yield driver


def test_the_page_follows_a_person_walking_in_and_says_stale_when_the_gateway_stops(
    browser: Any, tmp_path: Path
) -> None:
    with running_cell(tmp_path) as cell:
        wait_for(lambda: cell.robot() is not None, 60.0, "the gateway answers", [cell.gateway])
        browser.get(cell.base_url + "/")
        seen: list[dict[str, Any]] = []

        def view() -> dict[str, Any]:
            state: dict[str, Any] = browser.execute_script(VIEW_JS)
            seen.append(state)
            return state

        def nobody(s: dict[str, Any]) -> bool:
            # the cell running with nobody in it; not the start-up, when faults hold the robot in safety exception
            return bool(s["conn"] == "LIVE" and s["humans"] == 0 and s["links"] > 0 and s["zone"] == "autonomous")

        def nobody_then_someone() -> bool:
            state = view()
            return any(nobody(s) for s in seen) and state["humans"] > 0 and state["zone"] != "autonomous"

        wait_for(nobody_then_someone, 2 * SCENARIO_LOOP_S + 15.0, "the page shows nobody, then the person walking in")
        after = seen[-1]
        assert after["zone"] in ("guarded distance", "reduced speed", "safety exception")
        assert after["closest"] == 1, "the closest pair is drawn once someone is seen"
        assert after["seen"], "the People panel lists the person seen"
        close = ("reduced speed", "safety exception")
        wait_for(lambda: view()["zone"] in close and seen[-1]["humans"] > 0, SCENARIO_LOOP_S, "the person comes close")
        shot = SCREENSHOT if os.environ.get("HRC_UPDATE_SCREENSHOT") == "1" else tmp_path / SCREENSHOT.name
        wait_for(lambda: view()["px_per_m"] >= READABLE_PX_PER_M, 5.0, "the views zoom in on the person and the robot")
        shot.write_bytes(browser.get_screenshot_as_png())
        assert shot.stat().st_size > 10_000  # a real rendering, not an empty page
        shown = seen[-1]
        assert all(0.0 <= x <= 400.0 and 0.0 <= y <= 400.0 for x, y in shown["drawn"]), "person and robot in view"
        plot = next(h for h in shown["headings"] if h.lower().startswith("last 30 s of"))  # as rendered
        assert "δ commanded" in plot, plot
        assert "δ applied" in plot, plot
        events = EventsResponse.model_validate_json(cell.get("/api/v1/events").content).events
        sha = EffectiveConfig.model_validate_json(cell.get("/api/v1/config").content).config_sha256
        assert [e.kind for e in events[:2]] == ["start", "config_loaded"]
        assert events[1].config_sha256 == sha
        entered = {e.zone for e in events if e.kind == "zone_changed"}
        assert "autonomous" in entered
        assert entered & {"reduced_speed", "safety_exception"}, entered

        stopped_s = time.monotonic()
        cell.gateway.send_signal(signal.SIGINT)  # Ctrl-C; watched from the page while the gateway shuts down
        wait_for(lambda: view()["conn"] == "STALE", 5.0, "the page says STALE")
        stale_after_s = time.monotonic() - stopped_s
        assert stop_program(cell.gateway) == 0, "the gateway's shutdown did not hang on the open stream"
        assert stale_after_s < 1.0, f"STALE shown {stale_after_s:.2f} s after the gateway was told to stop"
        print(f"STALE shown {stale_after_s:.3f} s after SIGINT to the gateway")
        assert "stale" in browser.find_element("tag name", "body").get_attribute("class")
