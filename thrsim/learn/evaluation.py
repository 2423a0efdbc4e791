"""Table-10-style evaluation [7.3.5]: precision, recall and F1 of newly removed elements after rollouts.

From several start frames of every case (every ``start_stride`` frames) the model rolls out from
the ground truth; at horizons 1, 30 and 60 the elements it removed since the start are compared
with the solver's. A case that ends before a start's longest horizon scores that rollout at its
last frame, under "end". Horizon 1 is also scored from every ``one_step_stride``-th frame (one
frame's removal varies, and a few starts are too few to judge it). Counts are summed over the
windows of all cases of one γ. Modes: ``autonomous`` (the regressor advances the reamer: the
headline), ``tool_forced`` (recorded positions), ``mlp`` (the node-wise baseline) and
``geometric`` (every element entering the teeth's envelope); at the longest horizon, the removed
volume's error and the distance between predicted and true reamed surfaces too.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from thrsim.geometry.mesh import CORTICAL
from thrsim.learn.cases import CaseArrays, case_graphs, require_damage
from thrsim.learn.graph import StaticGraph
from thrsim.learn.metrics import Counts, fit_sphere, plate_left_mm3, surface_distance_mm
from thrsim.learn.model_dir import LoadedModel, reads_any_mesh
from thrsim.learn.reaction_feed import ReactionFeed, feed_m_s, felt_at_push
from thrsim.learn.rollout import BoneState, GeometricStep, LearnedStep, rollout
from thrsim.learn.training import next_reaction

HORIZONS = (1, 30, 60)
MODES = ("autonomous", "tool_forced", "mlp", "geometric")

#: Table 10 of the thesis: γ → horizon → (precision, recall, F1) in %
THESIS_TABLE_10 = {
    "0": {"1": (75.3, 79.4, 77.3), "30": (76.2, 98.8, 86.1), "60": (90.8, 95.3, 92.9)},
    "15": {"1": (69.3, 59.4, 64.0), "30": (92.1, 93.5, 92.8), "60": (92.2, 93.5, 92.8)},
    "30": {"1": (69.3, 58.1, 60.6), "30": (85.2, 85.1, 85.1), "60": (85.5, 84.7, 85.1)},
    "45": {"1": (76.7, 71.1, 73.8), "30": (86.1, 83.3, 84.7), "60": (85.2, 87.1, 86.1)},
}


def gamma_key(inclination_deg: float) -> str:
    return f"{inclination_deg:g}"


def windows(
    frames: int, start_stride: int, one_step_stride: int = 1, horizons: tuple[int, ...] = HORIZONS
) -> list[tuple[int, list[str], int]]:
    """(start, horizon keys, frames to roll out) for every start frame of a case of ``frames``
    frames: the full windows every ``start_stride`` frames, one-step windows (key "1" alone)
    every ``one_step_stride`` frames between them."""
    last = frames - 1
    out = []
    for start in range(0, last):
        if start % start_stride == 0:
            keys = [str(h) for h in horizons if start + h <= last]
            if start + max(horizons) > last:
                keys.append("end")
            out.append((start, keys, min(last, start + max(horizons)) - start))
        elif start % one_step_stride == 0:
            out.append((start, ["1"], 1))
    return out


def _steppers(model: LoadedModel, case: CaseArrays, graph: StaticGraph) -> dict:
    """Each mode's step and feed on ``case``'s bone and reamer. A socket model's autonomous feed is
    the push the case was reamed with against the reaction law (a model without the reaction
    head has none: its modes are tool-forced)."""
    features, energy = model.settings.features, case.element_cutting_energy_j_m3
    learned = LearnedStep(model.gn, graph, features, case.teeth_radius_m, energy)
    mlp = LearnedStep(model.mlp, graph, features, case.teeth_radius_m, energy)
    geometric = GeometricStep(graph, case.teeth_radius_m)
    if reads_any_mesh(model.settings):
        modes: dict[str, tuple[object, object]] = {"tool_forced": (learned, None), "mlp": (mlp, None), "geometric": (geometric, None)}
        if model.settings.arch.reaction_head:
            margin_m = model.settings.features.reach_margin_mm * 1e-3
            pushed = ReactionFeed(graph, case.teeth_radius_m, margin_m, model.threshold, case.frame_dt_s, model.hold)
            autonomous = LearnedStep(model.gn, graph, features, case.teeth_radius_m, energy)
            modes = {"autonomous": (autonomous, pushed), **modes, "mlp": (mlp, pushed)}
        return modes
    feed = model.reamer_feed()
    return {"autonomous": (learned, feed), "tool_forced": (learned, None), "mlp": (mlp, feed), "geometric": (geometric, None)}


def cavity_depth_mm(graph: StaticGraph, removed: np.ndarray, start: np.ndarray, axis: np.ndarray) -> float | None:
    """How deep along the axis, from the reamer centre at the window's start, the removed elements
    reach (their deepest centroid, mm); None when none was removed."""
    if not removed.any():
        return None
    return float(((graph.centroids[removed] - start) @ axis).max()) * 1e3


def sphere_depth_mm(sphere: tuple[np.ndarray, float] | None, start: np.ndarray, axis: np.ndarray) -> float | None:
    """How deep along the axis, from the reamer centre at the window's start, the sphere fitted to a
    cavity's reamed surface reaches (its deepest point, mm; None where no sphere fits): the depth a
    scan of the reamed socket gives, which elements deleted a few mm ahead of the teeth barely move."""
    if sphere is None:
        return None
    centre, radius = sphere
    return float((centre - start) @ axis + radius) * 1e3


def cavity_errors(
    graph: StaticGraph, predicted: np.ndarray, true: np.ndarray, initial: np.ndarray, start: np.ndarray, axis: np.ndarray
) -> dict:
    """The predicted cavity (``predicted`` removed elements) against the solver's (``true``), signed
    predicted − solver's: removed volume since ``initial`` (relative; None when the solver removed
    nothing), mean and largest reamed-surface distance (mm; NaN where a surface is empty), the
    diameter and the deepest point along ``axis`` from ``start`` of the sphere fitted to the whole
    cavity's reamed surface and the depth of its deepest removed element (mm; None where unknown;
    a prediction that removed nothing or fits no sphere counts as depth 0); also the predicted volume (mm³)."""
    true_volume = float((true & ~initial) @ graph.volumes)
    pred_volume = float((predicted & ~initial) @ graph.volumes)
    surfaces = graph.reamed_surface(~predicted), graph.reamed_surface(~true)
    surface_mean_mm, surface_max_mm = surface_distance_mm(*surfaces)
    sphere_pred, sphere_true = (fit_sphere(surface) for surface in surfaces)
    sphere_depth_pred, sphere_depth_true = (sphere_depth_mm(sphere, start, axis) for sphere in (sphere_pred, sphere_true))
    depth_pred, depth_true = (cavity_depth_mm(graph, removed, start, axis) for removed in (predicted, true))
    return {
        "removed_volume_mm3": pred_volume * 1e9,
        "removed_volume_error": (pred_volume - true_volume) / true_volume if true_volume > 0 else None,
        "surface_distance_mean_mm": surface_mean_mm,
        "surface_distance_max_mm": surface_max_mm,
        "cavity_diameter_error_mm": None if sphere_pred is None or sphere_true is None else 2e3 * (sphere_pred[1] - sphere_true[1]),
        "cavity_depth_error_mm": None if depth_true is None else (depth_pred or 0.0) - depth_true,
        "sphere_depth_error_mm": None if sphere_depth_true is None else (sphere_depth_pred or 0.0) - sphere_depth_true,
    }


def group_key(model: LoadedModel, case: CaseArrays) -> str:
    """The row a case's windows count in: its γ (patch) or its reamer size in mm (socket)."""
    if reads_any_mesh(model.settings):
        return f"{2e3 * case.teeth_radius_m:g}"
    return gamma_key(case.inclination_deg)


def reaction_errors(model: LoadedModel, case: CaseArrays, graph: StaticGraph) -> dict[str, np.ndarray] | None:
    """Sums over a tool-forced pass through ``case`` against the solver's reaction R and torque T of
    each frame (None: nothing to compare): ``law`` Σ|R̂ − R|, Σ|R|, Σ|T̂ − T|, Σ|T| with the law read
    at the next recorded feed; for a pushed case also ``felt``, the same with what the simulator
    reports under the case's push (:func:`~thrsim.learn.reaction_feed.felt_at_push`), ``felt_step``
    Σ(R̂ − R), Σ|R|, Σ(T̂ − T), Σ|T|: the error of the mean over the step, and ``feed`` Σv̂, Σv over
    the whole case and over its second half (a whole socket's reamer seated there): the feed at which
    the push meets the law (:func:`~thrsim.learn.reaction_feed.feed_m_s`) and the solver's."""
    if not model.settings.arch.reaction_head or case.reaction_n is None or case.motor_torque_n_m is None:
        return None
    step = LearnedStep(model.gn, graph, model.settings.features, case.teeth_radius_m, case.element_cutting_energy_j_m3)
    state = BoneState.start(case.alpha[0], None if case.damage is None else case.damage[0])
    pushed, push, damping = case.set_feed_mm_s is None, case.recorded_push_n(), case.hold.axial_damping_n_s_m
    sums = {"law": np.zeros(4), **({"felt": np.zeros(4), "felt_step": np.zeros(4), "feed": np.zeros(4)} if pushed else {})}
    for frame in range(1, case.frames - 1):
        moved = float((case.positions[frame] - case.positions[frame - 1]) @ case.axis)
        state = step(state, case.positions[frame], case.axis, push, moved, case.omega_rad_s)
        reaction, torque, feed = next_reaction(case, frame, model.threshold)
        law = step.reaction_law if step.reaction_law is not None else np.zeros(4)
        sums["law"] += [abs(law[0] + law[1] * feed - reaction), abs(reaction), abs(law[2] + law[3] * feed - torque), abs(torque)]
        if pushed:
            felt, felt_torque = felt_at_push(law, push, damping)
            sums["felt"] += [abs(felt - reaction), abs(reaction), abs(felt_torque - torque), abs(torque)]
            sums["felt_step"] += [felt - reaction, abs(reaction), felt_torque - torque, abs(torque)]
            balanced = feed_m_s(law, push, damping)
            seated = frame >= case.frames // 2
            sums["feed"] += [balanced, feed, balanced if seated else 0.0, feed if seated else 0.0]
    return sums


def reaction_report(per_case: dict[str, list[dict[str, np.ndarray]]]) -> dict:
    """Per row: the law's error at the recorded feeds (Σ|error| / Σ|solver's|, every case); over the
    pushed cases, the error of what the simulator reports under the push, per frame and of the mean
    over each case (averaged over cases), and the feed the law balances at the solver's states as a
    share of the solver's, over the cases and over their second halves (``balanced_feed_share``,
    ``seated_balanced_feed_share``: below 1, an autonomous reamer lags)."""

    def ratio(total: np.ndarray, k: int) -> float | None:
        return float(abs(total[k]) / total[k + 1]) if total[k + 1] > 0 else None

    report = {}
    for g, rows in sorted(per_case.items(), key=lambda item: _row_order(item[0])):
        law = np.sum([r["law"] for r in rows], axis=0)
        felt = [r for r in rows if "felt" in r]
        row = {"force_error": ratio(law, 0), "torque_error": ratio(law, 2), "pushed_cases": len(felt)}
        if felt:
            total = np.sum([r["felt"] for r in felt], axis=0)
            steps = [(ratio(r["felt_step"], 0), ratio(r["felt_step"], 2)) for r in felt]
            row |= {
                "felt_force_error": ratio(total, 0),
                "felt_torque_error": ratio(total, 2),
                "felt_force_step_mean_error": _summary([f for f, _ in steps if f is not None]),
                "felt_torque_step_mean_error": _summary([t for _, t in steps if t is not None]),
            }
            feeds = np.sum([r["feed"] for r in felt], axis=0)
            row["balanced_feed_share"] = float(feeds[0] / feeds[1]) if feeds[1] > 0 else None
            row["seated_balanced_feed_share"] = float(feeds[2] / feeds[3]) if feeds[3] > 0 else None
        report[g] = row
    return report


def _row_order(key: str) -> tuple[float, str]:
    """Rows by number (a reamer size, a tilt), then by name (a bone)."""
    try:
        return float(key), ""
    except ValueError:
        return float("inf"), key


def bone_key(case: CaseArrays) -> str:
    """The bone a case reams: a window of the socket, the whole socket, or the thesis's patch."""
    return "window" if case.is_window() else "whole socket" if case.bone_kind == "socket" else "patch"


#: the share of each case's push the physics checks ream at: none, less, as recorded, more
CHECK_PUSH_SHARES = (0.0, 0.5, 1.0, 2.0)


def physics_checks(model: LoadedModel, cases: list[CaseArrays], frames: int = 30) -> dict:
    """What the physics demands of any model's autonomous rollouts, from each case's first frame over
    ``frames`` frames: no push removes nothing and does not advance; more push never removes or
    advances less. Counts of the cases that hold, and the removed volume at each push share."""
    graphs = case_graphs(model.graph, cases, any_mesh=reads_any_mesh(model.settings))
    held = {"no_push_no_cut": 0, "no_push_no_advance": 0, "more_push_never_less": 0}
    volumes: dict[str, list[float]] = {f"{share:g}": [] for share in CHECK_PUSH_SHARES}
    for case in cases:
        graph = graphs[case.case_id]
        step, feed = _steppers(model, case, graph).get("autonomous", (None, None))
        if step is None:
            return {"checked": False, "why": "the model has no autonomous feed (a socket model without the reaction head)"}
        horizon = min(frames, case.frames - 1)
        start_removed = case.alpha[0] < model.threshold
        removed, advanced = [], []
        for share in CHECK_PUSH_SHARES:
            masks, centres = rollout(step, case, 0, horizon, model.threshold, feed, push_n=share * case.recorded_push_n())
            cut = masks[-1] & ~start_removed
            removed.append(float(cut @ graph.volumes) * 1e9)
            advanced.append(float((centres[-1] - case.positions[0]) @ case.axis))
            volumes[f"{share:g}"].append(removed[-1])
        held["no_push_no_cut"] += removed[0] == 0.0
        held["no_push_no_advance"] += advanced[0] == 0.0
        held["more_push_never_less"] += removed == sorted(removed) and advanced == sorted(advanced)
    return {
        "checked": True,
        "cases": len(cases),
        "frames": frames,
        "held": held,
        "removed_volume_mm3_mean_by_push_share": {share: float(np.mean(v)) for share, v in volumes.items()},
    }


def case_scores(model: LoadedModel, cases: list[CaseArrays], on_case=None) -> list[dict]:
    """Each case rolled out from its first frame to its last in every mode: F1 of the removed elements,
    the removed volume's relative error, the mean surface distance, the cavity's diameter, depth and
    fitted sphere's depth and the reamer's end along the axis against the solver's (mm; predicted − solver's); tool-forced also
    the plate left ahead of the teeth at every frame, the model's and the solver's (mm³)."""
    threshold = model.threshold
    graphs = case_graphs(model.graph, cases, any_mesh=reads_any_mesh(model.settings))
    rows = []
    for index, case in enumerate(cases):
        graph, last = graphs[case.case_id], case.frames - 1
        truth = case.alpha < threshold
        initial, final_true = truth[0], truth[last]
        row: dict = {"case_id": case.case_id, "split": case.split, "frames": case.frames}
        for mode, (step, feed) in _steppers(model, case, graph).items():
            masks, centres = rollout(step, case, 0, last, threshold, feed)
            final_pred = masks[-1]
            counts = Counts()
            counts.add(final_pred & ~initial, final_true & ~initial)
            cavity = cavity_errors(graph, final_pred, final_true, initial, case.positions[0], case.axis)
            surface_mm = cavity["surface_distance_mean_mm"]
            row[mode] = {
                "f1": counts.as_dict()["f1"],
                "removed_volume_error": cavity["removed_volume_error"],
                "surface_distance_mean_mm": surface_mm if np.isfinite(surface_mm) else None,
                "cavity_diameter_error_mm": cavity["cavity_diameter_error_mm"],
                "cavity_depth_error_mm": cavity["cavity_depth_error_mm"],
                "sphere_depth_error_mm": cavity["sphere_depth_error_mm"],
                "reamer_end_error_mm": float((centres[-1] - case.positions[last]) @ case.axis) * 1e3,
            }
            if mode == "tool_forced":
                row[mode]["plate_left_mm3"] = _plate_left(graph, case, [~initial, *(~m for m in masks)])
                row[mode]["solver_plate_left_mm3"] = _plate_left(graph, case, list(~truth))
        rows.append(row)
        if on_case is not None:
            on_case(index + 1, len(cases), case.case_id)
    return rows


def _plate_left(graph: StaticGraph, case: CaseArrays, alive: list[np.ndarray]) -> list[float]:
    """The cortical plate left ahead of the teeth (mm³) at each frame's recorded reamer centre."""
    mesh = case.mesh
    if mesh is None or CORTICAL not in mesh.material_names:
        plate = np.ones(graph.n_nodes, dtype=bool)  # a mesh without tags is all cortical
    else:
        plate = mesh.element_material == mesh.material_names.index(CORTICAL)
    return [
        plate_left_mm3(graph.centroids, graph.volumes, plate, alive_k, case.positions[k], case.axis, case.teeth_radius_m)
        for k, alive_k in enumerate(alive)
    ]


def evaluate(model: LoadedModel, cases: list[CaseArrays], start_stride: int = 30, on_case=None, one_step_stride: int = 1) -> dict:
    """Scores per mode, γ and horizon, plus volume and surface errors at each full window's longest horizon."""
    if model.settings.features.damage:
        require_damage(cases, "evaluate it on data of solver 0.4.0 or later")
    threshold = model.threshold
    counts: dict = {m: defaultdict(lambda: defaultdict(Counts)) for m in MODES}
    errors: dict = {
        m: defaultdict(
            lambda: {"volume_error": [], "surface_mean_mm": [], "surface_max_mm": [], "depth_error_mm": [], "diameter_error_mm": []}
        )
        for m in MODES
    }
    by_force: dict = defaultdict(lambda: {"volume_error": [], "removed_volume_mm3": []})
    reaction_rows: dict = defaultdict(list)
    reaction_bone_rows: dict = defaultdict(list)
    by_layer: dict = {m: defaultdict(Counts) for m in MODES}
    by_control: dict = {m: defaultdict(lambda: {"end": Counts(), "depth_error_mm": []}) for m in MODES}
    graphs = case_graphs(model.graph, cases, any_mesh=reads_any_mesh(model.settings))
    for index, case in enumerate(cases):
        graph = graphs[case.case_id]
        steppers = _steppers(model, case, graph)
        g = group_key(model, case)
        compared = reaction_errors(model, case, graph)
        if compared is not None:
            reaction_rows[g].append(compared)
            reaction_bone_rows[bone_key(case)].append(compared)
        truth_removed = case.alpha < threshold
        for start, keys, length in windows(case.frames, start_stride, one_step_stride):
            initial = truth_removed[start]
            for mode, (step, feed) in steppers.items():
                masks, _ = rollout(step, case, start, length, threshold, feed)
                for key in keys:
                    k = length if key == "end" else int(key)
                    counts[mode][g][key].add(masks[k - 1] & ~initial, truth_removed[start + k] & ~initial)
                    if key == "end":
                        by_control[mode][_control(case)]["end"].add(masks[k - 1] & ~initial, truth_removed[start + k] & ~initial)
                if start % start_stride:
                    continue  # a one-step window: no longest horizon of its own
                final_pred, final_true = masks[-1], truth_removed[start + length]
                for index_layer, layer in enumerate(graph.mesh.material_names):
                    in_layer = graph.mesh.element_material == index_layer
                    by_layer[mode][layer].add(final_pred & ~initial & in_layer, final_true & ~initial & in_layer)
                cavity = cavity_errors(graph, final_pred, final_true, initial, case.positions[start], case.axis)
                volume_error = cavity["removed_volume_error"]
                if volume_error is not None:
                    errors[mode][g]["volume_error"].append(volume_error)
                    if mode == "autonomous":
                        by_force[f"{case.force_n:g}"]["volume_error"].append(volume_error)
                if mode == "autonomous":
                    by_force[f"{case.force_n:g}"]["removed_volume_mm3"].append(cavity["removed_volume_mm3"])
                errors[mode][g]["surface_mean_mm"].append(cavity["surface_distance_mean_mm"])
                errors[mode][g]["surface_max_mm"].append(cavity["surface_distance_max_mm"])
                if cavity["cavity_diameter_error_mm"] is not None:
                    errors[mode][g]["diameter_error_mm"].append(abs(cavity["cavity_diameter_error_mm"]))
                if cavity["cavity_depth_error_mm"] is not None:
                    errors[mode][g]["depth_error_mm"].append(abs(cavity["cavity_depth_error_mm"]))
                    by_control[mode][_control(case)]["depth_error_mm"].append(abs(cavity["cavity_depth_error_mm"]))
        if on_case is not None:
            on_case(index + 1, len(cases), case.case_id)
    report = _report(counts, errors, cases)
    report["rows"] = "reamer_diameter_mm" if reads_any_mesh(model.settings) else "inclination_deg"
    report["physics_checks"] = physics_checks(model, cases)
    # per bone layer (material), at each full window's longest horizon
    report["by_layer"] = {mode: {layer: c.as_dict() for layer, c in layers.items()} for mode, layers in by_layer.items() if layers}
    # pushed cases against set-feed ones: does the reamer advance as the solver's did under the same push?
    report["by_control"] = {
        mode: {name: {"end": c["end"].as_dict(), "cavity_depth_error_mean_mm": _summary(c["depth_error_mm"])} for name, c in rows.items()}
        for mode, rows in by_control.items()
        if rows
    }
    # the reaction and torque against the solver's: the law at the recorded feeds, and what the simulator reports under the push
    report["reaction"] = reaction_report(reaction_rows)
    # the same by bone: the law learns from whole sockets, and a window's push can lie far below theirs
    report["reaction_by_bone"] = reaction_report(reaction_bone_rows)
    # force response (autonomous): relative volume error at the longest horizon and mean removed volume per push force
    report["by_force"] = {
        f: {
            "removed_volume_error_mean": _summary([abs(v) for v in e["volume_error"]]),
            "removed_volume_mm3_mean": _summary(e["removed_volume_mm3"]),
            "windows": len(e["removed_volume_mm3"]),
        }
        for f, e in sorted(by_force.items(), key=lambda item: float(item[0]))
    }
    return report


def _control(case: CaseArrays) -> str:
    """How the solver drove the case's reamer: a set push ("pushed") or a rig's set feed ("set feed")."""
    return "pushed" if case.set_feed_mm_s is None else "set feed"


def _summary(values: list[float]) -> float | None:
    values = [v for v in values if np.isfinite(v)]
    return float(np.mean(values)) if values else None


def _report(counts: dict, errors: dict, cases: list[CaseArrays]) -> dict:
    def scores(mode: str) -> dict:
        out = {}
        for g in sorted(counts[mode], key=float):
            row = {key: counts[mode][g][key].as_dict() for key in ("1", "30", "60", "end") if key in counts[mode][g]}
            e = errors[mode][g]
            row["longest_horizon"] = {
                "removed_volume_error_mean": _summary([abs(v) for v in e["volume_error"]]),
                "removed_volume_error_signed_mean": _summary(e["volume_error"]),
                "surface_distance_mean_mm": _summary(e["surface_mean_mm"]),
                "surface_distance_max_mm": float(np.nanmax(e["surface_max_mm"])) if np.isfinite(e["surface_max_mm"]).any() else None,
                "cavity_depth_error_mean_mm": _summary(e["depth_error_mm"]),
                "cavity_diameter_error_mean_mm": _summary(e["diameter_error_mm"]),
            }
            out[g] = row
        return out

    report = scores("autonomous")
    report["mode"] = "autonomous: the advance regressor moves the reamer"
    report["tool_forced"] = scores("tool_forced")
    report["mlp"] = scores("mlp")
    report["geometric"] = scores("geometric")
    report["cases"] = [
        {
            "case_id": c.case_id,
            "inclination_deg": c.inclination_deg,
            "anteversion_deg": c.anteversion_deg,
            "force_n": c.force_n,
            "reamer_diameter_mm": round(2e3 * c.teeth_radius_m, 3),
            "frames": c.frames,
            "end_reason": c.end_reason,
            "split": c.split,
        }
        for c in cases
    ]
    report["thesis_table_10_percent"] = {
        g: {h: dict(zip(("precision", "recall", "f1"), v, strict=True)) for h, v in row.items()} for g, row in THESIS_TABLE_10.items()
    }
    return report
