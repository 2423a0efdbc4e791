"""The reaming session's measurements, each defined once here (``metrics`` of ``thrsim report --json``).

Every figure comes from the session's record (:class:`~thrsim.session.reaming.ReamingRecord`),
read two ways: **the record**, every frame reamed, including frames later undone or wiped by a
restore (time with a reamer, time on plan, push, travel, errors: what the trainee did), and
**the final bone**, only the frames whose cutting the bone kept at the end (what the cavity is).
Angles are radiographic (Murray) in the anterior pelvic plane, as the page shows them; the cavity
centre's shifts are along the pelvis's medial and superior directions from the native socket's
centre. The plain-words definitions: the trainer guide, "Reaming measurements".
"""

from __future__ import annotations

import numpy as np

from thrsim.config import SafeZone
from thrsim.nav.anatomy import angles_from_local
from thrsim.nav.bone_frame import patch_in_app
from thrsim.session.plan import Plan
from thrsim.session.reaming import ReamingRecord


def final_rows(record: ReamingRecord) -> np.ndarray:
    """Trace rows of the frames the final bone kept, in order: a row with frame f replaces every
    row from frame f on, and an undo or restore drops every row past the frame it went back to
    (an undo steps back, a restore starts again at frame 0), reamed again after it or not."""
    backs = sorted((e["time_s"], e["frame"]) for e in record.events if e["kind"] in ("undo", "restore") and e.get("frame") is not None)
    kept: list[int] = []

    def go_back(until_s: float) -> None:
        while backs and backs[0][0] <= until_s:
            _, back = backs.pop(0)
            while kept and record.frame[kept[-1]] > back:
                kept.pop()

    for row, frame in enumerate(record.frame):
        go_back(float(record.time[row]))  # a control at a tick's time is applied before its frames
        while kept and record.frame[kept[-1]] >= frame:
            kept.pop()
        kept.append(row)
    go_back(np.inf)
    return np.array(kept, dtype=np.int64)


def removed_per_row(record: ReamingRecord, rows: np.ndarray) -> np.ndarray:
    """Volume (mm³) each of the final bone's ``rows`` removed: its volume less its predecessor's."""
    volumes = record.removed_volume_mm3[rows]
    return np.diff(volumes, prepend=0.0)


def in_range(record: ReamingRecord) -> np.ndarray | None:
    """Per frame: the push within the range the model learned (None when the session does not say it)."""
    if record.trained_force_n is None:
        return None
    low, high = record.trained_force_n
    return (record.force_n >= low) & (record.force_n <= high)


def cavity_axis_angles(record: ReamingRecord) -> tuple[float, float] | None:
    """The reamed cavity's axis as cup angles (inclination, anteversion): the reamer's axis over the
    final bone's frames, each weighted by the bone it removed. None when no bone was kept removed."""
    rows = final_rows(record)
    weights = np.clip(removed_per_row(record, rows), 0.0, None)
    if weights.sum() <= 0.0:
        return None
    mean = (record.axis[rows] * weights[:, None]).sum(axis=0)
    cup_axis_app = -(patch_in_app(SafeZone(**record.zone)) @ (mean / np.linalg.norm(mean)))
    return None if cup_axis_app[0] < 0.0 else angles_from_local(cup_axis_app)


def within_plan_fraction(record: ReamingRecord, plan: Plan, degrees: float) -> float | None:
    """Share of the reaming frames (the record; the reamer measured) with both angles within ``degrees`` of the plan."""
    measured = np.isfinite(record.angles[:, 0])
    if not measured.any():
        return None
    angles = record.angles[measured]
    close = (np.abs(angles[:, 0] - plan.inclination_deg) <= degrees) & (np.abs(angles[:, 1] - plan.anteversion_deg) <= degrees)
    return float(np.mean(close))


def cut_sizes_mm(record: ReamingRecord) -> np.ndarray:
    """Per frame, the reamer size the simulator cut with (files before the sequence: their model's one size)."""
    if record.cut_mm is not None:
        return record.cut_mm
    return np.full(len(record.frame), 2e3 * record.cavity["teeth_radius_m"]) if record.cavity else np.full(len(record.frame), np.nan)


def cavity_diameter_mm(record: ReamingRecord) -> float | None:
    """The cavity's diameter: the largest reamer size that cut bone the final bone kept removed."""
    rows = final_rows(record)
    cutting = rows[removed_per_row(record, rows) > 0.0]
    sizes = cut_sizes_mm(record)[cutting]
    return None if len(sizes) == 0 or not np.isfinite(sizes).all() else float(sizes.max())


def cavity_centre_shift_mm(record: ReamingRecord) -> tuple[float, float] | None:
    """(medial, superior) shift in mm of the cavity's centre from the native centre: the reamer's
    centre at the deepest of the final bone's frames with the largest reamer that cut."""
    rows = final_rows(record)
    cutting = rows[removed_per_row(record, rows) > 0.0]
    if len(cutting) == 0:
        return None
    sizes = cut_sizes_mm(record)[cutting]
    last_size = cutting[sizes == np.nanmax(sizes)] if np.isfinite(sizes).any() else cutting
    deepest = last_size[np.argmax(record.depth_mm[last_size])]
    lateral, _, inferior = patch_in_app(SafeZone(**record.zone)) @ record.position_m[deepest]
    return -lateral * 1e3, -inferior * 1e3


def reamer_sequence(record: ReamingRecord) -> tuple[list[float], list[float]] | None:
    """The reamers that reamed, in order (a size that reamed no frame is not in it; the record: undone
    frames count) and the reaming time with each (s). None for a file before the reamer sequence."""
    if record.reamer_mm is None:
        return None
    sizes: list[float] = []
    frames: list[int] = []
    for size in record.reamer_mm:
        if sizes and sizes[-1] == size:
            frames[-1] += 1
        else:
            sizes.append(float(size))
            frames.append(1)
    return sizes, [n * record.frame_dt_s for n in frames]


def path_length_mm(record: ReamingRecord) -> float:
    """The reamer centre's travel over the frames reamed; an undo's or a restore's jump back is no travel."""
    steps = np.linalg.norm(np.diff(record.position_m, axis=0), axis=1) * 1e3
    consecutive = np.diff(record.frame) == 1
    return float(steps[consecutive].sum())


def confirmed_cup_angles(record: ReamingRecord) -> tuple[float, float] | None:
    """The cup the trainee confirmed last (a ``cup_confirmed`` event: the reamer's radiographic
    inclination and anteversion when confirmed), None when none was."""
    confirmed = [e for e in record.events if e["kind"] == "cup_confirmed"]
    return None if not confirmed else (float(confirmed[-1]["inclination_deg"]), float(confirmed[-1]["anteversion_deg"]))


def cuts_trainees_reamers(record: ReamingRecord) -> bool:
    """Whether the simulator cut with the reamers the trainee held (a whole-socket model), so that the
    cavity is the plan's to measure; a model of one size (the patch's) cuts its own whatever is held."""
    return record.reamer_mm is not None and bool(np.allclose(record.reamer_mm, cut_sizes_mm(record)))


def planned_hemisphere(record: ReamingRecord) -> tuple[np.ndarray, np.ndarray, float]:
    """The hemisphere the final cavity is mapped against (patch frame: centre m, unit axis out of the
    socket, radius m): the planned cup where the simulator cut the trainee's reamers; else (a model of
    one reamer, files before the plan) that reamer's teeth at the native centre, along the opening."""
    if record.plan is not None and cuts_trainees_reamers(record):
        plan = Plan(**record.plan)
        centre, axis = plan.cup_in_patch(SafeZone(**record.zone))
        return centre, axis, plan.cup_diameter_mm / 2e3
    return np.zeros(3), np.array([0.0, 0.0, 1.0]), float(record.cavity["teeth_radius_m"])


def cavity_against_plan_mm(record: ReamingRecord, plan: Plan) -> dict | None:
    """The final cavity against the planned cup, from the final bone's elements (their centres: to
    within half an element): ``cavity_depth_error_mm``, the cavity's floor along the plan's axis
    beyond (+) or short of (−) the planned cup's floor, the floor being the deepest removed element
    or the native articular sphere's floor, whichever is deeper (a whole socket's native cavity is
    hollow before any reaming; the fossa's recess behind it is not the cavity's floor);
    ``over_reaming_mm``, the furthest bone removed beyond the planned hemisphere;
    ``under_reaming_mm``, the thickest bone left inside it, below its rim. None without the
    cavity's geometry or when no bone was removed."""
    cavity = record.cavity
    if not cavity or len(record.final_alpha) != len(cavity["centroids_m"]):
        return None
    removed = record.final_alpha < cavity["threshold"]
    if not removed.any():
        return None
    centre, axis = plan.cup_in_patch(SafeZone(**record.zone))
    offset = cavity["centroids_m"] - centre
    distance = np.linalg.norm(offset, axis=1)
    radius = plan.cup_diameter_mm / 2e3
    native_floor = cavity["inner_radius_m"] + float(centre @ axis)  # the articular sphere's deepest point along −axis
    floor = max(float(np.max(-(offset[removed] @ axis))), native_floor)
    inside = ~removed & (distance < radius) & (offset @ axis < 0.0)
    return {
        "cavity_depth_error_mm": (floor - radius) * 1e3,
        "over_reaming_mm": max(0.0, float(np.max(distance[removed])) - radius) * 1e3,
        "under_reaming_mm": float(np.max(radius - distance[inside])) * 1e3 if inside.any() else 0.0,
    }


def medial_wall_remaining_mm(record: ReamingRecord) -> float | None:
    """The least bone left between the reamer's teeth and the medial wall over the final bone's
    frames (the trace's, as the page showed it: 0 from a breach on); None where the bone has no
    medial wall (the bone patch) or no frame was kept."""
    if record.medial_wall_mm is None:
        return None
    rows = final_rows(record)
    return None if len(rows) == 0 else float(np.min(record.medial_wall_mm[rows]))


def metrics(record: ReamingRecord) -> dict:
    """The session's measurements by name (mm, degrees, seconds, fractions); a figure the session
    cannot give is None, a figure a file before it does not hold is left out."""
    kinds = [e["kind"] for e in record.events]
    found: dict = {
        "perforations": kinds.count("perforated") + kinds.count("passed_through"),
        "undos": kinds.count("undo"),
        "restores": kinds.count("restore"),
        "push_mean_n": float(np.mean(record.force_n)),
        "reamer_path_length_mm": path_length_mm(record),
        "medial_wall_remaining_mm": medial_wall_remaining_mm(record),
    }
    pushed = in_range(record)
    if pushed is not None:
        found["push_out_of_range_fraction"] = float(1.0 - np.mean(pushed))
    sequence = reamer_sequence(record)
    if sequence is not None:
        found["reamer_sequence_mm"], found["time_per_reamer_s"] = sequence
    diameter = cavity_diameter_mm(record)
    found["cavity_diameter_mm"] = diameter
    shift = cavity_centre_shift_mm(record)
    found["medialisation_mm"], found["superior_shift_mm"] = (None, None) if shift is None else shift
    if record.plan is None:
        return found
    plan = Plan(**record.plan)
    axis = cavity_axis_angles(record)
    found |= {
        "plan": plan.as_metric(record.plan_source),
        "inclination_error_deg": None if axis is None else abs(axis[0] - plan.inclination_deg),
        "anteversion_error_deg": None if axis is None else abs(axis[1] - plan.anteversion_deg),
        "within_5deg_fraction": within_plan_fraction(record, plan, 5.0),
        "within_10deg_fraction": within_plan_fraction(record, plan, 10.0),
        "cavity_diameter_error_mm": None if diameter is None else diameter - plan.cup_diameter_mm,
    }
    confirmed = confirmed_cup_angles(record)
    found["confirmed_inclination_error_deg"] = None if confirmed is None else abs(confirmed[0] - plan.inclination_deg)
    found["confirmed_anteversion_error_deg"] = None if confirmed is None else abs(confirmed[1] - plan.anteversion_deg)
    found |= cavity_against_plan_mm(record, plan) or dict.fromkeys(("cavity_depth_error_mm", "over_reaming_mm", "under_reaming_mm"))
    return found
