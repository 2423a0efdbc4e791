"""The interactive learned simulator: ``thrsim.ReamingSimulator`` [Algorithm 1].

Loads a model directory (the shipped model by default) and its mesh; each :meth:`step` takes the
tracked reamer axis and the push force and returns the new bone state. Without a given position
the reamer advances along its axis by the regressor (autonomous mode); a given position forces
it (tool-forced mode). The left hip is the mirror of the right across the bone frame's x = 0:
the model runs on the right mesh with mirrored vectors, the element ids the same on both sides.
A socket model (:func:`~thrsim.learn.model_dir.reads_any_mesh`) runs on any bone mesh, with any
reamer size in the range it learned, its reamer advancing by the push against the bone's
reaction (:mod:`thrsim.learn.reaction_feed`); each step returns that reaction and the motor
torque, and flags what lies outside what the model learned.
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from dataclasses import dataclass

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from thrsim.config import CANCELLOUS_PRESETS, PUSH_FORCE_N, LabelConfig, Side
from thrsim.data.labels import alpha as alpha_label
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.reaming_path import INITIAL_GAP_M, bone_in_path, breach_faces, breach_reason, clear_start, tip_exit_depth
from thrsim.learn.cases import axis_offset_mm, element_cutting_energy
from thrsim.learn.compiled import compile_network
from thrsim.learn.features import GraphBatch
from thrsim.learn.graph import StaticGraph, attached_nodes
from thrsim.learn.model_dir import LoadedModel, load_model, reads_any_mesh
from thrsim.learn.reaction_feed import ReactionFeed, felt_at_push
from thrsim.learn.reamer_feed import ReamerFeed
from thrsim.learn.rollout import BoneState, LearnedStep
from thrsim.nav.bone_frame import angles_of, check_side, on_side

#: why a rollout cannot go on, as the solver ends its cases (thrsim.physics.reaming_case)
PERFORATED, PASSED_THROUGH, MEDIAL_WALL_BREACHED = "perforated", "passed_through", "medial_wall_breached"


@dataclass(frozen=True)
class StepResult:
    """One frame: α and the removed mask per element, the ids removed in this frame, the reamer centre (m)."""

    frame: int
    alpha: np.ndarray
    removed: np.ndarray
    newly_removed: np.ndarray
    reamer_position: np.ndarray
    removed_volume_m3: float
    advance_m: float
    seconds: float
    #: None while there is bone to ream; PERFORATED when the teeth's tip has passed the outer face
    #: where bone is under it (a socket: an element of its supported boundary has gone),
    #: MEDIAL_WALL_BREACHED when one on the socket's medial wall has, PASSED_THROUGH when no bone
    #: is left in the reamer's path
    end_reason: str | None = None
    #: the reamer size (mm) this frame cut with (:meth:`ReamingSimulator.cutting_size_mm`)
    reamer_mm: float | None = None
    #: a socket model's bone reaction along the axis (N) and motor torque (N·m) over the frame
    reaction_n: float | None = None
    motor_torque_n_m: float | None = None
    #: inputs outside what the model learned this frame ("push", "feed", "tilt", "reamer size", "centre",
    #: "contact": a reaction law summed over more contact than the law learned), never silently extrapolated
    out_of_range: tuple[str, ...] = ()
    #: the contact (mm²) the frame's reaction law summed over (:func:`~thrsim.learn.features.law_contact_mm2`)
    law_contact_mm2: float | None = None


@dataclass(frozen=True)
class SimulatorSnapshot:
    """Everything :meth:`ReamingSimulator.restore` needs to go back to a frame (undo)."""

    side: Side
    frame: int
    bone: BoneState
    centre: np.ndarray | None
    start: np.ndarray | None
    impulse_n_s: float = 0.0


def start_position(nodes: np.ndarray, axis: np.ndarray, teeth_radius_m: float, gap_m: float = INITIAL_GAP_M) -> np.ndarray:
    """Reamer centre s·D on its axis where the teeth clear every bone node by ``gap_m`` (as the solver starts)."""
    try:
        return clear_start(nodes, np.zeros(3), axis, teeth_radius_m + gap_m) * axis
    except ValueError as error:
        raise ThrsimInputError(str(error)) from None


def check_axis(reamer_axis) -> np.ndarray:
    axis = np.asarray(reamer_axis, dtype=np.float64).reshape(-1)
    if axis.shape != (3,):
        raise ThrsimInputError(f"reamer axis must have 3 components, got {axis.shape[0]}")
    if not np.isfinite(axis).all():
        raise ThrsimInputError("reamer axis has NaN or infinite components")
    norm = float(np.linalg.norm(axis))
    if norm < 1e-9:
        raise ThrsimInputError("reamer axis has zero length")
    return axis / norm


#: how far (mm) the reamer's axis may pass beyond the trained offsets from the socket's centre unflagged: a hand's tremor
AXIS_OFFSET_SLACK_MM = 0.5

#: a push no hand gives a reamer (the trainer takes up to 400 N); larger ones overflow the float32 features
MAX_FORCE_N = 10_000.0

#: the kinds of simulator (socket model?, compiled network?) already warmed up in this process
_WARMED: set[tuple[bool, bool]] = set()
_WARMING = threading.Lock()


def check_force(force_n) -> float:
    """``force_n`` as newtons in [0, :data:`MAX_FORCE_N`], or ThrsimInputError saying why not."""
    try:
        force = float(force_n)
    except (TypeError, ValueError):
        raise ThrsimInputError(f"force must be a number of newtons, got {force_n!r}") from None
    if not math.isfinite(force) or not 0 <= force <= MAX_FORCE_N:
        raise ThrsimInputError(f"force must be finite, non-negative and at most {MAX_FORCE_N:g} N, got {force_n!r} N")
    return force


class ReamingSimulator:
    """Learned reaming, one frame (the model card's frame time, 1/60 s for the shipped model) per :meth:`step`.

    >>> sim = ReamingSimulator("MODEL_DIR")          # doctest: +SKIP
    >>> sim.reset(side="right")                       # doctest: +SKIP
    >>> state = sim.step((0.26, 0.15, -0.95), 230.0)  # doctest: +SKIP
    """

    def __init__(
        self,
        model_dir: str | os.PathLike | None = None,
        *,
        model: LoadedModel | None = None,
        threads: int | None = None,
        compile: bool = False,
        mesh: TetMesh | None = None,
        cancellous: str = "normal",
    ):
        """``threads``: PyTorch's threads and NumPy's BLAS threads, for the whole process. A step's
        NumPy work is small (thousands of rows), where OpenBLAS's threads cost more than they
        save, much more on a loaded machine: a boolean mask times the volumes took 1.6 ms with
        two BLAS threads beside other work, 0.07 ms with one.
        ``compile``: run the network through ``torch.compile`` (see :mod:`thrsim.learn.compiled`),
        compiling now; if that fails the simulator stays eager and ``compile_error`` says why.
        ``mesh`` and ``cancellous`` (a socket model only): the bone to ream instead of the model's
        own, and its cancellous bone (``CANCELLOUS_PRESETS``)."""
        if threads is not None:
            torch.set_num_threads(threads)
            threadpool_limits(threads, user_api="blas")
        model = model if model is not None else load_model(model_dir)
        self.socket = reads_any_mesh(model.settings)
        if mesh is not None:
            if not self.socket:
                raise ThrsimInputError("a patch model reams the mesh it was trained on only; a socket model takes any bone")
            model = dataclasses.replace(model, mesh=mesh, graph=StaticGraph(mesh))
        self.model = model
        self._breach_faces = breach_faces(model.mesh) if self.socket else {}
        energy = None
        if self.socket:
            if cancellous not in CANCELLOUS_PRESETS:
                raise ThrsimInputError(f"unknown cancellous bone {cancellous!r}: known {', '.join(sorted(CANCELLOUS_PRESETS))}")
            energy = element_cutting_energy({"cancellous": CANCELLOUS_PRESETS[cancellous].model_dump()}, model.mesh)
        self._step = LearnedStep(model.gn, model.graph, model.settings.features, model.teeth_radius_m, energy)
        self._feed: ReamerFeed | ReactionFeed = (
            ReactionFeed(
                model.graph,
                model.teeth_radius_m,
                model.settings.features.reach_margin_mm * 1e-3,
                model.threshold,
                model.frame_dt_s,
                model.hold,
            )
            if self.socket
            else model.reamer_feed()
        )
        self._threshold = self.model.threshold
        self._tip_exit: tuple[tuple[float, ...], float | None] | None = None  # (axis, depth) of the last axis seen
        self._intact_alpha = float(alpha_label(np.zeros(1), np.zeros(1), None, LabelConfig(**self.model.card["labels"]))[0])
        self.compile_error = compile_network(self.model.gn, self.example_inputs()) if compile else None
        self.reset()
        with _WARMING:
            if (self.socket, self.compiled) not in _WARMED:
                self._warm_up()
                self.reset()
                _WARMED.add((self.socket, self.compiled))

    def _warm_up(self) -> None:
        """Two frames in the bone before the process's first session of this kind (then :meth:`reset`):
        Numba loads its cached kernels of the cutting front, features and attachment here, not in a
        trainee's first frame in contact (that tick took 40-90 ms more; compiling them, on a fresh
        install, seconds), the chips' kernel, which only a frame that removes bone calls, and the
        pushed feed's front entry, which a reamer in free air calls. The frames cut with the size a
        step takes when none is asked, placed for that size (placed for another, a smaller reamer on
        the whole socket never reached the bone and warmed nothing). Once per process: the loaded
        kernels serve every later simulator, and a server's next session starts without stepping."""
        intact = np.ones(self.n_elements, dtype=bool)
        self.model.graph.chips(intact)
        axis = np.array([0.0, 0.0, -1.0])
        size_mm = self.cutting_size_mm(None)
        touching = start_position(self.model.mesh.nodes, axis, size_mm * 0.5e-3)
        self.model.graph.front_entry_m(intact, touching, axis, size_mm * 0.5e-3)
        for depth_mm in (0.5, 1.0, 2.0, 4.0):  # a coarse mesh's front lies deeper than a fine one's
            self.step(axis, PUSH_FORCE_N, reamer_position=touching + depth_mm * 1e-3 * axis, reamer_mm=size_mm)
            if self._step.last.region:
                self.step(axis, PUSH_FORCE_N, reamer_position=touching + (depth_mm + 0.1) * 1e-3 * axis, reamer_mm=size_mm)
                return

    @property
    def compiled(self) -> bool:
        """Whether the network runs compiled (see ``compile``)."""
        return bool(getattr(self.model.gn, "network_compiled", False))

    def example_inputs(self) -> GraphBatch:
        """Network inputs of a typical step (intact bone, the reamer 0.5 mm into it along −z), to compile on."""
        axis = np.array([0.0, 0.0, -1.0])
        centre = start_position(self.model.mesh.nodes, axis, self.model.teeth_radius_m) + 0.5e-3 * axis
        alpha = np.full(self.n_elements, self._intact_alpha, dtype=np.float32)
        _, inputs = self._step.inputs(BoneState.start(alpha), centre, axis, PUSH_FORCE_N, 0.5e-3, self.model.omega_rad_s)
        if inputs is None:
            raise ThrsimInputError("the model's mesh has no bone within the reamer's reach at its pole")
        return inputs

    @property
    def right_mesh(self) -> TetMesh:
        return self.model.mesh

    @property
    def mesh(self) -> TetMesh:
        """The bone of the current side (the left is mirrored, same element ids)."""
        return self.model.mesh if self.side == "right" else self.model.mesh.mirrored()

    @property
    def n_elements(self) -> int:
        return self.model.mesh.n_tets

    def reset(self, side: str = "right") -> None:
        """Intact bone (every element at α of an unstressed element), reamer not yet placed."""
        self.side = check_side(side)
        self.frame = 0
        self.bone = BoneState.start(np.full(self.n_elements, self._intact_alpha, dtype=np.float32))
        self._centre: np.ndarray | None = None  # right-side frame
        self._start: np.ndarray | None = None
        self._impulse_n_s = 0.0  # push impulse since the reamer was placed (the regressor's input)
        self._last_advance_m = 0.0  # the last frame's advance (a socket model's feed relaxes from it)
        self._step.reaction_law = None

    def withdraw(self) -> None:
        """Take the reamer out (to change its size): the next step places it clear of the bone again."""
        self._centre = self._start = None
        self._impulse_n_s = 0.0
        self._step.reaction_law = None

    def snapshot(self) -> SimulatorSnapshot:
        """The state now (copies), for :meth:`restore`."""
        copy = lambda v: None if v is None else v.copy()  # noqa: E731
        return SimulatorSnapshot(self.side, self.frame, self.bone.copy(), copy(self._centre), copy(self._start), self._impulse_n_s)

    def restore(self, snapshot: SimulatorSnapshot) -> None:
        """Go back to a state taken by :meth:`snapshot` (same model)."""
        if snapshot.bone.alpha.shape != self.alpha.shape:
            raise ThrsimInputError(f"snapshot of {snapshot.bone.alpha.size} elements, this model's mesh has {self.alpha.size}")
        self.side, self.frame = snapshot.side, snapshot.frame
        self.bone = snapshot.bone.copy()
        self._centre = None if snapshot.centre is None else snapshot.centre.copy()
        self._start = None if snapshot.start is None else snapshot.start.copy()
        self._impulse_n_s = snapshot.impulse_n_s
        self._step.reaction_law = None  # the bone changed: the next step stands first to read its law

    @property
    def reaction_law(self) -> np.ndarray | None:
        """A socket model's reaction law for the next frame (A, B, A_torque, B_torque: R = A + B·feed,
        N and N·s/m; torque likewise), a copy; None before it was read (a patch model: always)."""
        law = self._step.reaction_law
        return None if law is None else np.array(law, dtype=np.float64)

    @property
    def alpha(self) -> np.ndarray:
        """α of every element now (the simulator's own array: copy before changing it)."""
        return self.bone.alpha

    @property
    def removed(self) -> np.ndarray:
        return self.alpha < self._threshold

    @property
    def removed_volume_m3(self) -> float:
        return float(self.model.graph.volumes[self.removed].sum())

    def reamer_start(self, reamer_axis) -> np.ndarray:
        """Where the reamer starts on this axis (teeth just clear of the bone), in this side's frame."""
        axis = self._to_right(check_axis(reamer_axis))
        return self._to_side(start_position(self.model.mesh.nodes, axis, self._step.teeth_radius_m))

    def _to_right(self, vector: np.ndarray) -> np.ndarray:
        return on_side(vector, self.side)

    _to_side = _to_right  # the mirror is its own inverse

    def cutting_size_mm(self, reamer_mm: float | None) -> float:
        """The reamer size (mm) a frame cuts with when ``reamer_mm`` is asked for: a socket model cuts
        with the size asked (flagged when outside the sizes it learned); a patch model with its learned
        size nearest to it (:attr:`LoadedModel.trained_reamer_mm`), so a model trained on one size
        cuts with that size whatever is asked; None asks for the first learned size."""
        sizes = self.model.trained_reamer_mm
        if reamer_mm is None:
            return sizes[0]
        if self.socket:
            if not (math.isfinite(reamer_mm) and 10.0 <= reamer_mm <= 100.0):
                raise ThrsimInputError(f"reamer size must be between 10 and 100 mm, got {reamer_mm!r}")
            return float(reamer_mm)
        return min(sizes, key=lambda size: abs(size - reamer_mm))

    def out_of_range(
        self, force_n: float, reamer_mm: float, axis: np.ndarray, centre: np.ndarray, feed_mm_s: float, law_contact_mm2: float | None = None
    ) -> tuple[str, ...]:
        """What of a step's inputs lies outside what the model learned (its card's ranges): the push (a
        model whose network reads it: a socket model's reads the feed the push balances instead), the
        frame's feed, the reamer size asked for, the tilt γ of the axis from the socket's, the axis's
        offset from the socket's centre (the reamer ``centre`` on it; right-side frame, m), the contact
        the frame's reaction law summed over (larger than any the law learned from)."""
        flags = []
        contacts = self.model.trained_law_contact_mm2
        if contacts is not None and law_contact_mm2 is not None and law_contact_mm2 > contacts[1]:
            flags.append("contact")
        offsets = self.model.trained_axis_offset_mm
        if (
            offsets is not None
            and not offsets[0] - AXIS_OFFSET_SLACK_MM <= axis_offset_mm(centre, axis) <= offsets[1] + AXIS_OFFSET_SLACK_MM
        ):
            flags.append("centre")
        pushes = self.model.trained_force_n
        if not self.socket and pushes is not None and not pushes[0] <= force_n <= pushes[1]:
            flags.append("push")
        feeds = self.model.trained_feed_mm_s
        if feeds is not None and feed_mm_s > feeds[1]:
            flags.append("feed")
        tilts = self.model.trained_inclination_deg
        if tilts is not None and not tilts[0] - 1e-6 <= angles_of(axis)[0] <= tilts[1] + 1e-6:
            flags.append("tilt")
        sizes = self.model.trained_reamer_mm
        if not min(sizes) - 1e-6 <= reamer_mm <= max(sizes) + 1e-6:
            flags.append("reamer size")
        return tuple(flags)

    def step(self, reamer_axis, force_n: float, reamer_position=None, reamer_mm: float | None = None) -> StepResult:
        """Advance one frame with the reamer of size ``reamer_mm`` (mm; see :meth:`cutting_size_mm`);
        returns the new state (arrays are copies, in this side's frame)."""
        started = time.perf_counter()
        axis = self._to_right(check_axis(reamer_axis))
        force = check_force(force_n)
        size_mm = self.cutting_size_mm(reamer_mm)
        if self.socket and abs(2e3 * self._step.teeth_radius_m - size_mm) > 1e-9:
            self._step.set_teeth_radius(size_mm * 0.5e-3)
            self._feed.teeth_radius_m = size_mm * 0.5e-3
            self._step.reaction_law = None  # another head: its contact is not the last one's
        if reamer_position is not None:
            given = np.asarray(reamer_position, dtype=np.float64).reshape(-1)
            if given.shape != (3,) or not np.isfinite(given).all():
                raise ThrsimInputError("reamer position must be 3 finite numbers (m)")
            new_centre = self._to_right(given)
            if self._centre is None:
                self._centre = self._start = new_centre
        else:
            if self._centre is None or self._start is None:  # set together
                self._centre = self._start = start_position(self.model.mesh.nodes, axis, self._step.teeth_radius_m)
            if isinstance(self._feed, ReactionFeed):
                standing = self._step.reaction_law is None
                if standing:  # standing: the bone's law at the reamer now, no cut
                    self._step(self.bone, self._centre, axis, force, 0.0, self.model.omega_rad_s)
                last = 0.0 if standing else self._last_advance_m
                moved = self._feed.advance_m(self._step.reaction_law, self.alpha, self._centre, axis, force, last)
            else:
                gamma, theta = angles_of(axis)
                moved = self._feed.advance_m(self.alpha, self._centre, self._start, axis, gamma, theta, force, self._impulse_n_s)
            new_centre = self._centre + moved * axis
        advance = float((new_centre - self._centre) @ axis)
        law = self._step.reaction_law
        law_contact = None if law is None else self._step.law_contact_mm2
        reaction = torque = None
        if self.socket and law is not None:
            if reamer_position is None and isinstance(self._feed, ReactionFeed):  # pushed: the force the push balances
                reaction, torque = felt_at_push(law, force, self._feed.damping_n_s_m)
            else:  # moved by the caller: the law at the frame's feed
                feed = max(advance / self.model.frame_dt_s, 0.0)
                reaction, torque = float(law[0] + law[1] * feed), float(law[2] + law[3] * feed)
        before = self.removed
        self.bone = self._step(self.bone, new_centre, axis, force, advance, self.model.omega_rad_s)
        after = self.removed
        newly = np.flatnonzero(after & ~before)
        self._centre = new_centre
        self._last_advance_m = advance
        self._impulse_n_s += force * self.model.frame_dt_s
        self.frame += 1
        end_reason = self._end_reason(new_centre, axis, after)
        return StepResult(
            frame=self.frame,
            alpha=self.alpha.copy(),
            removed=after,
            newly_removed=newly,
            reamer_position=self._to_side(new_centre.copy()),
            removed_volume_m3=float(self.model.graph.volumes[after].sum()),
            advance_m=advance,
            seconds=time.perf_counter() - started,
            end_reason=end_reason,
            reamer_mm=size_mm,
            reaction_n=reaction,
            motor_torque_n_m=torque,
            out_of_range=self.out_of_range(
                force, size_mm if reamer_mm is None else reamer_mm, axis, new_centre, 1e3 * advance / self.model.frame_dt_s, law_contact
            ),
            law_contact_mm2=law_contact,
        )

    def _end_reason(self, centre: np.ndarray, axis: np.ndarray, removed: np.ndarray) -> str | None:
        """The solver's end conditions, checked on the learned state (right-side frame)."""
        teeth = self._step.teeth_radius_m
        if self.socket:
            reason = breach_reason(self._breach_faces, ~removed)
            if reason is not None:
                return reason
            attached = attached_nodes(self.model.mesh.tets, ~removed, self.model.mesh.n_nodes)
            return None if bone_in_path(self.model.mesh.nodes[attached], centre, axis, teeth) else PASSED_THROUGH
        key = tuple(axis.tolist())
        if self._tip_exit is None or self._tip_exit[0] != key:
            self._tip_exit = (key, tip_exit_depth(self.model.mesh, axis))
        exit_depth = self._tip_exit[1]
        if exit_depth is not None and float(centre @ axis) + teeth > exit_depth:
            return PERFORATED
        attached = attached_nodes(self.model.mesh.tets, ~removed, self.model.mesh.n_nodes)
        if not bone_in_path(self.model.mesh.nodes[attached], centre, axis, teeth):
            return PASSED_THROUGH
        return None

    @property
    def depth_m(self) -> float:
        """How far the reamer has advanced along its axis since it was placed."""
        if self._centre is None or self._start is None:
            return 0.0
        return float(np.linalg.norm(self._centre - self._start))
