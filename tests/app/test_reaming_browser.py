"""The reaming page in a real headless Chromium (Debian's, driven by Playwright) against a real
``thrsim serve`` with the shipped model: the bone is drawn, reaming removes it on screen."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from app_helpers import ServedTrainer, changed_fraction, keys, picture

from thrsim.app.drawing_bench import CHROMIUM, CHROMIUM_FLAGS

pytestmark = [
    pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)"),
    pytest.mark.timeout(240),
]


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    from playwright.sync_api import sync_playwright

    served = ServedTrainer(tmp_path_factory.mktemp("sessions"))  # the shipped model
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=[*CHROMIUM_FLAGS, "--no-first-run"])
            page = browser.new_page(viewport={"width": 1100, "height": 720})
            problems: list[str] = []
            page.on("pageerror", lambda error: problems.append(str(error)))
            page.goto(served.url + "/reaming?render-scale=1", timeout=30_000)  # pictures compared over time: one resolution
            page.wait_for_function(
                "window.trainer && trainer.stats.states > 5 && trainer.stats.visibleFaces > 0 && trainer.stats.frames > 2", timeout=60_000
            )
            page.problems = problems
            yield page
            browser.close()
    finally:
        served.stop()


# How far the reamer's drawn rotation is from its tracked pose's (sum of |Δ| over the 3×3).
_TURNED = "(() => { const r = trainer.view.tools.Reamer, a = r.group.matrix.elements, b = r.pose.elements; let d = 0; for (const i of [0, 1, 2, 4, 5, 6, 8, 9, 10]) d += Math.abs(a[i] - b[i]); return d; })()"


def test_the_bone_is_drawn_and_reaming_removes_it_on_screen(page):
    stats = page.evaluate("trainer.stats")
    assert stats["removed"] == 0 and stats["visibleFaces"] > 50
    before = picture(page)
    assert len(np.unique(before.reshape(-1, 3), axis=0)) > 50
    keys(page, "Space")  # start
    page.wait_for_function("trainer.stats.removed > 20 && trainer.stats.last.reaming.running", timeout=30_000)
    # the reamer turns about its axis while it reams: its drawn rotation leaves the tracked pose's
    page.wait_for_function(f"{_TURNED} > 0.05", timeout=10_000)
    keys(page, "Space")  # pause
    page.wait_for_function("!trainer.stats.last.reaming.running", timeout=10_000)
    page.wait_for_function(f"{_TURNED} < 1e-9", timeout=10_000)  # and stops when paused
    page.wait_for_function("trainer.stats.removed === trainer.stats.last.reaming.removed", timeout=10_000)
    # the faces kept up to date frame by frame (only the changed tets' and their neighbours') are
    # exactly the boundary a rebuild from the levels finds, with the same vertices and colours
    kept = page.evaluate(
        "(() => { const b = trainer.bone(); const s = b.faceSignature(), n = b.visibleFaces; b.rebuild(); return [s, n, b.faceSignature(), b.visibleFaces]; })()"
    )
    assert kept[0] == kept[2] and kept[1] == kept[3] > 50
    page.wait_for_timeout(300)
    after = picture(page)
    assert changed_fraction(before, after) > 0.002  # the removed bone is gone from the picture
    figures = page.evaluate("[document.getElementById('removed-volume').textContent, document.getElementById('depth').textContent]")
    assert not figures[0].startswith("0.0 ") and figures[1] != "0.00 mm"
    keys(page, "r")  # restore the bone: the page asks first
    page.click("#restore-yes")
    page.wait_for_function("trainer.stats.removed === 0 && trainer.stats.last.reaming.removed === 0", timeout=10_000)
    assert page.problems == [] and page.evaluate("trainer.stats.errors") == []  # every bone frame decoded


_RANDOM_FRAMES = """async () => {
  const { BonePatch } = await import('/static/bone.js');
  const mesh = trainer.bone().mesh, identity = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
  const kept = new BonePatch(mesh, identity, 8), rebuilt = new BonePatch(mesh, identity, 8);
  let seed = 12345;
  const random = () => { seed = (seed * 1103515245 + 12345) % 2147483648; return seed / 2147483648; };
  kept.levels.fill(8);
  kept.rebuild();
  const mismatches = [];
  let previous = new Uint32Array(0);
  for (let frame = 0; frame < 80; frame++) {
    // a frame's changes: tets removed or recoloured near one another, as a reamer's are, ids
    // ascending as the server sends them; every other frame puts the last frame's tets back (an
    // undo): the faces it exposed go again, and the slots handed out last are freed first
    let sorted = previous;
    if (frame % 2 === 1) {
      for (const id of previous) kept.levels[id] = 8;
    } else {
      const centre = Math.floor(random() * mesh.tets), ids = new Set();
      for (let k = 0; k < 300; k++) ids.add(Math.min(mesh.tets - 1, Math.max(0, centre + Math.floor((random() - 0.5) * 2000))));
      sorted = Uint32Array.from([...ids].sort((a, b) => a - b));
      for (const id of sorted) kept.levels[id] = random() < 0.6 ? 0 : 1 + Math.floor(random() * 8);
      previous = sorted;
    }
    kept.update(sorted);
    rebuilt.levels.set(kept.levels);
    rebuilt.rebuild();
    if (kept.faceSignature() !== rebuilt.faceSignature() || kept.visibleFaces !== rebuilt.visibleFaces) mismatches.push(frame);
  }
  return { mismatches, faces: kept.visibleFaces, drawn: kept.slotsUsed };
}"""


def test_faces_kept_frame_by_frame_match_a_rebuild_over_many_random_frames(page):
    result = page.evaluate(_RANDOM_FRAMES)
    assert result["mismatches"] == [] and result["faces"] > 1000
    assert result["drawn"] < 3 * result["faces"]  # freed slots are reused: the draw range stays near the faces drawn


def test_the_other_hip_keeps_the_pages_aim_and_push(page):
    """The server starts the other hip from its default aim (60°, 10°); the page's sliders win."""
    page.evaluate("document.getElementById('force').value = 300; document.getElementById('force').dispatchEvent(new Event('input'))")
    page.wait_for_function("trainer.stats.last.reaming.force_n === 300", timeout=10_000)
    page.select_option("#side", "left")
    page.wait_for_function("trainer.stats.acks.includes('left hip')", timeout=10_000)
    after = page.evaluate("trainer.stats.states") + 10  # states from after the switch
    page.wait_for_function(f"trainer.stats.states > {after}", timeout=10_000)
    page.wait_for_function(
        "(() => { const s = trainer.stats.last; const [inc, ant] = s.angles.radiographic;"
        " return Math.abs(inc - 40) < 0.5 && Math.abs(ant - 15) < 0.5 && s.reaming.force_n === 300; })()",
        timeout=10_000,
    )
    assert page.evaluate("trainer.stats.visibleFaces") > 50 and page.problems == []
