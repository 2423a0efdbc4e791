"""One trainee, one session, an honest record, never frozen, in a real headless Chromium against a
real ``thrsim serve`` with the shipped model: a perforation undone and the bone restored still
counts and scores; two tabs get two sessions, and an observer's view is read-only; a hidden page
pauses reaming and showing it goes on; a double click on End session saves one session; no
"tracking lost" after a session ends."""

from __future__ import annotations

import re
import shutil

import pytest
from app_helpers import ServedTrainer, keys

from thrsim.app.drawing_bench import CHROMIUM
from thrsim.report import build_assessment

pytestmark = [
    pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)"),
    pytest.mark.timeout(300),
]

_READY = "window.trainer && trainer.stats.hello && trainer.stats.states > 5"


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    trainer = ServedTrainer(tmp_path_factory.mktemp("sessions"))  # the shipped model
    yield trainer
    trainer.stop()


@pytest.fixture
def open_page(browser, served):
    """open_page(path) → a tab on the trainer, ready (its hello and a few states arrived); all closed after the test."""
    pages = []

    def open_page(path: str):
        page = browser.new_page(viewport={"width": 900, "height": 600})
        page.problems = []
        page.on("pageerror", lambda error: page.problems.append(str(error)))
        page.goto(served.url + path, timeout=30_000)
        page.wait_for_function(_READY, timeout=60_000)
        pages.append(page)
        return page

    yield open_page
    for page in pages:
        assert page.problems == []
        page.close()


def _visibility(page, state: str) -> None:
    """The page as the browser hides it (another tab, a minimised window) or shows it again."""
    page.evaluate(
        f"Object.defineProperty(document, 'visibilityState', {{value: '{state}', configurable: true}});"
        "document.dispatchEvent(new Event('visibilitychange'))"
    )


def test_a_perforation_undone_and_the_bone_restored_still_counts_and_scores(open_page, served):
    page = open_page("/reaming")
    for _ in range(15):
        keys(page, "ArrowUp")  # 55°: 15° off the socket's axis, through the bone within about two seconds
    page.wait_for_function("trainer.stats.last.angles && Math.abs(trainer.stats.last.angles.radiographic[0] - 55) < 0.5", timeout=10_000)
    keys(page, "Space")
    page.wait_for_function("['perforated', 'passed_through'].some((kind) => trainer.stats.events.includes(kind))", timeout=120_000)
    keys(page, "u")
    keys(page, "r")
    page.click("#restore-yes")  # restoring asks first
    page.wait_for_function("trainer.stats.events.includes('undo') && trainer.stats.events.includes('restore')", timeout=10_000)
    page.wait_for_function("trainer.stats.last.reaming.removed === 0", timeout=10_000)  # the bone is whole again
    page.click("#end")
    page.wait_for_function("trainer.stats.saved", timeout=30_000)
    saved = page.evaluate("trainer.stats.saved")
    assessment = build_assessment(saved["file"])
    points = {c.name: c for c in assessment.criteria}
    assert points["no perforation or breach"].points == 0 and points["no perforation or breach"].measured.startswith("perforated")
    assert points["cavity prepared"].points == 0 and points["no undo or restore"].points == 0
    assert assessment.metrics["perforations"] == 1 and assessment.metrics["undos"] == 1 and assessment.metrics["restores"] == 1
    report = page.request.get(served.url + saved["report"], timeout=60_000).text()
    assert (
        re.search(r"perforated(, no bone left in the reamer.{1,6}s path,)? at \d", report) and "Reaming: errors and corrections" in report
    )


def test_two_tabs_get_two_sessions_and_an_observer_watches_read_only(open_page):
    first, second = open_page("/reaming"), open_page("/reaming")
    one, two = (page.evaluate("trainer.stats.hello") for page in (first, second))
    assert one["session"] != two["session"] and one["role"] == two["role"] == "trainee"
    observer = open_page(one["observe"])
    hello = observer.evaluate("trainer.stats.hello")
    assert hello["session"] == one["session"] and hello["role"] == "observer"
    assert observer.evaluate("['run', 'undo', 'reset', 'force', 'end'].every((id) => document.getElementById(id).disabled)")
    assert "read-only" in observer.locator("#session-id").inner_text()
    keys(observer, "Space")  # its keys steer nothing: the trainee's reaming does not start
    first.wait_for_timeout(500)
    assert not first.evaluate("trainer.stats.last.reaming.running") and first.evaluate("trainer.stats.last.reaming.frame") == 0
    keys(first, "Space")
    first.wait_for_function("trainer.stats.last.reaming.frame > 10", timeout=60_000)
    assert second.evaluate("trainer.stats.last.reaming.frame") == 0 and not second.evaluate("trainer.stats.last.reaming.running")
    observer.wait_for_function("trainer.stats.last.reaming.frame > 10", timeout=30_000)  # it watches the first tab's reaming


def test_a_hidden_page_pauses_reaming_and_showing_it_goes_on(open_page):
    page = open_page("/reaming")
    keys(page, "Space")
    page.wait_for_function("trainer.stats.last.reaming.frame > 5", timeout=60_000)
    _visibility(page, "hidden")
    page.wait_for_function("trainer.stats.last.reaming.paused === 'page hidden'", timeout=10_000)
    held = page.evaluate("trainer.stats.last.reaming.frame")
    page.wait_for_timeout(1000)
    assert page.evaluate("trainer.stats.last.reaming.frame") == held and page.evaluate("trainer.stats.last.reaming.running")
    behind = page.evaluate("trainer.stats.last.reaming.behind_frames")
    _visibility(page, "visible")
    page.wait_for_function(f"trainer.stats.last.reaming.paused === null && trainer.stats.last.reaming.frame > {held}", timeout=30_000)
    # the hidden second is not owed: owed, it would be 60 frames due at once (a slow machine falls a few behind anyway)
    assert page.evaluate("trainer.stats.last.reaming.behind_frames") - behind < 30


def test_a_double_click_on_end_saves_one_session_and_no_tracking_lost_follows(open_page, served):
    page = open_page("/")
    landmark = page.evaluate("trainer.stats.last.registration.current")
    page.mouse.click(*page.evaluate(f"trainer.screenOf('{landmark}')"))  # the probe's tip on the first landmark
    page.wait_for_function("trainer.stats.last.registration.acquired.length > 0", timeout=30_000)
    before = set(served.sessions.glob("*.h5"))
    first = page.evaluate("trainer.stats.hello.session")
    page.dblclick("#end")
    page.wait_for_function(f"trainer.stats.saved && trainer.stats.hello.session !== '{first}'", timeout=30_000)
    page.wait_for_timeout(1500)  # the fresh session's first states
    assert [p.stem for p in set(served.sessions.glob("*.h5")) - before] == [first]  # one file, no empty one scored 0/100
    assert "tracking_lost" not in page.evaluate("trainer.stats.events")
    assert not any("tracking lost" in text for text in page.locator(".toast").all_inner_texts())
