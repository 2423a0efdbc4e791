"""The reaming mode's group of a session file: what was reamed, how, and the final cavity.

The group (layout: :func:`write_reaming`) keeps the plan the session is measured against, one
row per simulated frame (push, reamer axis and centre, removed elements and volume, depth,
angles, the reamer size held and the size cut), every event whatever was undone or restored
after it, the final α, and what the report's depth map needs without the model (centroids,
outer-face flags, radii), beside the composed navigation trainer's group.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import h5py
import numpy as np

from thrsim.config import FRAME_RATE_HZ, BonePatchConfig
from thrsim.errors import ThrsimInputError
from thrsim.session.navigation import NavigationRecord, read_navigation, write_navigation

_TEXT = h5py.string_dtype()
_EVENT_FIELDS = ("time_s", "kind", "detail", "frame")
#: what goes wrong in the bone, scored however it was undone or restored: the bone patch reports
#: perforations; the whole socket adds medial-wall breaches, and rim damage once a simulator reports it
BONE_ERRORS = ("perforated", "passed_through", "medial_wall_breached", "rim_damaged")
#: what a bone error's ``face`` names besides the medial wall (``medial_wall``): the whole socket's cut
#: edge, its supported boundary, where the modelled bone is cut off from the pelvis it continues into
#: (not anatomy: the simulated bone ends there), and the bone patch's far face, where it perforates
CUT_EDGE, FAR_FACE = "cut_edge", "far_face"
_RENAMED = {"reset": "restore"}  # thrsim 0.4.0 called a restore of the intact bone "reset"
_TRACE = ("time", "frame", "force_n", "axis", "position_m", "removed", "removed_volume_mm3", "depth_mm", "angles")
#: trace columns some files lack: those before the reamer sequence, a bone without a medial wall, a model without a reaction
#: the cavity group's sizes every file holds
_CAVITY_SIZES = ("inner_radius_m", "outer_radius_m", "teeth_radius_m", "threshold")
#: files before ``element_size_m`` were all reamed on the bone patch, meshed at its default size
PATCH_ELEMENT_SIZE_M = BonePatchConfig().element_size_mm * 1e-3
_SEQUENCE = ("reamer_mm", "cut_mm", "medial_wall_mm", "reaction_n", "motor_torque_n_m")


@dataclass
class ReamingRecord:
    side: str
    zone: dict
    mesh_digest: str
    patch_to_model: np.ndarray
    time: np.ndarray
    frame: np.ndarray
    force_n: np.ndarray
    axis: np.ndarray
    position_m: np.ndarray
    removed: np.ndarray
    removed_volume_mm3: np.ndarray
    depth_mm: np.ndarray
    angles: np.ndarray
    events: list[dict]  # time_s, kind, detail, frame and the event's data
    trained_force_n: tuple[float, float] | None  # the push the model learned (a patch model), None when unknown or not read (socket)
    final_alpha: np.ndarray
    behind_frames: int
    navigation: NavigationRecord
    cavity: dict  # centroids_m, outer, inner_radius_m, outer_radius_m, teeth_radius_m, threshold, element_size_m (empty without a model)
    frame_dt_s: float = 1.0 / FRAME_RATE_HZ  # seconds of reaming per frame: the model's (settings' model; files before it: 1/60 s)
    reamer_mm: np.ndarray | None = None  # per frame, the size held (None: a file before the reamer sequence)
    cut_mm: np.ndarray | None = None  # per frame, the size the simulator cut with
    medial_wall_mm: np.ndarray | None = None  # per frame, bone left before the medial wall (None: the bone has none)
    reaction_n: np.ndarray | None = None  # per frame, the bone's reaction along the axis, N (None: a model without one, the patch's)
    motor_torque_n_m: np.ndarray | None = None  # per frame, the reamer's motor torque, N·m (likewise)
    plan: dict | None = None  # the Plan's fields (None: a file before the plan)
    plan_source: str = "trainee"

    @property
    def assessable(self) -> bool:
        """Whether there is anything to score: bone was reamed."""
        return len(self.frame) > 0


def write_reaming(group: h5py.Group, record: ReamingRecord, settings: dict) -> None:
    """Fill the session file's reaming group.

    Group ``/reaming``: attrs ``side``, ``zone`` and ``settings`` (JSON), ``plan`` (JSON: the
    :class:`~thrsim.session.plan.Plan` the session is measured against) and ``plan_source``
    (``trainee`` or ``case file``; both absent from files before the plan), ``mesh_digest`` (the
    model's mesh: a report of this session needs that mesh), ``behind_frames`` (frames the
    simulation could not keep up with); ``patch_to_model`` (4×4, the bone patch in the pelvis
    model frame, m); ``trace/`` one row per simulated frame: ``time`` (session s), ``frame``,
    ``force_n``, ``axis`` (F×3, reamer axis D in the patch frame), ``position_m`` (F×3, reamer
    centre, patch frame), ``removed`` (elements), ``removed_volume_mm3``, ``depth_mm``, ``angles``
    (F×3: radiographic inclination, anteversion and distance to the safe zone in degrees, NaN when
    the reamer was not measured), ``reamer_mm`` (the reamer size the trainee held) and ``cut_mm``
    (the size the simulator cut with: its model's, where the model learned one size; both absent
    from files before the reamer sequence), ``medial_wall_mm`` (bone left between the reamer's teeth
    and the nearest node of the remaining elements touching the medial wall, 0 once one is gone;
    only where the bone has one: the bone patch has none), ``reaction_n`` and
    ``motor_torque_n_m`` (the bone's reaction along the axis, N, and the motor torque, N·m, a
    whole-socket model predicts each frame; only with such a model); ``events/`` ``time``,
    ``kind``, ``detail``, ``frame`` and ``data``
    (JSON object per event: its figures, e.g. ``frames`` undone, ``force_n``; files before it read as
    ``{}``), every one kept whatever was undone or restored after it: ``start``, ``pause``, ``undo``
    (``frames``), ``restore`` (``frames``), ``side_changed``, ``page_hidden``, ``page_shown``,
    ``push_out_of_range`` (``force_n``, ``trained_force_n``), ``feed_out_of_range`` (``feed_mm_s``,
    ``trained_feed_mm_s``), ``tilt_out_of_range`` (``tilt_deg``,
    ``trained_tilt_deg``), ``reamer_out_of_range`` (``reamer_mm``, ``trained_reamer_mm``), ``centre_out_of_range`` (``axis_offset_mm``, ``trained_axis_offset_mm``), ``contact_out_of_range`` (``contact_mm2``, ``trained_contact_mm2``), ``plan_set`` (``plan``),
    ``reamer_changed`` (``from_mm``, ``to_mm``), ``cancellous_reached`` (a reamer first cut from the
    subchondral plate into cancellous bone: once a reamer, a layered bone's only), ``cup_confirmed`` (``inclination_deg``,
    ``anteversion_deg``: the reamer's radiographic angles when the trainee confirmed the cup), the
    simulator's end reasons
    (the :data:`BONE_ERRORS`, ``passed_through`` the reamer through the bone with none left in its path,
    with ``depth_mm``, ``removed``, ``angles_deg``, and for a
    breach the ``face`` gone through: ``medial_wall``, :data:`CUT_EDGE` with the ``medial_wall_left_mm``
    then, or :data:`FAR_FACE`), ``edge_warning`` (``edge_left_mm``, ``reamer_mm``: the page first warned a
    reamer of the whole socket's cut edge);
    ``final_alpha`` (E, α of every element at the end); ``cavity/`` what the report's depth map
    needs without the model: ``centroids_m`` (E×3, patch frame), ``outer`` (E, the element lies on
    a face the reamer breaks through: the patch's outer face, the socket's medial wall and supported
    boundary), attrs ``inner_radius_m`` (the native articular sphere), ``outer_radius_m`` (the
    patch's outer face), ``teeth_radius_m`` (the model's reamer), ``threshold`` (α below it is
    removed), ``element_size_m`` (the mesh's RMS edge length where the reamers cut; files before it
    were the 0.45 mm patch's); ``navigation/`` the
    composed navigation trainer's group (:mod:`thrsim.session.navigation`).
    """
    group.attrs.update(
        side=record.side,
        zone=json.dumps(record.zone),
        settings=json.dumps(settings),
        mesh_digest=record.mesh_digest,
        behind_frames=int(record.behind_frames),
    )
    if record.plan is not None:
        group.attrs.update(plan=json.dumps(record.plan), plan_source=record.plan_source)
    group.create_dataset("patch_to_model", data=np.asarray(record.patch_to_model, dtype=float))
    trace = group.create_group("trace")
    for name in _TRACE:
        trace.create_dataset(name, data=getattr(record, name))
    for name in _SEQUENCE:
        if getattr(record, name) is not None:
            trace.create_dataset(name, data=np.asarray(getattr(record, name), dtype=float))
    events = group.create_group("events")
    events.create_dataset("time", data=np.array([e["time_s"] for e in record.events], dtype=float))
    events.create_dataset("frame", data=np.array([e["frame"] for e in record.events], dtype=np.int64))
    for key in ("kind", "detail"):
        events.create_dataset(key, data=np.array([e[key] for e in record.events], dtype=object).astype(_TEXT))
    data = [json.dumps({k: v for k, v in e.items() if k not in _EVENT_FIELDS}) for e in record.events]
    events.create_dataset("data", data=np.array(data, dtype=object).astype(_TEXT))
    group.create_dataset("final_alpha", data=np.asarray(record.final_alpha, dtype=np.float32), compression="gzip")
    cavity = group.create_group("cavity")
    if record.cavity:
        cavity.create_dataset("centroids_m", data=np.asarray(record.cavity["centroids_m"], dtype=np.float32), compression="gzip")
        cavity.create_dataset("outer", data=np.asarray(record.cavity["outer"], dtype=bool), compression="gzip")
        cavity.attrs.update({k: float(record.cavity[k]) for k in (*_CAVITY_SIZES, "element_size_m") if k in record.cavity})
    write_navigation(group.create_group("navigation"), record.navigation, settings)


def read_reaming(group: dict) -> ReamingRecord:
    """The reaming group as read by :func:`thrsim.session.read_session` (nested dicts)."""
    try:
        attrs, trace, events = group["attrs"], group["trace"], group["events"]
        data = [json.loads(d) for d in events["data"]] if "data" in events else [{}] * len(events["kind"])
        model = json.loads(attrs["settings"]).get("model") or {}
        trained = model.get("trained_force_n")
        return ReamingRecord(
            side=str(attrs["side"]),
            zone=json.loads(attrs["zone"]),
            mesh_digest=str(attrs["mesh_digest"]),
            patch_to_model=np.asarray(group["patch_to_model"], dtype=float).reshape(4, 4),
            **{name: np.asarray(trace[name]) for name in _TRACE},
            **{name: np.asarray(trace[name], dtype=float) if name in trace else None for name in _SEQUENCE},  # type: ignore[arg-type]
            plan=json.loads(attrs["plan"]) if "plan" in attrs else None,
            plan_source=str(attrs.get("plan_source", "trainee")),
            events=[
                {"time_s": float(t), "kind": _RENAMED.get(str(k), str(k)), "detail": str(d), "frame": int(f), **extra}
                for t, k, d, f, extra in zip(events["time"], events["kind"], events["detail"], events["frame"], data, strict=True)
            ],
            trained_force_n=None if trained is None else (float(trained[0]), float(trained[1])),
            frame_dt_s=float(model.get("frame_dt_s", 1.0 / FRAME_RATE_HZ)),
            final_alpha=np.asarray(group["final_alpha"], dtype=np.float32),
            behind_frames=int(attrs["behind_frames"]),
            navigation=read_navigation(group["navigation"]),
            cavity={}
            if "centroids_m" not in group["cavity"]
            else {
                "centroids_m": np.asarray(group["cavity"]["centroids_m"], dtype=float),
                "outer": np.asarray(group["cavity"]["outer"], dtype=bool),
                **{k: float(group["cavity"]["attrs"][k]) for k in _CAVITY_SIZES},
                "element_size_m": float(group["cavity"]["attrs"].get("element_size_m", PATCH_ELEMENT_SIZE_M)),
            },
        )
    except (KeyError, TypeError, ValueError) as error:
        raise ThrsimInputError(f"session file's reaming group is incomplete or garbled ({error})") from None
