"""Navigation sections of the report: orientation against the safe zone, registration accuracy
and pace, tracking dropouts by cause, and their scoring criteria."""

from __future__ import annotations

import math

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


def _orientation(record: NavigationRecord, dt: np.ndarray) -> Section:
    import matplotlib.pyplot as plt

    zone = record.zone
    aiming = record.phase == 1
    measured = aiming & np.isfinite(record.angles[:, 0])
    inside = measured & (record.angles[:, 2] == 0.0)
    aiming_s, measured_s, inside_s = float(dt[aiming].sum()), float(dt[measured].sum()), float(dt[inside].sum())
    share = inside_s / measured_s if measured_s > 0 else math.nan

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
        ["aiming time (after registration)", f"{aiming_s:.1f} s"],
        ["reamer measured while aiming", f"{measured_s:.1f} s"],
        ["inside the safe zone", f"{inside_s:.1f} s" + ("" if math.isnan(share) else f" ({100 * share:.0f} % of measured)")],
    ]
    for k, cup in enumerate(record.confirmations, 1):
        where = "inside" if cup["inside"] else f"{cup['distance_deg']:.1f}° outside"
        rows.append([f"confirmed cup #{k}", f"{cup['inclination_deg']:.1f}° / {cup['anteversion_deg']:.1f}° — {where}"])
    body += table(["orientation", "value"], rows)

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
    return Section("Cup orientation against the safe zone", body, criteria)


def _registration(record: NavigationRecord) -> Section:
    import matplotlib.pyplot as plt

    acquired = np.isfinite(record.acquired[:, 0])
    error_mm = np.linalg.norm(record.acquired - record.targets, axis=1) * 1e3
    residual_mm = record.residual_m * 1e3
    figure, axes = plt.subplots(2, 1, figsize=(11, 5.2), sharex=True)
    x = np.arange(len(record.names))
    axes[0].bar(x - 0.2, np.where(acquired, error_mm, 0.0), 0.4, label="acquired point to target", color="tab:gray")
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

    count, total = int(acquired.sum()), len(record.names)
    times = record.landmark_time_s[np.isfinite(record.landmark_time_s)]
    median_time = float(np.median(times)) if times.size else math.nan
    retakes = int(record.retakes.sum())
    body += table(
        ["registration", "value"],
        [
            ["landmarks acquired", f"{count} of {total}"],
            ["fit RMS residual", "—" if math.isnan(record.rms_m) else f"{record.rms_m * 1e3:.2f} mm"],
            ["median time per landmark", "—" if math.isnan(median_time) else f"{median_time:.1f} s"],
            ["retakes", str(retakes)],
        ],
    )
    criteria = [
        Criterion("registration completed", f"{count} of {total} landmarks", "all acquired: 20", 20.0 if record.completed else 0.0, 20),
        Criterion(
            "registration accuracy",
            "no fit" if math.isnan(record.rms_m) else f"RMS {record.rms_m * 1e3:.2f} mm",
            "≤ 2 mm: 15, ≤ 4 mm: 8",
            0.0 if math.isnan(record.rms_m) else _tiered(record.rms_m * 1e3, [(2.0, 15), (4.0, 8)]),
            15,
        ),
        Criterion(
            "pace",
            "—" if math.isnan(median_time) else f"median {median_time:.1f} s per landmark",
            "≤ 5 s: 10, ≤ 10 s: 5",
            0.0 if math.isnan(median_time) else _tiered(median_time, [(5.0, 10), (10.0, 5)]),
            10,
        ),
        Criterion("retakes", str(retakes), "≤ 2: 10, ≤ 5: 5", _tiered(retakes, [(2, 10), (5, 5)]) if count else 0.0, 10),
    ]
    return Section("Landmark registration", body, criteria)


def _dropouts(record: NavigationRecord, dt: np.ndarray) -> Section:
    import matplotlib.pyplot as plt

    states = record.tool_states
    tracked = states.index("tracked")
    missing = states.index("missing")
    figure, axes = plt.subplots(1, 2, figsize=(11, 2.8), gridspec_kw={"width_ratios": [2.2, 1]})
    rows = []
    in_use = record.tool_codes != missing
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

    used = in_use.any(axis=1)
    all_tracked = np.all((record.tool_codes == tracked) | ~in_use, axis=1)
    share = float(dt[used & all_tracked].sum() / dt[used].sum()) if dt[used].sum() > 0 else math.nan
    criteria = [
        Criterion(
            "markers kept visible",
            "—" if math.isnan(share) else f"every tool in use tracked {100 * share:.0f} % of the time",
            "≥ 90 %: 10, ≥ 75 %: 5",
            0.0 if math.isnan(share) else _tiered(share, [(0.9, 10), (0.75, 5)], higher_is_better=True),
            10,
        )
    ]
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
    """The navigation mode's assessment; its criteria come with its plots (built here, for the data too)."""
    if "navigation" not in session.groups:
        return None
    record = read_navigation(session.groups["navigation"])
    if not record.assessable:
        return Part(
            [], record.events, {}, lambda: [Section("Navigation", "<p>No landmark was acquired and no cup confirmed in this session.</p>")]
        )
    dt = _durations(record.time)
    sections = [_registration(record), _orientation(record, dt), _dropouts(record, dt)]
    calibration = _calibration(record)
    sections += [calibration] if calibration else []
    return Part([c for s in sections for c in s.criteria], record.events, {}, lambda: sections)
