// The 3-D view's render scale: the fraction of the window's device pixels the canvas is drawn at
// (CSS stretches it to the window). Under software WebGL (SwiftShader, Chromium without a GPU)
// most of a frame's CPU grows with the canvas's pixels: rasterising the scene and the grid's long
// lines, reading the canvas back and compositing it; so while the page draws slower than the
// display, it draws fewer pixels. Frames are judged by windows of WINDOW intervals between
// consecutive drawn frames (a page that draws only when something changed says nothing of its
// speed between changes; a window with a stall in it is dropped), against the display's rate, at
// most 60 frames/s (the shortest interval between animation frames seen, drawn or not):
// * SLOW_WINDOWS windows in a row slower than SLOW of that rate (55 of 60 frames/s): one step
//   down (one slow window alone is a hiccup, such as the page's start or new shaders compiling);
// * a window at STEADY of it (58 of 60) or faster, the wait (FIRST_WAIT_MS) after the last
//   change: one step up, to try; a try undone within TRY_WINDOWS windows doubles the wait (up to
//   LONGEST_WAIT_MS), so the scale settles at the finest one the machine keeps up with; during a
//   try one slow window is enough to step back (the try is known to be risky: a second slow
//   window at the finer scale was a second of stutter, a fifth of a 10 s count in `thrsim bench`).
// ?render-scale=S pins it (0 < S <= 1).
export const STEPS = [1, 0.75, 0.5];
export const WINDOW = 60; // a second at 60 Hz
export const SLOW_WINDOWS = 2;
export const FIRST_WAIT_MS = 8000;
const SLOW = 55 / 60;
const STEADY = 58 / 60;
const TOP_FPS = 60;
const STALL_MS = 250; // a longer gap is a stall (hidden tab, garbage collection), not a frame rate
const TRY_WINDOWS = 4;
const LONGEST_WAIT_MS = 64000;

export class RenderScale {
  constructor(pinned = null) {
    this.pinned = pinned;
    this.step = 0;
    this.wait = FIRST_WAIT_MS;
    this.changedAt = -Infinity;
    this.tried = false; // the last change was a step up
    this.changes = 0;
    this.display = Infinity; // the shortest interval between animation frames (ms)
    this.lastFrame = null;
    this.lastDrew = false;
    this.sum = 0;
    this.count = 0;
    this.windows = 0; // judged since the last change
    this.slowWindows = 0; // in a row
  }

  static fromQuery(search) {
    const value = Number(new URLSearchParams(search).get("render-scale"));
    return new RenderScale(value > 0 && value <= 1 ? value : null);
  }

  get scale() { return this.pinned ?? STEPS[this.step]; }

  // One animation frame, before the page draws: its timestamp (ms) and whether the page draws in
  // it (the interval since the last frame is that frame's drawing). True when the scale changed:
  // the page resizes its canvas and draws.
  frame(now, draws) {
    const interval = this.lastFrame === null ? Infinity : now - this.lastFrame;
    const consecutive = draws && this.lastDrew;
    this.lastFrame = now;
    this.lastDrew = draws;
    if (interval > 0) this.display = Math.min(this.display, interval);
    if (this.pinned !== null || !consecutive) return false;
    if (interval > STALL_MS) {
      this.sum = 0;
      this.count = 0;
      return false;
    }
    this.sum += interval;
    this.count += 1;
    if (this.count < WINDOW) return false;
    const rate = (1000 * this.count) / this.sum / Math.min(TOP_FPS, 1000 / this.display);
    this.sum = 0;
    this.count = 0;
    this.windows += 1;
    this.slowWindows = rate < SLOW ? this.slowWindows + 1 : 0;
    const trying = this.tried && this.windows <= TRY_WINDOWS;
    if (this.slowWindows >= (trying ? 1 : SLOW_WINDOWS) && this.step < STEPS.length - 1) {
      if (trying) this.wait = Math.min(2 * this.wait, LONGEST_WAIT_MS);
      return this.change(this.step + 1, now);
    }
    if (rate >= STEADY && this.step > 0 && now - this.changedAt >= this.wait) return this.change(this.step - 1, now);
    return false;
  }

  change(step, now) {
    this.tried = step < this.step;
    this.step = step;
    this.changedAt = now;
    this.changes += 1;
    this.windows = 0;
    this.slowWindows = 0;
    return true;
  }
}

// The canvas's CSS image-rendering for a canvas drawn at `canvasRatio` device pixels per CSS pixel:
// where each canvas pixel covers a whole number of screen pixels (1:1 at full scale, 2×2 at half
// scale on a 1× display), nearest-pixel stretching gives the same picture at 1:1 and a crisp one
// at 2×2, and Chromium's software compositor draws it for under half the CPU of smoothing (about
// 1.2 instead of 2.8 ms a frame at 1280×720); other ratios are smoothed.
export function imageRendering(canvasRatio, deviceRatio = window.devicePixelRatio) {
  const factor = deviceRatio / canvasRatio;
  return Math.abs(factor - Math.round(factor)) < 1e-6 ? "pixelated" : "auto";
}
