"""End to end in a real headless Chromium (Debian's, driven by Playwright; no browser download):
the page from a real ``thrsim serve``, WebGL2 drawing, OpenIGTLink moving a tool on the page,
the safe-zone colour, landmark registration through the page's controls, the report."""

from __future__ import annotations

import shutil
import time

import numpy as np
import pytest
from app_helpers import ServedTrainer, changed_fraction, keys, picture, reamer_to_reference, send_transform

from thrsim.app.drawing_bench import CHROMIUM, CHROMIUM_FLAGS
from thrsim.app.navigation import NavigationTrainer
from thrsim.session import read_session
from thrsim.session.navigation import read_navigation

pytestmark = pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    trainer = ServedTrainer(tmp_path_factory.mktemp("sessions"))
    yield trainer
    trainer.stop()


@pytest.fixture(scope="module")
def page(served):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=CHROMIUM,
            args=[*CHROMIUM_FLAGS, "--disable-background-networking", "--no-first-run"],
        )
        page = browser.new_page(viewport={"width": 1100, "height": 720})
        problems: list[str] = []
        page.on("pageerror", lambda error: problems.append(str(error)))
        page.goto(served.url + "/", timeout=30_000)
        page.wait_for_function("window.trainer && trainer.stats.states > 5 && trainer.stats.frames > 3", timeout=30_000)
        page.problems = problems
        yield page
        browser.close()


def wait_state(page, expression: str, timeout_ms: int = 30_000) -> None:
    try:
        page.wait_for_function(f"(() => {{ const s = trainer.stats.last; return !!s && ({expression}); }})()", timeout=timeout_ms)
    except Exception as error:
        last = page.evaluate("JSON.stringify({last: trainer.stats.last, errors: trainer.stats.errors})")
        raise AssertionError(f"page never reached {expression}: {last[:3000]}") from error


def test_webgl2_scene_is_drawn_and_follows_the_ir_camera(page):
    assert page.evaluate("!!document.createElement('canvas').getContext('webgl2')")
    before = picture(page)
    assert before.std() > 10 and len(np.unique(before.reshape(-1, 3), axis=0)) > 50  # not a blank canvas
    azimuth = page.evaluate("trainer.stats.last.camera.azimuth_deg")
    keys(page, "]")
    keys(page, "]")
    keys(page, "]")
    wait_state(page, f"s.camera.azimuth_deg === {azimuth + 15}")
    page.wait_for_timeout(300)
    assert changed_fraction(before, picture(page)) > 0.005
    for _ in range(3):
        keys(page, "[")
    wait_state(page, f"s.camera.azimuth_deg === {azimuth}")
    assert not page.problems


def test_openigtlink_transform_moves_the_reamer_on_the_page(page, served):
    before = picture(page)
    pose = reamer_to_reference(NavigationTrainer(side="right").targets, 25.0, 35.0)
    pose[:3, 3] += [0.03, 0.05, 0.0]
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        send_transform(served.igtl_port, "ReamerToReference", pose, count=5, interval_s=0.02)
        if page.evaluate("trainer.stats.last.tools.Reamer.source === 'tracker' && trainer.stats.last.tools.Reamer.tracked"):
            break
    state = page.evaluate("trainer.stats.last")
    assert state["tools"]["Reamer"]["source"] == "tracker"
    assert state["angles"]["radiographic"] == pytest.approx([25.0, 35.0], abs=0.01)
    assert changed_fraction(before, picture(page)) > 0.002


def test_continuous_drawing_moves_the_reamer_every_frame(page, served):
    # What `thrsim bench --browser` counts: frames of a scene that changes, not redraws of a still one.
    measured = page.context.browser.new_page(viewport={"width": 1100, "height": 720})
    try:
        measured.goto(served.url + "/?continuous=1", timeout=30_000)
        measured.wait_for_function("window.trainer && trainer.stats.states > 5 && trainer.stats.frames > 3", timeout=30_000)
        before = picture(measured)
        frames = measured.evaluate("trainer.stats.frames")
        measured.wait_for_function(f"trainer.stats.frames > {frames + 5}", timeout=30_000)
        assert changed_fraction(before, picture(measured)) > 0.0005  # the landmark's pulse alone: ~0.0001
    finally:
        measured.close()


def test_safe_zone_colour_changes_when_the_aim_leaves_the_zone(page):
    for _ in range(4):
        keys(page, "Shift+ArrowDown")  # 60° → 40° inclination
    for _ in range(5):
        keys(page, "ArrowRight")  # 10° → 15° anteversion
    wait_state(page, "s.tools.Reamer.source === 'page' && s.zone && s.zone.colour === 'green'")
    assert "green" in page.locator("#angles").get_attribute("class")
    for _ in range(4):
        keys(page, "Shift+ArrowRight")  # 35° anteversion: 10° outside the zone
    wait_state(page, "s.zone && s.zone.colour === 'red'")
    assert "red" in page.locator("#angles").get_attribute("class")
    for _ in range(4):
        keys(page, "Shift+ArrowLeft")
    wait_state(page, "s.zone && s.zone.colour === 'green'")


def test_registration_through_the_page_then_end_session_and_report(page, served):
    page.get_by_role("button", name="Restart").click()
    wait_state(page, "s.registration.acquired.length === 0")
    for _ in range(40):
        count = page.evaluate("trainer.stats.last.registration.acquired.length")
        if count == 27:
            break
        keys(page, "Space")
        wait_state(page, f"s.registration.acquired.length > {count}")
    wait_state(page, "s.registration.done && s.app_source === 'registered'")
    assert "done" in page.locator("#reg-target").inner_text()
    page.get_by_role("button", name="Confirm cup orientation").click()
    wait_state(page, "s.confirmed !== null")
    page.get_by_role("button", name="End session & get report").click()
    link = page.locator("#report-link")
    link.wait_for(timeout=15_000)
    report = page.request.get(served.url + link.get_attribute("href"), timeout=60_000)
    assert report.ok and "Assessment report" in report.text() and "27 of 27" in report.text()
    saved = page.evaluate("trainer.stats.saved")
    record = read_navigation(read_session(saved["file"]).groups["navigation"])
    assert record.completed and np.isfinite(record.residual_m).all() and len(record.confirmations) == 1
    assert not page.problems
