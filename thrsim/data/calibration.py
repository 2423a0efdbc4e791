"""The whole socket's feed under a push, from a dataset of socket windows (``thrsim dataset --bone socket``).

At a set feed f a window records the bone's axial reaction R: k = R / (f·A) is its resistance per
mm² and per mm/s; summed over the polar bands of a seated reamer's hemisphere (each band's median
k) it gives the push a feed takes, F = f·Σ k_b·A_b, hence a seated feed, removal rate (π r²·f) and
time per reamer step (the slowest, seated figures; the rim phase goes faster). At a set push a
window stalls below a pressure and cuts above it: the brackets between the highest pressure that
stalled and the lowest that cut give the cutting threshold, and the push a reamer seated on the
whole hemisphere needs to reach it. Only cases reamed along the socket's axis through its centre
are used: the seated reamer does not cut the others' windows that way.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from thrsim.config import SocketSweepConfig, SweepConfig
from thrsim.data.case_file import CaseReader
from thrsim.data.generate import read_manifest
from thrsim.errors import ThrsimInputError
from thrsim.geometry.socket import window_area_mm2

#: the pushes the seated feed is reported at (N): the sweep's, the thesis's range about its mean
PUSHES_N = tuple(sorted({*SweepConfig().forces_n, *SweepConfig().extra_forces_n}))
#: reamer sizes (mm) the seated push at the cutting threshold is reported for: the plan's steps'
SEATED_SIZES_MM = tuple(sorted({step[2] for step in SocketSweepConfig().steps}))


def window_resistance(entry: dict, case_file: Path) -> dict | None:
    """k (N per mm² per mm/s) of one complete window case reamed along the socket's axis; None otherwise."""
    params = entry["params"]
    settings = dict((key, value) for key, value in params.get("settings", []))
    centre = settings.get("reamer_centre_mm", (0.0, 0.0, 0.0))
    if entry.get("status") != "complete" or params["inclination_deg"] != 0.0 or centre[0] or centre[1]:
        return None
    if "feed_mm_s" not in settings or "socket.window_polar_deg" not in settings:
        return None
    socket_mm = settings["socket.socket_diameter_mm"]
    prepared_mm = settings.get("pre_ream_mm")
    radius_mm = 0.5 * float(socket_mm if prepared_mm is None else prepared_mm)
    with CaseReader(case_file) as reader:
        axial = reader.series("contact_force_axial")
    first = (entry.get("solver_summary") or {}).get("first_contact_frame")
    if axial is None or first is None:
        return None
    reaction_n = float(np.mean(axial[first + 1 :])) if len(axial) > first + 1 else 0.0
    area = window_area_mm2(radius_mm, settings["socket.window_half_angle_deg"])
    return {
        "polar_deg": float(settings["socket.window_polar_deg"]),
        "cancellous": "osteoporotic" if settings["cancellous"]["specific_cutting_energy_j_m3"] < 1e8 else "normal",
        "feed_mm_s": float(settings["feed_mm_s"]),
        "radius_mm": radius_mm,
        "reaction_n": reaction_n,
        "k": reaction_n / (settings["feed_mm_s"] * area),
    }


def pushed_window(entry: dict, case_file: Path) -> dict | None:
    """A complete pushed window (no set feed) reamed along the socket's axis: its pressure (push over the
    window's area, N/mm²), its mean feed after first contact (mm/s) and whether it stalled; None otherwise."""
    params = entry["params"]
    settings = dict((key, value) for key, value in params.get("settings", []))
    if entry.get("status") != "complete" or params["inclination_deg"] != 0.0 or "feed_mm_s" in settings:
        return None
    if settings.get("socket.window_polar_deg") is None or any(settings.get("reamer_centre_mm", (0.0, 0.0, 0.0))[:2]):
        return None  # a whole socket, or a window off the axis
    summary = entry.get("solver_summary") or {}
    first = summary.get("first_contact_frame")
    with CaseReader(case_file) as reader:
        positions = reader.series("reamer_position")
        frame_dt_s = float(reader.attrs.get("frame_dt_s", 0.0))
    if positions is None or first is None or len(positions) <= first + 1 or not frame_dt_s > 0:
        return None
    travel_mm = 1e3 * float(np.linalg.norm(positions[-1] - positions[first]))
    feed = travel_mm / ((len(positions) - 1 - first) * frame_dt_s)
    area = window_area_mm2(0.5 * float(settings["socket.socket_diameter_mm"]), settings["socket.window_half_angle_deg"])
    return {
        "window": [float(settings["socket.window_polar_deg"]), float(settings.get("socket.window_azimuth_deg", 0.0))],
        "socket_mm": float(settings["socket.socket_diameter_mm"]),
        "pressure_n_mm2": float(params["force_n"]) / area,
        "feed_mm_s": feed,
        "stalled": summary.get("end_reason") == "stalled",
    }


def cutting_threshold(windows: list[dict]) -> dict:
    """Where the pushed windows start cutting: per window the pressure bracket between the highest that
    stalled (0 if none did) and the lowest that cut; per polar band the median bracket; and the bracket
    of the push a reamer seated on the whole hemisphere of each planned size needs, Σ p_b·A_b."""
    brackets = []
    for key in sorted({(tuple(w["window"]), w["socket_mm"]) for w in windows}):
        own = [w for w in windows if (tuple(w["window"]), w["socket_mm"]) == key]
        stalled = [w["pressure_n_mm2"] for w in own if w["stalled"]]
        cut = [w["pressure_n_mm2"] for w in own if not w["stalled"]]
        brackets.append(
            {"window": list(key[0]), "socket_mm": key[1], "bracket_n_mm2": [max(stalled, default=0.0), min(cut, default=math.inf)]}
        )
    polars = sorted({b["window"][0] for b in brackets})
    edges = [0.0, *((a + b) / 2 for a, b in zip(polars, polars[1:], strict=False)), 90.0]
    bands, low_sum, high_sum = [], 0.0, 0.0  # Σ p_b·A_b on a unit sphere, N/mm² × mm² per mm² of r²
    for polar, low_edge, high_edge in zip(polars, edges[:-1], edges[1:], strict=True):
        held = np.array([b["bracket_n_mm2"] for b in brackets if b["window"][0] == polar])
        low, high = float(np.median(held[:, 0])), float(np.median(held[:, 1]))
        share = 2.0 * math.pi * (math.cos(math.radians(low_edge)) - math.cos(math.radians(high_edge)))
        low_sum, high_sum = low_sum + low * share, high_sum + high * share
        bands.append({"polar_deg": polar, "band_deg": [low_edge, high_edge], "windows": int(len(held)), "bracket_n_mm2": [low, high]})
    seated = {f"{size:g}": [low_sum * (size / 2.0) ** 2, high_sum * (size / 2.0) ** 2] for size in SEATED_SIZES_MM}
    return {"windows": brackets, "bands": bands, "seated_push_n": seated}


def socket_calibration(root: str | os.PathLike) -> dict:
    """The windows' resistance by polar band and the whole socket's seated feed, removal rate and time
    per 2 mm reamer step it implies at :data:`PUSHES_N` (see the module's note)."""
    root = Path(root)
    manifest = read_manifest(root)
    if manifest is None:
        raise ThrsimInputError(f"{root}: not a thrsim dataset (no manifest.json)")
    entries = manifest.get("cases", {}).values()
    pushed = [w for e in entries if (w := pushed_window(e, root / e["file"])) is not None]
    at_a_push = {"pushed": {"cases_used": len(pushed), **cutting_threshold(pushed)}} if pushed else {}
    windows = [w for e in entries if (w := window_resistance(e, root / e["file"])) is not None]
    if not windows:
        return {"cases_used": 0, **at_a_push}
    polars = sorted({w["polar_deg"] for w in windows})
    edges = [0.0, *((a + b) / 2 for a, b in zip(polars, polars[1:], strict=False)), 90.0]
    bands, resistance = [], 0.0  # Σ k_b·A_b for a unit sphere (× r² later), N per mm/s per mm²
    for polar, low, high in zip(polars, edges[:-1], edges[1:], strict=True):
        ks = np.array([w["k"] for w in windows if w["polar_deg"] == polar])
        share = 2.0 * math.pi * (math.cos(math.radians(low)) - math.cos(math.radians(high)))
        median = float(np.median(ks))
        resistance += median * share
        bands.append({
            "polar_deg": polar, "band_deg": [low, high], "cases": int(len(ks)), "k_median": median,
            "k_quartiles": [float(np.percentile(ks, 25)), float(np.percentile(ks, 75))],
        })  # fmt: skip
    radius_mm = float(np.median([w["radius_mm"] for w in windows]))
    per_feed_n = resistance * radius_mm**2  # N of push per mm/s of seated feed
    step_volume = 2.0 * math.pi / 3.0 * ((radius_mm + 1.0) ** 3 - radius_mm**3)
    seated = {}
    for push in PUSHES_N:
        feed = push / per_feed_n if per_feed_n > 0 else math.inf
        rate = math.pi * radius_mm**2 * feed
        seated[f"{push:g}"] = {"feed_mm_s": feed, "removal_mm3_s": rate, "seconds_per_2mm_step": step_volume / rate if rate else math.inf}
    return {
        "cases_used": len(windows),
        "radius_mm": radius_mm,
        "bands": bands,
        "push_per_feed_n_s_mm": per_feed_n,
        "seated": seated,
        **at_a_push,
    }
