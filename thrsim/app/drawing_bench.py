"""Drawing speed of the trainer page (``thrsim bench --browser``).

A real ``thrsim serve`` child process (this code: the parent of the imported ``thrsim`` leads its
``PYTHONPATH``) and Debian's headless Chromium driven by Playwright with software WebGL2, on the
page's ``?continuous=1`` (it draws every animation frame and turns the reamer each time, so the
scene changes on every frame; headless Chromium paces frames at 60 Hz, the most this can show).
Frames per second and Chromium's CPU time per frame (steadier under load) are both reported,
with the render scale the page drew at (it lowers its resolution while it draws slowly).
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import thrsim
from thrsim.errors import ThrsimInputError

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--no-sandbox", "--headless", "--disable-gpu", "--enable-unsafe-swiftshader"]
_ANNOUNCE = re.compile(r"http://127\.0\.0\.1:(\d+)/")

# What the page reports about itself: WebGL renderer (through the debug extension, when offered),
# canvas size in device pixels (the render scale's), the last frame's draw calls and triangles.
_PAGE_INFO = """() => {
  const renderer = trainer.view.renderer, gl = renderer.getContext();
  const debug = gl.getExtension("WEBGL_debug_renderer_info");
  return {
    webgl_renderer: debug ? gl.getParameter(debug.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
    canvas: [renderer.domElement.width, renderer.domElement.height],
    device_pixel_ratio: devicePixelRatio,
    render_scale: trainer.view.renderScale.scale,
    draw_calls: renderer.info.render.calls,
    triangles: renderer.info.render.triangles,
  };
}"""
# Read at the start and the end of the count: time, frames drawn, states received, render scale
# and how often it changed so far.
_COUNTERS = (
    "[performance.now(), trainer.stats.frames, trainer.stats.states, trainer.view.renderScale.scale, trainer.view.renderScale.changes]"
)


def chromium_cpu_seconds() -> float | None:
    """CPU seconds (user + system) used so far by this process's Chromium descendants (Linux)."""
    proc = Path("/proc")
    if not (proc / "self" / "stat").exists():
        return None
    children: dict[int, list[int]] = {}
    stats: dict[int, list[str]] = {}
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            text = (entry / "stat").read_text()
        except OSError:  # the process ended meanwhile
            continue
        name, fields = text[text.index("(") + 1 : text.rindex(")")], text[text.rindex(")") + 2 :].split()
        stats[int(entry.name)] = [name, *fields]
        children.setdefault(int(fields[1]), []).append(int(entry.name))
    ticks, stack, seen = 0, [os.getpid()], set()
    while stack:
        pid = stack.pop()
        for child in children.get(pid, []):
            if child not in seen:
                seen.add(child)
                stack.append(child)
                if "chrom" in stats[child][0]:
                    ticks += int(stats[child][12]) + int(stats[child][13])  # utime, stime
    return ticks / os.sysconf("SC_CLK_TCK")


def serve_child(sessions: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    """``thrsim serve`` of this code in a child process on free ports; (process, page URL)."""
    code_root = str(Path(thrsim.__file__).resolve().parents[1])
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in [code_root, os.environ.get("PYTHONPATH", "")] if p),
        "PYTHONUNBUFFERED": "1",
    }
    process = subprocess.Popen(
        [sys.executable, "-m", "thrsim", "serve", "--port", "0", "--igtl-port", "0", "--sessions", str(sessions), "--seed", "7", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    found: list[str] = []
    announced = threading.Event()

    def read() -> None:
        for line in process.stdout:  # type: ignore[union-attr]  # (stdout=PIPE: never None) drained to the end, so the child never blocks on a full pipe
            match = _ANNOUNCE.search(line)
            if match and not found:
                found.append(f"http://127.0.0.1:{match.group(1)}")
                announced.set()

    threading.Thread(target=read, daemon=True).start()
    if not announced.wait(180):  # it compiles the reaming network first (tens of seconds on a cold cache)
        stop_child(process)
        raise RuntimeError("thrsim serve did not start within 180 s")
    return process, found[0]


def stop_child(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)


def check_browser(chromium: str = CHROMIUM) -> None:
    """Playwright and Chromium are there, or a one-line error saying how to get them."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        raise ThrsimInputError("page benchmarks need Playwright for Python (pip install playwright; ./install.sh installs it)") from None
    if not Path(chromium).exists():
        raise ThrsimInputError(f"page benchmarks need Chromium at {chromium} (./install.sh installs Debian's)")


@contextlib.contextmanager
def served_page(path: str, width: int, height: int, *serve_args: str, chromium: str = CHROMIUM, prepare=None):
    """A ``thrsim serve`` child and a headless Chromium page on ``path`` of it: yields (browser, page).
    ``prepare(page)`` runs before the page loads (a benchmark's init scripts)."""
    from playwright.sync_api import sync_playwright

    check_browser(chromium)
    with tempfile.TemporaryDirectory() as folder:
        process, url = serve_child(Path(folder), *serve_args)
        try:
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=chromium, args=CHROMIUM_FLAGS)
                try:
                    page = browser.new_page(viewport={"width": width, "height": height})
                    if prepare is not None:
                        prepare(page)
                    page.goto(url + path, timeout=60_000)
                    yield browser, page
                finally:
                    browser.close()
        finally:
            stop_child(process)


def time_drawing(
    seconds: float = 10.0, width: int = 1280, height: int = 720, chromium: str = CHROMIUM, render_scale: float | None = None
) -> dict:
    """Frames per second the trainer page draws with its reamer moving every frame; ``render_scale``
    pins the page's render scale (``?render-scale=``) instead of letting it follow the frame rate."""
    load_before = os.getloadavg()
    path = "/?continuous=1" + ("" if render_scale is None else f"&render-scale={render_scale}")
    with served_page(path, width, height, chromium=chromium) as (browser, page):
        page.wait_for_function("window.trainer && trainer.stats.states > 10 && trainer.stats.frames > 10", timeout=60_000)
        page.wait_for_timeout(2000)  # warm-up: shaders compiled, caches filled
        cpu_first = chromium_cpu_seconds()
        first = page.evaluate(_COUNTERS)
        page.wait_for_timeout(seconds * 1000)
        last = page.evaluate(_COUNTERS)
        cpu_last = chromium_cpu_seconds()
        info = page.evaluate(_PAGE_INFO)
        chromium_version = browser.version
    elapsed = (last[0] - first[0]) / 1000
    frames = last[1] - first[1]
    cpu_ms = None if cpu_first is None or cpu_last is None or not frames else 1e3 * (cpu_last - cpu_first) / frames
    return {
        "what": "frames drawn per second by the trainer page, reamer turning every frame (?continuous=1); at most 60 (headless Chromium's frame pacing)",
        "fps": frames / elapsed,
        "frames": frames,
        "chromium_cpu_ms_per_frame": cpu_ms,
        "seconds": elapsed,
        "page_states_per_s": (last[2] - first[2]) / elapsed,
        "viewport": [width, height],
        **info,
        "render_scale_at_start": first[3],
        "render_scale_changes": last[4] - first[4],
        "chromium": chromium_version,
        "chromium_flags": CHROMIUM_FLAGS,
        "load_average_1min": [load_before[0], os.getloadavg()[0]],
    }
