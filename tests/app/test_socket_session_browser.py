"""A whole-socket session end to end: a real ``thrsim serve`` on 127.0.0.1 with the shipped socket
model (the native 46 mm socket meshed coarse) and a headless Chromium trainee who reams with the
46 mm reamer and then the 48 mm one (keys), hears the cue as the 48 mm reamer reaches cancellous
bone, reads the bone left before the medial wall (and its warning), sees native bone beyond the plan apart from
reamed bone, ends the session and reads a report whose figures are those of the saved file."""

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


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    served = ServedTrainer(
        tmp_path_factory.mktemp("sessions"), "--model", str(SHIPPED_SOCKET_MODEL), "--socket-element-size", "5", timeout=600
    )
    yield served
    served.stop()


def _ream(page, size_mm: int, until_s: float) -> None:
    """Step the reamer up with ``]`` to ``size_mm`` and ream (Space) until ``until_s`` of reaming in all."""
    while page.evaluate("trainer.stats.last.reaming.reamer.size_mm") < size_mm:
        before = page.evaluate("trainer.stats.last.reaming.reamer.size_mm")
        keys(page, "]")
        page.wait_for_function(f"trainer.stats.last.reaming.reamer.size_mm === {before + 1}", timeout=30_000)
    page.wait_for_function(f"document.getElementById('reamer').textContent === '{size_mm} mm'", timeout=30_000)
    keys(page, "Space")
    page.wait_for_function("trainer.stats.last.reaming.running", timeout=30_000)
    page.wait_for_function(f"trainer.stats.last.reaming.time_s >= {until_s} || !trainer.stats.last.reaming.running", timeout=WAIT_MS)
    page.evaluate("trainer.send({type: 'run', action: 'pause'})")
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
    _ream(page, 46, 0.5)
    _ream(page, 48, 1.25)
    # the cue sounded once, when the 48 mm reamer left the subchondral plate for cancellous bone
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
    assert found["reamer_sequence_mm"] == [46.0, 48.0] and found["cavity_diameter_mm"] == 48.0
    page.goto(urljoin(page.url, saved["report"]), timeout=60_000)
    report = page.inner_text("body")
    assert "46 → 48 mm" in report and "planned 48 mm cup" in report
    assert f"{record.removed_volume_mm3[-1]:.1f} mm³" in report
    for name in ("medial_wall_remaining_mm", "over_reaming_mm", "cavity_depth_error_mm"):
        assert f"{found[name]:.1f} mm" in report, name
    times = page.locator("table", has_text="reaming time").last.inner_text()
    for size, seconds in zip(found["reamer_sequence_mm"], found["time_per_reamer_s"], strict=True):
        assert f"{size:g} mm\t{seconds:.1f} s" in times
    assert page.locator("img").count() >= 2  # the course and the cavity against the plan
    assert not problems
    page.close()
