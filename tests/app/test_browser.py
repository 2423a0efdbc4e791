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
        page.goto(served.url + "/?render-scale=1", timeout=30_000)  # pictures compared over time: one resolution
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
        measured.goto(served.url + "/?continuous=1&render-scale=1", timeout=30_000)  # a resolution change is no motion
        measured.wait_for_function("window.trainer && trainer.stats.states > 5 && trainer.stats.frames > 3", timeout=30_000)
        before = picture(measured)
        frames = measured.evaluate("trainer.stats.frames")
        measured.wait_for_function(f"trainer.stats.frames > {frames + 5}", timeout=30_000)
        assert changed_fraction(before, picture(measured)) > 0.0005  # the landmark's pulse alone: ~0.0001
    finally:
        measured.close()


# The render scale's rules (render_scale.js), fed frame timestamps: one call per animation frame;
# each step of the feed is (frames, ms between frames, draw every nth frame).
_FEED = """async (steps) => {
  const { RenderScale } = await import("/static/render_scale.js");
  const scale = new RenderScale();
  let now = 0;
  const seen = [];
  for (const [frames, interval, drawEvery] of steps) {
    for (let i = 0; i < frames; i++) {
      now += interval;
      scale.frame(now, i % drawEvery === 0);
    }
    seen.push(scale.scale);
  }
  return { seen, wait: scale.wait };
}"""


def test_render_scale_follows_the_frame_rate(page):
    rules = page.evaluate(
        "import('/static/render_scale.js').then((m) => ({ steps: m.STEPS, window: m.WINDOW, slow: m.SLOW_WINDOWS, wait: m.FIRST_WAIT_MS }))"
    )
    steps, window, wait = rules["steps"], rules["window"], rules["wait"]
    judged = rules["slow"] * window  # slow frames before a step down

    def feed(*chunks):
        return page.evaluate(_FEED, [list(chunk) for chunk in chunks])["seen"][1:]

    fast, slow = 1000 / 60, 1000 / 30
    display = (3, fast, 99)  # animation frames at 60 Hz with nothing drawn: the display's rate
    keeping_up = round(wait / fast)  # frames at 60 Hz that last the wait before a try
    assert feed(display, (20 * window, fast, 1)) == [1]  # keeps up: full resolution
    down = [display, (1, slow, 1)] + [(judged, slow, 1)] * (len(steps) - 1) + [(10 * window, slow, 1)]
    assert feed(*down) == [*steps, steps[-1]]  # a step down per run of slow windows, to the lowest
    assert feed(display, (window + 1, slow, 1), (10 * window, fast, 1)) == [1, 1]  # one slow window: a hiccup
    assert feed(display, (10 * window, slow, 2), (10 * window, slow, 3)) == [1, 1]  # drawn now and then: no rate to judge
    assert feed(display, (10 * window, 300, 1)) == [1]  # stalls are not a frame rate
    assert feed((1, 0, 1), (20 * window, slow, 1), (20 * window, 20, 1)) == [1, 1]  # 30 and 50 Hz displays, kept up with
    # Slow, then keeping up: stays down for the wait, then tries one step up.
    assert feed(display, (judged + 1, slow, 1), (keeping_up - window, fast, 1), (3 * window, fast, 1)) == [steps[1], steps[1], 1]
    # A try that turns out slow steps back down after one slow window and doubles the wait before
    # the next try.
    chunks = [
        display,
        (judged + 1, slow, 1),
        (keeping_up + window, fast, 1),
        (window, slow, 1),
        (2 * keeping_up - window, fast, 1),
        (3 * window, fast, 1),
    ]
    tried = page.evaluate(_FEED, chunks)
    assert tried["seen"][1:] == [steps[1], 1, steps[1], steps[1], 1] and tried["wait"] == 2 * wait


_BURN = """() => {
  window.burning = true;
  const burn = () => {
    const start = performance.now();
    while (performance.now() - start < 40);
    if (window.burning) requestAnimationFrame(burn);
  };
  requestAnimationFrame(burn);
}"""


def test_render_scale_drops_when_frames_are_slow_and_the_page_still_draws(page, served):
    slowed = page.context.browser.new_page(viewport={"width": 1100, "height": 720})
    try:
        slowed.goto(served.url + "/?continuous=1", timeout=30_000)
        slowed.wait_for_function("window.trainer && trainer.stats.states > 5 && trainer.stats.frames > 30", timeout=30_000)
        slowed.evaluate(_BURN)  # every animation frame 40 ms longer: about 20 frames/s on any machine
        slowed.wait_for_function("trainer.view.renderScale.scale < 1", timeout=60_000)
        slowed.evaluate("window.burning = false")
        scale, canvas = slowed.evaluate(
            "[trainer.view.renderScale.scale, [trainer.view.renderer.domElement.width, trainer.view.renderer.domElement.height]]"
        )
        assert canvas == [int(1100 * scale), int(720 * scale)]
        frames = slowed.evaluate("trainer.stats.frames")
        slowed.wait_for_function(f"trainer.stats.frames > {frames + 5}", timeout=30_000)
        drawn = picture(slowed)
        assert drawn.std() > 10 and len(np.unique(drawn.reshape(-1, 3), axis=0)) > 50  # stretched, not blank
    finally:
        slowed.close()


def test_render_scale_can_be_pinned(page, served):
    pinned = page.context.browser.new_page(viewport={"width": 1100, "height": 720})
    canvas = """(() => {
      const scale = trainer.view.renderScale, element = trainer.view.renderer.domElement;
      return [scale.scale, scale.changes, element.width, getComputedStyle(element).imageRendering];
    })()"""
    try:
        pinned.goto(served.url + "/?continuous=1&render-scale=0.5", timeout=30_000)
        pinned.wait_for_function("window.trainer && trainer.stats.frames > 60", timeout=60_000)
        assert pinned.evaluate(canvas) == [0.5, 0, 550, "pixelated"]  # each canvas pixel drawn as 2×2
        pinned.goto(served.url + "/?continuous=1&render-scale=0.75", timeout=30_000)
        pinned.wait_for_function("window.trainer && trainer.stats.frames > 60", timeout=60_000)
        assert pinned.evaluate(canvas) == [0.75, 0, 825, "auto"]  # stretched by 4/3: smoothed
    finally:
        pinned.close()
    assert page.evaluate("getComputedStyle(trainer.view.renderer.domElement).imageRendering") == "pixelated"  # 1:1


def test_safe_zone_colour_changes_when_the_aim_leaves_the_zone(page):
    page.locator("#steer-inc").fill("60")  # the default aim, whatever an earlier test left
    page.locator("#steer-ant").fill("10")
    wait_state(page, "s.angles && Math.abs(s.angles.radiographic[0] - 60) < 0.5 && Math.abs(s.angles.radiographic[1] - 10) < 0.5")
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


def test_the_other_hip_keeps_the_pages_aim(page):
    """The server starts the other hip from its default aim (60°, 10°); the page's sliders (40°, 15°) win."""
    page.locator("#steer-inc").fill("40")
    page.locator("#steer-ant").fill("15")
    wait_state(page, "s.angles && Math.abs(s.angles.radiographic[0] - 40) < 0.5 && Math.abs(s.angles.radiographic[1] - 15) < 0.5")
    for side in ("left", "right"):
        page.select_option("#side", side)
        page.wait_for_function(f"trainer.stats.acks.includes('{side} hip')", timeout=10_000)
        after = page.evaluate("trainer.stats.states") + 10  # states from after the switch
        page.wait_for_function(f"trainer.stats.states > {after}", timeout=10_000)
        wait_state(page, "s.angles && Math.abs(s.angles.radiographic[0] - 40) < 0.5 && Math.abs(s.angles.radiographic[1] - 15) < 0.5")


def test_registration_through_the_page_then_end_session_and_report(page, served):
    page.get_by_role("button", name="Restart").click()
    wait_state(page, "s.registration.acquired.length === 0")
    page.mouse.move(550, 360)
    page.mouse.wheel(0, 500)  # zoom out: every landmark between the side panels
    page.wait_for_timeout(300)
    places = page.evaluate("Object.keys(trainer.view.sceneInfo.landmarks).map((name) => trainer.screenOf(name))")
    assert all(300 < x < 1100 - 270 and 50 < y < 720 for x, y in places), places
    for _ in range(40):
        count = page.evaluate("trainer.stats.last.registration.acquired.length")
        if count == 27:
            break
        landmark = page.evaluate("trainer.stats.last.registration.current")
        page.mouse.click(*page.evaluate(f"trainer.screenOf('{landmark}')"))  # the probe's tip on the glowing point
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
