"""The trainer in an emulated headset: a Meta Quest 3 in headless Chromium (``thrsim bench --headset``).

The `iwer` WebXR emulator (Meta's Immersive Web Emulation Runtime, an npm devDependency of the
page's folder) is injected by Playwright before the page loads, as the tests inject it: the shipped
pages never load it. The emulated headset draws both eyes side by side on the page's canvas, so a
viewport twice a Quest 3's per-eye resolution wide (2064×2208 per eye) draws each eye at that
resolution. Software WebGL (SwiftShader) makes the draw time a relative figure, to compare scenes
and changes; the headset's own budget is a frame at 72–90 Hz (11–14 ms for both eyes).
"""

from __future__ import annotations

import os
import statistics

from thrsim.app.drawing_bench import CHROMIUM, CHROMIUM_FLAGS, served_page
from thrsim.app.live import STATIC
from thrsim.errors import ThrsimInputError

#: the emulator's browser build (defines the global IWER)
IWER = STATIC / "node_modules" / "iwer" / "build" / "iwer.min.js"
#: a Meta Quest 3's per-eye resolution (pixels)
QUEST3_EYE = (2064, 2208)
#: installs an emulated Meta Quest 3 (stereo) over the browser's own WebXR, as window.emulatedHeadset
INSTALL_HEADSET = """(() => {
  const device = new IWER.XRDevice(IWER.metaQuest3, { stereoEnabled: true });
  device.installRuntime({ forceInstall: true });
  window.emulatedHeadset = device;
})();"""
# The headset looks down at the hip from a surgeon's eye height (xr.js puts the hip 1 m above the
# floor, 0.55 m ahead before calibration): 1.45 m up, pitched 39° down.
_LOOK_AT_HIP = """() => {
  const d = window.emulatedHeadset, half = -39 * Math.PI / 360;
  d.position.set(0, 1.45, 0);
  d.quaternion.set(Math.sin(half), 0, 0, Math.cos(half));
}"""


def emulate_headset(page) -> None:
    """Load the emulator into ``page`` (a Playwright page) before its scripts run."""
    if not IWER.exists():
        raise ThrsimInputError(f"the headset emulator is not installed ({IWER}): run npm ci in {STATIC}")
    page.add_init_script(path=str(IWER))
    page.add_init_script(script=INSTALL_HEADSET)


def enter_headset(page, mode: str = "immersive-vr") -> None:
    """Click the page's "Enter headset" button and wait for the headset's first frames."""
    page.wait_for_selector("#enter-vr" if mode == "immersive-vr" else "#enter-ar", timeout=30_000)
    page.click("#enter-vr" if mode == "immersive-vr" else "#enter-ar")
    page.wait_for_function("trainer.xr.session !== null && trainer.xr.frames > 3", timeout=60_000)
    page.evaluate(_LOOK_AT_HIP)


def time_headset(seconds: float = 10.0, path: str = "/reaming", chromium: str = CHROMIUM) -> dict:
    """Per-eye draw time of a page in the emulated Quest 3 at its per-eye resolution, with its draw calls and triangles."""
    load_before = os.getloadavg()
    width, height = 2 * QUEST3_EYE[0], QUEST3_EYE[1]
    with served_page(path, width, height, "--no-compile", chromium=chromium, prepare=emulate_headset) as (browser, page):
        page.wait_for_function("window.trainer && trainer.stats.states > 5", timeout=120_000)
        enter_headset(page)
        page.wait_for_timeout(2000)  # warm-up: shaders compiled, the bone and the panels drawn once
        page.evaluate("trainer.xr.timing.measure = true")
        first = page.evaluate("[performance.now(), trainer.xr.frames]")
        page.wait_for_timeout(seconds * 1000)
        last = page.evaluate("[performance.now(), trainer.xr.frames]")
        timing = page.evaluate("trainer.xr.timing")
        canvas = page.evaluate("[trainer.view.renderer.domElement.width, trainer.view.renderer.domElement.height]")
        chromium_version = browser.version
    frames = timing["drawMs"]
    if not frames:
        raise RuntimeError("the emulated headset drew no frame")
    ordered = sorted(frames)
    return {
        "what": "both eyes of the page drawn in an emulated Meta Quest 3 (iwer) at its per-eye resolution, software WebGL; "
        "per eye: half a stereo frame's time; a relative figure (the headset's budget: 72–90 Hz, 11–14 ms a frame for both eyes)",
        "page": path,
        "eye_pixels": [canvas[0] // 2, canvas[1]],
        "frames": len(frames),
        "frames_per_s": (last[1] - first[1]) / ((last[0] - first[0]) / 1000),
        "draw_ms_per_eye": {"median": statistics.median(frames) / 2, "p90": ordered[int(0.9 * (len(ordered) - 1))] / 2},
        "draw_calls_per_eye": timing["calls"] / 2,
        "triangles_per_eye": timing["triangles"] / 2,
        "chromium": chromium_version,
        "chromium_flags": CHROMIUM_FLAGS,
        "load_average_1min": [load_before[0], os.getloadavg()[0]],
    }
