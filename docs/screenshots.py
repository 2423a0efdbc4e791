"""Makes the README's trainer screenshots from this checkout, on the shipped socket model:

* docs/reaming.png: the reaming trainer (`/reaming`, the whole socket meshed at 2 mm, 1280x720) of a named trainee who planned a 48 mm cup on the native 46 mm socket, after the 46 mm
  reamer and then the 48 mm one at the safe zone's centre (the page's default aim and push), the
  cup's orientation confirmed;
* docs/report_reaming.png: the reaming sections of that session's assessment report;
* docs/sessions.png and docs/trainee.png: the session list and the trainee's page after a second
  session of the same trainee, aimed 5° off the plan;
* with ``--headset-only``, docs/headset_left.png and docs/headset_right.png: each eye of the
  reaming page (the patch model) in an emulated Meta Quest 3 (the iwer runtime, as the headset
  tests use it), the controller reaming.

    python3 docs/screenshots.py [--headset-only]

It starts `python -m thrsim serve` of this checkout (sessions in a temporary folder) and drives
Debian's headless Chromium with Playwright, as the browser tests do. On failure it exits 1 with
a one-line message.
"""

from __future__ import annotations

import io
import os
import sys
from pathlib import Path
from urllib.parse import quote, urljoin

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent))  # this checkout's thrsim (the server child inherits it), whatever is installed

from thrsim.app.drawing_bench import served_page  # noqa: E402
from thrsim.app.headset_bench import emulate_headset, enter_headset  # noqa: E402
from thrsim.learn.model_dir import SHIPPED_SOCKET_MODEL  # noqa: E402

WIDTH, HEIGHT = 1280, 720
TRAINEE = "Trainee A"
PLAN = {"plan-cup": 48, "plan-inc": 40, "plan-ant": 15, "plan-med": 0, "plan-sup": 0}
#: the reamers, in order, and the simulated seconds each reams (the 46 mm one seats on the native 46 mm socket, the 48 mm one cuts)
REAMERS = ((46, 0.5), (48, 0.5))
MIN_REMOVED = 100  # elements; fewer means the simulator did not ream
WAIT_MS = 600_000  # the simulation may run far behind real time on a busy machine
MAX_PNG_BYTES = 300_000
#: the whole socket meshed at 2 mm (thrsim ream's 1.5 mm takes a busy machine longer to serve than the 180 s a child is given),
#: the network uncompiled (what is pictured does not depend on it)
SERVE = ("--model", str(SHIPPED_SOCKET_MODEL), "--socket-element-size", "2", "--no-compile")

# The page is ready once the bone is drawn, or has said why reaming is unavailable.
READY = "window.trainer && (trainer.stats.framed && trainer.stats.visibleFaces > 0 || document.getElementById('unavailable').textContent !== '')"
# Paused, the drawn bone is the server's last state, and the start/pause messages have faded.
SETTLED = "!trainer.stats.last.reaming.running && trainer.stats.removed === trainer.stats.last.reaming.removed && document.getElementById('toasts').childElementCount === 0"
# The report's reaming part: from its first "Reaming" heading to the provenance note after the sections.
REAMING_SECTIONS = """() => {
  const first = [...document.querySelectorAll("h2")].find((h) => h.textContent.startsWith("Reaming"));
  if (!first) return null;
  const top = first.getBoundingClientRect().top + scrollY, bottom = document.querySelector("details").getBoundingClientRect().top + scrollY;
  const body = document.body.getBoundingClientRect();
  return { x: body.left - 8, y: top - 8, width: body.width + 16, height: bottom - top };
}"""


def save_png(screenshot: bytes, path: Path) -> int:
    """Write a screenshot as an optimised PNG (256 colours when that is needed to stay small),
    through a temporary name so that a failed run leaves the old file; returns its size in bytes."""
    from PIL import Image

    image = Image.open(io.BytesIO(screenshot)).convert("RGB")
    data = io.BytesIO()
    image.save(data, "PNG", optimize=True)
    if data.tell() > MAX_PNG_BYTES:
        data = io.BytesIO()
        image.quantize(256).save(data, "PNG", optimize=True)
    if data.tell() > MAX_PNG_BYTES:
        raise RuntimeError(f"{path.name} would be {data.tell()} bytes, over {MAX_PNG_BYTES}")
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_bytes(data.getvalue())
    os.replace(temporary, path)
    return data.tell()


def ream_a_session(page, aim: dict | None = None) -> dict:
    """Name the trainee (the page remembers), plan, ream with each of :data:`REAMERS` in turn, confirm
    the cup; the reaming state once paused and settled."""
    page.wait_for_function(READY, timeout=WAIT_MS)
    unavailable = page.text_content("#unavailable")
    if unavailable:
        raise RuntimeError(unavailable)
    if page.get_attribute("#trainee", "class") == "asking":
        page.fill("#trainee-id", TRAINEE)
        page.click("#trainee-save")
    for field, value in PLAN.items():
        page.fill(f"#{field}", str(value))
    page.click("#plan-set")
    page.wait_for_function(f"trainer.stats.last.reaming.plan.cup_diameter_mm === {PLAN['plan-cup']}", timeout=WAIT_MS)
    if aim is not None:
        page.evaluate(
            f"trainer.send({{type: 'reamer', inclination_deg: {aim['inclination_deg']}, anteversion_deg: {aim['anteversion_deg']}}})"
        )
    reamed_s = 0.0
    for size, seconds in REAMERS:
        page.select_option("#reamer-size", str(size))
        page.wait_for_function(
            f"trainer.stats.last.reaming.reamer.size_mm === {size} && !trainer.stats.last.reaming.running", timeout=WAIT_MS
        )
        page.click("#run")  # the aim (default: the safe zone's centre, 40°, 15°) and the default push, 230 N
        page.wait_for_function("trainer.stats.last.reaming.running", timeout=WAIT_MS)
        reamed_s += seconds
        page.wait_for_function(f"trainer.stats.last.reaming.time_s >= {reamed_s} || !trainer.stats.last.reaming.running", timeout=WAIT_MS)
        page.evaluate("trainer.send({type: 'run', action: 'pause'})")  # not the toggle: a run that stopped by itself stays stopped
    page.click("#confirm-cup")
    page.wait_for_function("trainer.stats.events.includes('cup_confirmed')", timeout=WAIT_MS)
    page.wait_for_function(SETTLED, timeout=WAIT_MS)
    return page.evaluate("trainer.stats.last.reaming")


# Each eye 640 × 640; the headset above the hip at a surgeon's eye height, the controller held as
# the reamer along the plan's axis 25 cm out of the socket, pushing at half the largest push.
EYE = 640
HEADSET_POSE = """() => {
  const d = window.emulatedHeadset, half = -30 * Math.PI / 360;
  d.position.set(0.03, 1.4, -0.1);
  d.quaternion.set(Math.sin(half), 0, 0, Math.cos(half));
}"""
REAMER_IN_HAND = """async () => {
  const THREE = await import("three");
  const plan = trainer.stats.last.reaming.plan, root = trainer.view.root.matrixWorld;
  const axis = new THREE.Vector3(...plan.axis).transformDirection(root);
  const grip = new THREE.Vector3(...plan.centre_m).applyMatrix4(root).addScaledVector(axis, 0.25);
  const turn = new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 0, 1), axis);
  const c = emulatedHeadset.controllers.right;
  c.position.set(grip.x, grip.y, grip.z);
  c.quaternion.set(turn.x, turn.y, turn.z, turn.w);
  c.updateButtonValue("trigger", 0.5);
}"""


def headset_eyes() -> None:
    """Each eye of the reaming page in the emulated headset, after the controller reamed a little."""
    with served_page("/reaming", 2 * EYE, EYE, prepare=emulate_headset) as (_, page):
        page.wait_for_function(READY, timeout=WAIT_MS)
        enter_headset(page, "immersive-vr")
        page.evaluate(HEADSET_POSE)
        page.evaluate(REAMER_IN_HAND)
        page.wait_for_function("trainer.stats.last.reaming.removed > 50", timeout=WAIT_MS)
        page.evaluate("emulatedHeadset.controllers.right.updateButtonValue('trigger', 0)")
        page.wait_for_function(SETTLED, timeout=WAIT_MS)
        page.wait_for_timeout(500)
        for eye, left in (("left", 0), ("right", EYE)):
            shot = page.screenshot(clip={"x": left, "y": 0, "width": EYE, "height": EYE})
            print(f"docs/headset_{eye}.png: {save_png(shot, DOCS / f'headset_{eye}.png')} bytes")


def main() -> None:
    if "--headset-only" in sys.argv[1:]:
        headset_eyes()
        return
    # render-scale=1: full resolution (the page lowers it while it draws slower than the display).
    with served_page("/reaming?render-scale=1", WIDTH, HEIGHT, *SERVE) as (_, page):
        reaming = ream_a_session(page)
        if reaming["removed"] < MIN_REMOVED:
            raise RuntimeError(f"only {reaming['removed']} elements removed in {reaming['time_s']:.1f} s of reaming")
        page.wait_for_timeout(500)  # the last state drawn
        size = save_png(page.screenshot(), DOCS / "reaming.png")
        print(
            f"docs/reaming.png: {size} bytes; {reaming['removed']} elements, {reaming['removed_volume_mm3']:.1f} mm³, depth {reaming['depth_mm']:.2f} mm in {reaming['time_s']:.1f} s"
        )

        page.click("#end")
        page.wait_for_function("trainer.stats.saved", timeout=WAIT_MS)
        page.goto(urljoin(page.url, page.evaluate("trainer.stats.saved.report")), timeout=WAIT_MS)
        clip = page.evaluate(REAMING_SECTIONS)
        if clip is None:
            raise RuntimeError("the report has no reaming section")
        size = save_png(page.screenshot(clip=clip, full_page=True), DOCS / "report_reaming.png")
        print(f"docs/report_reaming.png: {size} bytes")

        page.goto(urljoin(page.url, "/reaming?render-scale=1"), timeout=WAIT_MS)
        ream_a_session(page, {"inclination_deg": 45, "anteversion_deg": 20})
        page.click("#end")
        page.wait_for_function("trainer.stats.saved", timeout=WAIT_MS)
        page.goto(urljoin(page.url, "/sessions"), timeout=WAIT_MS)
        print(f"docs/sessions.png: {save_png(page.screenshot(), DOCS / 'sessions.png')} bytes")
        page.goto(urljoin(page.url, "/trainee/" + quote(TRAINEE.casefold())), timeout=WAIT_MS)
        print(f"docs/trainee.png: {save_png(page.screenshot(), DOCS / 'trainee.png')} bytes")


if __name__ == "__main__":
    try:
        main()
    except Exception as error:  # one line, whatever failed: server, browser, page or report
        sys.exit(f"docs/screenshots.py: {(str(error).strip().splitlines() or [type(error).__name__])[0]}")
