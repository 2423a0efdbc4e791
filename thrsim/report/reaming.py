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
from thrsim.report.reaming_metrics import (
    cavity_axis_angles,
    confirmed_cup_angles,
    cut_sizes_mm,
    cuts_trainees_reamers,
    in_range,
    metrics,
    planned_hemisphere,
)
from thrsim.report.thresholds import AtLeast, AtMost, Thresholds, default_thresholds
from thrsim.session.file import SessionFile
from thrsim.session.plan import Plan
from thrsim.session.reaming import BONE_ERRORS, CUT_EDGE, PATCH_ELEMENT_SIZE_M, ReamingRecord, read_reaming

GRID_M = 0.5e-3
ON_PLAN_TOLERANCE_M = 0.45e-3
_ERROR_WORDS = {
    "perforated": "perforated",
    "passed_through": "perforated, no bone left in the reamer's path,",
    "medial_wall_breached": "medial wall breached",
    "rim_damaged": "rim damaged",
}
#: a break through the whole socket's cut edge, named as what it is
_CUT_EDGE_WORDS = "through the edge of the modelled bone (the simulated bone ended there, not at the medial wall)"
#: the events listed under errors and corrections
_LISTED = (
    *BONE_ERRORS,
    "push_out_of_range",
    "feed_out_of_range",
    "tilt_out_of_range",
    "reamer_out_of_range",
    "centre_out_of_range",
    "contact_out_of_range",
    "edge_warning",
    "undo",
    "restore",
)
#: the depth map's classes of cell; the last, a native hollow beyond the plan (the socket's fossa), is shown, never counted
CLASSES = ("not reached", "under-reamed", "on plan", "over-reamed", "perforated", "native hollow")
#: the depth map's colours of the cut surface against the plan (mm), as the reaming page colours the bone (static/bone.js);
#: on a mesh coarser than 0.9 mm the green band widens to its on-plan tolerance (half an element)
_ERROR_STOPS = ((-2.0, "#e3dccb"), (-1.0, "#f2c14e"), (-0.45, "#2ca25f"), (0.45, "#2ca25f"), (1.0, "#d7301f"), (2.0, "#5a0d0d"))
_CLASS_COLOURS = ("#e8e8e8", "#f2c14e", "#2ca25f", "#d7301f", "#000000", "#9ecae1")


def map_axes(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The depth map's in-plane directions across ``axis`` (patch frame): anterior and superior, the
    patch frame's +y and −x (its +x is inferior, :data:`thrsim.app.reaming.SOCKET_IN_PATCH`) made
    square to the axis, so the map reads as the socket seen from outside (anterior right, superior up)."""
    anterior = np.array([0.0, 1.0, 0.0]) - axis[1] * axis
    anterior /= np.linalg.norm(anterior)
    return anterior, np.cross(axis, anterior)


def cavity_map(record: ReamingRecord) -> dict:
    """Per grid cell: the cut surface against the planned hemisphere (mm, + beyond it) and its class.

    The planned hemisphere (:func:`~thrsim.report.reaming_metrics.planned_hemisphere`) is seen along
    its axis from outside the socket, on a grid of cells the mesh's element size across (0.5 mm at
    the least) over the cup's footprint. Down each cell's column from the cup's rim, the cut surface
    lies midway between the deepest removed element and the nearest kept one beyond it (half an
    element beyond the deepest removed when none is kept: through the bone); where nothing was
    removed it is the native surface, half an element before the first kept element. A cell is on
    plan when its surface lies within half an element (at least 0.45 mm) of the planned sphere,
    under-reamed short of it (not reached when nothing was removed there), over-reamed beyond it (a
    native hollow when nothing was removed: the socket's fossa, left out of the fractions), and
    perforated when a removed element lay on a face the reamer breaks through (the patch's outer
    face; the socket's medial wall or supported boundary)."""
    cavity = record.cavity
    centre, axis, planned = planned_hemisphere(record)
    element = float(cavity.get("element_size_m", PATCH_ELEMENT_SIZE_M))
    grid, tolerance = max(GRID_M, element), max(ON_PLAN_TOLERANCE_M, element / 2)
    offset = cavity["centroids_m"] - centre
    anterior, superior = map_axes(axis)
    across = np.column_stack([offset @ anterior, offset @ superior])
    depth = -(offset @ axis)  # into the bone from the cup's rim
    cells_across = int(np.ceil(planned / grid))
    cells = np.floor(across / grid).astype(int) + cells_across
    n = 2 * cells_across
    shown = (depth > -element) & (cells >= 0).all(axis=1) & (cells < n).all(axis=1)
    flat = np.where(shown, cells[:, 0] * n + cells[:, 1], 0)
    removed = (record.final_alpha < cavity["threshold"]) & shown
    kept = ~removed & shown
    bone = np.zeros(n * n, dtype=bool)
    bone[flat[shown]] = True
    deepest = np.full(n * n, -np.inf)
    np.maximum.at(deepest, flat[removed], depth[removed])
    reached = np.isfinite(deepest)
    beyond = kept & (depth > deepest[flat])  # kept elements deeper than the cut in their column
    nearest_kept = np.full(n * n, np.inf)
    np.minimum.at(nearest_kept, flat[beyond], depth[beyond])
    through = np.zeros(n * n, dtype=bool)
    through[flat[removed & cavity["outer"]]] = True
    with np.errstate(invalid="ignore"):  # a column without bone: no surface (NaN), never shown
        surface = np.where(
            reached,
            np.where(np.isfinite(nearest_kept), 0.5 * (deepest + nearest_kept), deepest + element / 2),
            nearest_kept - element / 2,
        )
    middle = (np.arange(n) - cells_across + 0.5) * grid
    radial = np.hypot(middle[:, None], middle[None, :]).ravel()
    error = np.hypot(radial, surface) - planned
    footprint = bone & (radial <= planned) & np.isfinite(surface)
    classes = np.where(reached, 1, 0).astype(np.int8)
    classes[np.abs(error) <= tolerance] = 2
    classes[(error > tolerance) & reached] = 3
    classes[(error > tolerance) & ~reached] = 5
    classes[through] = 4
    counted = footprint & (classes != 5)  # the native hollow is no bone to ream
    fractions = {name: float(np.mean(classes[counted] == k)) if counted.any() else 0.0 for k, name in enumerate(CLASSES)}
    edge = cells_across * grid * 1e3
    return {
        "error_mm": np.where(footprint & (classes != 5), error * 1e3, np.nan).reshape(n, n),
        "classes": np.where(footprint, classes, -1).reshape(n, n),
        "extent_mm": (-edge, edge, -edge, edge),
        "fractions": fractions,
        "planned_radius_mm": planned * 1e3,
        "tolerance_mm": tolerance * 1e3,
        "against_cup": bool(record.plan is not None and cuts_trainees_reamers(record)),
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


def _error_words(event: dict) -> str:
    """An error as the catalogue names it: a break through the socket's cut edge is the modelled bone ending, not anatomy."""
    return _CUT_EDGE_WORDS if event.get("face") == CUT_EDGE else _ERROR_WORDS[event["kind"]]


def _event_name(event: dict) -> str:
    return "perforated: the edge of the modelled bone" if event.get("face") == CUT_EDGE else event["kind"].replace("_", " ")


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
    said = [f"{_error_words(e)} at {e['time_s']:.1f} s{_corrected(record, e)}" for e in errors]
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
            Criterion("over-reaming", f"{100 * beyond:.0f} % of the cavity beyond the plan" + (f"; {failed}" if failed else ""),
                      f"never through; ≤ {100 * over.full:g} %: 1; ≤ {100 * over.partial:g} %: 0.5", 0.0 if failed else _tier_at_most(beyond, over), 1.0),
            Criterion("cavity prepared",
                      f"not a prepared cavity: {failed} (the final bone {100 * prepared:.0f} % reamed to the plan)" if failed
                      else f"{100 * prepared:.0f} % of the cavity reamed to the plan",
                      "never through; " + _rule_at_least(ready, 1.0), 0.0 if failed else _tier(prepared, ready), 1.0),
        ]  # fmt: skip
    pushed = in_range(record)
    if pushed is not None and record.trained_force_n is not None:
        low, high = record.trained_force_n
        share = float(np.mean(pushed))
        out.append(
            Criterion(
                "push force",
                f"{100 * share:.0f} % of reaming time in {low:.0f}–{high:.0f} N",
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
    axes[0].set_ylabel("removed volume (mm³)", color="tab:brown")  # each axis in its line's colour
    depth_axis = axes[0].twinx()
    depth_axis.plot(t, record.depth_mm, color="tab:blue", label="depth")
    depth_axis.set_ylabel("reamer advance since placed (mm)", color="tab:blue")
    axes[0].set_title("Bone removed and reamer depth")
    if record.reamer_mm is not None:  # each reamer of the sequence, where the trainee took it up
        for row in np.flatnonzero(np.diff(record.reamer_mm, prepend=np.nan) != 0):
            for ax in axes:
                ax.axvline(t[row], color="0.6", lw=0.8, ls=":")
            axes[0].annotate(f"{record.reamer_mm[row]:g} mm", (t[row], 1.0), xycoords=("data", "axes fraction"), xytext=(2, -10),
                             textcoords="offset points", fontsize=8, color="0.35")  # fmt: skip
    if record.trained_force_n is not None:
        low, high = record.trained_force_n
        axes[1].axhspan(low, high, color="tab:green", alpha=0.12, label=f"learned range {low:.0f}–{high:.0f} N")
    axes[1].plot(t, record.force_n, color="tab:red", lw=1.2, label="push")
    axes[1].set_xlabel("reaming time (s)")
    axes[1].set_ylabel("push force (N)")
    axes[1].legend(fontsize=8)
    axes[1].set_title("Push force")
    frames = len(record.frame)
    pushed = in_range(record)
    rate = record.removed_volume_mm3[-1] / (frames * record.frame_dt_s)
    body = figure_png(figure) + table(
        [
            "reaming time",
            "removed",
            "last reamer's advance",
            "mean removal rate",
            "push in the learned range",
            "frames the simulation fell behind",
        ],
        [
            [
                f"{frames * record.frame_dt_s:.1f} s",
                f"{record.removed_volume_mm3[-1]:.1f} mm³",
                f"{record.depth_mm[-1]:.2f} mm",
                f"{rate:.0f} mm³/s",
                _push_in_range_words(record, pushed),
                record.behind_frames,
            ]
        ],
    )
    return Section("Reaming: removal, depth and push", body)


def _push_in_range_words(record: ReamingRecord, pushed: np.ndarray | None) -> str:
    """The share of reaming time pushed within the learned range; a whole-socket model reads the feed the
    push balances, not the push (it has no learned push), and older files do not say the range."""
    if pushed is not None:
        return f"{100 * np.mean(pushed):.0f} %"
    return "— (the simulator reads the feed, not the push)" if record.reaction_n is not None else "— (not recorded)"


def _cavity(record: ReamingRecord) -> Section:
    import matplotlib.pyplot as plt
    from matplotlib.colors import LinearSegmentedColormap, ListedColormap

    found = cavity_map(record)
    fractions = found["fractions"]
    tolerance = found["tolerance_mm"]  # the green band is the map's on-plan tolerance: the two maps agree
    stops = [(x + np.sign(x) * (tolerance - _ERROR_STOPS[3][0]), colour) for x, colour in _ERROR_STOPS]
    low, high = stops[0][0], stops[-1][0]
    palette = LinearSegmentedColormap.from_list("against_plan", [((x - low) / (high - low), c) for x, c in stops])
    figure, axes = plt.subplots(1, 2, figsize=(11.5, 4.4), gridspec_kw={"wspace": 0.55})
    image = axes[0].imshow(found["error_mm"].T, origin="lower", extent=found["extent_mm"], cmap=palette, vmin=low, vmax=high)
    hollow = np.ma.masked_not_equal(found["classes"].T, 5)  # no surface of bone to measure: drawn as the class map draws it
    axes[0].imshow(hollow, origin="lower", extent=found["extent_mm"], cmap=ListedColormap([_CLASS_COLOURS[5]]), interpolation="nearest")
    bar = figure.colorbar(image, ax=axes[0], extend="both")
    bar.set_label("cut surface against the planned cup (mm)\n− short of it · + beyond it")
    axes[0].set_title(f"Cavity against the {2 * found['planned_radius_mm']:g} mm plan")
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
    shown = [k for k in range(len(CLASSES)) if k < 5 or (found["classes"] == k).any()]
    handles = [plt.Rectangle((0, 0), 1, 1, color=_CLASS_COLOURS[k]) for k in shown]
    words = [CLASSES[k] + ("" if k == 5 else f" ({100 * fractions[CLASSES[k]]:.0f} %)") for k in shown]
    axes[1].legend(handles, words, fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    axes[1].set_title("Cells against the plan")
    edge = found["planned_radius_mm"]
    for ax in axes:
        ax.add_patch(plt.Circle((0, 0), edge, fill=False, color="0.3", lw=0.8, ls="--"))
        ax.set_xlabel("posterior ← → anterior (mm)")
        ax.set_ylabel("inferior ← → superior (mm)")
        ax.set_aspect("equal")
    restored = any(e["kind"] in ("undo", "restore") for e in record.events)
    planned = (
        f"the planned {2 * edge:g} mm cup at its planned centre and angles"
        if found["against_cup"]
        else f"the hemisphere of the simulator's one {2 * edge:g} mm reamer at the native centre (its model cuts that size whatever is held)"
    )
    body = figure_png(figure) + (
        f"<p>The cavity seen from outside the socket along the planned cup's axis, within the cup's rim (dashed). The plan is "
        f"{html.escape(planned)}; a cell is on plan within {found['tolerance_mm']:.2f} mm of it (half the mesh's element)."
        + (" A native hollow (the fossa, bone never there) is shown but not counted." if found["classes"].max() == 5 else "")
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
            "centre, medial (− lateral)",
            f"{plan.medialisation_mm:g} mm",
            shown(medial, " mm"),
            shown(None if medial is None else medial - plan.medialisation_mm, " mm"),
        ],
        [
            "centre, superior (− inferior)",
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
        f"over- and under-reaming are measured at the final bone's elements (to within half an element, {_half_element_mm(record):.2f} mm). "
        "The centre is the reamer's at its deepest with the largest reamer that cut.</p>"
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


def _half_element_mm(record: ReamingRecord) -> float:
    """Half the mesh's element where the reamers cut (mm): how closely the final bone's elements place a surface."""
    return float(record.cavity.get("element_size_m", PATCH_ELEMENT_SIZE_M)) * 0.5e3 if record.cavity else PATCH_ELEMENT_SIZE_M * 0.5e3


def _errors_and_corrections(record: ReamingRecord) -> Section:
    listed = [e for e in record.events if e["kind"] in _LISTED]
    body = (
        table(["time", "event", "what"], [[f"{e['time_s']:.1f} s", _event_name(e), e["detail"]] for e in listed])
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
