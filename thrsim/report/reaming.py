"""Reaming part of the report: removal, depth and push over time, the final cavity against the
planned hemisphere (:func:`cavity_map`), orientation while cutting, and the errors and
corrections (every event, undone or not); the criteria and metrics as data.

The record is the session, not the final bone: a perforation (or another of the
:data:`~thrsim.session.reaming.BONE_ERRORS`) counts however it was undone or the bone restored
after it, and a cavity reamed through is not a cavity prepared to plan.
"""

from __future__ import annotations

import html
import math

import numpy as np

from thrsim.report.parts import Criterion, Part, Section, figure_png, table
from thrsim.report.reaming_metrics import cavity_axis_angles, confirmed_cup_angles, cut_sizes_mm, in_range, metrics
from thrsim.report.thresholds import AtLeast, AtMost, Thresholds, default_thresholds
from thrsim.session.file import SessionFile
from thrsim.session.plan import Plan
from thrsim.session.reaming import BONE_ERRORS, ReamingRecord, read_reaming

GRID_M = 0.5e-3
ON_PLAN_TOLERANCE_M = 0.45e-3
_ERROR_WORDS = {"perforated": "perforated", "medial_wall_breached": "medial wall breached", "rim_damaged": "rim damaged"}
#: the events listed under errors and corrections
_LISTED = (
    *BONE_ERRORS,
    "passed_through",
    "push_out_of_range",
    "feed_out_of_range",
    "tilt_out_of_range",
    "reamer_out_of_range",
    "centre_out_of_range",
    "undo",
    "restore",
)
CLASSES = ("not reached", "under-reamed", "on plan", "over-reamed", "perforated")
_CLASS_COLOURS = ("#e8e8e8", "#f2c14e", "#2ca25f", "#d7301f", "#000000")


def cavity_map(record: ReamingRecord) -> dict:
    """Per grid cell: depth reamed below the articular surface (mm, NaN where intact) and class.

    The planned cavity is the reamer's hemisphere (the teeth's reach) centred at the acetabular
    centre, where the cup is meant to sit. The final cavity is read per cell of a 0.5 mm grid over
    the patch seen along its axis: the cut surface lies between the deepest removed element and the
    nearest kept one beyond it (midway between their centroids' distances from the acetabular
    centre; at the outer surface when none is kept beyond). A cell is on plan when that lies within
    one element (0.45 mm, the mesh's resolution) of the planned radius, under-reamed short of it,
    over-reamed beyond it, and perforated when a removed element had a face on the bone's outer
    surface."""
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


def _tier(value: float, entry: AtLeast) -> float:
    """1, 0.5 or 0 of a criterion's points: ``value`` reaching the entry's full or partial threshold."""
    return 1.0 if value >= entry.full else 0.5 if value >= entry.partial else 0.0


def _tier_at_most(value: float, entry: AtMost) -> float:
    return 1.0 if value <= entry.full else 0.5 if value <= entry.partial else 0.0


def _count(limit: float) -> str:
    return "none" if limit == 0 else "one" if limit == 1 else f"at most {limit:g}"


def _rule_at_least(entry: AtLeast, points: float, percent: bool = True) -> str:
    shown = (lambda v: f"{100 * v:g} %") if percent else (lambda v: f"{v:g}")
    return f"≥ {shown(entry.full)}: {points:g}; ≥ {shown(entry.partial)}: {points / 2:g}"


def _rule_at_most(entry: AtMost, points: float, unit: str = "") -> str:
    return f"≤ {entry.full:g}{unit}: {points:g}; ≤ {entry.partial:g}{unit}: {points / 2:g}"


def _errors(record: ReamingRecord) -> list[dict]:
    return [e for e in record.events if e["kind"] in BONE_ERRORS]


def _corrected(record: ReamingRecord, event: dict) -> str:
    """How an error was gone back on: ", then undone" / ", then the bone restored" / ""."""
    later = [e["kind"] for e in record.events if e["time_s"] >= event["time_s"] and e["kind"] in ("undo", "restore")]
    return "" if not later else ", then undone" if later[0] == "undo" else ", then the bone restored"


def criteria(record: ReamingRecord, thresholds: Thresholds | None = None) -> list[Criterion]:
    """The reaming criteria, scored against ``thresholds`` (None: the shipped defaults); none for a session that reamed no bone."""
    if not record.assessable:
        return []
    t = thresholds or default_thresholds()
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
        over, ready = t.over_reaming_fraction, t.prepared_fraction
        out += [
            Criterion("over-reaming", f"{100 * beyond:.0f} % of the patch beyond the plan" + (f"; {failed}" if failed else ""),
                      f"never through; ≤ {100 * over.full:g} %: 1; ≤ {100 * over.partial:g} %: 0.5", 0.0 if failed else _tier_at_most(beyond, over), 1.0),
            Criterion("cavity prepared",
                      f"not a prepared cavity: {failed} (the final bone {100 * prepared:.0f} % reamed to the plan)" if failed
                      else f"{100 * prepared:.0f} % of the patch reamed to the plan",
                      "never through; " + _rule_at_least(ready, 1.0), 0.0 if failed else _tier(prepared, ready), 1.0),
        ]  # fmt: skip
    pushed = in_range(record)
    if pushed is not None and record.trained_force_n is not None:
        low, high = record.trained_force_n
        share = float(np.mean(pushed))
        out.append(
            Criterion(
                "push force",
                f"{100 * share:.0f} % of reaming time in {low:g}–{high:g} N",
                _rule_at_least(t.push_in_range_fraction, 1.0),
                _tier(share, t.push_in_range_fraction),
                1.0,
            )
        )
    kinds = [e["kind"] for e in record.events]
    undos, restores = kinds.count("undo"), kinds.count("restore")
    out.append(
        Criterion(
            "no undo or restore",
            f"{undos} undo{'s' * (undos != 1)}, {restores} restore{'s' * (restores != 1)}",
            f"{_count(t.corrections.full)}: 1; {_count(t.corrections.partial)}: 0.5",
            _tier_at_most(undos + restores, t.corrections),
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
                _rule_at_least(t.safe_zone_fraction, 2.0),
                2.0 * _tier(share, t.safe_zone_fraction),
                2.0,
            )
        )
    return out + _plan_criteria(record, t, failed)


def _plan_criteria(record: ReamingRecord, t: Thresholds, failed: str) -> list[Criterion]:
    """The criteria against the plan and of the reamer sequence (none for a file before the plan). A cavity
    reamed through (``failed`` says how) is not a cavity to plan: its orientation, centre and diameter score nothing."""
    if record.plan is None:
        return []
    found = metrics(record)
    plan = Plan(**(record.plan or {}))
    out = []

    def cavity(name: str, measured: str, rule: str, points: float, max_points: float) -> Criterion:
        if failed:
            return Criterion(name, f"not a prepared cavity: {failed} ({measured})", f"never through; {rule}", 0.0, max_points)
        return Criterion(name, measured, rule, points, max_points)

    if found["inclination_error_deg"] is not None:
        worst = max(found["inclination_error_deg"], found["anteversion_error_deg"])
        out.append(
            cavity(
                "cavity orientation against the plan",
                f"inclination {found['inclination_error_deg']:.1f}°, anteversion {found['anteversion_error_deg']:.1f}° off the planned "
                f"{plan.inclination_deg:g}°/{plan.anteversion_deg:g}°",
                "both angles " + _rule_at_most(t.orientation_error_deg, 2.0, "°"),
                2.0 * _tier_at_most(worst, t.orientation_error_deg),
                2.0,
            )
        )
    if found["within_10deg_fraction"] is not None:
        share = found["within_10deg_fraction"]
        out.append(
            Criterion(
                "reaming within 10° of the plan",
                f"{100 * share:.0f} % of reaming frames, both angles",
                _rule_at_least(t.within_10deg_fraction, 1.0),
                _tier(share, t.within_10deg_fraction),
                1.0,
            )
        )
    shift = (found["medialisation_mm"], found["superior_shift_mm"])
    if shift[0] is not None:
        worst = max(abs(shift[0] - plan.medialisation_mm), abs(shift[1] - plan.superior_shift_mm))
        out.append(
            cavity(
                "centre of rotation against the plan",
                f"{shift[0]:.1f} mm medial, {shift[1]:.1f} mm superior for a plan of {plan.medialisation_mm:g} and {plan.superior_shift_mm:g} mm",
                "each way " + _rule_at_most(t.centre_error_mm, 1.0, " mm"),
                _tier_at_most(worst, t.centre_error_mm),
                1.0,
            )
        )
    simulated = found["cavity_diameter_mm"]
    if simulated is not None and record.reamer_mm is not None and np.allclose(record.reamer_mm, cut_sizes_mm(record)):
        error = found["cavity_diameter_error_mm"]
        out.append(
            cavity(
                "cavity diameter against the plan",
                f"{simulated:g} mm for a {plan.cup_diameter_mm:g} mm cup ({error:+.1f} mm)",
                "either way " + _rule_at_most(t.cavity_diameter_error_mm, 1.0, " mm"),
                _tier_at_most(abs(error), t.cavity_diameter_error_mm),
                1.0,
            )
        )
    if "reamer_sequence_mm" in found:
        out.append(_sequence_criterion(found["reamer_sequence_mm"], plan, t))
    return out


def _sequence_criterion(sizes: list[float], plan: Plan, t: Thresholds) -> Criterion:
    """Steps up of at most the threshold, never down, and a last reamer line-to-line or a little under the cup: each half the point."""
    steps = np.diff(sizes)
    under = plan.cup_diameter_mm - sizes[-1]
    biggest = float(steps.max()) if len(steps) else 0.0
    stepping = 0.0 if (steps < 0).any() else _tier_at_most(biggest, t.reamer_step_mm)
    finishing = 0.0 if under < 0 else _tier_at_most(under, t.final_reamer_under_cup_mm)
    went_down = "; stepped down" if (steps < 0).any() else ""
    return Criterion(
        "reamer sequence",
        " → ".join(f"{size:g}" for size in sizes)
        + f" mm: largest step {biggest:g} mm{went_down}, the last reamer {under:g} mm under the cup",
        f"steps up {_rule_at_most(t.reamer_step_mm, 0.5, ' mm')}; the last reamer never over the cup and "
        f"{_rule_at_most(t.final_reamer_under_cup_mm, 0.5, ' mm')} under it",
        0.5 * stepping + 0.5 * finishing,
        1.0,
    )


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
    pushed = in_range(record)
    rate = record.removed_volume_mm3[-1] / (frames * record.frame_dt_s)
    body = figure_png(figure) + table(
        ["reaming time", "removed", "final depth", "mean removal rate", "push in the learned range", "frames the simulation fell behind"],
        [
            [
                f"{frames * record.frame_dt_s:.1f} s",
                f"{record.removed_volume_mm3[-1]:.1f} mm³",
                f"{record.depth_mm[-1]:.2f} mm",
                f"{rate:.0f} mm³/s",
                "— (not recorded)" if pushed is None else f"{100 * np.mean(pushed):.0f} %",
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


def _against_plan(record: ReamingRecord) -> Section:
    """The plan beside what was reamed, and the reamers used with the time each reamed."""
    found = metrics(record)
    plan = Plan(**(record.plan or {}))

    def shown(value: float | None, unit: str) -> str:
        return "—" if value is None else f"{value:.1f}{unit}"

    axis = cavity_axis_angles(record) or (None, None)
    medial, superior = found["medialisation_mm"], found["superior_shift_mm"]
    rows = [
        [
            "cup diameter",
            f"{plan.cup_diameter_mm:g} mm",
            shown(found["cavity_diameter_mm"], " mm"),
            shown(found["cavity_diameter_error_mm"], " mm"),
        ],
        ["cavity axis inclination", f"{plan.inclination_deg:g}°", shown(axis[0], "°"), shown(found["inclination_error_deg"], "°")],
        ["cavity axis anteversion", f"{plan.anteversion_deg:g}°", shown(axis[1], "°"), shown(found["anteversion_error_deg"], "°")],
        [
            "centre, medial",
            f"{plan.medialisation_mm:g} mm",
            shown(medial, " mm"),
            shown(None if medial is None else medial - plan.medialisation_mm, " mm"),
        ],
        [
            "centre, superior",
            f"{plan.superior_shift_mm:g} mm",
            shown(superior, " mm"),
            shown(None if superior is None else superior - plan.superior_shift_mm, " mm"),
        ],
    ]
    confirmed = confirmed_cup_angles(record) or (None, None)
    rows += [
        ["confirmed cup inclination", f"{plan.inclination_deg:g}°", shown(confirmed[0], "°"), shown(found["confirmed_inclination_error_deg"], "°")],
        ["confirmed cup anteversion", f"{plan.anteversion_deg:g}°", shown(confirmed[1], "°"), shown(found["confirmed_anteversion_error_deg"], "°")],
        ["cavity floor, along the cup's axis", "the planned cup's floor", "", shown(found["cavity_depth_error_mm"], " mm")],
        ["over-reaming: bone removed beyond the planned cup", "0 mm", shown(found["over_reaming_mm"], " mm"), ""],
        ["under-reaming: bone left inside the planned cup", "0 mm", shown(found["under_reaming_mm"], " mm"), ""],
        [
            "medial wall left",
            "",
            "not modelled (the bone patch has no medial wall)" if record.medial_wall_mm is None else shown(found["medial_wall_remaining_mm"], " mm"),
            "",
        ],
    ]  # fmt: skip
    five, ten = found["within_5deg_fraction"], found["within_10deg_fraction"]
    body = f"<p>Plan set by the {html.escape(record.plan_source)}.</p>" + table(["", "plan", "reamed", "error"], rows)
    if confirmed[0] is None:
        body += "<p>No cup orientation was confirmed (Enter on the reaming page).</p>"
    body += (
        "<p>The cavity floor's error is positive where the cavity goes deeper than the planned cup, negative where it stops short; "
        "over- and under-reaming are measured at the final bone's elements (to within half an element, 0.45 mm).</p>"
    )
    if five is not None:
        body += f"<p>Reaming time with both angles within 5° of the plan: {100 * five:.0f} %; within 10°: {100 * ten:.0f} %.</p>"
    if "reamer_sequence_mm" in found:
        body += table(
            ["reamer", "reaming time"],
            [[f"{size:g} mm", f"{time:.1f} s"] for size, time in zip(found["reamer_sequence_mm"], found["time_per_reamer_s"], strict=True)],
        )
    cut = cut_sizes_mm(record)
    if record.reamer_mm is not None and not np.allclose(record.reamer_mm, cut):
        body += (
            f"<p>The simulator cut with {', '.join(f'{size:g}' for size in np.unique(cut))} mm whatever reamer was chosen: its model "
            "was trained on that size only. The cavity diameter is what it cut; the sequence is the trainee's choice.</p>"
        )
    return Section("Reaming: against the plan", body)


def _errors_and_corrections(record: ReamingRecord) -> Section:
    listed = [e for e in record.events if e["kind"] in _LISTED]
    body = (
        table(["time", "event", "what"], [[f"{e['time_s']:.1f} s", e["kind"].replace("_", " "), e["detail"]] for e in listed])
        if listed
        else "<p>No perforation, no push, tilt or reamer outside what the simulator learned, nothing undone or restored.</p>"
    )
    return Section("Reaming: errors and corrections", body)


def _sections(record: ReamingRecord) -> list[Section]:
    if not record.assessable:
        return [Section("Reaming", "<p>No bone was reamed in this session.</p>")]
    sections = [_course(record), _orientation_while_cutting(record), _errors_and_corrections(record)]
    if record.plan is not None:
        sections.insert(1, _against_plan(record))
    if record.cavity:
        sections.insert(1, _cavity(record))
    return sections


def competency(thresholds: Thresholds) -> dict[str, tuple[float, str]]:
    """The competency level of each reaming metric that has one: the full-points tier of its
    criterion in ``thresholds`` (the file the report scores against), so a trainee's learning
    curve draws the level the instructor set."""
    t = thresholds
    angle = (t.orientation_error_deg.full, "max")
    return {
        "inclination_error_deg": angle,
        "anteversion_error_deg": angle,
        "confirmed_inclination_error_deg": angle,
        "confirmed_anteversion_error_deg": angle,
        "within_10deg_fraction": (t.within_10deg_fraction.full, "min"),
        "push_out_of_range_fraction": (1.0 - t.push_in_range_fraction.full, "max"),
    }


def reaming_part(session: SessionFile, thresholds: Thresholds) -> Part | None:
    if "reaming" not in session.groups:
        return None
    record = read_reaming(session.groups["reaming"])
    found = metrics(record) if record.assessable else {}
    return Part(criteria(record, thresholds), record.events, found, lambda: _sections(record), competency(thresholds))
