"""The reaming trainer: the learned simulator driven by the navigation trainer's reamer and a push force.

The trainee steers the reamer (the page's controls, or a tracked reamer over OpenIGTLink) and
pushes (the page's force control, or a force sensor's SENSOR stream); every frame the learned
simulator (:class:`thrsim.learn.simulator.ReamingSimulator`) removes bone. Tracking, the APP,
cup angles and the safe zone are the navigation trainer's (:mod:`thrsim.app.navigation`),
composed here, so the reamer is tracked, lost and measured exactly as in the navigation mode.
The frames, the plan and the reamer held, and time: :class:`ReamingTrainer`. No I/O here.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from thrsim.app import controls as c
from thrsim.app.navigation import NavigationTrainer
from thrsim.config import FRAME_RATE_HZ, PUSH_FORCE_N, SafeZone, SocketConfig
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import CANCELLOUS, CORTICAL, MEDIAL_WALL, OUTER, REAMED_FACES, SUPPORTED, TetMesh
from thrsim.geometry.reaming_path import breach_faces
from thrsim.geometry.tet_metrics import rms_edge_lengths
from thrsim.learn.cases import axis_offset_mm
from thrsim.learn.simulator import ReamingSimulator, SimulatorSnapshot
from thrsim.nav.bone_frame import angles_of, patch_in_app, reamer_axis_from_cup
from thrsim.nav.phantom import Phantom
from thrsim.nav.tracker_state import CUP_AXIS_IN_REAMER
from thrsim.session.plan import REAMER_SIZES_MM, Plan
from thrsim.session.reaming import CUT_EDGE, FAR_FACE, ReamingRecord, write_reaming

#: α is sent to viewers in this many levels above the removal threshold (0 = removed)
DISPLAY_LEVELS = 32
#: a force sensor reading counts for this long; then the page's force control applies again
SENSOR_FRESH_S = 0.5
#: simulator frames one server tick may step: one, so that no tick holds two network steps (a tick
#: that comes late drops the frame it owes, counted in ``behind_frames``, rather than stepping two);
#: sessions recorded with two (before 0.5.0's last change) replay with two, as their settings say
MAX_FRAMES_PER_TICK = 1
#: the events of a frame's inputs leaving what the model learned, by the simulator's flag (once per stretch outside)
OUT_OF_RANGE_EVENTS = {
    "push": "push_out_of_range", "feed": "feed_out_of_range", "tilt": "tilt_out_of_range", "reamer size": "reamer_out_of_range", "centre": "centre_out_of_range",
    "contact": "contact_out_of_range",
}  # fmt: skip
#: under this much bone (mm) between the reamer's teeth and a face it would break through (the medial
#: wall, the patch's far face, the modelled bone's cut edge) the page warns in red, and under the
#: caution shows the figure amber; the page reads both from the scene (``scene.reaming``)
BREAK_WARNING_MM = 1.0
BREAK_CAUTION_MM = 2.0
#: how the events say what a breach went through (its ``face``, :data:`~thrsim.session.reaming.CUT_EDGE`)
BREACH_WORDS = {
    MEDIAL_WALL: "the medial wall, into the pelvis",
    CUT_EDGE: "the edge of the modelled bone: the simulated bone ended there (the bone is cut off, not anatomy), not at the medial wall",
    FAR_FACE: "the bone patch's far face",
}
#: the report's element size is read over the bone this far beyond the articular surface: where the reamers cut
CUTTING_ZONE_M = 3e-3
#: the whole socket's axes (columns) in the bone patch's frame: the socket frame's +x (anterior) and
#: +y (superior, the dome) are the patch frame's +y (anterior) and −x (the patch's +x is inferior),
#: +z (out of the socket) is shared: a quarter turn about z
SOCKET_IN_PATCH = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def socket_in_patch(native_socket_mm: float, element_size_mm: float) -> TetMesh:
    """The layered socket of a native size (:func:`thrsim.geometry.socket.generate_socket`, the right
    hip's) turned into the bone patch's frame, so that the trainer places, aims and measures it as it
    does the patch (a whole-socket model's inputs do not depend on the bone's frame: only the mesh turns)."""
    from thrsim.geometry.socket import generate_socket

    coarse = max(SocketConfig().coarse_element_size_mm, element_size_mm)
    mesh = generate_socket(
        SocketConfig(socket_diameter_mm=native_socket_mm, element_size_mm=element_size_mm, coarse_element_size_mm=coarse)
    )
    return dataclasses.replace(mesh, nodes=mesh.nodes @ SOCKET_IN_PATCH.T)


@dataclass
class _Trace:
    time: list[float] = field(default_factory=list)
    frame: list[int] = field(default_factory=list)
    force_n: list[float] = field(default_factory=list)
    axis: list[tuple[float, ...]] = field(default_factory=list)
    position_m: list[tuple[float, ...]] = field(default_factory=list)
    removed: list[int] = field(default_factory=list)
    reamer_mm: list[float] = field(default_factory=list)  # the size the trainee holds
    cut_mm: list[float] = field(default_factory=list)  # the size the simulator cut with
    removed_volume_mm3: list[float] = field(default_factory=list)
    depth_mm: list[float] = field(default_factory=list)
    angles: list[tuple[float, float, float]] = field(default_factory=list)  # radiographic incl., antev., zone distance
    medial_wall_mm: list[float] = field(default_factory=list)  # bone_left_mm of the medial wall (a bone with one)
    reaction_n: list[float] = field(default_factory=list)  # the bone's reaction along the axis (a socket model's; NaN without)
    motor_torque_n_m: list[float] = field(default_factory=list)  # the motor torque (likewise)


@dataclass(frozen=True)
class _Face:
    """A face the reamer breaks through, as the bone left before it is measured: the elements whose
    loss ends the reaming (None where no element's does) and a KD-tree of the nodes measured to."""

    elements: np.ndarray | None
    tree: cKDTree

    @classmethod
    def of_elements(cls, mesh: TetMesh, elements: np.ndarray) -> _Face:
        """The face of ``elements``, measured to all their nodes (an element goes when the teeth reach any)."""
        return cls(elements, cKDTree(mesh.nodes[np.unique(mesh.tets[elements])] if len(elements) else np.zeros((0, 3))))


def cutting_layer(mesh, newly_removed: np.ndarray, previous: str | None) -> str | None:
    """The bone layer the reamer cuts: the material most of a frame's removed elements are made of
    (``previous`` when the frame removed none); None for a mesh of one material (the patch), where
    no layer changes."""
    if mesh.material is None or len(mesh.material_names) < 2:
        return None
    if len(newly_removed) == 0:
        return previous
    counts = np.bincount(mesh.material[newly_removed], minlength=len(mesh.material_names))
    return mesh.material_names[int(np.argmax(counts))]


class ReamingTrainer:
    """One trainee's reaming session. Feed it controls, poses, forces and ticks; read its state.

    Frames (:mod:`thrsim.nav.bone_frame`). The bone patch's frame (origin at the acetabular centre,
    +z out of the acetabulum) sits in the hip's APP frame (lateral, anterior, inferior) with its +z
    along the cup axis at the safe zone's centre (40° inclination, 15° anteversion, radiographic),
    so reaming at the zone's centre is the dataset's γ = 0 and the model's trained range (the
    card's) spans every clinical aim. The APP frame of a left hip is the mirror of a right one's,
    so one patch and one model serve both sides; only the placement in the pelvis
    (``patch_to_model``) is mirrored.

    Plan and reamer. The session is measured against a plan (:class:`~thrsim.session.plan.Plan`):
    the trainee's, which the page may set until the first frame is reamed, or an instructor's case,
    fixed. The trainee holds one reamer size at a time (every swap an event); each frame passes it
    to the simulator, which cuts with the nearest size its model learned, and the trace keeps both.

    Time. The simulator steps the model's frame time of reaming per frame (its card's). While
    running, every tick steps the frames that are due by the running time (at most
    ``max_frames_per_tick``; beyond that the simulation falls behind real time and says so). Frames
    are driven by the tick times, which the session logs, so a replay steps the same frames (with
    the session's recorded ``max_frames_per_tick``).
    """

    mode = "reaming"

    def __init__(
        self,
        side: str = "right",
        seed: int = 0,
        simulator: ReamingSimulator | None = None,
        unavailable: str | None = None,
        max_frames_per_tick: int = MAX_FRAMES_PER_TICK,
        undo_s: float = 1.0,
        zone: SafeZone = SafeZone(),
        plan: Plan | None = None,
        phantom: Phantom | None = None,
    ):
        # the reamer starts at the zone's centre, γ = 0 (the module docstring), where the page's aim starts too
        self.navigation = NavigationTrainer(
            side=side,
            seed=seed,
            zone=zone,
            reamer_start={"inclination_deg": zone.inclination_deg, "anteversion_deg": zone.anteversion_deg},
            phantom=phantom,
        )
        self.simulator = simulator
        self.unavailable = unavailable if simulator is None else None
        self.max_frames_per_tick = max_frames_per_tick
        #: simulated frames per second of reaming: the model's (its card's frame time)
        self.frame_rate_hz = FRAME_RATE_HZ if simulator is None else 1.0 / simulator.model.frame_dt_s
        self.undo_frames = max(1, int(round(undo_s * self.frame_rate_hz)))
        self.zone = zone
        self._cavity_geometry: dict | None = None
        self.patch_axes = patch_in_app(zone)
        self.page_force_n = PUSH_FORCE_N
        self.sensor_force_n: float | None = None
        self._sensor_time = -math.inf
        self.trace = _Trace()
        self.events: list[dict] = []
        self._pending_events: list[dict] = []
        self.page_hidden = False  # the trainee's page is hidden or left: reaming holds (a running reamer resumes when it shows)
        self._outside: tuple[str, ...] = ()  # what of the last frame's inputs lay outside what the model learned
        #: the plan the session is measured against: an instructor's case (fixed) or the trainee's, fixed once reaming starts
        self.plan = plan or Plan()
        self.plan_source = "trainee" if plan is None else "case file"
        self.reamer_mm = self.plan.first_reamer_mm()
        self._faces: dict[str, _Face] | None = None  # the faces the reamer breaks through, read once (_breakable)
        self._reset_run()

    # ---- state of the run ---------------------------------------------------------------------

    def _reset_run(self) -> None:
        self.running = False
        self.running_s = 0.0
        self.frames_run = 0
        self.behind_frames = 0
        self._last_tick: float | None = None
        self._history: deque[SimulatorSnapshot] = deque(maxlen=self.undo_frames + 1)
        self._last_step_ms = math.nan
        self._reamer_position: np.ndarray | None = None  # patch frame, m
        self._cutting_layer: str | None = None
        self._through_plate: set[float] = set()  # the reamers that have cut from the plate into cancellous bone (an event each)
        self._edge_warned: set[float] = set()  # the reamers the page has warned of the modelled bone's cut edge (an event each)
        self._reaction: tuple[float, float] | None = None  # the last frame's reaction (N) and motor torque (N·m)
        self._frame_forces: list[dict] = []  # frames stepped since the last state: their reaction and torque
        self.levels, self.levels_frame = np.zeros(0, dtype=np.uint8), 0  # the display levels viewers read (see _publish)
        if self.simulator is not None:
            self.simulator.reset("right")  # the patch frame: both hips are one patch (module docstring)
        self._publish()

    def _publish(self) -> None:
        """Replace (never mutate) the levels viewers read when they change: a sender holding the old array
        stays consistent; ``levels_frame`` is the frame of the last change (what a viewer must have drawn)."""
        levels = self.display_levels()
        if not np.array_equal(levels, self.levels):
            self.levels, self.levels_frame = levels, self.frames_run

    @property
    def side(self) -> str:
        return self.navigation.side

    @property
    def targets(self) -> dict[str, np.ndarray]:
        return self.navigation.targets

    @property
    def patch_to_model(self) -> np.ndarray:
        """4×4 placement of the patch frame in the pelvis model frame, metres (a mirror for a left hip)."""
        placement = np.eye(4)
        placement[:3, :3] = self.navigation.true_app_model.axes.T @ self.patch_axes
        placement[:3, 3] = self.navigation.acetabulum_model
        return placement

    def force_n(self, time_s: float) -> tuple[float, str]:
        if self.sensor_force_n is not None and time_s - self._sensor_time <= SENSOR_FRESH_S:
            return self.sensor_force_n, "sensor"
        return self.page_force_n, "page"

    def reamer_axis(self, nav_state: dict) -> np.ndarray | None:
        """D in the patch frame (into the bone), or None while the reamer cannot be measured."""
        tools = nav_state["tools"]
        if not (tools["Reamer"]["tracked"] and tools["Reference"]["tracked"]):
            return None
        nav = self.navigation
        return reamer_axis_from_cup(nav.app.to_local(nav.tools["Reamer"].pose[:3, :3] @ CUP_AXIS_IN_REAMER), self.zone)

    # ---- inputs -------------------------------------------------------------------------------

    def apply_pose(self, device: str, pose: np.ndarray, time_s: float) -> None:
        self.navigation.apply_pose(device, pose, time_s)

    def apply_force(self, newton: float, time_s: float) -> None:
        if not (math.isfinite(newton) and 0.0 <= newton <= c.MAX_FORCE_N):
            raise ThrsimInputError(f"force reading {newton!r} N outside [0, {c.MAX_FORCE_N:g}]")
        self.sensor_force_n = float(newton)
        self._sensor_time = time_s
        self.navigation.apply_force(newton, time_s)

    def apply_control(self, control: c._Control, time_s: float) -> str:
        if isinstance(control, c.RunControl):
            return self._run_control(control.action, time_s)
        if isinstance(control, c.ForceControl):
            self.page_force_n = control.newton
            return f"push {control.newton:g} N"
        if isinstance(control, c.PageControl):
            return self._page_control(control.visible, time_s)
        if isinstance(control, c.PlanControl):
            return self._plan_control(control, time_s)
        if isinstance(control, c.ReamerSizeControl):
            return self._swap_reamer(control.size_mm, time_s)
        if isinstance(control, c.ConfirmControl):
            return self._confirm_cup(time_s)
        if isinstance(control, c.SideControl):
            ack = self.navigation.apply_control(control, time_s)
            self._reset_run()
            self._event(time_s, "side_changed", control.value)
            return ack
        return self.navigation.apply_control(control, time_s)

    def _run_control(self, action: str, time_s: float) -> str:
        if self.simulator is None:
            raise ThrsimInputError(f"reaming is unavailable: {self.unavailable}")
        if action == "start":
            self.running = True
            self._last_tick = time_s
            self._event(time_s, "start")
            return "reaming"
        if action == "pause":
            self.running = False
            self._event(time_s, "pause")
            return "paused"
        if action == "reset":
            frames = self.frames_run
            self._reset_run()
            self._event(time_s, "restore", f"the intact bone restored after {frames} frames", frames=frames)
            return "bone restored"
        if not self._history:
            return "nothing to undo"
        back = self._history[0]
        self.simulator.restore(back)
        self._reamer_position = None if back.centre is None else back.centre.copy()
        self._cutting_layer = None
        self._through_plate.clear()  # the plate undone: reaching cancellous bone again is said again
        self._edge_warned.clear()  # likewise the cut edge's warning
        self._reaction = None
        undone = self.frames_run - back.frame
        self.frames_run = back.frame
        self.running_s = self.frames_run / self.frame_rate_hz
        self._history.clear()
        self._history.append(back)
        self.running = False
        self._publish()
        self._event(time_s, "undo", f"{undone} frames", frames=undone)
        return f"undid {undone} frames"

    def _plan_control(self, control: c.PlanControl, time_s: float) -> str:
        """The trainee's plan: refused once bone was reamed (measured against a plan set after seeing
        the cavity, a session would grade itself) and where an instructor's case file sets it."""
        if self.plan_source == "case file":
            raise ThrsimInputError("the instructor's case file sets this session's plan")
        if self.trace.frame:
            raise ThrsimInputError("the plan is fixed once reaming has started")
        patient = {"native_socket_mm": self.plan.native_socket_mm, "cancellous": self.plan.cancellous}  # the case's socket
        self.plan = Plan(**control.model_dump(exclude={"type"}), **patient)
        self._event(time_s, "plan_set", self._plan_words(), plan=self.plan.model_dump())
        return f"plan: {self._plan_words()}"

    def _plan_words(self) -> str:
        p = self.plan
        return (
            f"cup {p.cup_diameter_mm:g} mm at {p.inclination_deg:g}° inclination, {p.anteversion_deg:g}° anteversion, "
            f"centre {p.medialisation_mm:g} mm medial, {p.superior_shift_mm:g} mm superior"
        )

    def _swap_reamer(self, size_mm: int, time_s: float) -> str:
        """Another reamer: reaming pauses first (a reamer is changed out of the socket). Every swap is an event."""
        if size_mm == self.reamer_mm:
            return f"reamer {size_mm} mm"
        if self.running:
            self.running = False
            self._event(time_s, "pause")
        before, self.reamer_mm = self.reamer_mm, size_mm
        if self.simulator is not None and self.simulator.socket:
            self.simulator.withdraw()  # the next frame places the new reamer clear of the bone, as ``thrsim ream --reamers``
            self._reaction = None
            self._outside = tuple(flag for flag in self._outside if flag != "reamer size")  # a new reamer, a new stretch
        self._event(time_s, "reamer_changed", f"{before} → {size_mm} mm", from_mm=before, to_mm=size_mm)
        return f"reamer {size_mm} mm"

    def _confirm_cup(self, time_s: float) -> str:
        """The trainee confirms the cup's orientation: the reamer's radiographic angles now, on the
        pelvis the page shows (the report measures them against the plan; the last one counts)."""
        angles = self.navigation.reamer_angles_now(time_s)
        if angles is None:
            raise ThrsimInputError("the reamer cannot be measured: cannot confirm the cup's orientation")
        inclination, anteversion = angles["radiographic"]
        words = f"{inclination:.1f}° / {anteversion:.1f}°"
        self._event(time_s, "cup_confirmed", words, inclination_deg=inclination, anteversion_deg=anteversion)
        return f"cup orientation confirmed at {words}"

    def _page_control(self, visible: bool, time_s: float) -> str:
        """The trainee's page shown or hidden: a hidden page holds reaming (see :meth:`step`), never the record."""
        if self.page_hidden == visible:
            self.page_hidden = not visible
            self._event(time_s, "page_shown" if visible else "page_hidden")
        return "page shown" if visible else "page hidden: reaming holds"

    def _event(self, time_s: float, kind: str, detail: str = "", **data) -> None:
        """One event of the session (kept in its file): ``data`` holds its figures (JSON values)."""
        event = {"time_s": time_s, "kind": kind, "detail": detail, "frame": self.frames_run, **data}
        self.events.append(event)
        self._pending_events.append(event)

    # ---- stepping -----------------------------------------------------------------------------

    def step(self, time_s: float, early: Callable[[dict], None] | None = None) -> dict:
        """Navigation, then the simulator frames due by ``time_s``; the state for viewers. With frames
        to step, ``early`` first gets the state of the new poses on the bone as it was (the frames
        take 10–30 ms; the reamer drawn at its new pose need not wait for them)."""
        nav_state = self.navigation.step(time_s)
        axis = self.reamer_axis(nav_state)
        force, force_source = self.force_n(time_s)
        note = ""
        if self.running and self.simulator is not None and self.page_hidden:
            self._last_tick = time_s  # the hidden time is not owed
            note = "reaming paused while the page is hidden"
        elif self.running and self.simulator is not None:
            if self._last_tick is not None:
                self.running_s += max(0.0, time_s - self._last_tick)
            self._last_tick = time_s
            due = int(self.running_s * self.frame_rate_hz + 1e-9) - self.frames_run
            if axis is None:
                note = "reamer not measured: reaming holds"
                self.running_s = self.frames_run / self.frame_rate_hz  # the held time is not owed
            else:
                if due > 0 and early is not None:
                    early(self._state(time_s, nav_state, axis, force, force_source, note))
                for _ in range(min(due, self.max_frames_per_tick)):
                    if not self._step_frame(self.simulator, time_s, axis, force, nav_state):
                        break
                if due > 0:
                    self._publish()
                if due > self.max_frames_per_tick:
                    self.behind_frames += due - self.max_frames_per_tick
                    self.running_s = self.frames_run / self.frame_rate_hz  # do not burst to catch up
        return self._state(time_s, nav_state, axis, force, force_source, note)

    def _step_frame(self, simulator: ReamingSimulator, time_s: float, axis: np.ndarray, force: float, nav_state: dict) -> bool:
        """One simulator frame, traced; False when the frame ended the reaming (perforation, or no
        bone left in the reamer's path): reaming pauses there, and undo or reset go on from it."""
        if not self._history or self._history[-1].frame != simulator.frame:
            self._history.append(simulator.snapshot())
        result = simulator.step(axis, force, reamer_mm=self.reamer_mm)
        self._history.append(simulator.snapshot())
        self.frames_run = result.frame
        self._last_step_ms = result.seconds * 1e3
        self._reamer_position = result.reamer_position
        layer = cutting_layer(simulator.right_mesh, result.newly_removed, self._cutting_layer)
        if self._cutting_layer == CORTICAL and layer == CANCELLOUS and self.reamer_mm not in self._through_plate:
            self._through_plate.add(self.reamer_mm)  # once per reamer: a coarse mesh's layers alternate frame by frame at the plate
            self._event(time_s, "cancellous_reached", f"the {self.reamer_mm:g} mm reamer left the subchondral plate for cancellous bone")
        self._cutting_layer = layer
        edge = self.edge_left_mm()
        if edge is not None and edge < BREAK_WARNING_MM and self.reamer_mm not in self._edge_warned:
            self._edge_warned.add(self.reamer_mm)  # once per reamer, as the page's warning first shows for it
            words = (
                f"the {self.reamer_mm:g} mm reamer {edge:.2f} mm from the edge of the modelled bone (where the simulated bone is cut off)"
            )
            self._event(time_s, "edge_warning", words, edge_left_mm=edge, reamer_mm=float(self.reamer_mm))
        trace = self.trace
        trace.time.append(time_s)
        trace.frame.append(result.frame)
        trace.force_n.append(force)
        trace.axis.append(tuple(float(v) for v in axis))
        trace.position_m.append(tuple(float(v) for v in result.reamer_position))
        trace.removed.append(int(result.removed.sum()))
        trace.reamer_mm.append(float(self.reamer_mm))
        trace.cut_mm.append(math.nan if result.reamer_mm is None else result.reamer_mm)
        trace.removed_volume_mm3.append(result.removed_volume_m3 * 1e9)
        trace.depth_mm.append(simulator.depth_m * 1e3)
        angles, zone = nav_state.get("angles"), nav_state.get("zone")
        trace.angles.append(
            (math.nan, math.nan, math.nan) if angles is None or zone is None else (*angles["radiographic"], zone["distance_deg"])
        )
        if self.medial_wall_modelled():
            trace.medial_wall_mm.append(self.bone_left_mm() or 0.0)
        reaction = None if result.reaction_n is None else (result.reaction_n, result.motor_torque_n_m or 0.0)
        self._reaction = reaction
        trace.reaction_n.append(math.nan if reaction is None else reaction[0])
        trace.motor_torque_n_m.append(math.nan if reaction is None else reaction[1])
        if reaction is not None:
            self._frame_forces.append({"frame": result.frame, "reaction_n": reaction[0], "motor_torque_n_m": reaction[1]})
        self._check_ranges(
            simulator, time_s, force, axis, result.advance_m / simulator.model.frame_dt_s, result.out_of_range, result.law_contact_mm2
        )
        if result.end_reason is not None:
            self.running = False
            face = self._breach_face(simulator, result.end_reason)
            self._event(
                time_s,
                result.end_reason,
                ("" if face is None else f"through {BREACH_WORDS[face]}; ") + "reaming paused: undo (U) or restore (R) to go on",
                depth_mm=trace.depth_mm[-1],
                removed=trace.removed[-1],
                angles_deg=[None if math.isnan(v) else v for v in trace.angles[-1][:2]],
                **({} if face is None else {"face": face}),
                **({"medial_wall_left_mm": trace.medial_wall_mm[-1]} if face == CUT_EDGE else {}),
            )
            return False
        return True

    @staticmethod
    def _breach_face(simulator: ReamingSimulator, end_reason: str) -> str | None:
        """What a frame that ended the reaming broke through (:data:`BREACH_WORDS`); None where it broke nothing."""
        if end_reason == "medial_wall_breached":
            return MEDIAL_WALL
        if end_reason == "perforated":
            return CUT_EDGE if simulator.socket else FAR_FACE
        return None

    def _check_ranges(
        self,
        simulator: ReamingSimulator,
        time_s: float,
        force: float,
        axis: np.ndarray,
        feed_m_s: float,
        flags: tuple[str, ...],
        law_contact_mm2: float | None = None,
    ) -> None:
        """An event where a frame's input leaves what the model learned (once per stretch outside), as
        every step flags it (:attr:`~thrsim.learn.simulator.StepResult.out_of_range`). A patch model cuts
        with its one reamer whatever the sequence, as the page shows beside the size held: no event."""
        model = simulator.model
        if not simulator.socket:
            flags = tuple(flag for flag in flags if flag != "reamer size")
        for flag in flags:
            if flag in self._outside:
                continue
            if flag == "push" and model.trained_force_n is not None:
                low, high = model.trained_force_n
                words = f"{force:g} N: outside the {low:.0f}–{high:.0f} N the simulator learned"
                self._event(time_s, OUT_OF_RANGE_EVENTS[flag], words, force_n=force, trained_force_n=[low, high])
            elif flag == "feed" and model.trained_feed_mm_s is not None:
                feed, high = 1e3 * feed_m_s, model.trained_feed_mm_s[1]
                words = f"the reamer advancing {feed:.1f} mm/s: faster than the {high:.1f} mm/s the simulator learned"
                self._event(time_s, OUT_OF_RANGE_EVENTS[flag], words, feed_mm_s=feed, trained_feed_mm_s=[0.0, high])
            elif flag == "tilt" and model.trained_inclination_deg is not None:
                low, high = model.trained_inclination_deg
                gamma = angles_of(axis)[0]
                words = f"{gamma:.1f}° off the socket's axis: outside the {low:g}–{high:g}° the simulator learned"
                self._event(time_s, OUT_OF_RANGE_EVENTS[flag], words, tilt_deg=gamma, trained_tilt_deg=[low, high])
            elif flag == "reamer size":
                cut, sizes = simulator.cutting_size_mm(self.reamer_mm), list(model.trained_reamer_mm)
                words = f"{cut:g} mm: outside the {min(sizes):g}–{max(sizes):g} mm reamers the simulator learned"
                self._event(time_s, OUT_OF_RANGE_EVENTS[flag], words, reamer_mm=cut, trained_reamer_mm=sizes)
            elif flag == "centre" and model.trained_axis_offset_mm is not None and self._reamer_position is not None:
                low, high = model.trained_axis_offset_mm
                offset = axis_offset_mm(self._reamer_position, np.asarray(axis, dtype=np.float64))
                words = f"the reamer's axis {offset:.1f} mm from the socket's centre: beyond the {low:g}–{high:g} mm the simulator learned"
                self._event(time_s, OUT_OF_RANGE_EVENTS[flag], words, axis_offset_mm=offset, trained_axis_offset_mm=[low, high])
            elif flag == "contact" and model.trained_law_contact_mm2 is not None and law_contact_mm2 is not None:
                low, high = model.trained_law_contact_mm2
                words = f"the bone's reaction read over {law_contact_mm2:.0f} mm² of contact: more than the {high:.0f} mm² the simulator learned"
                self._event(time_s, OUT_OF_RANGE_EVENTS[flag], words, contact_mm2=law_contact_mm2, trained_contact_mm2=[low, high])
        self._outside = tuple(flags)

    def display_levels(self) -> np.ndarray:
        """uint8 per element for viewers: 0 removed, 1..DISPLAY_LEVELS α from the threshold to 1."""
        if self.simulator is None:
            return np.zeros(0, dtype=np.uint8)
        alpha = self.simulator.alpha
        threshold = self.simulator.model.threshold
        levels = 1 + np.minimum(DISPLAY_LEVELS - 1, ((alpha - threshold) * (DISPLAY_LEVELS / (1.0 - threshold))).astype(np.int64))
        return np.where(alpha < threshold, 0, levels).astype(np.uint8)

    def _state(self, time_s: float, nav_state: dict, axis, force: float, force_source: str, note: str) -> dict:
        sim = self.simulator
        gamma = theta = None
        if axis is not None:
            gamma, theta = angles_of(axis)
            trained = None if sim is None else sim.model.trained_inclination_deg
            if trained is not None and gamma > trained[1]:
                note = note or f"reamer {gamma:.0f}° off the acetabular axis: beyond what the model learned ({trained[1]:g}°)"
        events, self._pending_events = self._pending_events, []
        frame_forces, self._frame_forces = self._frame_forces, []
        bone_left, medial_wall = self.bone_left_mm(), self.medial_wall_modelled()
        reaming = {
            "available": sim is not None,
            "unavailable": self.unavailable,
            "running": self.running,
            "frame": self.frames_run,
            "bone_frame": self.levels_frame,  # the frame of the bone's last change: a page drawing it is up to date
            "time_s": self.frames_run / self.frame_rate_hz,
            "behind_frames": self.behind_frames,
            "force_n": force,
            "force_source": force_source,
            "gamma_deg": gamma,
            "theta_deg": theta,
            "removed": 0 if sim is None else int(sim.removed.sum()),
            "removed_volume_mm3": 0.0 if sim is None else sim.removed_volume_m3 * 1e9,
            "depth_mm": 0.0 if sim is None else sim.depth_m * 1e3,
            "step_ms": None if math.isnan(self._last_step_ms) else self._last_step_ms,
            "reamer_centre": None
            if self._reamer_position is None
            else (self.patch_to_model[:3, :3] @ self._reamer_position + self.patch_to_model[:3, 3]).tolist(),
            "bone_left_mm": bone_left,
            "medial_wall_modelled": medial_wall,
            "medial_wall_remaining_mm": bone_left if medial_wall else None,
            "edge_left_mm": self.edge_left_mm(),
            "cutting_layer": self._cutting_layer,
            "reaction_n": None if self._reaction is None else self._reaction[0],
            "motor_torque_n_m": None if self._reaction is None else self._reaction[1],
            "frame_forces": frame_forces,
            "out_of_range": list(self._outside),
            "contact": None if axis is None else self._contact(force),
            "paused": "page hidden" if self.running and self.page_hidden else None,
            "plan": {
                **self.plan.model_dump(),
                **self._plan_in_model(),
                "source": self.plan_source,
                "fixed": self.plan_source == "case file" or bool(self.trace.frame),
            },
            "reamer": self._reamer_state(),
            "note": note,
            "events": events,
        }
        return {**nav_state, "mode": self.mode, "reaming": reaming}

    def _contact(self, force: float) -> dict | None:
        """While reaming with a whole-socket model, what a fast contact model needs between frames
        (:mod:`thrsim.io.haptic`): the reaction law of the next frame (A, B, A_torque, B_torque), the
        hold's damping and the push; None otherwise (no law, not reaming, the reamer not measured)."""
        sim = self.simulator
        if sim is None or not self.running or self.page_hidden:
            return None
        law = sim.reaction_law
        if law is None:
            return None
        return {"law": law.tolist(), "damping_n_s_m": sim.model.hold.axial_damping_n_s_m, "force_n": force}

    def _reamer_state(self) -> dict:
        """The reamer held, the sizes offered, and the size the simulator cuts with for it (its model's: see its card)."""
        sim = self.simulator
        cuts = None if sim is None else sim.cutting_size_mm(self.reamer_mm)
        learned = None if sim is None else list(sim.model.trained_reamer_mm)
        note = ""
        if cuts is not None and abs(cuts - self.reamer_mm) > 1e-6:
            sizes = ", ".join(f"{size:g}" for size in learned or [])
            note = f"the model was trained on {sizes} mm only: it cuts {cuts:g} mm whatever reamer is chosen"
        return {"size_mm": self.reamer_mm, "sizes_mm": list(REAMER_SIZES_MM), "cuts_mm": cuts, "trained_mm": learned, "note": note}

    # ---- the cavity against the plan, for the page -------------------------------------------

    def _plan_in_model(self) -> dict:
        """Where the page draws the planned cup: its centre (m) and axis (unit, out of the socket) in the pelvis model frame."""
        centre, axis = self.plan.cup_in_patch(self.zone)
        placement = self.patch_to_model
        return {"centre_m": (placement[:3, :3] @ centre + placement[:3, 3]).tolist(), "axis": (placement[:3, :3] @ axis).tolist()}

    def _breakable(self) -> dict[str, _Face]:
        """The faces the reamer breaks through, read once from the mesh: the medial wall where the bone
        has one (the layered socket), the whole socket's cut edge (its supported boundary), and
        otherwise the far face (the patch's outer face). A face the simulator ends the reaming at when
        one of its elements goes (the wall and the edge, :func:`~thrsim.geometry.reaming_path.breach_faces`)
        is measured to every node of its remaining elements (an element goes when the teeth reach any
        of its nodes); the patch's far face, where the simulator ends the reaming geometrically, to its nodes."""
        if self._faces is None:
            assert self.simulator is not None
            mesh = self.simulator.right_mesh
            breaches, faces = breach_faces(mesh), {}
            for face, name in ((MEDIAL_WALL, MEDIAL_WALL), (CUT_EDGE, SUPPORTED)):
                if len(breaches.get(name, ())):
                    faces[face] = _Face.of_elements(mesh, breaches[name])
            if MEDIAL_WALL not in faces:
                outer = mesh.node_sets.get(OUTER, np.zeros(0, dtype=np.int64))
                faces[FAR_FACE] = _Face(None, cKDTree(mesh.nodes[outer] if len(outer) else np.zeros((0, 3))))
            self._faces = faces
        return self._faces

    def _bone_left_to(self, face: str) -> float | None:
        """Bone left between the reamer's teeth and ``face`` (:meth:`_breakable`), mm: 0 once an element
        of it is gone, else from the teeth sphere to its nearest node; None before the reamer has a
        position, or where the bone has no such face."""
        found = None if self.simulator is None or self._reamer_position is None else self._breakable().get(face)
        if found is None or found.tree.n == 0:
            return None
        if found.elements is not None and self.simulator is not None and self.simulator.removed[found.elements].any():
            return 0.0  # the reamer is through it (the simulator ends the reaming there)
        nearest, _ = found.tree.query(self._reamer_position)
        return max(0.0, (float(nearest) - self._teeth_radius_m()) * 1e3)

    def bone_left_mm(self) -> float | None:
        """Bone left before the reamer breaks into the pelvis (mm, 0 once through): before the medial
        wall where the bone has one (to the nearest node of its remaining elements), else before the
        bone patch's far face (to its nearest node). None before the reamer has a position."""
        return self._bone_left_to(MEDIAL_WALL if self.medial_wall_modelled() else FAR_FACE)

    def _teeth_radius_m(self) -> float:
        """The radius of the reamer's teeth sphere that cuts: the size held on a socket model, the model's one on a patch model."""
        sim = self.simulator
        assert sim is not None
        return sim.cutting_size_mm(self.reamer_mm) * 0.5e-3 if sim.socket else sim.model.teeth_radius_m

    def edge_left_mm(self) -> float | None:
        """Bone left between the reamer's teeth and the edge of the modelled bone (mm, 0 once through):
        the whole socket's supported boundary, whose loss the simulator ends as a perforation (measured
        as the medial wall is, :meth:`_bone_left_to`). None before the reamer has a position, and on the
        bone patch, whose cut edge is its far face (:meth:`bone_left_mm` measures it)."""
        sim = self.simulator
        return None if sim is None or not sim.socket else self._bone_left_to(CUT_EDGE)

    def medial_wall_modelled(self) -> bool:
        """Whether the bone has a medial wall (the layered socket does; the bone patch does not)."""
        return self.simulator is not None and MEDIAL_WALL in self._breakable()

    # ---- what the page and the session file get -----------------------------------------------

    def defaults(self) -> dict:
        """Where the page's controls start (a new session's): the aim, the push and its most, and the frame rate."""
        return {**self.navigation.defaults(), "force_n": PUSH_FORCE_N, "max_force_n": c.MAX_FORCE_N, "frame_rate_hz": self.frame_rate_hz}

    def scene(self) -> dict:
        scene = self.navigation.scene()
        sim = self.simulator
        scene["reaming"] = {
            "available": sim is not None,
            "unavailable": self.unavailable,
            "patch_to_model": self.patch_to_model.ravel().tolist(),
            "elements": 0 if sim is None else sim.n_elements,
            "mesh": "/api/reaming/mesh",
            "display_levels": DISPLAY_LEVELS,
            "teeth_radius_m": None if sim is None else sim.model.teeth_radius_m,
            "warning_mm": BREAK_WARNING_MM,
            "caution_mm": BREAK_CAUTION_MM,
            "bone": None if sim is None else "socket" if sim.socket else "patch",  # the whole socket: the case's, in the plan
        }
        return scene

    def settings(self) -> dict:
        sim = self.simulator
        return {
            **self.navigation.settings(),
            "max_frames_per_tick": self.max_frames_per_tick,
            "undo_frames": self.undo_frames,
            "model": None
            if sim is None
            else {
                "path": str(sim.model.path),
                "mesh_digest": sim.model.graph.digest,
                "data_digest": sim.model.card["data"]["digest"],
                "trained_force_n": None if sim.socket else sim.model.trained_force_n,  # a socket model reads the feed, not the push
                "trained_feed_mm_s": sim.model.trained_feed_mm_s,
                "trained_inclination_deg": sim.model.trained_inclination_deg,
                "trained_reamer_mm": list(sim.model.trained_reamer_mm),
                "frame_dt_s": sim.model.frame_dt_s,
                "bone": "socket" if sim.socket else "patch",
            },
        }

    def record(self) -> ReamingRecord:
        sim = self.simulator
        t = self.trace
        return ReamingRecord(
            side=self.side,
            zone=self.zone.model_dump(),
            mesh_digest="" if sim is None else sim.model.graph.digest,
            patch_to_model=self.patch_to_model,
            time=np.array(t.time, dtype=float),
            frame=np.array(t.frame, dtype=np.int64),
            force_n=np.array(t.force_n, dtype=float),
            axis=np.array(t.axis, dtype=float).reshape(-1, 3),
            position_m=np.array(t.position_m, dtype=float).reshape(-1, 3),
            removed=np.array(t.removed, dtype=np.int64),
            reamer_mm=np.array(t.reamer_mm, dtype=float),
            cut_mm=np.array(t.cut_mm, dtype=float),
            removed_volume_mm3=np.array(t.removed_volume_mm3, dtype=float),
            depth_mm=np.array(t.depth_mm, dtype=float),
            angles=np.array(t.angles, dtype=float).reshape(-1, 3),
            medial_wall_mm=np.array(t.medial_wall_mm, dtype=float) if self.medial_wall_modelled() else None,
            reaction_n=np.array(t.reaction_n, dtype=float) if sim is not None and sim.socket else None,
            motor_torque_n_m=np.array(t.motor_torque_n_m, dtype=float) if sim is not None and sim.socket else None,
            events=list(self.events),
            trained_force_n=None if sim is None or sim.socket else sim.model.trained_force_n,
            frame_dt_s=1.0 / self.frame_rate_hz,
            final_alpha=np.zeros(0, dtype=np.float32) if sim is None else sim.alpha.copy(),
            behind_frames=self.behind_frames,
            navigation=self.navigation.record(),
            cavity={} if sim is None else self._cavity(sim),
            plan=self.plan.model_dump(),
            plan_source=self.plan_source,
        )

    def _cavity(self, simulator: ReamingSimulator) -> dict:
        """The bone's geometry as the report's depth map reads it (computed once per model): the faces
        a reamer breaks through (the patch's outer face; the socket's medial wall and supported
        boundary, where the simulator ends a session), the native articular sphere, and the mesh's
        element size where the reamer cuts (the report's measures are good to about half of it)."""
        if self._cavity_geometry is None:
            mesh = simulator.right_mesh
            radii = np.linalg.norm(mesh.nodes, axis=1)
            outer_nodes = np.zeros(mesh.n_nodes, dtype=bool)
            outer_nodes[mesh.node_sets.get(OUTER, np.flatnonzero(radii >= radii.max() - 1e-9))] = True
            if simulator.socket:
                through = np.zeros(mesh.n_tets, dtype=bool)
                for elements in breach_faces(mesh).values():
                    through[elements] = True
            else:
                through = outer_nodes[mesh.tets].sum(axis=1) >= 3  # a face on the outer surface
            reamed = next((mesh.node_sets[name] for name in REAMED_FACES if len(mesh.node_sets.get(name, ()))), None)
            inner = float(np.median(radii[reamed])) if reamed is not None else float(radii.min())
            near = np.linalg.norm(mesh.centroids, axis=1) <= inner + CUTTING_ZONE_M
            self._cavity_geometry = {
                "centroids_m": mesh.centroids,
                "outer": through,
                "inner_radius_m": inner,
                "outer_radius_m": float(np.median(radii[outer_nodes])),
                "teeth_radius_m": simulator.model.teeth_radius_m,
                "threshold": simulator.model.threshold,
                "element_size_m": float(np.median(rms_edge_lengths(mesh.nodes, mesh.tets[near] if near.any() else mesh.tets))),
            }
        return self._cavity_geometry

    def write(self, group) -> None:
        write_reaming(group, self.record(), self.settings())
