"""Reaming sections of the report: removal, depth and push over time, the final cavity against
the planned hemisphere (under- and over-reaming, perforation), orientation while cutting.

The planned cavity is the reamer's hemisphere (the teeth's reach) centred at the acetabular
centre, where the cup is meant to sit. The final cavity is read per cell of a 0.5 mm grid over
the patch seen along its axis: the cut surface lies between the deepest removed element and the
nearest kept one beyond it (midway between their centroids' distances from the acetabular
centre; at the outer surface when none is kept beyond). A cell is on plan when that lies within
one element (0.45 mm, the mesh's resolution) of the planned radius, under-reamed short of it,
over-reamed beyond it, and perforated when a removed element had a face on the bone's outer
surface.
"""

from __future__ import annotations

import math

import numpy as np

from thrsim.report.document import Criterion, Section, figure_png, table
from thrsim.session.file import SessionFile
from thrsim.session.reaming import ReamingRecord, read_reaming

FRAME_S = 1 / 60
GRID_M = 0.5e-3
ON_PLAN_TOLERANCE_M = 0.45e-3
#: the push forces the simulator learned from (the dataset's 150–310 N)
TRAINED_FORCE_N = (150.0, 310.0)
CLASSES = ("not reached", "under-reamed", "on plan", "over-reamed", "perforated")
_CLASS_COLOURS = ("#e8e8e8", "#f2c14e", "#2ca25f", "#d7301f", "#000000")


def cavity_map(record: ReamingRecord) -> dict:
    """Per grid cell: depth reamed below the articular surface (mm, NaN where intact) and class."""
    cavity = record.cavity
    centroids = cavity["centroids_m"]
    removed = record.final_alpha < cavity["threshold"]
    radius = np.linalg.norm(centroids, axis=1)
    lo = centroids[:, :2].min(axis=0)
    cells = np.floor((centroids[:, :2] - lo) / GRID_M).astype(int)
    shape = tuple(cells.max(axis=0) + 1)
    flat = np.ravel_multi_index(cells.T, shape)
    bone = np.zeros(np.prod(shape), dtype=bool)
    bone[flat] = True
    deepest = np.full(np.prod(shape), -np.inf)
    np.maximum.at(deepest, flat[removed], radius[removed])
    beyond = ~removed & (radius > deepest[flat])  # kept elements deeper than the cut in their cell
    nearest_kept = np.full(np.prod(shape), cavity["outer_radius_m"])
    np.minimum.at(nearest_kept, flat[beyond], radius[beyond])
    surface = np.where(np.isfinite(deepest), 0.5 * (deepest + nearest_kept), -np.inf)
    perforated = np.zeros(np.prod(shape), dtype=bool)
    perforated[flat[removed & cavity["outer"]]] = True
    planned = cavity["teeth_radius_m"]
    classes = np.zeros(np.prod(shape), dtype=np.int8)
    reached = np.isfinite(surface)
    classes[reached & (surface < planned - ON_PLAN_TOLERANCE_M)] = 1
    classes[reached & (np.abs(surface - planned) <= ON_PLAN_TOLERANCE_M)] = 2
    classes[reached & (surface > planned + ON_PLAN_TOLERANCE_M)] = 3
    classes[perforated] = 4
    depth = np.where(reached, (surface - cavity["inner_radius_m"]) * 1e3, np.nan)
    fractions = {name: float(np.mean(classes[bone] == k)) for k, name in enumerate(CLASSES)}
    return {
        "depth_mm": np.where(bone, depth, np.nan).reshape(shape),
        "classes": np.where(bone, classes, -1).reshape(shape),
        "extent_mm": (lo[0] * 1e3, (lo[0] + shape[0] * GRID_M) * 1e3, lo[1] * 1e3, (lo[1] + shape[1] * GRID_M) * 1e3),
        "fractions": fractions,
        "planned_depth_mm": (planned - cavity["inner_radius_m"]) * 1e3,
        "shell_mm": (cavity["outer_radius_m"] - cavity["inner_radius_m"]) * 1e3,
    }


def _course(record: ReamingRecord) -> Section:
    import matplotlib.pyplot as plt

    t = record.frame * FRAME_S
    # room between the panels for the twin depth axis's label
    figure, axes = plt.subplots(1, 2, figsize=(11.5, 3.4), gridspec_kw={"wspace": 0.45})
    axes[0].plot(t, record.removed_volume_mm3, color="tab:brown", label="removed volume")
    axes[0].set_xlabel("reaming time (s)")
    axes[0].set_ylabel("removed volume (mm³)")
    depth_axis = axes[0].twinx()
    depth_axis.plot(t, record.depth_mm, color="tab:blue", label="depth")
    depth_axis.set_ylabel("depth along the reamer axis (mm)")
    axes[0].set_title("Bone removed and reamer depth")
    low, high = TRAINED_FORCE_N
    axes[1].axhspan(low, high, color="tab:green", alpha=0.12, label=f"learned range {low:g}–{high:g} N")
    axes[1].plot(t, record.force_n, color="tab:red", lw=1.2, label="push")
    axes[1].set_xlabel("reaming time (s)")
    axes[1].set_ylabel("push force (N)")
    axes[1].legend(fontsize=8)
    axes[1].set_title("Push force")
    frames = len(record.frame)
    in_range = float(np.mean((record.force_n >= low) & (record.force_n <= high))) if frames else math.nan
    rate = record.removed_volume_mm3[-1] / (frames * FRAME_S) if frames else 0.0
    body = figure_png(figure) + table(
        ["reaming time", "removed", "final depth", "mean removal rate", "push in the learned range", "frames the simulation fell behind"],
        [
            [
                f"{frames * FRAME_S:.1f} s",
                f"{record.removed_volume_mm3[-1]:.1f} mm³" if frames else "0 mm³",
                f"{record.depth_mm[-1]:.2f} mm" if frames else "0 mm",
                f"{rate:.0f} mm³/s",
                "—" if math.isnan(in_range) else f"{100 * in_range:.0f} %",
                record.behind_frames,
            ]
        ],
    )
    criteria = (
        []
        if not frames
        else [
            Criterion(
                "push force",
                f"{100 * in_range:.0f} % of reaming time in {low:g}–{high:g} N",
                "≥ 90 %: 1; ≥ 60 %: 0.5",
                1.0 if in_range >= 0.9 else 0.5 if in_range >= 0.6 else 0.0,
                1.0,
            )
        ]
    )
    return Section("Reaming: removal, depth and push", body, criteria)


def _cavity(record: ReamingRecord) -> Section:
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    found = cavity_map(record)
    fractions = found["fractions"]
    figure, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    image = axes[0].imshow(found["depth_mm"].T, origin="lower", extent=found["extent_mm"], cmap="viridis", vmin=0, vmax=found["shell_mm"])
    figure.colorbar(image, ax=axes[0], label="reamed below the articular surface (mm)")
    axes[0].set_title(f"Final cavity depth (plan {found['planned_depth_mm']:.2f} mm)")
    classes = np.ma.masked_less(found["classes"].T, 0)
    axes[1].imshow(
        classes,
        origin="lower",
        extent=found["extent_mm"],
        cmap=ListedColormap(_CLASS_COLOURS),
        vmin=-0.5,
        vmax=len(CLASSES) - 0.5,
        interpolation="nearest",
    )
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in _CLASS_COLOURS]
    axes[1].legend(handles, [f"{n} ({100 * fractions[n]:.0f} %)" for n in CLASSES], fontsize=8, loc="upper right")
    axes[1].set_title("Against the planned hemisphere")
    for ax in axes:
        ax.set_xlabel("x (mm, patch frame)")
        ax.set_ylabel("y (mm)")
        ax.set_aspect("equal")
    perforated = fractions["perforated"] > 0
    body = figure_png(figure) + (
        "<p>Seen along the acetabular opening. The plan is the reamer's hemisphere at the acetabular centre; a cell is "
        "on plan within one element (0.45 mm) of it.</p>"
    )
    criteria = [
        Criterion("no perforation", "perforated" if perforated else "the outer surface is intact", "intact: 2", 0.0 if perforated else 2.0, 2.0),
        Criterion("over-reaming", f"{100 * (fractions['over-reamed'] + fractions['perforated']):.0f} % of the patch beyond the plan", "≤ 5 %: 1; ≤ 15 %: 0.5",
                  1.0 if fractions["over-reamed"] + fractions["perforated"] <= 0.05 else 0.5 if fractions["over-reamed"] + fractions["perforated"] <= 0.15 else 0.0, 1.0),
        Criterion("cavity prepared", f"{100 * (fractions['on plan'] + fractions['over-reamed'] + fractions['perforated']):.0f} % of the patch reamed to the plan", "≥ 80 %: 1; ≥ 50 %: 0.5",
                  _tier(fractions["on plan"] + fractions["over-reamed"] + fractions["perforated"], 0.8, 0.5), 1.0),
    ]  # fmt: skip
    return Section("Reaming: the final cavity", body, criteria)


def _tier(value: float, full: float, half: float) -> float:
    return 1.0 if value >= full else 0.5 if value >= half else 0.0


def _orientation_while_cutting(record: ReamingRecord) -> Section:
    measured = np.isfinite(record.angles[:, 2])
    inside = measured & (record.angles[:, 2] == 0.0)
    share = float(inside.sum() / measured.sum()) if measured.any() else math.nan
    body = table(
        ["frames cutting", "reamer measured", "inside the safe zone", "largest distance outside"],
        [[len(record.frame), int(measured.sum()), "—" if math.isnan(share) else f"{100 * share:.0f} %",
          f"{np.nanmax(record.angles[:, 2]):.1f}°" if measured.any() else "—"]],
    )  # fmt: skip
    criteria = (
        []
        if math.isnan(share)
        else [
            Criterion(
                "safe zone while cutting",
                f"{100 * share:.0f} % of reaming frames",
                "≥ 90 %: 2; ≥ 70 %: 1",
                2.0 if share >= 0.9 else 1.0 if share >= 0.7 else 0.0,
                2.0,
            )
        ]
    )
    return Section("Reaming: orientation while cutting", body, criteria)


def reaming_sections(session: SessionFile) -> list[Section]:
    if "reaming" not in session.groups:
        return []
    record = read_reaming(session.groups["reaming"])
    if len(record.frame) == 0:
        return [Section("Reaming", "<p>No bone was reamed in this session.</p>")]
    sections = [_course(record), _orientation_while_cutting(record)]
    if record.cavity:
        sections.insert(1, _cavity(record))
    return sections
