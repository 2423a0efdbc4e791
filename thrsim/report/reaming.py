"""Reaming part of the report: removal, depth and push over time, the final cavity against the
planned hemisphere (under- and over-reaming, perforation), orientation while cutting, and the
errors and corrections (every event, undone or not); the criteria and metrics as data.

The record is the session, not the final bone: a perforation (or another of the
:data:`~thrsim.session.reaming.BONE_ERRORS`) counts however it was undone or the bone restored
after it, and a cavity reamed through is not a cavity prepared to plan.

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

from thrsim.report.parts import Criterion, Part, Section, figure_png, table
from thrsim.session.file import SessionFile
from thrsim.session.reaming import BONE_ERRORS, ReamingRecord, read_reaming

GRID_M = 0.5e-3
ON_PLAN_TOLERANCE_M = 0.45e-3
_ERROR_WORDS = {"perforated": "perforated", "medial_wall_breached": "medial wall breached", "rim_damaged": "rim damaged"}
#: the events listed under errors and corrections
_LISTED = (*BONE_ERRORS, "passed_through", "push_out_of_range", "undo", "restore")
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


def _tier(value: float, full: float, half: float) -> float:
    return 1.0 if value >= full else 0.5 if value >= half else 0.0


def _in_range(record: ReamingRecord) -> np.ndarray | None:
    """Per frame: the push within the range the model learned (None when the session does not say it)."""
    if record.trained_force_n is None:
        return None
    low, high = record.trained_force_n
    return (record.force_n >= low) & (record.force_n <= high)


def metrics(record: ReamingRecord) -> dict:
    """The metrics the bone patch measures (the plan's and the reamer sequence's come with them)."""
    kinds = [e["kind"] for e in record.events]
    steps = np.linalg.norm(np.diff(record.position_m, axis=0), axis=1) * 1e3
    consecutive = np.diff(record.frame) == 1  # an undo or a restore moves the reamer back: no travel
    in_range = _in_range(record)
    found = {
        "perforations": kinds.count("perforated"),
        "undos": kinds.count("undo"),
        "restores": kinds.count("restore"),
        "push_mean_n": float(np.mean(record.force_n)),
        "reamer_path_length_mm": float(steps[consecutive].sum()),
    }
    if in_range is not None:
        found["push_out_of_range_fraction"] = float(1.0 - np.mean(in_range))
    return found


def _errors(record: ReamingRecord) -> list[dict]:
    return [e for e in record.events if e["kind"] in BONE_ERRORS]


def _corrected(record: ReamingRecord, event: dict) -> str:
    """How an error was gone back on: ", then undone" / ", then the bone restored" / ""."""
    later = [e["kind"] for e in record.events if e["time_s"] >= event["time_s"] and e["kind"] in ("undo", "restore")]
    return "" if not later else ", then undone" if later[0] == "undo" else ", then the bone restored"


def criteria(record: ReamingRecord) -> list[Criterion]:
    """The reaming criteria; none for a session that reamed no bone."""
    if not record.assessable:
        return []
    errors = _errors(record)
    found = cavity_map(record)["fractions"] if record.cavity else None
    through = bool(found and found["perforated"] > 0)
    said = [f"{_ERROR_WORDS[e['kind']]} at {e['time_s']:.1f} s{_corrected(record, e)}" for e in errors]
    if through and not errors:
        said.append("the final cavity is perforated")
    failed = "; ".join(said)
    out = [
        Criterion(
            "no perforation or breach",
            failed or "the outer surface and the walls were never broken",
            "none, undone or not: 2",
            0.0 if failed else 2.0,
            2.0,
        )
    ]
    if found is not None:
        beyond = found["over-reamed"] + found["perforated"]
        prepared = found["on plan"] + found["over-reamed"]
        out += [
            Criterion("over-reaming", f"{100 * beyond:.0f} % of the patch beyond the plan" + (f"; {failed}" if failed else ""),
                      "≤ 5 %, never through: 1; ≤ 15 %: 0.5", 0.0 if failed else 1.0 if beyond <= 0.05 else 0.5 if beyond <= 0.15 else 0.0, 1.0),
            Criterion("cavity prepared",
                      f"not a prepared cavity: {failed} (the final bone {100 * prepared:.0f} % reamed to the plan)" if failed
                      else f"{100 * prepared:.0f} % of the patch reamed to the plan",
                      "never through; ≥ 80 %: 1; ≥ 50 %: 0.5", 0.0 if failed else _tier(prepared, 0.8, 0.5), 1.0),
        ]  # fmt: skip
    in_range = _in_range(record)
    if in_range is not None and record.trained_force_n is not None:
        low, high = record.trained_force_n
        share = float(np.mean(in_range))
        out.append(
            Criterion(
                "push force",
                f"{100 * share:.0f} % of reaming time in {low:g}–{high:g} N",
                "≥ 90 %: 1; ≥ 60 %: 0.5",
                _tier(share, 0.9, 0.6),
                1.0,
            )
        )
    kinds = [e["kind"] for e in record.events]
    undos, restores = kinds.count("undo"), kinds.count("restore")
    out.append(
        Criterion(
            "no undo or restore",
            f"{undos} undo{'s' * (undos != 1)}, {restores} restore{'s' * (restores != 1)}",
            "none: 1; one: 0.5",
            1.0 if undos + restores == 0 else 0.5 if undos + restores == 1 else 0.0,
            1.0,
        )
    )
    measured = np.isfinite(record.angles[:, 2])
    if measured.any():
        share = float(np.sum(measured & (record.angles[:, 2] == 0.0)) / measured.sum())
        out.append(
            Criterion(
                "safe zone while cutting",
                f"{100 * share:.0f} % of reaming frames",
                "≥ 90 %: 2; ≥ 70 %: 1",
                2.0 if share >= 0.9 else 1.0 if share >= 0.7 else 0.0,
                2.0,
            )
        )
    return out


def _course(record: ReamingRecord) -> Section:
    import matplotlib.pyplot as plt

    t = record.frame * record.frame_dt_s
    # room between the panels for the twin depth axis's label
    figure, axes = plt.subplots(1, 2, figsize=(11.5, 3.4), gridspec_kw={"wspace": 0.45})
    axes[0].plot(t, record.removed_volume_mm3, color="tab:brown", label="removed volume")
    axes[0].set_xlabel("reaming time (s)")
    axes[0].set_ylabel("removed volume (mm³)")
    depth_axis = axes[0].twinx()
    depth_axis.plot(t, record.depth_mm, color="tab:blue", label="depth")
    depth_axis.set_ylabel("depth along the reamer axis (mm)")
    axes[0].set_title("Bone removed and reamer depth")
    if record.trained_force_n is not None:
        low, high = record.trained_force_n
        axes[1].axhspan(low, high, color="tab:green", alpha=0.12, label=f"learned range {low:g}–{high:g} N")
    axes[1].plot(t, record.force_n, color="tab:red", lw=1.2, label="push")
    axes[1].set_xlabel("reaming time (s)")
    axes[1].set_ylabel("push force (N)")
    axes[1].legend(fontsize=8)
    axes[1].set_title("Push force")
    frames = len(record.frame)
    in_range = _in_range(record)
    rate = record.removed_volume_mm3[-1] / (frames * record.frame_dt_s)
    body = figure_png(figure) + table(
        ["reaming time", "removed", "final depth", "mean removal rate", "push in the learned range", "frames the simulation fell behind"],
        [
            [
                f"{frames * record.frame_dt_s:.1f} s",
                f"{record.removed_volume_mm3[-1]:.1f} mm³",
                f"{record.depth_mm[-1]:.2f} mm",
                f"{rate:.0f} mm³/s",
                "— (not recorded)" if in_range is None else f"{100 * np.mean(in_range):.0f} %",
                record.behind_frames,
            ]
        ],
    )
    return Section("Reaming: removal, depth and push", body)


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
    restored = any(e["kind"] in ("undo", "restore") for e in record.events)
    body = figure_png(figure) + (
        "<p>Seen along the acetabular opening. The plan is the reamer's hemisphere at the acetabular centre; a cell is "
        "on plan within one element (0.45 mm) of it."
        + (" This is the bone as the session ended: what was undone or restored is gone from it, not from the record "
           "(see errors and corrections).</p>" if restored else "</p>")
    )  # fmt: skip
    return Section("Reaming: the final cavity", body)


def _orientation_while_cutting(record: ReamingRecord) -> Section:
    measured = np.isfinite(record.angles[:, 2])
    inside = measured & (record.angles[:, 2] == 0.0)
    share = float(inside.sum() / measured.sum()) if measured.any() else math.nan
    body = table(
        ["frames cutting", "reamer measured", "inside the safe zone", "largest distance outside"],
        [[len(record.frame), int(measured.sum()), "—" if math.isnan(share) else f"{100 * share:.0f} %",
          f"{np.nanmax(record.angles[:, 2]):.1f}°" if measured.any() else "—"]],
    )  # fmt: skip
    return Section("Reaming: orientation while cutting", body)


def _errors_and_corrections(record: ReamingRecord) -> Section:
    listed = [e for e in record.events if e["kind"] in _LISTED]
    body = (
        table(["time", "event", "what"], [[f"{e['time_s']:.1f} s", e["kind"].replace("_", " "), e["detail"]] for e in listed])
        if listed
        else "<p>No perforation, no push outside the learned range, nothing undone or restored.</p>"
    )
    return Section("Reaming: errors and corrections", body)


def _sections(record: ReamingRecord) -> list[Section]:
    if not record.assessable:
        return [Section("Reaming", "<p>No bone was reamed in this session.</p>")]
    sections = [_course(record), _orientation_while_cutting(record), _errors_and_corrections(record)]
    if record.cavity:
        sections.insert(1, _cavity(record))
    return sections


def reaming_part(session: SessionFile) -> Part | None:
    if "reaming" not in session.groups:
        return None
    record = read_reaming(session.groups["reaming"])
    return Part(criteria(record), record.events, metrics(record) if record.assessable else {}, lambda: _sections(record))
