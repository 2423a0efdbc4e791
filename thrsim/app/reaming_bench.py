"""The reaming page under load (``thrsim bench --reaming-page``): what a trainee's browser gets.

A real ``thrsim serve`` child with the model, Debian's headless Chromium on ``/reaming`` (the
flags and helpers of :mod:`thrsim.app.drawing_bench`), and a tracker streaming the reamer's pose
over OpenIGTLink at 60 Hz, aimed at the safe zone's centre, while the trainee reams (from the
intact bone until the page pauses where it is reamed through, repeated until the window is
full). Reported: simulator frames per second delivered, the bone's binary frames and their size
against every element's α as float32, frames drawn per second once the page's render scale has
settled, Chromium's CPU per drawn frame, and the latency from an OpenIGTLink pose to the state
that shows it and to its first drawing (median, p90), the session's worst server tick and how far the drawn
bone trailed the simulation (wall-clock). A whole-socket model first reams the socket whole with a
reamer sequence (:func:`whole_reaming`): its worst tick, lag, and whether inputs apply in order.
"""

from __future__ import annotations

import os
import socket
import statistics
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from thrsim.app.drawing_bench import CHROMIUM, chromium_cpu_seconds, served_page
from thrsim.app.navigation import NavigationTrainer
from thrsim.config import TrackingVolumeConfig
from thrsim.errors import ThrsimInputError
from thrsim.io import igtl

_SEED = 7  # serve_child starts the server with --seed 7: the same pelvis placement here
#: a whole reaming on a whole-socket model: this reamer sequence (mm) over this many simulator frames
#: in all (shared among the reamers), at the safe zone's centre with the page's push
WHOLE_REAMING_MM = (46, 48)
WHOLE_REAMING_FRAMES = 600
#: as each reamer starts (its slowest ticks: the placement, the approach), the page sends this many
#: pushes this far apart (ms), each this much (N) above the last, then the push it had again
PROBE_PUSHES, PROBE_PERIOD_MS, PROBE_STEP_N = 50, 20, 0.01
_BREACHES = ("perforated", "medial_wall_breached", "passed_through")


class _Tracker:
    """One OpenIGTLink connection sending ReamerToReference poses (and reading each reply)."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.lock = threading.Lock()

    def send(self, pose_m: np.ndarray) -> None:
        with self.lock:
            self.sock.sendall(igtl.encode_message(igtl.Message("TRANSFORM", "ReamerToReference", igtl.pack_transform(pose_m))))
            header = igtl.parse_header(self._exactly(igtl.HEADER_SIZE))
            self._exactly(header.body_size)

    def _exactly(self, size: int) -> bytes:
        data = b""
        while len(data) < size:
            chunk = self.sock.recv(size - len(data))
            if not chunk:
                raise ConnectionError("OpenIGTLink connection closed")
            data += chunk
        return data

    def close(self) -> None:
        self.sock.close()


_PROBE = "[performance.now(), trainer.stats.frames, trainer.stats.states, trainer.stats.boneFrames, trainer.stats.boneBytes, trainer.stats.last.reaming.frame]"
_SCALE_CHANGES = "trainer.view.renderScale.changes"
_SETTLE_S = 3.0  # reaming this long with no change of the render scale: settled (a shorter window settles over its own length)
_WARMUP_MAX_S = 30.0


def _start_run(page) -> None:
    """Restore the intact bone and start reaming; returns once the simulator is a few frames in."""
    page.evaluate("trainer.send({type: 'run', action: 'reset'})")
    page.wait_for_function("trainer.stats.last.reaming.frame === 0", timeout=60_000)
    page.evaluate("trainer.send({type: 'run', action: 'start'})")
    page.wait_for_function("trainer.stats.last.reaming.frame > 5", timeout=60_000)


def _ream(page, seconds: float) -> tuple[np.ndarray, float]:
    """Ream for ``seconds`` of counted time: the differences of ``_PROBE`` and Chromium's CPU
    seconds. A run reams the patch through in about 2 s of frames and pauses there, so the window
    is made of runs: restore the bone, start, count while it reams, until the window is full."""
    totals, cpu_seconds = np.zeros(6), 0.0
    while totals[0] < seconds * 1000:
        _start_run(page)
        cpu_first = chromium_cpu_seconds()
        first = page.evaluate(_PROBE)
        until = first[0] + seconds * 1000 - totals[0]  # a run that never ends fills the window
        page.wait_for_function(f"!trainer.stats.last.reaming.running || performance.now() > {until}", timeout=seconds * 1000 + 60_000)
        last = page.evaluate(_PROBE)
        cpu_last = chromium_cpu_seconds()
        totals += np.array(last) - np.array(first)
        cpu_seconds += 0.0 if cpu_first is None or cpu_last is None else cpu_last - cpu_first
    return totals, cpu_seconds


# The pushes of :data:`PROBE_PUSHES`, from the page as its push control sends them, and the push of
# every state the page receives meanwhile (a hook on trainer.stats.last, which each state replaces).
_SEND_PUSHES = """(([count, period, step]) => {
  const stats = trainer.stats, base = stats.last.reaming.force_n;
  const probe = stats.pushProbe = { sent: [], seen: [], acksFrom: stats.acks.length, done: false };
  let last = stats.last;
  Object.defineProperty(stats, "last", { configurable: true, get: () => last, set: (state) => {
    last = state;
    if (!probe.done) probe.seen.push(state.reaming.force_n);
  } });
  const timer = setInterval(() => {
    if (probe.sent.length === count) {
      clearInterval(timer);
      probe.done = true;
      trainer.send({ type: "force", newton: base });
      return;
    }
    const newton = Math.round((base + step * (probe.sent.length + 1)) * 100) / 100;
    probe.sent.push(newton);
    trainer.send({ type: "force", newton });
  }, period);
})"""


# Every push the probe sent, and the push it restored last, acknowledged (other acknowledgements, of
# the run's start or pause, interleave with them).
_ALL_PUSHES_ACKNOWLEDGED = """(() => {
  const probe = trainer.stats.pushProbe;
  const pushes = trainer.stats.acks.slice(probe.acksFrom).filter((text) => text.startsWith("push "));
  return pushes.length >= probe.sent.length + 1;
})()"""


def _pushes_in_order(page) -> dict:
    """Whether the probe's pushes were acknowledged, and shown in the states, in the order sent, and the
    most of them that first showed in one state the page received (a state the page skipped counts too)."""
    probe = page.evaluate("trainer.stats.pushProbe")
    sent = probe["sent"]
    acks = [text for text in page.evaluate("trainer.stats.acks")[probe["acksFrom"] :] if text.startswith("push ")]
    acked = [float(text.split()[1]) for text in acks[: len(sent)]]
    shown = [sent.index(value) for value in probe["seen"] if value in sent]
    steps = np.diff([-1, *shown]) if shown else np.zeros(0)
    return {
        "sent": len(sent),
        "acknowledged": len(acked),
        "acks_in_order": acked == sent,
        "states_in_order": bool(np.all(steps >= 0)),
        "most_in_one_state": int(steps.max()) if len(steps) else 0,
    }


def whole_reaming(page, reamers: tuple[int, ...], frames: int) -> dict:
    """The intact socket reamed whole with ``reamers`` in turn, ``frames`` simulator frames in all
    shared among them (a reamer the simulator stops, through the bone or through its path, stops
    early), from the page's own controls; as each reamer starts, the pushes of :data:`PROBE_PUSHES`.
    Reported: the frames each reamer reamed and what stopped it; the session's worst tick by the end
    (and before the reaming: the session began with it, so a larger figure is the reaming's); how far
    the drawn bone trailed the simulation while reaming; the frames the simulator fell behind; and
    whether every probe's pushes applied in order."""
    share = -(-frames // len(reamers))
    page.evaluate("trainer.send({type: 'run', action: 'reset'})")
    page.wait_for_function("trainer.stats.last.reaming.frame === 0 && !trainer.stats.last.reaming.running", timeout=60_000)
    before = page.evaluate("[trainer.stats.last.session.worst_tick_ms, trainer.stats.last.reaming.behind_frames]")
    page.evaluate("trainer.stats.boneLag = { worst: 0, sum: 0, count: 0 }")
    done, orders = [], []
    for size in reamers:
        page.evaluate(f"trainer.send({{type: 'reamer_size', size_mm: {size}}})")
        page.wait_for_function(f"trainer.stats.last.reaming.reamer.size_mm === {size}", timeout=60_000)
        first, events = page.evaluate("[trainer.stats.last.reaming.frame, trainer.stats.events.length]")
        page.evaluate("trainer.send({type: 'run', action: 'start'})")
        page.evaluate(_SEND_PUSHES, [PROBE_PUSHES, PROBE_PERIOD_MS, PROBE_STEP_N])
        page.wait_for_function(
            f"trainer.stats.last.reaming.frame >= {first + share} || trainer.stats.events.slice({events}).some((k) => {list(_BREACHES)}.includes(k))",
            timeout=60_000 + share * 2_000,
        )
        page.evaluate("trainer.send({type: 'run', action: 'pause'})")
        page.wait_for_function("!trainer.stats.last.reaming.running && trainer.stats.pushProbe.done", timeout=60_000)
        page.wait_for_function(_ALL_PUSHES_ACKNOWLEDGED, timeout=60_000)
        orders.append(_pushes_in_order(page))
        reamed, kinds = page.evaluate(f"[trainer.stats.last.reaming.frame, trainer.stats.events.slice({events})]")
        done.append({"reamer_mm": size, "frames": reamed - first, "stopped_by": next((k for k in kinds if k in _BREACHES), None)})
    worst, worst_cpu, behind, lag = page.evaluate(
        "[trainer.stats.last.session.worst_tick_ms, trainer.stats.last.session.worst_tick_cpu_ms, "
        "trainer.stats.last.reaming.behind_frames, trainer.stats.boneLag]"
    )
    return {
        "what": f"the intact socket reamed with {' → '.join(f'{size} mm' for size in reamers)}, {share} frames each unless stopped",
        "reamers": done,
        "frames": sum(step["frames"] for step in done),
        "worst_tick_ms": worst,
        "worst_tick_cpu_ms": worst_cpu,
        "worst_tick_ms_before": before[0],
        "drawn_bone_lag_s": _lag(lag),
        "behind_frames": behind - before[1],
        "pushes_in_order": {
            "sent": sum(order["sent"] for order in orders),
            "acknowledged": sum(order["acknowledged"] for order in orders),
            "acks_in_order": all(order["acks_in_order"] for order in orders),
            "states_in_order": all(order["states_in_order"] for order in orders),
            "most_in_one_state": max(order["most_in_one_state"] for order in orders),
        },
    }


def _lag(lag: dict) -> dict:
    """The page's drawn-bone lag figures (ms) in seconds: the worst, the mean and the drawings counted."""
    return {"worst": lag["worst"] / 1000, "mean": lag["sum"] / lag["count"] / 1000 if lag["count"] else None, "drawings": lag["count"]}


def time_reaming_page(
    model: Path | None = None,
    seconds: float = 10.0,
    latency_trials: int = 20,
    width: int = 1280,
    height: int = 720,
    chromium: str = CHROMIUM,
    compile: bool = True,
    reamers: tuple[int, ...] = WHOLE_REAMING_MM,
    reaming_frames: int = WHOLE_REAMING_FRAMES,
    socket_element_size_mm: float | None = None,
) -> dict:
    """The figures of the module docstring; ``reamers``, ``reaming_frames`` and ``socket_element_size_mm``
    shape a whole-socket model's whole reaming (:func:`whole_reaming`) and the socket it reams."""
    aim = NavigationTrainer(side="right", seed=_SEED)
    poses = {inclination: aim.reamer_pose(inclination, 15.0) for inclination in (38.0, 40.0, 42.0)}
    load_before = os.getloadavg()
    extra = (("--model", str(model)) if model is not None else ()) + (() if compile else ("--no-compile",))
    extra += () if socket_element_size_mm is None else ("--socket-element-size", f"{socket_element_size_mm:g}")
    with served_page("/reaming", width, height, *extra, chromium=chromium) as (browser, page):
        page.wait_for_function("window.trainer && trainer.stats.hello && trainer.stats.states > 10", timeout=60_000)
        if not page.evaluate("trainer.stats.hello.scene.reaming.available"):
            raise ThrsimInputError("reaming unavailable: " + str(page.evaluate("trainer.stats.hello.scene.reaming.unavailable")))
        page.wait_for_function("trainer.stats.visibleFaces > 0", timeout=60_000)
        elements = int(page.evaluate("trainer.stats.hello.scene.reaming.elements"))
        tracker = _Tracker(int(page.evaluate("trainer.stats.hello.igtl[1]")))
        streaming: dict[str, Any] = {"pose": poses[40.0], "on": True}

        period_s = 1.0 / TrackingVolumeConfig().rate_hz

        def stream() -> None:  # a tracker at its rate: samples on a fixed schedule, whatever the replies take
            next_sample = time.monotonic()
            while streaming["on"]:
                tracker.send(streaming["pose"])
                next_sample = max(next_sample + period_s, time.monotonic() - period_s)  # late: no burst to catch up
                time.sleep(max(0.0, next_sample - time.monotonic()))

        thread = threading.Thread(target=stream, daemon=True)
        thread.start()
        try:
            page.wait_for_function("trainer.stats.last.tools.Reamer.source === 'tracker'", timeout=20_000)
            socket = page.evaluate("trainer.stats.hello.scene.reaming.bone") == "socket"
            whole = (
                whole_reaming(page, reamers, reaming_frames) if socket else None
            )  # first: the session's worst tick is then the reaming's
            # the page starts at full resolution and lowers it while it draws slowly: ream until
            # its render scale has settled, then count (its later tries of a finer scale stay in)
            warmup_s, scale_changes = 0.0, page.evaluate(_SCALE_CHANGES)
            while warmup_s < _WARMUP_MAX_S:
                warmup_s += _ream(page, min(_SETTLE_S, seconds))[0][0] / 1000
                scale_changes, before = page.evaluate(_SCALE_CHANGES), scale_changes
                if scale_changes == before:
                    break
            scale_at_start = page.evaluate("trainer.view.renderScale.scale")
            page.evaluate("trainer.stats.boneLag = { worst: 0, sum: 0, count: 0 }")
            totals, cpu_seconds = _ream(page, seconds)
            lag = page.evaluate("trainer.stats.boneLag")
            scale_changes = page.evaluate(_SCALE_CHANGES) - scale_changes
            reaming = page.evaluate("trainer.stats.last.reaming")
            render_scale = page.evaluate("trainer.view.renderScale.scale")  # the canvas's resolution (render_scale.js)
            arrived, drawn = [], []
            for k in range(latency_trials):
                target = 38.0 if k % 2 == 0 else 42.0
                if not page.evaluate("trainer.stats.last.reaming.running"):  # timed while the simulator reams
                    _start_run(page)
                sent_at = page.evaluate("performance.now()")
                streaming["pose"] = poses[target]
                page.wait_for_function(
                    f"trainer.stats.probe.drawn > 0 && Math.abs(trainer.stats.probe.inclination - {target}) < 0.5", timeout=60_000
                )
                timing = page.evaluate("trainer.stats.probe")
                arrived.append(timing["arrived"] - sent_at)
                drawn.append(timing["drawn"] - sent_at)
                page.wait_for_timeout(150)
        finally:
            streaming["on"] = False
            thread.join(2)
            tracker.close()
        session = page.evaluate("trainer.stats.last.session")
        chromium_version = browser.version
    elapsed = totals[0] / 1000
    drawn_frames, bone_frames = totals[1], totals[3]
    bytes_per_frame = totals[4] / bone_frames if bone_frames else None
    return {
        "what": f"the reaming page with a tracker streaming the reamer at {TrackingVolumeConfig().rate_hz:g} Hz while reaming at the safe zone's centre",
        "simulator_frames_per_s": totals[5] / elapsed,
        "states_per_s": totals[2] / elapsed,
        "bone_frames_per_s": bone_frames / elapsed,
        "bone_bytes_per_frame": bytes_per_frame,
        "whole_alpha_bytes": 4 * elements,
        "bone_bytes_fraction_of_whole": None if bytes_per_frame is None else bytes_per_frame / (4 * elements),
        # a bone frame can carry two simulator frames' changes when the page or the server fell behind
        "bone_bytes_per_simulator_frame_fraction_of_whole": totals[4] / totals[5] / (4 * elements) if totals[5] else None,
        "fps": drawn_frames / elapsed,
        "chromium_cpu_ms_per_frame": None if chromium_cpu_seconds() is None or not drawn_frames else 1e3 * cpu_seconds / drawn_frames,
        "pose_to_state_ms": {"median": statistics.median(arrived), "p90": float(np.percentile(arrived, 90))},
        "pose_to_drawn_ms": {"median": statistics.median(drawn), "p90": float(np.percentile(drawn, 90))},
        "latency_trials": latency_trials,
        "step_ms_last": reaming.get("step_ms"),
        "worst_tick_ms": session["worst_tick_ms"],
        "worst_tick_cpu_ms": session["worst_tick_cpu_ms"],
        "drawn_bone_lag_s": _lag(lag),
        "behind_frames": reaming.get("behind_frames"),
        "removed_at_end": reaming.get("removed"),
        "elements": elements,
        "seconds": elapsed,
        "viewport": [width, height],
        "render_scale": render_scale,
        "render_scale_at_start": scale_at_start,
        "render_scale_changes": scale_changes,
        "warmup_s": warmup_s,
        "chromium": chromium_version,
        "load_average_1min": [load_before[0], os.getloadavg()[0]],
        "whole_reaming": whole,
    }
