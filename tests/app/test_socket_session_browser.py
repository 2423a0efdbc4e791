"""A whole-socket session end to end: a real ``thrsim serve`` on 127.0.0.1 with the shipped socket
model (the native 46 mm socket meshed at 3 mm) and a headless Chromium trainee who reams with the
46 mm reamer, the 48 mm one (which seats in the subchondral plate, reamed one size up) and the
50 mm one (keys), hears the cue as the 50 mm reamer reaches cancellous bone, reads the bone left
before the medial wall (and its warning), sees native bone beyond the plan apart from reamed bone,
ends the session and reads a report whose figures are those of the saved file; and a trainee at
1280×720 (the socket meshed coarse, 5 mm) who reaches every control of the panels, and is warned
before the 52 mm reamer pushed at 400 N breaks through the edge of the modelled bone."""

from __future__ import annotations

import shutil
from urllib.parse import urljoin

import pytest
from app_helpers import ServedTrainer, keys

from thrsim.app.drawing_bench import CHROMIUM
from thrsim.learn.model_dir import SHIPPED_SOCKET_MODEL
from thrsim.report.reaming_metrics import metrics
from thrsim.session.file import read_session
from thrsim.session.reaming import read_reaming

pytestmark = [
    pytest.mark.timeout(900),
    pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)"),
]

WAIT_MS = 300_000  # a loaded machine steps the socket slower than real time


def _served(tmp_path_factory, element_mm: str):
    served = ServedTrainer(
        tmp_path_factory.mktemp("sessions"), "--model", str(SHIPPED_SOCKET_MODEL), "--socket-element-size", element_mm, timeout=600
    )
    yield served
    served.stop()


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The socket meshed at 3 mm: fine enough that the reamers reach neither the wall nor the cut edge."""
    yield from _served(tmp_path_factory, "3")


@pytest.fixture(scope="module")
def served_coarse(tmp_path_factory):
    """The socket meshed at 5 mm: its cut edge close enough for the 52 mm reamer to break through."""
    yield from _served(tmp_path_factory, "5")


#: the page pauses the reaming itself, in the poll that first sees ``time_s`` past the mark (no round
#: trip through the test); the server still steps frames until the pause reaches it, a few on a loaded machine
_PAUSE_PAST = """(until) => {
  const reaming = trainer.stats.last.reaming;
  if (reaming.running && reaming.time_s < until) return false;
  if (reaming.running) trainer.send({ type: "run", action: "pause" });
  return true;
}"""


def _ream(page, size_mm: int, seconds: float) -> None:
    """Step the reamer up with ``]`` to ``size_mm`` and ream (Space) with it for ``seconds`` (and the frames the pause takes to arrive)."""
    while page.evaluate("trainer.stats.last.reaming.reamer.size_mm") < size_mm:
        before = page.evaluate("trainer.stats.last.reaming.reamer.size_mm")
        keys(page, "]")
        page.wait_for_function(f"trainer.stats.last.reaming.reamer.size_mm === {before + 1}", timeout=30_000)
    page.wait_for_function(f"document.getElementById('reamer').textContent === '{size_mm} mm'", timeout=30_000)
    until_s = page.evaluate("trainer.stats.last.reaming.time_s") + seconds
    keys(page, "Space")
    page.wait_for_function("trainer.stats.last.reaming.running", timeout=30_000)
    page.wait_for_function(_PAUSE_PAST, arg=until_s, timeout=WAIT_MS)
    page.wait_for_function("!trainer.stats.last.reaming.running", timeout=30_000)


def test_a_socket_session_from_the_page_to_its_report(served, browser):
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    problems: list[str] = []
    page.on("pageerror", lambda error: problems.append(str(error)))
    page.goto(served.url + "/reaming", timeout=60_000)
    page.wait_for_function("window.trainer && trainer.stats.framed && trainer.stats.visibleFaces > 0", timeout=WAIT_MS)
    if page.get_attribute("#trainee", "class") == "asking":
        page.fill("#trainee-id", "Trainee S")
        page.click("#trainee-save")
    assert page.evaluate("trainer.stats.hello.scene.reaming.bone") == "socket"
    assert page.evaluate("trainer.stats.last.reaming.plan.cup_diameter_mm") == 48  # the default plan, on the native 46 mm socket
    page.check("#cue-sound")
    # one size up, the 48 mm reamer seats and cuts the subchondral plate: on this mesh it leaves the plate
    # after some 0.87 s of its own reaming (after the 46 mm one's 0.5 s), so 0.45 s leaves 25 frames for the pause
    _ream(page, 46, 0.5)
    _ream(page, 48, 0.45)
    assert page.evaluate("trainer.stats.events.includes('cancellous_reached')") is False  # one size up: still in the plate
    _ream(page, 50, 0.2)  # the plate thinned, the 50 mm reamer reaches cancellous bone within some 0.05 s
    # the cue sounded once, when the 50 mm reamer left the subchondral plate for cancellous bone
    page.wait_for_function("trainer.stats.events.includes('cancellous_reached')", timeout=30_000)
    assert (
        page.evaluate("trainer.stats.cues") == page.evaluate("trainer.stats.events.filter((k) => k === 'cancellous_reached').length") == 1
    )
    # the medial wall is the socket's: its distance, never "not modelled"
    wall = page.inner_text("#medial-wall")
    left = page.evaluate("trainer.stats.last.reaming.bone_left_mm")
    assert page.evaluate("trainer.stats.last.reaming.medial_wall_modelled") and wall == f"Medial wall: {left:.1f} mm of bone left"
    # the warning before the medial wall: the socket's own words, from the state's bone left (0.6 mm: a state the page is given)
    warned = page.evaluate(
        """(() => {
          const last = trainer.stats.last;
          trainer.cavityView.apply({ ...last, reaming: { ...last.reaming, bone_left_mm: 0.6, events: [] } });
          const warning = document.getElementById("wall-warning");
          return [warning.classList.contains("hidden"), warning.textContent];
        })()"""
    )
    assert warned == [False, "Medial wall close: 0.6 mm of bone left"]
    # every drawn face knows whether a reamer made it (the bone across it removed) or it is native bone: both are drawn
    faces = page.evaluate(
        """(() => {
          const b = trainer.bone(), seen = [0, 0];
          for (let slot = 0; slot < b.slotsUsed; slot++) {
            const face = b.faceAt[slot];
            if (face < 0) continue;
            const cut = b.cut[3 * slot];
            if (cut !== (b.mesh.neighbours[face] >= 0 ? 1 : 0)) return null;
            seen[cut] += 1;
          }
          return seen;
        })()"""
    )
    assert faces is not None and faces[0] > 0 and faces[1] > 0
    page.click("#end")
    page.wait_for_function("trainer.stats.saved", timeout=WAIT_MS)
    saved = page.evaluate("trainer.stats.saved")
    record = read_reaming(read_session(saved["file"]).groups["reaming"])
    found = metrics(record)
    assert found["reamer_sequence_mm"] == [46.0, 48.0, 50.0] and found["cavity_diameter_mm"] == 50.0
    page.goto(urljoin(page.url, saved["report"]), timeout=60_000)
    report = page.inner_text("body")
    assert "46 → 48 → 50 mm" in report and "planned 48 mm cup" in report
    assert f"{record.removed_volume_mm3[-1]:.1f} mm³" in report
    for name in ("medial_wall_remaining_mm", "over_reaming_mm", "cavity_depth_error_mm"):
        assert f"{found[name]:.1f} mm" in report, name
    times = page.locator("table", has_text="reaming time").last.inner_text()
    for size, seconds in zip(found["reamer_sequence_mm"], found["time_per_reamer_s"], strict=True):
        assert f"{size:g} mm\t{seconds:.1f} s" in times
    assert page.locator("img").count() >= 2  # the course and the cavity against the plan
    assert not problems
    page.close()


#: every shown control and read-out of the page's panels (their ids given), scrolled into view within
#: its panel (never the page): the problems found (one line each), and whether the page itself can scroll
_PANELS_REACHABLE = """((panels) => {
  const problems = [];
  for (const id of panels) {
    const panel = document.getElementById(id);
    for (const item of panel.querySelectorAll("input, select, button, a, tr, li, #medial-wall, #cut-edge, #zone-text")) {
      if (item.closest(".hidden")) continue; // not shown in this state
      item.scrollIntoView({ block: "nearest", inline: "nearest" });
      const r = item.getBoundingClientRect(), p = panel.getBoundingClientRect();
      const name = `${id} ${item.id || item.tagName} ${item.textContent.trim().slice(0, 30)}`;
      if (r.width === 0 || r.height === 0) { problems.push(`${name}: no size`); continue; }
      if (r.top < p.top - 0.5 || r.bottom > p.bottom + 0.5 || r.left < p.left - 0.5 || r.right > p.right + 0.5) problems.push(`${name}: outside its panel`);
      if (r.top < 0 || r.bottom > innerHeight || r.left < 0 || r.right > innerWidth) problems.push(`${name}: off the window`);
      const hit = document.elementFromPoint((r.left + r.right) / 2, (r.top + r.bottom) / 2);
      if (!hit || !item.contains(hit)) problems.push(`${name}: covered by ${hit && (hit.id || hit.tagName)}`);
    }
  }
  const page = document.scrollingElement;
  const scrolls = page.scrollTop !== 0 || page.scrollLeft !== 0 || page.scrollHeight > innerHeight || page.scrollWidth > innerWidth;
  return { problems, scrolls };
})"""


def _every_control_reachable(page) -> None:
    """The panels', and the help's (opened, then closed again)."""
    page.wait_for_function("!document.querySelector('#toasts .toast')", timeout=30_000)  # passing messages gone
    assert page.evaluate(_PANELS_REACHABLE, ["topbar", "steps", "readouts", "cavity-legend"]) == {"problems": [], "scrolls": False}
    page.click("#help-toggle")
    assert page.evaluate(_PANELS_REACHABLE, ["help"]) == {"problems": [], "scrolls": False}
    page.click("#help-close")
    assert not page.is_visible("#help")


def test_the_panels_fit_or_scroll_within_and_the_page_warns_before_the_modelled_bones_edge(served_coarse, browser):
    """At 1280×720 (and 1920×1080) every control and read-out of the panels is on screen or scrolls
    into view within its panel, the page never scrolls; the 52 mm reamer pushed at 400 N breaks
    through the socket's cut edge, and the page warned before it, in the edge's own words."""
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    problems: list[str] = []
    page.on("pageerror", lambda error: problems.append(str(error)))
    page.goto(served_coarse.url + "/reaming", timeout=60_000)
    page.wait_for_function("window.trainer && trainer.stats.framed && trainer.stats.states > 3", timeout=WAIT_MS)
    page.wait_for_timeout(500)  # the panels' text follows the next drawn frame
    _every_control_reachable(page)  # the tallest controls panel: the trainee's name asked first
    if page.get_attribute("#trainee", "class") == "asking":
        page.fill("#trainee-id", "Trainee E")
        page.click("#trainee-save")
    assert page.is_visible("#cut-edge") and page.inner_text("#cut-edge") == "Edge of the modelled bone: —"
    page.select_option("#reamer-size", "52")
    page.wait_for_function("trainer.stats.last.reaming.reamer.size_mm === 52", timeout=30_000)
    page.evaluate("trainer.send({type: 'force', newton: 400})")
    page.wait_for_function("trainer.stats.last.reaming.force_n === 400", timeout=30_000)
    keys(page, "Space")
    page.wait_for_function("trainer.stats.events.includes('perforated')", timeout=WAIT_MS)
    page.wait_for_function("!trainer.stats.last.reaming.running", timeout=30_000)
    events = page.evaluate("trainer.stats.events")
    assert events.index("edge_warning") < events.index("perforated") and "medial_wall_breached" not in events
    assert page.evaluate("trainer.stats.edgeWarnings") >= 1 and page.evaluate("trainer.stats.wallWarnings") == 0
    page.wait_for_function("document.getElementById('cut-edge').textContent.endsWith('0.0 mm of bone left')", timeout=30_000)
    assert page.get_attribute("#cut-edge", "data-level") == "bad" and page.is_visible("#edge-warning")
    assert page.inner_text("#edge-warning") == "Edge of the modelled bone reached: the simulated bone ends here"
    assert not page.is_visible("#wall-warning") and page.evaluate("trainer.stats.last.reaming.bone_left_mm") > 1.0
    page.wait_for_function("!document.querySelector('.force-row.hidden')", timeout=30_000)  # the read-outs at their tallest
    _every_control_reachable(page)
    page.set_viewport_size({"width": 1920, "height": 1080})
    page.wait_for_timeout(500)
    _every_control_reachable(page)
    assert not problems
    page.close()
