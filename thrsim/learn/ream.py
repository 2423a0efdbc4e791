"""``thrsim ream``: a learned rollout at one orientation and force, written as a time series and a summary.

The rollout ends early, as the solver's cases do, when the reamer perforates the bone or no bone
is left in its path (``end_reason`` in the summary, said in words in ``end_reason_text``); frames
past that would only move the reamer through empty space. The summary also says where the series
is and how to open it, and which frame the picture shows: a run that went through the bone ends
with little or none of it left, so the picture is of the last frame that still shows the bone.

The output folder is assembled under a temporary name beside its target and renamed into place
when complete, so a failed run leaves nothing (and a rerun replaces an earlier ream output).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
from pydantic import TypeAdapter, ValidationError

from thrsim.atomic import atomic_folder
from thrsim.config import FrameCount, Orientation
from thrsim.errors import ThrsimInputError
from thrsim.learn.simulator import MEDIAL_WALL_BREACHED, PASSED_THROUGH, PERFORATED, ReamingSimulator, check_force
from thrsim.learn.vtk_series import write_frame, write_pvd
from thrsim.nav.bone_frame import check_side, cup_angles_from_bone, on_side
from thrsim.provenance import json_default, package_versions

SUMMARY = "ream.json"
SERIES = "ream.pvd"
#: why a rollout stopped, in words (``end_reason`` → ``end_reason_text``)
END_REASON_TEXT = {
    PERFORATED: "perforated, the reamer's teeth passed the bone's outer face",
    PASSED_THROUGH: "passed through, no bone was left in the reamer's path",
    MEDIAL_WALL_BREACHED: "breached the medial wall, the reamer went through into the pelvis",
    "completed": "completed, every frame asked for was run, with bone still in the reamer's path",
}
#: --png draws the last frame with at least this share of the elements left: the last frames of a
#: run that went through the bone hold a few scattered elements or none, an almost empty picture
PICTURE_BONE_FRACTION = 0.1


def check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise ThrsimInputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / SUMMARY).is_file():
        raise ThrsimInputError(f"{out} is not empty and holds no earlier ream output; choose another", "out")
    parent = out.parent if str(out.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise ThrsimInputError(f"{out}: {parent} is not a folder")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ThrsimInputError(f"{out}: cannot create folder {parent} ({error.strerror or error})") from None
    if not os.access(parent, os.W_OK):
        raise ThrsimInputError(f"{out}: parent folder {parent} is not writable")


def ream(
    inclination_deg: float, anteversion_deg: float, force_n: float, frames: int, side: str, out: str | os.PathLike,
    model_dir: str | os.PathLike | None = None, png: str | os.PathLike | None = None, threads: int | None = None,
) -> dict:  # fmt: skip
    """Roll the learned simulator out and write the series (and, with ``png``, a picture of the last frame);
    ``threads``: the simulator's (PyTorch's and NumPy's BLAS)."""
    out = Path(out)
    try:  # as many as a case may ask for: a frame each is written
        TypeAdapter(FrameCount).validate_python(frames)
    except ValidationError as error:
        raise ThrsimInputError(f"{error.errors()[0]['msg']}, got {frames}", "frames") from None
    force = check_force(force_n)
    hip = check_side(side)
    if not (0 <= inclination_deg <= 90 and np.isfinite(inclination_deg)):
        raise ThrsimInputError(f"must lie in [0, 90] degrees, got {inclination_deg:g}", "inclination_deg")
    if not (0 <= anteversion_deg <= 360 and np.isfinite(anteversion_deg)):
        raise ThrsimInputError(f"must lie in [0, 360] degrees, got {anteversion_deg:g}", "anteversion_deg")
    if png is not None and Path(png).suffix.lower() != ".png":
        raise ThrsimInputError(f"{png}: a picture is written as PNG; give a .png name", "png")
    check_out(out)
    simulator = ReamingSimulator(model_dir, threads=threads)
    simulator.reset(hip)
    # γ, θ are the right hip's bone frame (as the case files'); the simulator takes the side's
    axis = on_side(Orientation(inclination_deg=inclination_deg, anteversion_deg=anteversion_deg).reamer_axis, hip)
    mesh = simulator.mesh
    teeth = simulator.model.teeth_radius_m
    frame_dt = simulator.model.frame_dt_s
    with atomic_folder(out) as staging:
        start = simulator.reamer_start(axis)
        first_alpha = simulator.alpha
        entries = [(0.0, *write_frame(staging, 0, mesh, simulator.alpha, simulator.removed, start, axis, teeth))]
        step_ms, states = [], []
        for k in range(1, frames + 1):
            t0 = time.perf_counter()
            state = simulator.step(axis, force)
            step_ms.append((time.perf_counter() - t0) * 1e3)
            states.append(state)
            entries.append((k * frame_dt, *write_frame(staging, k, mesh, state.alpha, state.removed, state.reamer_position, axis, teeth)))
            if state.end_reason is not None:  # as the solver's cases end: nothing is left to ream
                break
        write_pvd(staging / SERIES, entries)
        removed = int(states[-1].removed.sum())
        end_reason = states[-1].end_reason or "completed"
        cup = cup_angles_from_bone(inclination_deg, anteversion_deg)
        series_path = out.resolve() / SERIES
        summary = {
            "inclination_deg": inclination_deg,
            "anteversion_deg": anteversion_deg,
            "force_n": force,
            "side": side,
            "frames": len(states),
            "frames_requested": frames,
            "frame_rate_hz": 1.0 / frame_dt,
            "end_reason": end_reason,
            "end_reason_text": END_REASON_TEXT[end_reason],
            "elements": simulator.n_elements,
            "removed": removed,
            "removed_all": removed == simulator.n_elements,
            "removed_volume_mm3": states[-1].removed_volume_m3 * 1e9,
            "depth_mm": simulator.depth_m * 1e3,
            "reamer_start_mm": (np.asarray(start) * 1e3).tolist(),
            "reamer_end_mm": (states[-1].reamer_position * 1e3).tolist(),
            "removed_per_frame": [int(s.removed.sum()) for s in states],
            "ms_per_frame_median": float(np.median(step_ms)),
            "ms_per_frame_max": float(np.max(step_ms)),
            "model": {
                "path": str(simulator.model.path),
                "arch": simulator.model.card.get("arch"),
                "data_digest": simulator.model.card["data"]["digest"],
                "created_utc": simulator.model.card.get("created_utc"),
            },
            "series": SERIES,
            "series_path": str(series_path),
            "open_with": f"ParaView: File > Open {series_path}, Apply; the time steps are the frames, colour by alpha, Threshold removed = 0 shows the bone left",
            "cup_inclination_deg": None if cup is None else cup[0],
            "cup_anteversion_deg": None if cup is None else cup[1],
            "versions": package_versions(),
        }
        if png is not None:
            alphas = [first_alpha] + [s.alpha for s in states]
            positions = [start] + [s.reamer_position for s in states]
            left = [simulator.n_elements] + [simulator.n_elements - int(s.removed.sum()) for s in states]
            frame = max(k for k, n in enumerate(left) if n >= PICTURE_BONE_FRACTION * simulator.n_elements)
            summary["png"] = str(_picture(simulator, alphas[frame], positions[frame], axis, teeth, Path(png)))
            summary["png_frame"] = frame
            summary["png_bone_left"] = left[frame]
        (staging / SUMMARY).write_text(json.dumps(summary, indent=2, default=json_default))
    return summary


def _picture(
    simulator: ReamingSimulator, alpha: np.ndarray, reamer_position: np.ndarray, axis: np.ndarray, teeth_radius_m: float, png: Path
) -> Path:
    """One frame seen along the reamer axis, the reamer a translucent dome (thrsim.render)."""
    from thrsim.render import BoneRenderer, ReamerView, save_png

    with BoneRenderer(simulator.mesh, 1024, 768, threshold=simulator.model.threshold) as renderer:
        image = renderer.image(alpha, reamer=ReamerView(reamer_position, axis, teeth_radius_m))
    return save_png(image, png)


#: a reamer is seated, and the next size taken, once it advanced less than ``SEATED_ADVANCE_MM`` over
#: the last ``SEATED_WINDOW_S``: seven of the solver's eight long whole sockets seat so 31–58 frames
#: in, before their plate gives way one size up (from frame 62 on; the benchmarks page)
SEATED_WINDOW_S, SEATED_ADVANCE_MM = 0.5, 0.2
#: the whole socket's default element size for learned reaming (mm): the finest that steps at
#: interactive rates on a 2-core CPU (see the benchmarks page, "socket model")
SOCKET_ELEMENT_SIZE_MM = 1.5


def parse_reamers(text: str) -> list[float]:
    """``"46,48,50"`` → [46.0, 48.0, 50.0]: each a finite size in mm, growing, one or more."""
    try:
        sizes = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise ThrsimInputError(f"reamer sizes must be numbers of mm separated by commas, got {text!r}", "reamers") from None
    if not sizes or not all(np.isfinite(sizes)) or any(not 30.0 <= size <= 80.0 for size in sizes):
        raise ThrsimInputError(f"reamer sizes must lie in [30, 80] mm, got {text!r}", "reamers")
    if sizes != sorted(sizes):
        raise ThrsimInputError(f"reamers are taken in growing sizes, got {text!r}", "reamers")
    return sizes


def ream_socket(
    inclination_deg: float, anteversion_deg: float, force_n: float, frames_per_reamer: int, side: str, out: str | os.PathLike,
    model_dir: str | os.PathLike | None, reamers: list[float], element_size_mm: float = SOCKET_ELEMENT_SIZE_MM,
    cancellous: str = "normal", threads: int | None = None,
) -> dict:  # fmt: skip
    """Ream the whole default socket with a socket model, one reamer after another (each until it is
    seated, the bone breached or ``frames_per_reamer`` run); write each reamer's last frame and a summary."""
    from thrsim.config import SocketConfig
    from thrsim.geometry.socket import generate_socket
    from thrsim.learn.model_dir import SHIPPED_SOCKET_MODEL, load_model, reads_any_mesh

    out = Path(out)
    try:
        TypeAdapter(FrameCount).validate_python(frames_per_reamer)
    except ValidationError as error:
        raise ThrsimInputError(f"{error.errors()[0]['msg']}, got {frames_per_reamer}", "frames") from None
    force = check_force(force_n)
    hip = check_side(side)
    if not (np.isfinite(element_size_mm) and 0.3 <= element_size_mm <= 5.0):
        raise ThrsimInputError(f"must lie in [0.3, 5] mm, got {element_size_mm:g}", "element_size_mm")
    check_out(out)
    model = load_model(SHIPPED_SOCKET_MODEL if model_dir is None else model_dir)
    if not reads_any_mesh(model.settings):
        raise ThrsimInputError(f"{model.path}: a patch model; the socket needs a model trained with the socket feature set", "model_dir")
    mesh = generate_socket(SocketConfig(element_size_mm=element_size_mm))
    simulator = ReamingSimulator(model=model, threads=threads, mesh=mesh, cancellous=cancellous)
    simulator.reset(hip)
    axis = on_side(Orientation(inclination_deg=inclination_deg, anteversion_deg=anteversion_deg).reamer_axis, hip)
    frame_dt = simulator.model.frame_dt_s
    steps: list[dict] = []
    with atomic_folder(out) as staging:
        entries = [
            (0.0, *write_frame(staging, 0, simulator.mesh, simulator.alpha, simulator.removed, simulator.reamer_start(axis), axis, 0.0))
        ]
        frame, end_reason, step_ms = 0, None, []
        window = max(1, round(SEATED_WINDOW_S / frame_dt))
        for size in reamers:
            simulator.withdraw()
            seated, results = False, []
            for _ in range(frames_per_reamer):
                t0 = time.perf_counter()
                state = simulator.step(axis, force, reamer_mm=size)
                step_ms.append((time.perf_counter() - t0) * 1e3)
                results.append(state)
                end_reason = state.end_reason
                recent = [r.advance_m for r in results[-window:]]
                seated = len(recent) == window and sum(recent) * 1e3 < SEATED_ADVANCE_MM
                if end_reason is not None or seated:
                    break
            frame += len(results)
            last = results[-1]
            entries.append(
                (
                    frame * frame_dt,
                    *write_frame(staging, frame, simulator.mesh, last.alpha, last.removed, last.reamer_position, axis, size * 0.5e-3),
                )
            )
            reactions = [r.reaction_n for r in results if r.reaction_n is not None]
            torques = [r.motor_torque_n_m for r in results if r.motor_torque_n_m is not None]
            steps.append({
                "reamer_mm": size, "frames": len(results), "seconds": len(results) * frame_dt,
                "ended": end_reason or ("seated" if seated else "frames"),
                "removed_volume_mm3": last.removed_volume_m3 * 1e9, "travel_mm": simulator.depth_m * 1e3,
                "reaction_n_mean": float(np.mean(reactions)) if reactions else None,
                "motor_torque_n_m_mean": float(np.mean(torques)) if torques else None,
                "out_of_range": sorted({flag for r in results for flag in r.out_of_range}),
            })  # fmt: skip
            if end_reason is not None:
                break
        write_pvd(staging / SERIES, entries)
        series_path = out.resolve() / SERIES
        summary = {
            "bone": "socket", "inclination_deg": inclination_deg, "anteversion_deg": anteversion_deg, "force_n": force, "side": side,
            "element_size_mm": element_size_mm, "cancellous": cancellous, "elements": simulator.n_elements,
            "seated_rule": {"advance_mm": SEATED_ADVANCE_MM, "window_s": SEATED_WINDOW_S},
            "reamers": steps, "end_reason": end_reason or "completed",
            "end_reason_text": END_REASON_TEXT[end_reason or "completed"],
            "removed": int(simulator.removed.sum()), "removed_volume_mm3": simulator.removed_volume_m3 * 1e9,
            "ms_per_frame_median": float(np.median(step_ms)), "ms_per_frame_max": float(np.max(step_ms)),
            "model": {"path": str(simulator.model.path), "arch": simulator.model.card.get("arch"), "data_digest": simulator.model.card["data"]["digest"]},
            "series": SERIES, "series_path": str(series_path),
            "open_with": f"ParaView: File > Open {series_path}, Apply; one time step per reamer, Threshold removed = 0 shows the bone left",
            "versions": package_versions(),
        }  # fmt: skip
        (staging / SUMMARY).write_text(json.dumps(summary, indent=2, default=json_default))
    return summary
