"""Navigation sections of the report: orientation against the safe zone, registration accuracy
and pace, tracking dropouts by cause, and their scoring criteria."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from thrsim.report.parts import Criterion, Part, Section, figure_png, table
from thrsim.session.file import SessionFile
from thrsim.session.navigation import NavigationRecord, read_navigation

_DROPOUT_COLOURS = {"outside_volume": "#d62728", "angle": "#ff7f0e", "occluded": "#9467bd", "stale": "#7f7f7f", "missing": "#dddddd"}


def _durations(time: np.ndarray) -> np.ndarray:
    """Seconds each trace sample stands for (its step to the next; the last one repeats)."""
    if time.size < 2:
        return np.zeros_like(time)
    steps = np.diff(time)
    return np.append(steps, steps[-1])


def _tiered(value: float, tiers: list[tuple[float, float]], higher_is_better: bool = False) -> float:
    for threshold, points in tiers:
        if (value >= threshold) if higher_is_better else (value <= threshold):
            return points
    return 0.0


#: the competency level of each navigation metric: the full-points tier of its criterion (thrsim's
#: defaults; the thesis gives no rubric). ``(threshold, "max")``: at most; ``"min"``: at least.
COMPETENCY: dict[str, tuple[float, str]] = {
    "acquisition_error_mean_mm": (1.5, "max"),
    "registration_rms_mm": (2.0, "max"),
    "median_time_per_landmark_s": (5.0, "max"),
    "retakes": (2, "max"),
    "time_in_zone_fraction": (0.7, "min"),
    "markers_visible_fraction": (0.9, "min"),
}


def _number(value: float) -> float | None:
    """A metric as data: None where it was not measured (NaN)."""
    return None if math.isnan(value) else float(value)


@dataclass(frozen=True)
class _Figures:
    """What the navigation criteria, metrics and tables measure, computed once (no plots)."""

    count: int
    total: int
    error_mm: np.ndarray  # acquired point to its landmark, NaN where not acquired
    median_time_s: float
    registration_time_s: float
    retakes: int
    aiming_s: float
    measured_s: float
    inside_s: float
    visible_share: float

    @property
    def mean_error_mm(self) -> float:
        return float(np.nanmean(self.error_mm)) if self.count else math.nan

    @property
    def zone_share(self) -> float:
        return self.inside_s / self.measured_s if self.measured_s > 0 else math.nan


def _figures(record: NavigationRecord, dt: np.ndarray) -> _Figures:
    acquired = np.isfinite(record.acquired[:, 0])
    times = record.landmark_time_s[np.isfinite(record.landmark_time_s)]
    aiming = record.phase == 1
    measured = aiming & np.isfinite(record.angles[:, 0])
    inside = measured & (record.angles[:, 2] == 0.0)
    tracked, missing = record.tool_states.index("tracked"), record.tool_states.index("missing")
    in_use = record.tool_codes != missing
    used = in_use.any(axis=1)
    all_tracked = np.all((record.tool_codes == tracked) | ~in_use, axis=1)
    return _Figures(
        count=int(acquired.sum()),
        total=len(record.names),
        error_mm=np.where(acquired, np.linalg.norm(np.nan_to_num(record.acquired) - record.targets, axis=1) * 1e3, math.nan),
        median_time_s=float(np.median(times)) if times.size else math.nan,
        registration_time_s=float(times.sum()) if record.completed else math.nan,
        retakes=int(record.retakes.sum()),
        aiming_s=float(dt[aiming].sum()),
        measured_s=float(dt[measured].sum()),
        inside_s=float(dt[inside].sum()),
        visible_share=float(dt[used & all_tracked].sum() / dt[used].sum()) if dt[used].sum() > 0 else math.nan,
    )


def metrics(record: NavigationRecord, figures: _Figures) -> dict:
    """The navigation metrics as data (None where not measured): what the trainee's record plots."""
    last = record.confirmations[-1] if record.confirmations else None
    return {
        "landmarks_acquired": figures.count,
        "acquisition_error_mean_mm": _number(figures.mean_error_mm),
        "acquisition_error_max_mm": _number(float(np.nanmax(figures.error_mm)) if figures.count else math.nan),
        "registration_rms_mm": _number(record.rms_m * 1e3),
        "median_time_per_landmark_s": _number(figures.median_time_s),
        "registration_time_s": _number(figures.registration_time_s),
        "retakes": figures.retakes,
        "time_in_zone_fraction": _number(figures.zone_share),
        "confirmed_cup_distance_deg": None if last is None else float(last["distance_deg"]),
        "markers_visible_fraction": _number(figures.visible_share),
    }


def _orientation_criteria(record: NavigationRecord, figures: _Figures) -> list[Criterion]:
    share = figures.zone_share
    criteria = [
        Criterion(
            "time in the safe zone while aiming",
            "no aiming phase" if math.isnan(share) else f"{100 * share:.0f} %",
            "≥ 70 %: 15, ≥ 40 %: 8",
            0.0 if math.isnan(share) else _tiered(share, [(0.7, 15), (0.4, 8)], higher_is_better=True),
            15,
        )
    ]
    last = record.confirmations[-1] if record.confirmations else None
    margin = float(record.zone.get("warning_margin_deg", 5.0))
    criteria.append(
        Criterion(
            "confirmed cup orientation",
            "not confirmed"
            if last is None
            else f"{last['inclination_deg']:.1f}° / {last['anteversion_deg']:.1f}° ({last['distance_deg']:.1f}° from the zone)",
            f"inside the zone: 20, within {margin:g}°: 10",
            0.0 if last is None else 20.0 if last["inside"] else 10.0 if last["distance_deg"] <= margin else 0.0,
            20,
        )
    )
    return criteria


def _orientation(record: NavigationRecord, dt: np.ndarray, figures: _Figures, criteria: list[Criterion]) -> Section:
    import matplotlib.pyplot as plt

    zone = record.zone
    aiming = record.phase == 1
    measured = aiming & np.isfinite(record.angles[:, 0])
    share = figures.zone_share

    figure, axes = plt.subplots(1, 2, figsize=(11, 3.6), gridspec_kw={"width_ratios": [2.2, 1]})
    t = record.time
    for key, colour, centre, tolerance in (
        (0, "tab:blue", zone["inclination_deg"], zone["inclination_tolerance_deg"]),
        (1, "tab:green", zone["anteversion_deg"], zone["anteversion_tolerance_deg"]),
    ):
        label = "inclination" if key == 0 else "anteversion"
        axes[0].axhspan(centre - tolerance, centre + tolerance, color=colour, alpha=0.12)
        axes[0].plot(t, record.angles[:, key], color=colour, lw=1.2, label=f"{label} (band: safe zone)")
    if aiming.any():
        axes[0].axvline(t[np.argmax(aiming)], color="k", ls="--", lw=0.8, label="registration complete")
    axes[0].set_xlabel("session time (s)")
    axes[0].set_ylabel("radiographic angle (°)")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[0].set_title("Reamer orientation over the session")
    rect = plt.Rectangle(
        (zone["inclination_deg"] - zone["inclination_tolerance_deg"], zone["anteversion_deg"] - zone["anteversion_tolerance_deg"]),
        2 * zone["inclination_tolerance_deg"],
        2 * zone["anteversion_tolerance_deg"],
        color="tab:green",
        alpha=0.15,
        label="Lewinnek safe zone",
    )
    axes[1].add_patch(rect)
    axes[1].plot(record.angles[measured, 0], record.angles[measured, 1], ".", ms=2, color="tab:blue", label="while aiming")
    for cup in record.confirmations:
        axes[1].plot(cup["inclination_deg"], cup["anteversion_deg"], "k*", ms=12, label="confirmed cup")
    axes[1].set_xlim(0, 90)
    axes[1].set_ylim(-30, 60)
    axes[1].set_xlabel("inclination (°)")
    axes[1].set_ylabel("anteversion (°)")
    axes[1].legend(fontsize=8)
    axes[1].set_title("Aim against the safe zone")
    body = figure_png(figure)

    rows = [
        ["aiming time (after registration)", f"{figures.aiming_s:.1f} s"],
        ["reamer measured while aiming", f"{figures.measured_s:.1f} s"],
        ["inside the safe zone", f"{figures.inside_s:.1f} s" + ("" if math.isnan(share) else f" ({100 * share:.0f} % of measured)")],
    ]
    for k, cup in enumerate(record.confirmations, 1):
        where = "inside" if cup["inside"] else f"{cup['distance_deg']:.1f}° outside"
        rows.append([f"confirmed cup #{k}", f"{cup['inclination_deg']:.1f}° / {cup['anteversion_deg']:.1f}° — {where}"])
    body += table(["orientation", "value"], rows)
    return Section("Cup orientation against the safe zone", body, criteria)


def _registration_criteria(record: NavigationRecord, figures: _Figures) -> list[Criterion]:
    """Completion, how close each acquired point is to its landmark (the probe's placement), the
    fit, the pace and the retakes; the thresholds are thrsim's (see :data:`COMPETENCY`)."""
    mean_error, median_time = figures.mean_error_mm, figures.median_time_s
    return [
        Criterion(
            "registration completed",
            f"{figures.count} of {figures.total} landmarks",
            "all acquired: 15",
            15.0 if record.completed else 0.0,
            15,
        ),
        Criterion(
            "acquisition accuracy",
            "none acquired" if math.isnan(mean_error) else f"mean {mean_error:.2f} mm from the landmarks",
            "≤ 1.5 mm: 10, ≤ 3 mm: 5",
            0.0 if math.isnan(mean_error) else _tiered(mean_error, [(1.5, 10), (3.0, 5)]),
            10,
        ),
        Criterion(
            "registration accuracy",
            "no fit" if math.isnan(record.rms_m) else f"RMS {record.rms_m * 1e3:.2f} mm",
            "≤ 2 mm: 10, ≤ 4 mm: 5",
            0.0 if math.isnan(record.rms_m) else _tiered(record.rms_m * 1e3, [(2.0, 10), (4.0, 5)]),
            10,
        ),
        Criterion(
            "pace",
            "—" if math.isnan(median_time) else f"median {median_time:.1f} s per landmark",
            "≤ 5 s: 10, ≤ 10 s: 5",
            0.0 if math.isnan(median_time) else _tiered(median_time, [(5.0, 10), (10.0, 5)]),
            10,
        ),
        Criterion(
            "retakes", str(figures.retakes), "≤ 2: 10, ≤ 5: 5", _tiered(figures.retakes, [(2, 10), (5, 5)]) if figures.count else 0.0, 10
        ),
    ]


def _registration(record: NavigationRecord, figures: _Figures, criteria: list[Criterion]) -> Section:
    import matplotlib.pyplot as plt

    acquired = np.isfinite(record.acquired[:, 0])
    residual_mm = record.residual_m * 1e3
    figure, axes = plt.subplots(2, 1, figsize=(11, 5.2), sharex=True)
    x = np.arange(len(record.names))
    axes[0].bar(x - 0.2, np.where(acquired, figures.error_mm, 0.0), 0.4, label="acquired point to landmark", color="tab:gray")
    axes[0].bar(x + 0.2, np.nan_to_num(residual_mm), 0.4, label="fit residual", color="tab:blue")
    axes[0].set_ylabel("mm")
    axes[0].legend(fontsize=8)
    axes[0].set_title("Registration accuracy per landmark")
    axes[1].bar(x, np.nan_to_num(record.landmark_time_s), color=np.where(record.retakes > 0, "tab:orange", "tab:green"))
    for k in np.flatnonzero(record.retakes):
        axes[1].annotate(f"{record.retakes[k]}×", (x[k], np.nan_to_num(record.landmark_time_s[k])), ha="center", va="bottom", fontsize=8)
    axes[1].set_ylabel("s")
    axes[1].set_title("Time per landmark (orange: retaken, count above)")
    axes[1].set_xticks(x, record.names, rotation=70, fontsize=7)
    body = figure_png(figure)

    mean_error, median_time = figures.mean_error_mm, figures.median_time_s
    body += table(
        ["registration", "value"],
        [
            ["landmarks acquired", f"{figures.count} of {figures.total}"],
            ["mean distance of the acquired points to their landmarks", "—" if math.isnan(mean_error) else f"{mean_error:.2f} mm"],
            ["fit RMS residual", "—" if math.isnan(record.rms_m) else f"{record.rms_m * 1e3:.2f} mm"],
            ["median time per landmark", "—" if math.isnan(median_time) else f"{median_time:.1f} s"],
            ["retakes", str(figures.retakes)],
        ],
    )
    return Section("Landmark registration", body, criteria)


def _dropouts_criteria(figures: _Figures) -> list[Criterion]:
    share = figures.visible_share
    return [
        Criterion(
            "markers kept visible",
            "—" if math.isnan(share) else f"every tool in use tracked {100 * share:.0f} % of the time",
            "≥ 90 %: 10, ≥ 75 %: 5",
            0.0 if math.isnan(share) else _tiered(share, [(0.9, 10), (0.75, 5)], higher_is_better=True),
            10,
        )
    ]


def _dropouts(record: NavigationRecord, dt: np.ndarray, criteria: list[Criterion]) -> Section:
    import matplotlib.pyplot as plt

    states = record.tool_states
    tracked = states.index("tracked")
    missing = states.index("missing")
    figure, axes = plt.subplots(1, 2, figsize=(11, 2.8), gridspec_kw={"width_ratios": [2.2, 1]})
    rows = []
    for k, tool in enumerate(record.tools):
        codes = record.tool_codes[:, k]
        lost = (codes != tracked) & (codes != missing)
        episodes = int(np.sum(lost[1:] & ~lost[:-1]) + (lost[0] if lost.size else 0))
        by_cause = {states[c]: float(dt[codes == c].sum()) for c in np.unique(codes[lost])}
        rows.append(
            [tool, f"{dt[codes == tracked].sum():.1f} s", episodes]
            + [f"{by_cause.get(c, 0.0):.1f} s" for c in ("outside_volume", "angle", "occluded", "stale")]
        )
        for cause, colour in _DROPOUT_COLOURS.items():
            mask = codes == states.index(cause)
            spans = _spans(record.time, dt, mask)
            if spans:
                axes[0].broken_barh(spans, (k - 0.35, 0.7), color=colour, label=cause)
        left = 0.0
        for cause, colour in _DROPOUT_COLOURS.items():
            if cause == "missing":
                continue
            seconds = by_cause.get(cause, 0.0)
            axes[1].barh(k, seconds, left=left, color=colour)
            left += seconds
    handles, labels = axes[0].get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    if unique:
        axes[0].legend(unique.values(), unique.keys(), fontsize=8, loc="upper right")
    for ax in axes:
        ax.set_yticks(range(len(record.tools)), record.tools)
    axes[0].set_xlim(0.0, float(record.time[-1]) if record.time.size else 1.0)
    axes[0].set_xlabel("session time (s)")
    axes[0].set_title("When markers were not tracked, and why")
    axes[1].set_xlabel("s")
    axes[1].set_title("Time lost by cause")
    body = figure_png(figure)
    body += table(["tool", "tracked", "dropouts", "outside volume", "beyond 45°", "occluded", "no data"], rows)
    return Section("Tracking dropouts", body, criteria)


def _spans(time: np.ndarray, dt: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    spans = []
    start = None
    for k, flag in enumerate(mask):
        if flag and start is None:
            start = k
        if start is not None and (not flag or k == len(mask) - 1):
            end = k if not flag else k + 1
            spans.append((float(time[start]), float(time[end - 1] + dt[end - 1] - time[start])))
            start = None
    return spans


def _calibration(record: NavigationRecord) -> Section | None:
    if not record.calibrations:
        return None
    rows = []
    for attempt in record.calibrations:
        if attempt.get("ok"):
            outcome = f"{attempt['rotation_residual_rms_deg']:.2f}° / {attempt['translation_residual_rms_mm']:.2f} mm RMS, {attempt['used']} used, {attempt['rejected']} rejected"
        else:
            outcome = "refused: " + attempt.get("message", "")
        rows.append([f"{attempt['time_s']:.1f} s", outcome])
    return Section(
        "Display calibration",
        "<p>Tracker and display both observed one target; the transform between their frames is the "
        "gated average of the paired samples [3.3].</p>" + table(["time", "outcome"], rows),
    )


def navigation_part(session: SessionFile) -> Part | None:
    """The navigation mode's assessment: criteria and metrics as data; its plots only when the page is built."""
    if "navigation" not in session.groups:
        return None
    record = read_navigation(session.groups["navigation"])
    if not record.assessable:
        return Part(
            [], record.events, {}, lambda: [Section("Navigation", "<p>No landmark was acquired and no cup confirmed in this session.</p>")]
        )
    dt = _durations(record.time)
    figures = _figures(record, dt)
    registration, orientation, dropouts = (
        _registration_criteria(record, figures),
        _orientation_criteria(record, figures),
        _dropouts_criteria(figures),
    )

    def sections() -> list[Section]:
        built = [
            _registration(record, figures, registration),
            _orientation(record, dt, figures, orientation),
            _dropouts(record, dt, dropouts),
        ]
        calibration = _calibration(record)
        return built + ([calibration] if calibration else [])

    return Part(registration + orientation + dropouts, record.events, metrics(record, figures), sections, COMPETENCY)
