"""The trainer in a headset, tested without one: an emulated Meta Quest 3 (the `iwer` WebXR runtime,
injected by Playwright; the shipped pages never load it) in headless Chromium against a real
``thrsim serve --phantom`` with the shipped phantom and a tracker streaming over OpenIGTLink."""

from __future__ import annotations

import io
import shutil

import numpy as np
import pytest
from app_helpers import ServedTrainer, send_transform
from scipy.spatial.transform import Rotation

from thrsim.app.drawing_bench import CHROMIUM
from thrsim.app.headset_bench import IWER, emulate_headset, enter_headset
from thrsim.app.navigation import NavigationTrainer
from thrsim.nav.phantom import SIMULATED_PHANTOM, phantom_from_file, read_phantom_file
from thrsim.nav.rigid import invert, make_pose

pytestmark = [
    pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)"),
    pytest.mark.skipif(not IWER.exists(), reason="the iwer emulator is not installed (npm ci in thrsim/app/static)"),
    pytest.mark.timeout(400),
]

#: how close the calibrated scene lies to where the emulated tracker sees the phantom
PLACEMENT_TOLERANCE_MM, PLACEMENT_TOLERANCE_DEG = 1.0, 0.1
# The emulated room: the tracker 1.8 m ahead of the headset's origin, 1.6 m up, turned toward it.
HEADSET_FROM_TRACKER = make_pose(Rotation.from_euler("yx", [160, -20], degrees=True), np.array([0.3, 1.6, -1.8]))


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    served = ServedTrainer(tmp_path_factory.mktemp("sessions"), "--phantom", str(SIMULATED_PHANTOM))
    yield served
    served.stop()


def _headset_page(browser, served, path: str):
    page = browser.new_page(viewport={"width": 1000, "height": 500})  # each eye 500 × 500
    page.problems = []
    page.on("pageerror", lambda error: page.problems.append(str(error)))
    emulate_headset(page)
    page.goto(served.url + path, timeout=30_000)
    page.wait_for_function("window.trainer && trainer.stats.states > 5 && trainer.view.pelvis.geometry.attributes.position", timeout=60_000)
    return page


def _eyes(page) -> tuple[np.ndarray, np.ndarray]:
    from PIL import Image

    picture = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"), dtype=np.int16)
    half = picture.shape[1] // 2
    return picture[:, :half], picture[:, half:]


def _bone_mask(eye: np.ndarray) -> np.ndarray:
    """Where the bone is drawn: its lit bone-white (bright, red over green over blue)."""
    r, g, b = eye[..., 0], eye[..., 1], eye[..., 2]
    return (r > 120) & (r - b > 25) & (g - b > 10) & (r >= g)


def _set_controller(page, hand: str, ray_pose: np.ndarray) -> None:
    """The emulated controller's target ray at a pose (the headset's space, metres)."""
    q = Rotation.from_matrix(ray_pose[:3, :3]).as_quat()
    page.evaluate(
        "([hand, p, q]) => { const c = emulatedHeadset.controllers[hand]; c.position.set(...p); c.quaternion.set(...q); }",
        [hand, ray_pose[:3, 3].tolist(), q.tolist()],
    )
    frames = page.evaluate("trainer.xr.frames")
    page.wait_for_function(f"trainer.xr.frames > {frames + 2}", timeout=10_000)


def _matrix(page, expression: str) -> np.ndarray:
    """A three.js matrix of the page (column-major elements) as a 4×4 array."""
    return np.array(page.evaluate(f"{expression}.elements")).reshape(4, 4).T


def _right_controller(page) -> str:
    return "trainer.xr.controllers.find((c) => c.source?.handedness === 'right')"


@pytest.fixture
def navigation(browser, served):
    """A page of its own per test (its own session): each test enters the headset as it needs."""
    page = _headset_page(browser, served, "/")
    yield page
    page.close()


def test_a_page_without_a_headset_offers_none_and_the_pages_never_load_the_emulator(browser, served):
    for path in ("/", "/reaming"):
        page = browser.new_page()
        requested: list[str] = []
        page.on("request", lambda request, requested=requested: requested.append(request.url))
        page.goto(served.url + path, timeout=30_000)
        page.wait_for_function("window.trainer && trainer.stats.states > 2", timeout=60_000)
        page.wait_for_timeout(500)
        assert page.locator("button.headset").count() == 0 and page.evaluate("trainer.xr.session") is None
        assert any(url.endswith("/static/xr.js") for url in requested) and not any("iwer" in url for url in requested)
        page.close()


def test_a_session_starts_and_both_eyes_draw_the_bone(navigation):
    page = navigation
    assert page.locator("#enter-ar").is_visible() and page.locator("#enter-vr").is_visible()
    enter_headset(page, "immersive-vr")
    page.wait_for_timeout(500)
    left, right = _eyes(page)
    masks = _bone_mask(left), _bone_mask(right)
    assert masks[0].sum() > 2000 and masks[1].sum() > 2000  # the bone in each eye
    # the two eyes see it from 63 mm apart: the bone lies further left in the right eye's view
    centres = [np.argwhere(mask)[:, 1].mean() for mask in masks]
    assert centres[0] - centres[1] > 2.0
    assert np.abs(left - right).sum(axis=2).astype(bool).mean() > 0.01
    assert page.problems == [] and page.evaluate("trainer.stats.errors") == []
    # passthrough: the room shows where nothing is drawn
    page.evaluate("trainer.xr.session.end()")
    page.wait_for_function("trainer.xr.session === null", timeout=10_000)
    enter_headset(page, "immersive-ar")
    assert page.evaluate("trainer.xr.mode === 'immersive-ar' && trainer.view.scene.background === null")


def test_a_controller_acquires_a_landmark(navigation):
    page = navigation
    if page.evaluate("trainer.xr.session === null"):
        enter_headset(page, "immersive-ar")
    target = page.evaluate("trainer.stats.last.registration.current")
    landmark = np.array(page.evaluate(f"trainer.view.sceneInfo.landmarks[{target!r}]"))
    root = _matrix(page, "trainer.view.root.matrixWorld")
    tip_world = root[:3, :3] @ landmark + root[:3, 3]
    ray = make_pose(np.eye(3), tip_world + np.array([0.0, 0.0, 0.08]))  # the needle's tip 8 cm along the ray (−z)
    _set_controller(page, "right", ray)
    page.evaluate("emulatedHeadset.controllers.right.updateButtonValue('trigger', 1)")
    page.wait_for_function(f"trainer.stats.last.registration.acquired.includes({target!r})", timeout=30_000)
    page.evaluate("emulatedHeadset.controllers.right.updateButtonValue('trigger', 0)")
    assert "acquired" in page.evaluate("trainer.stats.events") and page.evaluate("trainer.xr.sent.probe") > 0


def test_the_calibration_places_the_bone_on_the_tracked_phantom(navigation, served):
    page = navigation
    if page.evaluate("trainer.xr.session === null"):
        enter_headset(page, "immersive-ar")
    phantom = phantom_from_file(read_phantom_file(SIMULATED_PHANTOM))
    # the tracker sees the phantom's marker array where the simulated camera would
    tracker_from_reference = invert(NavigationTrainer("right", phantom=phantom).camera_pose)
    send_transform(served.igtl_port, "ReferenceToTracker", tracker_from_reference, count=3, interval_s=0.05)
    page.wait_for_function("trainer.stats.last.tools.Reference.source === 'tracker'", timeout=10_000)
    # the controller seated in the calibration target's cradle: its grip on the target
    controller = _right_controller(page)
    grip_offset = invert(_matrix(page, f"{controller}.ray.matrixWorld")) @ _matrix(page, f"{controller}.grip.matrixWorld")
    grip_on_target = HEADSET_FROM_TRACKER @ tracker_from_reference @ phantom.target
    _set_controller(page, "right", grip_on_target @ invert(grip_offset))
    page.evaluate("emulatedHeadset.controllers.right.updateButtonValue('b-button', 1)")
    page.wait_for_function("trainer.stats.last.headset.state === 'done'", timeout=30_000)
    page.evaluate("emulatedHeadset.controllers.right.updateButtonValue('b-button', 0)")
    page.wait_for_function("trainer.stats.last.headset.placement !== null && trainer.xr.frames > 0", timeout=10_000)
    page.wait_for_timeout(300)
    drawn = _matrix(page, "trainer.view.root.matrixWorld")
    expected = HEADSET_FROM_TRACKER @ tracker_from_reference @ phantom.reference_from_model
    offset = invert(expected) @ drawn
    assert np.linalg.norm(drawn[:3, 3] - expected[:3, 3]) * 1e3 < PLACEMENT_TOLERANCE_MM
    assert np.degrees(Rotation.from_matrix(offset[:3, :3]).magnitude()) < PLACEMENT_TOLERANCE_DEG
    # the residual is shown on the headset's status panel
    assert "residual" in page.evaluate("trainer.xr.panels.status.shown")
    assert page.evaluate("trainer.stats.hello.scene.phantom.name").startswith("thrsim's simulated pelvis")


def test_a_controller_reams_with_the_triggers_push(browser, served):
    page = _headset_page(browser, served, "/reaming")
    page.wait_for_function("trainer.stats.last.reaming.available", timeout=60_000)
    enter_headset(page, "immersive-vr")
    # the controller's ray along the plan's cup axis, into the socket: its +z (the shaft) out of it
    axis = np.array(page.evaluate("trainer.stats.last.reaming.plan.axis"))
    rotation, _ = Rotation.align_vectors([axis], [[0.0, 0.0, 1.0]])
    centre = np.array(page.evaluate("trainer.stats.last.reaming.plan.centre_m"))
    root = _matrix(page, "trainer.view.root.matrixWorld")
    _set_controller(page, "right", make_pose(rotation, root[:3, :3] @ centre + root[:3, 3] + 0.2 * axis))
    page.wait_for_function("trainer.xr.sent.aim > 0", timeout=10_000)
    page.evaluate("emulatedHeadset.controllers.right.updateButtonValue('trigger', 0.5)")
    maximum = page.evaluate("trainer.stats.hello.defaults.max_force_n")
    page.wait_for_function(
        f"trainer.stats.last.reaming.force_n === {round(0.5 * maximum)} && trainer.stats.last.reaming.running", timeout=20_000
    )
    page.wait_for_function("trainer.stats.last.reaming.removed > 0", timeout=60_000)  # bone removed on the server
    page.evaluate("emulatedHeadset.controllers.right.updateButtonValue('trigger', 0)")
    page.wait_for_function("!trainer.stats.last.reaming.running && trainer.stats.last.reaming.force_n === 0", timeout=20_000)
    assert page.problems == [] and page.evaluate("trainer.stats.errors") == []
    page.close()
