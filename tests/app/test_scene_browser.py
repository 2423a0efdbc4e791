"""The trainer pages' scene in a real headless Chromium against a real ``thrsim serve`` (the shipped
model): the pelvis's surface is drawn and the socket seen from the default view, the camera views
(reset, surgeon's eye) on both pages, the bone coloured by depth against the planned cup with its
legend in mm, the plan outlined, the inset's depth scale, the medial wall's warning and the sound
cue's switch."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from app_helpers import ServedTrainer, changed_fraction, keys, picture

from thrsim.app.drawing_bench import CHROMIUM, CHROMIUM_FLAGS

pytestmark = [
    pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)"),
    pytest.mark.timeout(600),
]

BACKGROUND = np.array([0x1B, 0x20, 0x26])
READY = "window.trainer && trainer.stats.states > 5 && trainer.view.pelvis && trainer.view.pelvis.geometry.index && trainer.stats.framed"


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    from playwright.sync_api import sync_playwright

    served = ServedTrainer(tmp_path_factory.mktemp("sessions"), timeout=300.0)  # the shipped model; a loaded machine starts it slowly
    try:
        with sync_playwright() as playwright:
            chromium = playwright.chromium.launch(executable_path=CHROMIUM, args=[*CHROMIUM_FLAGS, "--no-first-run"])
            chromium.served = served
            yield chromium
            chromium.close()
    finally:
        served.stop()


def _open(browser, path: str):
    page = browser.new_page(viewport={"width": 1100, "height": 720})
    page.problems = []
    page.on("pageerror", lambda error: page.problems.append(str(error)))
    page.goto(browser.served.url + path + "?render-scale=1", timeout=60_000)  # pictures compared: one resolution
    page.wait_for_function(READY + (" && trainer.stats.visibleFaces > 0" if path == "/reaming" else ""), timeout=120_000)
    page.wait_for_timeout(500)
    return page


@pytest.fixture(scope="module")
def reaming(browser):
    page = _open(browser, "/reaming")
    yield page
    page.close()


@pytest.fixture
def unreamed(browser):
    """A reaming page of its own (its own session): a plan is set before reaming, and other tests ream."""
    page = _open(browser, "/reaming")
    yield page
    page.close()


@pytest.fixture(scope="module")
def navigation(browser):
    page = _open(browser, "/")
    yield page
    page.close()


# Where a point of the bone's own frame (mm) is drawn on the canvas (CSS pixels).
_PROJECT = """([x, y, z]) => {
  const view = trainer.view, bone = trainer.bone().object;
  const ndc = bone.position.clone().set(x, y, z).applyMatrix4(bone.matrix).project(view.camera);
  return [(ndc.x + 1) / 2 * innerWidth, (1 - ndc.y) / 2 * innerHeight];
}"""


def test_the_pelvis_is_drawn_and_the_socket_is_seen_from_the_default_view(reaming):
    triangles = reaming.evaluate("trainer.view.pelvis.geometry.index.count / 3")
    assert 3_000 <= triangles <= 9_000
    assert reaming.evaluate("trainer.view.content.getObjectByName('sockets')") is None  # no tubes and discs any more
    # the floor of the socket, the bone being reamed (its articular face, 22 mm deep, around the pole:
    # the reamer's ray covers the pole itself), is in view, between the panels and above the legend
    angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    points = [reaming.evaluate(_PROJECT, [4.0 * np.cos(a), 4.0 * np.sin(a), -math.sqrt(22.0**2 - 4.0**2)]) for a in angles]
    assert all(300 < x < 840 and 40 < y < 560 for x, y in points)
    blocks = [np.s_[int(y) - 3 : int(y) + 4, int(x) - 3 : int(x) + 4] for x, y in points]
    shot = picture(reaming)
    assert all(np.all(np.abs(shot[b].reshape(-1, 3) - BACKGROUND).sum(axis=1) > 60) for b in blocks)  # drawn, not background
    # and what is drawn there is the bone being reamed, not the pelvis in front of it: without it, it changes
    reaming.evaluate("trainer.bone().object.visible = false; trainer.cavityView.onChange()")
    reaming.wait_for_timeout(400)
    without = picture(reaming)
    reaming.evaluate("trainer.bone().object.visible = true; trainer.cavityView.onChange()")
    reaming.wait_for_timeout(400)
    assert sum(changed_fraction(shot[b], without[b]) > 0.9 for b in blocks) >= 5  # some lie under the reamer's ray and shaft
    # the pelvis's socket around it too: its wall, 45° from the pole on the 23 mm sphere, is drawn bone
    polar = math.radians(45.0)
    ring = [
        reaming.evaluate(_PROJECT, [23.0 * math.sin(polar) * np.cos(a), 23.0 * math.sin(polar) * np.sin(a), -23.0 * math.cos(polar)])
        for a in angles
    ]
    drawn = [np.abs(shot[int(py), int(px)] - BACKGROUND).sum() > 60 for px, py in ring if 0 <= px < 1100 and 0 <= py < 720]
    assert len(drawn) == 8 and all(drawn)
    assert reaming.problems == []


def test_the_pelvis_is_shaded_as_lambert_once_and_only_its_socket_is_drawn_with_the_discard(reaming):
    # two draws: the triangles with a corner near the served bone (discarding what lies inside it) and the rest, plain
    far, near = reaming.evaluate("trainer.view.pelvis.geometry.groups.map((g) => [g.start, g.count, g.materialIndex])")
    total = reaming.evaluate("trainer.view.pelvis.geometry.index.count")
    assert far == [0, far[1], 0] and near == [far[1], total - far[1], 1] and 0 < near[1] < 0.2 * total
    # every triangle that reaches into the served bone's extent (its outer radius, mm in its frame) is in the near draw
    missed = reaming.evaluate(
        """(() => {
      const view = trainer.view, g = view.pelvis.geometry, served = view.servedExtent();
      const p = g.attributes.position, index = g.index.array;
      let missed = 0;
      for (let t = 0; t < g.groups[0].count; t += 3)
        for (let c = 0; c < 3; c++) {
          const v = view.camera.position.clone().fromBufferAttribute(p, index[t + c]).applyMatrix4(served.boneFromModel.value);
          if (v.length() < served.boneExtent.value.y) missed += 1;
        }
      return missed;
    })()"""
    )
    assert missed == 0
    # the colours shaded per vertex draw the pelvis as three.js's Lambert shading of it under the scene's lights does
    shaded = picture(reaming)
    reaming.evaluate(
        """(async () => {
      const THREE = await import("three"), pelvis = trainer.view.pelvis;
      window.shadedPelvis = pelvis.material;
      pelvis.material = new THREE.MeshLambertMaterial({ color: 0xe6d8b8 });
      pelvis.material.onBeforeCompile = shadedPelvis[1].onBeforeCompile;
      trainer.cavityView.onChange();
    })()"""
    )
    reaming.wait_for_timeout(400)
    lambert = picture(reaming)
    reaming.evaluate("trainer.view.pelvis.material = shadedPelvis; trainer.cavityView.onChange()")
    reaming.wait_for_timeout(400)
    pelvis_pixels = np.abs(lambert - BACKGROUND).sum(axis=2) > 60
    assert pelvis_pixels.mean() > 0.2  # the pelvis fills much of the view
    differ = np.abs(shaded.astype(int) - lambert.astype(int)).sum(axis=2) > 30
    assert differ.mean() < 0.02
    assert changed_fraction(shaded, picture(reaming)) < 0.01  # drawn shaded again
    assert reaming.problems == []


def _camera(page) -> np.ndarray:
    return np.array(page.evaluate("[...trainer.view.camera.position.toArray(), ...trainer.view.camera.quaternion.toArray()]"))


@pytest.mark.parametrize("path", ["/reaming", "/"])
def test_camera_reset_and_the_surgeons_view_change_the_view(reaming, navigation, path):
    page = reaming if path == "/reaming" else navigation
    home, first = _camera(page), picture(page)
    keys(page, "e")
    page.wait_for_timeout(400)
    surgeon = _camera(page)
    assert np.abs(surgeon - home).max() > 0.01 and changed_fraction(first, picture(page)) > 0.2
    # looking down the socket's axis (the planned cup's on the reaming page), 0.3 rad off it, past the reamer's shaft
    angle = page.evaluate(
        """() => {
      const view = trainer.view, plan = trainer.stats.last.reaming?.plan;
      const centre = plan ? plan.centre_m : view.sceneInfo.acetabulum[view.sceneInfo.side], axis = plan ? plan.axis : view.socketAxis();
      const eye = view.camera.position.clone().sub(view.camera.position.clone().fromArray(centre)).normalize();
      return Math.acos(eye.dot(view.camera.position.clone().fromArray(axis).normalize()));
    }"""
    )
    assert abs(angle - 0.3) < 1e-3
    keys(page, "Home")
    page.wait_for_timeout(400)
    assert np.allclose(_camera(page), home, atol=1e-9)
    assert changed_fraction(first, picture(page)) < 0.02  # the same view again (a landmark may pulse)
    # the buttons do the same
    page.click("#view-surgeon")
    page.wait_for_timeout(300)
    assert np.allclose(_camera(page), surgeon, atol=1e-9)
    page.click("#view-reset")
    page.wait_for_timeout(300)
    assert np.allclose(_camera(page), home, atol=1e-9)
    help_text = page.inner_text("#help") if page.is_visible("#help") else page.evaluate("document.getElementById('help').textContent")
    assert "surgeon's view" in help_text and "Home" in help_text and "E" in help_text
    assert page.problems == []


def test_the_bone_is_coloured_by_depth_against_the_plan_with_a_legend_in_mm(unreamed):
    reaming = unreamed
    legend = reaming.inner_text("#cavity-legend")
    assert "Depth against the plan (mm)" in legend and all(tick in legend for tick in ("−2", "−1", "0", "+1", "+2"))
    # the plan: the trainee's, outlined at its size, and the depth measured from its centre; a 44 mm
    # cup's hemisphere is the patch's articular face (22 mm), so the intact bone shows on plan (green)
    assert reaming.evaluate("trainer.stats.last.reaming.plan.cup_diameter_mm") == 48.0  # the default cup until set
    reaming.evaluate(
        "trainer.send({type: 'plan', cup_diameter_mm: 44, medialisation_mm: 0, superior_shift_mm: 0, inclination_deg: 40, anteversion_deg: 15})"
    )
    reaming.wait_for_function("trainer.stats.last.reaming.plan.cup_diameter_mm === 44", timeout=30_000)
    reaming.wait_for_timeout(400)
    plan = reaming.evaluate("trainer.stats.last.reaming.plan")
    outline_radius = reaming.evaluate(
        "(() => { const o = trainer.cavityView.outline; return o.visible ? o.matrix.getMaxScaleOnAxis() : 0; })()"
    )
    assert outline_radius == pytest.approx(plan["cup_diameter_mm"] / 2e3, rel=1e-6)
    uniforms = reaming.evaluate(
        "(() => { const p = trainer.bone().object.material.userData.plan; return [p.planCentre.value.toArray(), p.planRadius.value, p.depthColours.value]; })()"
    )
    assert np.allclose(uniforms[0], 0.0, atol=1e-6) and uniforms[1] == pytest.approx(plan["cup_diameter_mm"] / 2) and uniforms[2] == 1
    # the inset is a depth map with its scale beside it, in mm
    scale = reaming.locator("#inset-scale")
    assert scale.is_visible() and "mm" in scale.inner_text() and all(tick in scale.inner_text() for tick in ("−2", "0", "+2"))
    box, height = scale.bounding_box(), 720
    inset_left = 1100 - round(0.36 * height) - 8
    assert inset_left - 40 <= box["x"] + box["width"] <= inset_left and box["height"] == pytest.approx(0.36 * height, abs=2)
    # colouring by the bone's layers instead: the legend names them and the bone's colours change
    before = picture(reaming)
    reaming.select_option("#bone-colours", "layers")
    reaming.wait_for_timeout(400)
    assert "cortical bone" in reaming.inner_text("#cavity-legend") and not scale.is_visible()
    inset = np.s_[720 - 8 - 259 : 720 - 8, 1100 - 8 - 259 : 1100 - 8]
    assert changed_fraction(before[inset], picture(reaming)[inset]) > 0.2
    reaming.select_option("#bone-colours", "depth")
    reaming.wait_for_timeout(400)
    assert changed_fraction(before[inset], picture(reaming)[inset]) < 0.02
    assert reaming.problems == []


def test_the_bone_left_is_shown_and_warned_of_and_the_patch_has_no_medial_wall(reaming):
    not_modelled = "Medial wall: not modelled on the bone patch"
    assert not reaming.is_checked("#cue-sound")  # sound is off until the trainee asks for it
    assert reaming.inner_text("#medial-wall") == not_modelled and not reaming.is_visible("#wall-warning")
    keys(reaming, "Space")  # ream at the safe zone's centre: the patch goes through in about two seconds
    reaming.wait_for_function("trainer.stats.wallWarnings > 0", timeout=120_000)
    left = reaming.evaluate("trainer.stats.last.reaming.bone_left_mm")
    assert left is not None and left < 1.0
    assert reaming.evaluate("trainer.stats.last.reaming.medial_wall_remaining_mm") is None  # no number for a wall not modelled
    assert "break through" in reaming.inner_text("#wall-warning") or "Through the bone" in reaming.inner_text("#wall-warning")
    assert reaming.inner_text("#medial-wall").startswith(
        not_modelled + " · "
    ) and "mm of bone left before its far face" in reaming.inner_text("#medial-wall")
    reaming.wait_for_function("!trainer.stats.last.reaming.running", timeout=60_000)  # it pauses where it perforates
    keys(reaming, "r")  # restore the bone (the page asks first): nothing under the reamer to warn of
    reaming.click("#restore-yes")
    reaming.wait_for_function("trainer.stats.last.reaming.bone_left_mm === null", timeout=30_000)
    reaming.wait_for_timeout(300)
    assert not reaming.is_visible("#wall-warning") and reaming.inner_text("#medial-wall") == not_modelled
    assert reaming.problems == []


def test_the_sound_cue_follows_the_layer_the_reamer_cuts_when_switched_on(reaming):
    """The patch has one layer (no reamer of it reaches cancellous bone), so the cue is driven here with
    the states of the layered socket: the server's cancellous_reached event, once a reamer."""
    cue = """(kinds) => {
      const base = trainer.stats.last;
      for (const kind of kinds) {
        const events = kind ? [{ kind, time_s: 1, frame: 1, detail: "the 46 mm reamer left the subchondral plate for cancellous bone" }] : [];
        trainer.cavityView.apply({ ...base, reaming: { ...base.reaming, running: true, events } });
      }
      return trainer.stats.cues;
    }"""
    assert reaming.evaluate(cue, ["cancellous_reached"]) == 0  # off by default: no sound
    reaming.check("#cue-sound")
    assert reaming.evaluate(cue, ["cancellous_reached"]) == 1
    assert reaming.evaluate(cue, [None, "start", None]) == 1  # only on the event
    assert reaming.evaluate(cue, [None, "cancellous_reached"]) == 2
    reaming.uncheck("#cue-sound")
