"""The whole socket's feed under a push, from a dataset of socket windows reamed at set feeds.

A window case (``thrsim dataset --bone socket``) prescribes the feed f and records the bone's axial
reaction R on the reamer. The cutting law removes the volume the teeth's friction work pays for,
so R grows with f: k = R / (f·A) is the window's axial resistance per mm² of cavity surface and
per mm/s. A reamer one size up, seated along the socket's axis, cuts the whole hemisphere; summing k
over its polar bands (each band's k the median of its windows' cases) gives the push a feed takes,
F = f·Σ k_b·A_b, so the seated feed under a push is f = F / Σ k_b·A_b. Removal then follows from
geometry (π r²·f), and a reamer step's time from the step's volume over that rate. The rim phase
before seating, when the teeth touch only the rim, goes faster: these are the slowest, seated
figures. Cases tilted off the axis or with their reamer's axis moved sideways are left out: the
seated reamer does not cut their windows that way.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from thrsim.config import SweepConfig
from thrsim.data.case_file import CaseReader
from thrsim.data.generate import read_manifest
from thrsim.errors import ThrsimInputError
from thrsim.geometry.socket import window_area_mm2

#: the pushes the seated feed is reported at (N): the sweep's, the thesis's range about its mean
PUSHES_N = tuple(sorted({*SweepConfig().forces_n, *SweepConfig().extra_forces_n}))


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


def socket_calibration(root: str | os.PathLike) -> dict:
    """The windows' resistance by polar band and the whole socket's seated feed, removal rate and time
    per 2 mm reamer step it implies at :data:`PUSHES_N` (see the module's note)."""
    root = Path(root)
    manifest = read_manifest(root)
    if manifest is None:
        raise ThrsimInputError(f"{root}: not a thrsim dataset (no manifest.json)")
    windows = [w for e in manifest.get("cases", {}).values() if (w := window_resistance(e, root / e["file"])) is not None]
    if not windows:
        return {"cases_used": 0}
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
    }
