"""Ground-truth cases in memory for training and evaluation: α per frame, reamer path, settings.

A dataset directory (``thrsim dataset``, with its manifest and splits), a learning pack
(``thrsim dataset pack``) or a single case file is read into arrays once. A patch model learns one
mesh, which every case must share; a socket model learns from windows, each case with its own mesh
and its elements' cutting energy. Extra datasets a newer solver writes are ignored; only the layout
of :mod:`thrsim.data.case_file` is read.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from thrsim.config import FRAME_RATE_HZ, PUSH_FORCE_N, LabelConfig, ReamerConfig, ReamerHoldConfig, ReamingCaseConfig
from thrsim.data.case_file import data_digest, read_case
from thrsim.data.labels import alpha as alpha_label
from thrsim.data.labels import compacting_elements
from thrsim.data.pack import is_pack, read_pack
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import WINDOW_SIDE, TetMesh
from thrsim.learn.graph import StaticGraph, mesh_digest
from thrsim.physics.reaming_case import cutting_energies


@dataclass
class CaseArrays:
    case_id: str
    path: Path
    alpha: np.ndarray  # (T, E) float32, eq. 47 (a crushable foam: its damage for its plastic strain)
    positions: np.ndarray  # (T, 3) m, reamer centre
    axis: np.ndarray  # (3,) unit D
    force_n: float
    inclination_deg: float
    anteversion_deg: float
    omega_rad_s: float
    split: str | None
    end_reason: str
    teeth_radius_m: float
    digest: str
    solver_version: str
    frame_dt_s: float = 1.0 / FRAME_RATE_HZ
    damage: np.ndarray | None = None  # (T, E) float32 D, where the case records it (solver 0.4.0 on)
    mesh: TetMesh | None = None  # the case's bone
    element_cutting_energy_j_m3: np.ndarray | None = None  # (E,) the cutting law's u_c of each element
    reaction_n: np.ndarray | None = None  # (T,) the bone's axial reaction on the reamer over each frame
    motor_torque_n_m: np.ndarray | None = None  # (T,) the torque spinning the reamer took over each frame
    hold: ReamerHoldConfig = ReamerHoldConfig()  # the hand-held reamer's mass and damping the case was solved with
    set_feed_mm_s: float | None = None  # the feed a rig set (None: the push drove the reamer against the bone)
    reamer_centre_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)  # a point the reamer's axis passes through (bone frame)
    bone_kind: str = "patch"  # the thesis's patch or the layered socket (its windows and the whole socket)

    def is_window(self) -> bool:
        """Whether the case's bone is a window of the socket (held at its cut sides), not a whole bone."""
        return self.mesh is not None and len(self.mesh.node_sets.get(WINDOW_SIDE, ())) > 0

    def axis_offset_mm(self) -> float:
        """How far (mm) the reamer's axis passes from the socket's centre."""
        return axis_offset_mm(np.asarray(self.reamer_centre_mm) * 1e-3, self.axis)

    def recorded_push_n(self) -> float:
        """The push the bone and the hold took, median over the frames: the recorded reaction plus the
        hold's damping times the feed (the reamer's weight, which the solver adds to a set push and
        takes from a set feed's, left out); the set push where no reaction is recorded."""
        if self.reaction_n is None or self.frames < 2:
            return self.force_n
        feed = self.advances() / self.frame_dt_s
        return float(np.median(self.reaction_n[1:] + self.hold.axial_damping_n_s_m * feed))

    @property
    def frames(self) -> int:
        return int(len(self.alpha))

    def advances(self) -> np.ndarray:
        """(T − 1,) m: how far the reamer moved along D from each frame to the next."""
        return np.diff(self.positions, axis=0) @ self.axis


def feed_range_mm_s(cases: list[CaseArrays]) -> list[float]:
    """The slowest and fastest the reamer advanced from one frame to the next (mm/s) over ``cases``:
    the feeds a model trained on them has seen (a pulled-back frame counts as no feed)."""
    feeds = np.concatenate([np.maximum(case.advances(), 0.0) / case.frame_dt_s for case in cases]) * 1e3
    return [float(feeds.min()), float(feeds.max())]


def axis_offset_mm(point_m: np.ndarray, axis: np.ndarray) -> float:
    """The distance (mm) from the socket's centre (the bone frame's origin) to the line through ``point_m`` along ``axis``."""
    point = np.asarray(point_m, dtype=np.float64)
    return 1e3 * float(np.linalg.norm(point - (point @ axis) * axis))


def require_damage(cases: list[CaseArrays], remedy: str) -> None:
    """Refuse, in one line, cases that do not record damage, for a model that reads it."""
    undamaged = [case.case_id for case in cases if case.damage is None]
    if undamaged:
        raise ThrsimInputError(
            f"{len(undamaged)} case(s) do not record damage (e.g. {undamaged[0]}; solver before 0.4.0), which this model reads: {remedy}"
        )


def element_cutting_energy(config: dict, mesh: TetMesh) -> np.ndarray:
    """u_c (J/m³) of each element from the case's settings (the solver's defaults where a setting is absent)."""
    case = ReamingCaseConfig.model_validate({"inclination_deg": 0.0, "anteversion_deg": 0.0, **config})
    return cutting_energies(case, mesh)[mesh.element_material]


def _case_arrays(
    case_id: str,
    path: Path,
    split: str | None,
    digest: str,
    attrs: dict,
    alpha: np.ndarray,
    positions,
    axis,
    damage: np.ndarray | None,
    mesh: TetMesh,
    reaction_n: np.ndarray | None = None,
    motor_torque_n_m: np.ndarray | None = None,
) -> CaseArrays:
    axis = np.asarray(axis, dtype=np.float64).reshape(3)
    config = attrs.get("config")
    if not isinstance(config, dict):
        config = {}
    reamer = {**ReamerConfig().model_dump(), **config.get("reamer", {})}
    return CaseArrays(
        case_id=case_id,
        path=path,
        alpha=alpha,
        positions=np.asarray(positions, dtype=np.float64),
        axis=axis / np.linalg.norm(axis),
        force_n=float(attrs.get("force_n", PUSH_FORCE_N)),
        inclination_deg=float(attrs.get("inclination_deg", 0.0)),
        anteversion_deg=float(attrs.get("anteversion_deg", 0.0)),
        omega_rad_s=float(attrs.get("omega_rad_s", 136.0)),
        split=split,
        end_reason=str(attrs.get("end_reason", "completed")),
        teeth_radius_m=ReamerConfig.model_validate(reamer).size_mm * 0.5e-3,  # the teeth's reach from the head centre
        digest=digest,
        solver_version=str(attrs.get("thrsim_version", "unknown")),
        frame_dt_s=1.0 / float(config.get("frame_rate_hz", FRAME_RATE_HZ)),
        damage=None if damage is None else np.asarray(damage, dtype=np.float32),
        mesh=mesh,
        element_cutting_energy_j_m3=element_cutting_energy(config, mesh),
        reaction_n=None if reaction_n is None else np.asarray(reaction_n, dtype=np.float64),
        motor_torque_n_m=None if motor_torque_n_m is None else np.asarray(motor_torque_n_m, dtype=np.float64),
        hold=ReamerHoldConfig.model_validate(config.get("hold", {})),
        set_feed_mm_s=None if config.get("feed_mm_s") is None else float(config["feed_mm_s"]),
        reamer_centre_mm=tuple(float(v) for v in config.get("reamer_centre_mm") or (0.0, 0.0, 0.0)),  # type: ignore[arg-type]
        bone_kind=str(config.get("bone_kind", "patch")),
    )


def _read_case(path: Path, case_id: str, split: str | None, digest: str | None, labels: LabelConfig) -> tuple[TetMesh, CaseArrays]:
    case = read_case(path)
    frames = case.frames
    config = case.attrs.get("config")
    compacting = compacting_elements(config, case.mesh)
    alpha = alpha_label(frames.peeq, frames.von_mises, frames.status, labels, damage=frames.damage, compacting=compacting)
    return case.mesh, _case_arrays(
        case_id,
        path,
        split,
        digest or data_digest(path),
        case.attrs,
        alpha,
        frames.reamer_position,
        case.reamer_axis,
        frames.damage,
        case.mesh,
        frames.contact_force_axial,
        frames.motor_torque,
    )


def _read_pack(path: Path, splits: tuple[str, ...] | None, labels: LabelConfig) -> tuple[TetMesh, list[CaseArrays]]:
    mesh, packed = read_pack(path, splits, labels)
    return mesh, [
        _case_arrays(
            p.case_id,
            path,
            p.split,
            p.data_digest,
            p.attrs,
            p.alpha,
            p.reamer_position,
            p.reamer_axis,
            p.damage,
            p.mesh or mesh,
            p.contact_force_axial,
            p.motor_torque,
        )
        for p in packed
    ]


def load_cases(
    source: str | os.PathLike, splits: tuple[str, ...] | None = None, labels: LabelConfig | None = None, *, one_mesh: bool = True
) -> tuple[TetMesh, list[CaseArrays]]:
    """The mesh and the cases of a dataset directory or learning pack (optionally some splits only) or of one case file.

    ``one_mesh``: refuse cases whose meshes differ (a patch model's data); otherwise each case keeps
    its own (``CaseArrays.mesh``) and the mesh returned is the first case's."""
    from thrsim.data.generate import load_dataset

    labels = labels or LabelConfig()
    source = Path(source)
    if is_pack(source):
        packed_mesh, packed = _read_pack(source, splits, labels)
        packed = [case for case in packed if case.frames >= 2]
        if not packed:
            raise ThrsimInputError(f"{source}: no case with two frames or more{' in split(s) ' + ', '.join(splits) if splits else ''}")
        return packed_mesh, packed
    entries: list[dict]
    if source.is_file():
        if not h5py.is_hdf5(source):
            raise ThrsimInputError(f"{source}: not an HDF5 case file")
        entries = [{"path": str(source), "case_id": source.stem, "split": None}]
    elif source.is_dir():
        entries = [e for e in load_dataset(source) if splits is None or e.get("split") in splits]
    else:
        raise ThrsimInputError(f"{source}: no such dataset directory or case file")
    if not entries:
        wanted = f" in split(s) {', '.join(splits)}" if splits else ""
        raise ThrsimInputError(f"{source}: no complete cases{wanted}")
    mesh: TetMesh | None = None
    cases: list[CaseArrays] = []
    digest = None
    for entry in entries:
        case_mesh, case = _read_case(Path(entry["path"]), entry["case_id"], entry.get("split"), entry.get("data_digest"), labels)
        if mesh is None:
            mesh, digest = case_mesh, mesh_digest(case_mesh)
        elif one_mesh and mesh_digest(case_mesh) != digest:
            raise ThrsimInputError(f"{entry['path']}: its mesh differs from the other cases' (one model learns one mesh)")
        if case.frames < 2:
            continue
        cases.append(case)
    if mesh is None or not cases:
        raise ThrsimInputError(f"{source}: no case has two frames or more")
    return mesh, cases


def case_graphs(graph: StaticGraph, cases: list[CaseArrays], any_mesh: bool) -> dict[str, StaticGraph]:
    """Each case's graph by case id: ``graph`` where the case's bone is its mesh, else (``any_mesh``,
    a socket model's frame-free inputs) one built once per distinct mesh; refused otherwise."""
    by_digest = {graph.digest: graph}
    graphs = {}
    for case in cases:
        elements = graph.n_nodes if case.mesh is None else case.mesh.n_tets
        if case.alpha.shape[1] != elements:
            raise ThrsimInputError(f"{case.path}: case {case.case_id} has {case.alpha.shape[1]} elements, its mesh {elements}")
        digest = graph.digest if case.mesh is None else mesh_digest(case.mesh)
        if digest not in by_digest:
            if not any_mesh or case.mesh is None:
                raise ThrsimInputError(
                    f"{case.path}: case {case.case_id} has another mesh than the model's (a patch model learns one mesh)"
                )
            by_digest[digest] = StaticGraph(case.mesh)
        graphs[case.case_id] = by_digest[digest]
    return graphs
