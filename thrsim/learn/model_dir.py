"""A model directory on disk: weights (safetensors), the regressor's arrays, the mesh, and a JSON card.

``card.json`` (format, version, data, settings, metrics, regressor table, code versions),
``network.safetensors`` (the Graph Network ``gn.*`` and MLP baseline ``mlp.*``, normalisers
included), ``advance.safetensors`` (the regressor as plain arrays) and ``mesh.safetensors``.
Nothing is pickled. Every file is written atomically and the card last, so a directory with a
card is complete. Loading refuses another format version, files that do not match the card's
mesh digest, or a mesh other than the one asked for; a folder is used only when every part
passes its checks, so a corrupt or tampered folder is refused with one line that names the file
and the value, never a traceback or an endless loop.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from safetensors import SafetensorError, safe_open
from safetensors.numpy import load_file as load_arrays
from safetensors.numpy import save as array_bytes
from safetensors.torch import load_file as load_tensors
from safetensors.torch import save as tensor_bytes

from thrsim.atomic import atomic_path
from thrsim.config import FRAME_RATE_HZ, LabelConfig, ReamerHoldConfig
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh
from thrsim.learn.advance import ArrayRegressor, Kind
from thrsim.learn.graph import StaticGraph, mesh_digest
from thrsim.learn.learned_simulator import LearnedSimulator
from thrsim.learn.reamer_feed import ReamerFeed
from thrsim.learn.settings import ModelSettings

if TYPE_CHECKING:
    from thrsim.learn.cases import CaseArrays

MODEL_FORMAT = "thrsim-model"
MODEL_FORMAT_VERSION = 1
CARD, NETWORK, ADVANCE, MESH = "card.json", "network.safetensors", "advance.safetensors", "mesh.safetensors"
#: where the shipped default model lives inside the package
SHIPPED_MODEL = Path(__file__).parent / "models" / "default"
#: the shipped whole-socket model (the socket feature set and the reaction head): ``thrsim ream --bone socket``'s
SHIPPED_SOCKET_MODEL = Path(__file__).parent / "models" / "socket"
#: a card is a few kilobytes (the shipped one 10 KB); anything far larger is not one
MAX_CARD_BYTES = 16 << 20


class _CardSection(BaseModel):
    """A part of the card that loading reads: its fields checked, any others kept as they are."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


class ReamerCard(_CardSection):
    teeth_radius_m: float = Field(gt=0, le=0.1, description="radius of the teeth's sphere the model was trained with")
    omega_rad_s: float = Field(ge=-1e4, le=1e4, description="the reamer's spin in the training cases")
    hold: ReamerHoldConfig = Field(default_factory=ReamerHoldConfig, description="the hand-held reamer's hold in the training cases")


class MeshCard(_CardSection):
    digest: str = Field(pattern=r"^[0-9a-f]{64}$")
    elements: int = Field(ge=1)
    nodes: int = Field(ge=4)


class DataCard(_CardSection):
    digest: str
    source: str


class AdvanceCard(_CardSection):
    chosen: Kind


class ModelCard(_CardSection):
    """The fields of ``card.json`` that loading and the commands read, with their types and ranges
    (``settings`` is checked by :class:`ModelSettings` itself)."""

    reamer: ReamerCard
    labels: LabelConfig
    mesh: MeshCard
    data: DataCard
    advance: AdvanceCard
    settings: dict
    training: dict


@dataclass
class LoadedModel:
    path: Path | None  # None: a model built in memory (an untrained one to time)
    card: dict
    settings: ModelSettings
    gn: LearnedSimulator
    mlp: LearnedSimulator
    advance: ArrayRegressor
    mesh: TetMesh
    graph: StaticGraph = field(repr=False)

    @property
    def teeth_radius_m(self) -> float:
        return float(self.card["reamer"]["teeth_radius_m"])

    @property
    def omega_rad_s(self) -> float:
        return float(self.card["reamer"]["omega_rad_s"])

    @property
    def threshold(self) -> float:
        return float(self.card["labels"]["removed_threshold"])

    @property
    def trained_force_n(self) -> tuple[float, float] | None:
        """The lowest and highest push of the training cases (None on a card written before cards recorded it)."""
        found = self.card.get("data", {}).get("force_range_n")
        return None if found is None else (float(found[0]), float(found[1]))

    @property
    def trained_feed_mm_s(self) -> tuple[float, float] | None:
        """The slowest and fastest frame-to-frame feed (mm/s) of the training cases (None on a card
        written before cards recorded it)."""
        found = self.card.get("data", {}).get("feed_range_mm_s")
        return None if found is None else (float(found[0]), float(found[1]))

    @property
    def trained_law_contact_mm2(self) -> tuple[float, float] | None:
        """The smallest and largest contact (mm², :func:`~thrsim.learn.features.law_contact_mm2`) the
        reaction law learned from (None: a card written before cards recorded it, or no reaction head)."""
        found = self.card.get("data", {}).get("law_contact_mm2")
        return None if found is None else (float(found[0]), float(found[1]))

    @property
    def trained_reamer_mm(self) -> tuple[float, ...]:
        """The reamer sizes (mm, the diameter the teeth cut) of the training cases: the card's
        ``reamer.sizes_mm`` where it lists them, else the one reamer its teeth radius says."""
        sizes = self.card["reamer"].get("sizes_mm")
        return tuple(float(s) for s in sizes) if sizes else (round(2e3 * self.teeth_radius_m, 3),)

    @property
    def trained_inclination_deg(self) -> tuple[float, float] | None:
        """The lowest and highest γ (reamer axis from the socket axis) of the training cases (None on a
        card written before cards recorded it)."""
        found = self.card.get("data", {}).get("inclination_range_deg")
        return None if found is None else (float(found[0]), float(found[1]))

    @property
    def trained_anteversion_deg(self) -> tuple[float, float] | None:
        """The lowest and highest θ (which way the axis tilts from the socket's) of the training
        cases (None on a card written before cards recorded it)."""
        found = self.card.get("data", {}).get("anteversion_range_deg")
        return None if found is None else (float(found[0]), float(found[1]))

    @property
    def trained_axis_offset_mm(self) -> tuple[float, float] | None:
        """The nearest and farthest the training cases' reamer axis passed from the socket's centre (mm;
        None on a card written before cards recorded it)."""
        found = self.card.get("data", {}).get("axis_offset_range_mm")
        return None if found is None else (float(found[0]), float(found[1]))

    @property
    def frame_dt_s(self) -> float:
        """Seconds of reaming one step of the model stands for: the training cases' frame time (cards
        written before cards recorded it: the thesis's frame rate, which every case then had)."""
        return float(self.card.get("data", {}).get("frame_dt_s", 1.0 / FRAME_RATE_HZ))

    @property
    def hold(self) -> ReamerHoldConfig:
        """The hand-held reamer's hold the training cases were solved with (the card's, else the default)."""
        return ReamerHoldConfig.model_validate(self.card["reamer"].get("hold", {}))

    def reamer_feed(self) -> ReamerFeed:
        """How the reamer advances when no position is given (regressor, resting on the bone)."""
        return ReamerFeed(
            self.advance,
            self.mesh,
            self.teeth_radius_m,
            self.threshold,
            force_range_n=self.trained_force_n,
            anteversion_range_deg=self.trained_anteversion_deg,
        )


def mesh_arrays(mesh: TetMesh) -> dict[str, np.ndarray]:
    arrays = {"nodes": mesh.nodes, "tets": mesh.tets, "fixed_nodes": mesh.fixed_nodes}
    arrays.update({f"set.{name}": ids for name, ids in mesh.node_sets.items()})
    return {k: np.ascontiguousarray(v) for k, v in arrays.items()}


def mesh_from_arrays(arrays: dict[str, np.ndarray]) -> TetMesh:
    sets = {k[4:]: v for k, v in arrays.items() if k.startswith("set.")}
    return TetMesh(nodes=arrays["nodes"], tets=arrays["tets"], node_sets=sets, fixed_nodes=arrays["fixed_nodes"])


def network_tensors(gn: LearnedSimulator, mlp: LearnedSimulator) -> dict[str, torch.Tensor]:
    tensors = {f"gn.{k}": v.detach().contiguous() for k, v in gn.state_dict().items()}
    tensors.update({f"mlp.{k}": v.detach().contiguous() for k, v in mlp.state_dict().items()})
    return tensors


def load_network_tensors(gn: LearnedSimulator, mlp: LearnedSimulator, tensors: dict[str, torch.Tensor]) -> None:
    gn.load_state_dict({k[3:]: v for k, v in tensors.items() if k.startswith("gn.")})
    mlp.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("mlp.")})


def save_model(out: Path, card: dict, gn: LearnedSimulator, mlp: LearnedSimulator, advance: ArrayRegressor, mesh: TetMesh) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # serialised here and written by Python: safetensors' own file writer reports a full disk as
    # a SafetensorError, not as the OSError every writer of thrsim turns into one line
    with atomic_path(out / NETWORK) as tmp:
        tmp.write_bytes(tensor_bytes(network_tensors(gn, mlp)))
    with atomic_path(out / MESH) as tmp:
        tmp.write_bytes(array_bytes(mesh_arrays(mesh)))
    card = {**card, "mesh": {**card.get("mesh", {}), "digest": mesh_digest(mesh), "elements": mesh.n_tets, "nodes": mesh.n_nodes}}
    return save_advance(out, card, advance)


def save_advance(out: Path, card: dict, advance: ArrayRegressor) -> Path:
    """Write the regressor, then the card (last, so a directory with a card is complete)."""
    with atomic_path(out / ADVANCE) as tmp:
        tmp.write_bytes(array_bytes({k: np.ascontiguousarray(v) for k, v in advance.arrays.items()}, metadata={"kind": advance.kind}))
    card = {**card, "format": MODEL_FORMAT, "format_version": MODEL_FORMAT_VERSION}
    card["advance"] = {**card.get("advance", {}), "chosen": advance.kind}
    with atomic_path(out / CARD) as tmp:
        tmp.write_text(json.dumps(card, indent=2, sort_keys=True, default=_json_default))
    return out


def read_mesh(path: str | os.PathLike) -> TetMesh:
    """The mesh a model directory belongs to, checked against its card."""
    path = Path(path)
    card = read_card(path)
    arrays = _read_safetensors(path / MESH, load_arrays)
    expected = {"nodes": ("f", (None, 3)), "tets": ("i", (None, 4)), "fixed_nodes": ("i", (None,))}
    expected.update({name: ("i", (None,)) for name in arrays if name.startswith("set.")})
    _check_arrays(path / MESH, arrays, expected)
    n_nodes = len(arrays["nodes"])
    for name, values in arrays.items():
        if values.dtype.kind == "i" and values.size and (values.min() < 0 or values.max() >= n_nodes):
            raise ThrsimInputError(f"{path / MESH}: {name} refers to node {int(values.max())} of {n_nodes} (or below 0)")
    mesh = mesh_from_arrays(arrays)
    if mesh_digest(mesh) != card["mesh"]["digest"]:
        raise ThrsimInputError(f"{path}: {MESH} does not match the card's mesh digest (mixed model files)")
    if (mesh.n_tets, mesh.n_nodes) != (card["mesh"]["elements"], card["mesh"]["nodes"]):
        raise ThrsimInputError(
            f"{path}: the card says {card['mesh']['elements']} elements and {card['mesh']['nodes']} nodes, "
            f"{MESH} holds {mesh.n_tets} and {mesh.n_nodes}"
        )
    mesh.validate(source=str(path / MESH))
    return mesh


def _read_safetensors(file: Path, loader) -> dict:
    """Every array of a safetensors file; a missing, truncated or garbled file is one line naming it."""
    try:
        return loader(str(file))
    except (SafetensorError, OSError, ValueError, KeyError, TypeError) as error:
        reason = " ".join(str(error).split()) or type(error).__name__
        raise ThrsimInputError(f"{file}: unreadable model file ({reason})") from None


def _check_arrays(file: Path, arrays: dict[str, np.ndarray], expected: dict[str, tuple[str, tuple]]) -> None:
    """Exactly the ``expected`` names, each of its dtype kind ('f' floating, 'i' integer) and shape
    (None: any length on that axis) and, for floats, finite values."""
    missing, unknown = sorted(set(expected) - set(arrays)), sorted(set(arrays) - set(expected))
    if missing or unknown:
        raise ThrsimInputError(f"{file}: arrays do not match the card (missing {missing or 'none'}, unexpected {unknown or 'none'})")
    for name, (kind, shape) in expected.items():
        values = arrays[name]
        if values.dtype.kind != kind or values.dtype.itemsize not in (4, 8):
            raise ThrsimInputError(f"{file}: {name} has dtype {values.dtype}, expected {'float' if kind == 'f' else 'int'}32 or 64")
        if values.ndim != len(shape) or any(want is not None and got != want for got, want in zip(values.shape, shape, strict=True)):
            raise ThrsimInputError(f"{file}: {name} has shape {values.shape}, expected {tuple('n' if n is None else n for n in shape)}")
        if kind == "f" and not np.isfinite(values).all():
            raise ThrsimInputError(f"{file}: {name} holds NaN or infinite values")


def _json_default(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def read_card(path: str | os.PathLike) -> dict:
    path = Path(path)
    card_file = path / CARD
    if not path.is_dir():
        raise ThrsimInputError(f"{path}: no such model directory")
    if not card_file.is_file():
        raise ThrsimInputError(f"{path}: not a thrsim model directory (no {CARD})")
    if card_file.stat().st_size > MAX_CARD_BYTES:
        raise ThrsimInputError(f"{card_file}: {card_file.stat().st_size} bytes, more than a model card's {MAX_CARD_BYTES}")
    try:
        card = json.loads(card_file.read_text())
    except (ValueError, UnicodeDecodeError, RecursionError) as error:
        raise ThrsimInputError(f"{card_file}: unreadable model card ({' '.join(str(error).split())})") from None
    if not isinstance(card, dict) or card.get("format") != MODEL_FORMAT:
        raise ThrsimInputError(f"{path}: not a thrsim model (card format {card.get('format') if isinstance(card, dict) else None!r})")
    if card.get("format_version") != MODEL_FORMAT_VERSION:
        raise ThrsimInputError(
            f"{path}: model format version {card.get('format_version')!r} is incompatible with this thrsim "
            f"(reads version {MODEL_FORMAT_VERSION}); retrain it with `thrsim train`"
        )
    try:
        ModelCard.model_validate(card)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        got = "" if first["type"] == "missing" else f" (got {first['input']!r:.60})"
        raise ThrsimInputError(f"{card_file}: invalid model card: {where}: {first['msg']}{got}") from None
    return card


def check_network_tensors(file: Path, tensors: dict[str, torch.Tensor], expected: dict[str, torch.Tensor]) -> None:
    """The weights are exactly the networks' parameters and buffers: same names, shapes and dtypes, finite."""
    missing, unknown = sorted(set(expected) - set(tensors)), sorted(set(tensors) - set(expected))
    if missing or unknown:
        raise ThrsimInputError(
            f"{file}: weights do not fit the card's architecture (missing {missing[:3] or 'none'}, unexpected {unknown[:3] or 'none'})"
        )
    for name, reference in expected.items():
        tensor = tensors[name]
        if tensor.dtype != reference.dtype or tensor.shape != reference.shape:
            raise ThrsimInputError(
                f"{file}: {name} is {tensor.dtype} {tuple(tensor.shape)}, the card's architecture needs {reference.dtype} {tuple(reference.shape)}"
            )
        if tensor.is_floating_point() and not torch.isfinite(tensor).all():
            raise ThrsimInputError(f"{file}: {name} holds NaN or infinite values")


def read_advance(file: Path) -> ArrayRegressor:
    """The regressor stored in ``file``, checked (kind, arrays, tree indices) before it can predict."""

    def arrays_and_kind(name: str) -> tuple[dict, str]:
        with safe_open(name, framework="numpy") as handle:
            return {key: handle.get_tensor(key) for key in handle.keys()}, (handle.metadata() or {}).get("kind", "")

    arrays, kind = _read_safetensors(file, arrays_and_kind)
    try:
        return ArrayRegressor(kind, arrays)
    except ValueError as error:
        raise ThrsimInputError(f"{file}: {error}") from None


def reads_any_mesh(settings: ModelSettings) -> bool:
    """A socket model's inputs hold nothing of the bone frame: it runs on any mesh (windows, the whole socket)."""
    return settings.features.feature_set == "socket"


def shipped_model_for(cases: Iterable[CaseArrays]) -> Path:
    """The shipped model that learned the cases' bone: the socket model for socket cases, else the patch model."""
    return SHIPPED_SOCKET_MODEL if any(case.bone_kind == "socket" for case in cases) else SHIPPED_MODEL


def load_model(path: str | os.PathLike | None = None, expect_mesh: TetMesh | None = None) -> LoadedModel:
    """Read and check a model directory (the shipped model when ``path`` is None)."""
    if path is None:
        path = SHIPPED_MODEL
        if not (path / CARD).is_file():
            raise ThrsimInputError(
                "no shipped model in this thrsim build yet (it is trained on the 0.3.0 dataset); train one (thrsim train) and name its folder",
                "model_dir",
            )
    path = Path(path)
    card = read_card(path)
    for name in (NETWORK, ADVANCE, MESH):
        if not (path / name).is_file():
            raise ThrsimInputError(f"{path}: incomplete model directory (no {name})")
    mesh = read_mesh(path)
    tensors = _read_safetensors(path / NETWORK, load_tensors)
    advance = read_advance(path / ADVANCE)
    try:
        settings = ModelSettings.model_validate(card["settings"])
    except ValidationError as error:
        raise ThrsimInputError(f"{path}: the card's settings are not valid for this thrsim ({str(error).splitlines()[0]})") from None
    digest = mesh_digest(mesh)
    if expect_mesh is not None and not reads_any_mesh(settings) and mesh_digest(expect_mesh) != digest:
        raise ThrsimInputError(
            f"{path}: the model belongs to another mesh ({mesh.n_tets} tets, digest {digest[:12]}) than the data "
            f"({expect_mesh.n_tets} tets, digest {mesh_digest(expect_mesh)[:12]})"
        )
    threshold = float(card["labels"]["removed_threshold"])
    gn, mlp = LearnedSimulator(settings, "gn", threshold), LearnedSimulator(settings, "mlp", threshold)
    check_network_tensors(path / NETWORK, tensors, network_tensors(gn, mlp))
    load_network_tensors(gn, mlp, tensors)
    return LoadedModel(
        path=path, card=card, settings=settings, gn=gn.eval(), mlp=mlp.eval(), advance=advance, mesh=mesh, graph=StaticGraph(mesh)
    )
