"""Summaries of a dataset directory and the α histograms of the thesis's Figure 44.

Figure 44 [7.2.1] shows, at a frame, the distributions of von Mises stress, PEEQ and α for
elements removed (STATUS = 0) and remaining (STATUS = 1); α here is eq. 47 *before* removed
elements are set to 0, which is what shows that a threshold (0.3) separates the two classes.
Files are read frame by frame; histograms are accumulated on fixed bins, never all values.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from thrsim.config import LabelConfig
from thrsim.data.case_file import CaseReader
from thrsim.data.generate import MANIFEST, read_manifest
from thrsim.data.labels import alpha, compacting_elements
from thrsim.errors import ThrsimInputError

ALPHA_BINS = np.linspace(0.0, 1.0, 51)


#: per-case figures of the solver's summary that :func:`solver_rates` reports as medians
RATE_FIELDS = ("frames", "feed_rate_mm_s", "removal_rate_mm3_s", "excursion_median_mm", "contact_fraction_mean", "energy_balance_error")


def solver_rates(entries: dict) -> dict:
    """Per inclination and push force ("γ/F", e.g. "15/230"), over complete cases: how many, how they
    ended, the median of each of :data:`RATE_FIELDS` (None where no case reports it) and the
    worker hours they took. The solver's own summary per case (the manifest's) is the source."""
    groups: dict[str, list[dict]] = {}
    for entry in entries.values():
        if entry.get("status") != "complete":
            continue
        params = entry["params"]
        groups.setdefault(f"{params['inclination_deg']:g}/{params['force_n']:g}", []).append(entry)
    rates = {}
    for key in sorted(groups, key=lambda k: tuple(float(v) for v in k.split("/"))):
        cases = groups[key]
        summaries = [c.get("solver_summary") or {} for c in cases]
        ends: dict[str, int] = {}
        for summary in summaries:
            ends[str(summary.get("end_reason"))] = ends.get(str(summary.get("end_reason")), 0) + 1
        group = {"cases": len(cases), "end_reasons": ends}
        for field in RATE_FIELDS:
            values = [float(v) for v in (summary.get(field) for summary in summaries) if v is not None]
            group[field] = float(np.median(values)) if values else None
        group["worker_hours"] = sum(float(c.get("wall_s") or 0.0) for c in cases) / 3600.0
        rates[key] = group
    return rates


def dataset_info(root: str | os.PathLike, labels: LabelConfig | None = None, *, histograms: bool = False) -> dict:
    """Cases, frames, splits, removed fraction per frame (mean over cases), PEEQ/von Mises ranges, α counts,
    worker hours and size on disk, and the solver's rates per inclination and force (:func:`solver_rates`)."""
    root = Path(root)
    labels = labels or LabelConfig()
    if not root.is_dir():
        raise ThrsimInputError(f"{root}: no such dataset directory")
    manifest = read_manifest(root)
    if manifest is None:
        raise ThrsimInputError(f"{root}: not a thrsim dataset (no {MANIFEST})")
    entries = manifest.get("cases", {})
    statuses: dict[str, int] = {}
    for entry in entries.values():
        statuses[entry.get("status", "?")] = statuses.get(entry.get("status", "?"), 0) + 1
    complete = {k: e for k, e in sorted(entries.items()) if e.get("status") == "complete"}
    splits: dict[str, int] = {}
    forces: dict[str, int] = {}
    removed_sum: list[float] = []
    removed_n: list[int] = []
    peeq_range = [np.inf, -np.inf]
    vm_range = [np.inf, -np.inf]
    hist_removed = np.zeros(len(ALPHA_BINS) - 1, dtype=np.int64)
    hist_remaining = np.zeros(len(ALPHA_BINS) - 1, dtype=np.int64)
    below_threshold = {"removed": 0, "remaining": 0}
    totals = {"removed": 0, "remaining": 0}
    frames_total = 0
    missing = []
    for case_id, entry in complete.items():
        path = root / entry["file"]
        if not path.exists():
            missing.append(case_id)
            continue
        splits[entry.get("split", "?")] = splits.get(entry.get("split", "?"), 0) + 1
        force = f"{entry['params']['force_n']:g}"
        forces[force] = forces.get(force, 0) + 1
        with CaseReader(path) as reader:
            frames_total += reader.n_frames
            config = reader.attrs.get("config")
            compacting = compacting_elements(config, reader.mesh)
            for t in range(reader.n_frames):
                frame = reader.frame(t)
                status = frame["status"]
                n = status.size
                if len(removed_sum) <= t:
                    removed_sum.append(0.0)
                    removed_n.append(0)
                removed_sum[t] += float((status == 0).sum()) / n if n else 0.0
                removed_n[t] += 1
                peeq, vm = frame["peeq"], frame["von_mises"]
                if n:
                    peeq_range = [min(peeq_range[0], float(peeq.min())), max(peeq_range[1], float(peeq.max()))]
                    vm_range = [min(vm_range[0], float(vm.min())), max(vm_range[1], float(vm.max()))]
                raw = alpha(peeq, vm, None, labels, damage=frame.get("damage"), compacting=compacting)
                gone = status == 0
                hist_removed += np.histogram(raw[gone], bins=ALPHA_BINS)[0]
                hist_remaining += np.histogram(raw[~gone], bins=ALPHA_BINS)[0]
                below = raw < labels.removed_threshold
                below_threshold["removed"] += int((below & gone).sum())
                below_threshold["remaining"] += int((below & ~gone).sum())
                totals["removed"] += int(gone.sum())
                totals["remaining"] += int((~gone).sum())
    identity = manifest.get("identity", {})
    info = {
        "out": str(root),
        "cases": len(complete),
        "cases_by_status": statuses,
        "cases_by_split": splits,
        "cases_by_force_n": forces,
        "missing_files": missing,
        "frames": frames_total,
        "solver": identity.get("solver"),
        "frames_per_case": identity.get("template", {}).get("frames"),
        "removed_fraction_per_frame": [s / n for s, n in zip(removed_sum, removed_n, strict=True)],
        "peeq_range": peeq_range if frames_total else None,
        "von_mises_range_pa": vm_range if frames_total else None,
        "element_frames": totals,
        "alpha_below_threshold_fraction": {k: (below_threshold[k] / totals[k] if totals[k] else None) for k in totals},
        "split_rule": manifest.get("split_rule"),
        "worker_hours": sum(float(e.get("wall_s") or 0.0) for e in complete.values()) / 3600.0,
        "size_mb": sum((root / e["file"]).stat().st_size for k, e in complete.items() if k not in missing) / 1e6,
        "solver_rates": solver_rates(complete),
    }
    if identity.get("template", {}).get("bone_kind") == "socket":
        from thrsim.data.calibration import socket_calibration

        info["socket_calibration"] = socket_calibration(root)
    if histograms:
        info["alpha_histogram"] = {"bins": ALPHA_BINS.tolist(), "removed": hist_removed.tolist(), "remaining": hist_remaining.tolist()}
    return info


def plot_alpha_histograms(info: dict, out: str | os.PathLike, threshold: float = 0.3) -> Path:
    """Figure 44-style PNG: α distribution of removed vs remaining elements (counts, log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from thrsim.atomic import atomic_path

    hist = info.get("alpha_histogram")
    if hist is None:
        raise ThrsimInputError("no α histogram in the summary (computed with histograms=True)")
    out = Path(out)
    bins = np.asarray(hist["bins"])
    centres, width = 0.5 * (bins[1:] + bins[:-1]), np.diff(bins)
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    ax.bar(centres, hist["remaining"], width=width, alpha=0.6, label="remaining (STATUS = 1)", color="tab:blue")
    ax.bar(centres, hist["removed"], width=width, alpha=0.6, label="removed (STATUS = 0)", color="tab:red")
    ax.axvline(threshold, color="k", linestyle="--", linewidth=1, label=f"threshold α = {threshold:g}")
    if max(max(hist["remaining"], default=0), max(hist["removed"], default=0)) > 0:
        ax.set_yscale("log")
    ax.set_xlabel("α (eq. 47, before removed elements are set to 0)")
    ax.set_ylabel("element-frames")
    ax.set_title(f"α of removed vs remaining elements — {info['cases']} case(s), {info['frames']} frame(s)")
    ax.legend()
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return out
