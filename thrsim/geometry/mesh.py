"""The tetrahedral bone mesh: nodes in metres, positively oriented linear tets, named node sets."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from thrsim.errors import ThrsimInputError
from thrsim.geometry.adjacency import FaceAdjacency, face_adjacency
from thrsim.geometry.tet_metrics import QualityReport, centroids, quality_report, rms_edge_lengths, signed_volumes

#: node-set names used across thrsim: the fixed outer (bottom) face, the reamed articular
#: face, and the side faces of the patch (cuts through bone that continues in reality)
OUTER, INNER, SIDE = "outer", "inner", "side"
#: node sets of the anatomical socket: the reamed cavity face (articular surface and fossa), the
#: medial wall's pelvic face, the supported boundary (cuts through bone that continues) and the rim
ARTICULAR, MEDIAL_WALL, SUPPORTED, RIM = "articular", "medial_wall", "supported", "rim"
#: a window of the socket's side faces: cuts through the socket's own bone, held like the supported
#: boundary but not a way through the bone (a reamer reaching them has not perforated)
WINDOW_SIDE = "window_side"
#: the node set of the face a reamer meets first, the patch's and the socket's
REAMED_FACES = (INNER, ARTICULAR)
#: bone materials by name; a mesh without material tags is all cortical (the thesis's patch)
CORTICAL, CANCELLOUS = "cortical", "cancellous"
#: the material names of a mesh without material tags: all cortical
DEFAULT_MATERIAL_NAMES: tuple[str, ...] = (CORTICAL,)
#: the materials a mesh file's element sets or cell data may name
MATERIAL_NAMES = (CORTICAL, CANCELLOUS)


@dataclass(frozen=True, eq=False)
class TetMesh:
    """Linear tetrahedral mesh (C3D4). ``nodes`` (N, 3) float64 in metres, ``tets`` (E, 4) int32.

    ``node_sets`` maps a name (``outer``, ``inner``, ``side`` for the generated patch; any
    NSET or physical-group name for a read mesh) to sorted node indices. ``fixed_nodes`` are
    the nodes held by the encastre boundary condition. ``material`` (E,) uint8 indexes
    ``material_names`` per element; None means every element is cortical.
    """

    nodes: np.ndarray
    tets: np.ndarray
    node_sets: dict[str, np.ndarray] = field(default_factory=dict)
    fixed_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    material: np.ndarray | None = None
    material_names: tuple[str, ...] = DEFAULT_MATERIAL_NAMES

    def __post_init__(self) -> None:
        object.__setattr__(self, "nodes", np.ascontiguousarray(self.nodes, dtype=np.float64))
        object.__setattr__(self, "tets", np.ascontiguousarray(self.tets, dtype=np.int32))
        object.__setattr__(self, "fixed_nodes", np.unique(np.asarray(self.fixed_nodes, dtype=np.int32)))
        sets = {name: np.unique(np.asarray(ids, dtype=np.int32)) for name, ids in self.node_sets.items()}
        object.__setattr__(self, "node_sets", sets)
        object.__setattr__(self, "material_names", tuple(str(name) for name in self.material_names))
        if self.material is not None:
            object.__setattr__(self, "material", np.ascontiguousarray(self.material, dtype=np.uint8))

    @property
    def element_material(self) -> np.ndarray:
        """(E,) uint8 index into ``material_names`` (all zeros when the mesh carries no tags)."""
        return self.material if self.material is not None else np.zeros(self.n_tets, dtype=np.uint8)

    def material_counts(self) -> dict[str, int]:
        """Elements per material name."""
        counts = np.bincount(self.element_material, minlength=len(self.material_names))
        return {name: int(counts[i]) for i, name in enumerate(self.material_names)}

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_tets(self) -> int:
        return len(self.tets)

    @cached_property
    def volumes(self) -> np.ndarray:
        return signed_volumes(self.nodes, self.tets)

    @cached_property
    def centroids(self) -> np.ndarray:
        return centroids(self.nodes, self.tets)

    @cached_property
    def mean_edge_length_m(self) -> float:
        """The elements' RMS edge length, averaged: the mesh's resolution (computed once; a step
        that asks for it every frame, as a steered reamer's end check does, must not pay for it)."""
        return float(rms_edge_lengths(self.nodes, self.tets).mean())

    @cached_property
    def adjacency(self) -> FaceAdjacency:
        return face_adjacency(self.tets)

    def quality(self) -> QualityReport:
        return quality_report(self.nodes, self.tets)

    def validate(self, source: str = "mesh") -> QualityReport:
        """Refuse what no solver can use: NaN coordinates, bad indices, inverted or zero-volume tets."""
        if self.nodes.ndim != 2 or self.nodes.shape[1] != 3:
            raise ThrsimInputError(f"{source}: nodes must be an (N, 3) array, got shape {self.nodes.shape}")
        if self.tets.ndim != 2 or self.tets.shape[1] != 4:
            raise ThrsimInputError(f"{source}: tets must be an (E, 4) array, got shape {self.tets.shape}")
        if self.n_tets == 0:
            raise ThrsimInputError(f"{source}: the mesh has no tetrahedra")
        bad_nodes = ~np.isfinite(self.nodes).all(axis=1)
        if bad_nodes.any():
            raise ThrsimInputError(
                f"{source}: {int(bad_nodes.sum())} node(s) with NaN or infinite coordinates "
                f"(first: node {int(np.flatnonzero(bad_nodes)[0])})"
            )
        if self.tets.min() < 0 or self.tets.max() >= self.n_nodes:
            raise ThrsimInputError(f"{source}: element connectivity refers to nodes that do not exist")
        if np.any(np.sort(self.tets, axis=1)[:, 1:] == np.sort(self.tets, axis=1)[:, :-1]):
            raise ThrsimInputError(f"{source}: an element repeats a node (zero-volume element)")
        report = self.quality()
        if report.degenerate:
            raise ThrsimInputError(f"{source}: {report.degenerate} zero-volume (degenerate) element(s)")
        if report.inverted:
            first = int(np.flatnonzero(self.volumes < 0)[0])
            raise ThrsimInputError(f"{source}: {report.inverted} inverted element(s) with negative volume (first: element {first})")
        for name, ids in {"fixed_nodes": self.fixed_nodes, **self.node_sets}.items():
            if len(ids) and (ids.min() < 0 or ids.max() >= self.n_nodes):
                raise ThrsimInputError(f"{source}: node set {name!r} refers to nodes that do not exist")
        if self.material is not None:
            if self.material.shape != (self.n_tets,):
                raise ThrsimInputError(f"{source}: {len(self.material)} material tags for {self.n_tets} elements")
            if len(self.material) and int(self.material.max()) >= len(self.material_names):
                raise ThrsimInputError(
                    f"{source}: material tag {int(self.material.max())} has no name (names: {', '.join(self.material_names)})"
                )
        _ = self.adjacency  # built here: raises on non-manifold faces
        return report

    def mirrored(self, axis: int = 0) -> TetMesh:
        """Mirror across the plane normal to ``axis`` through the origin, keeping volumes positive.

        A reflection flips every tet's orientation; swapping two nodes of each tet restores it.
        """
        nodes = self.nodes.copy()
        nodes[:, axis] *= -1.0
        return TetMesh(
            nodes=nodes,
            tets=self.tets[:, [0, 2, 1, 3]],
            node_sets=self.node_sets,
            fixed_nodes=self.fixed_nodes,
            material=self.material,
            material_names=self.material_names,
        )

    def summary(self) -> dict:
        """Counts and measures the CLI reports (elements, nodes, edges, volume_mm3, ...)."""
        report = self.quality()
        lo, hi = self.nodes.min(axis=0), self.nodes.max(axis=0)
        return {
            "elements": self.n_tets,
            "nodes": self.n_nodes,
            "edges": int(len(self.adjacency.pairs)),
            "boundary_faces": int(len(self.adjacency.boundary_faces)),
            "volume_mm3": float(self.volumes.sum() * 1e9),
            "min_volume_mm3": float(self.volumes.min() * 1e9),
            "fixed_nodes": int(len(self.fixed_nodes)),
            "node_sets": {name: int(len(ids)) for name, ids in sorted(self.node_sets.items())},
            "materials": self.material_counts(),
            "bounding_box_mm": {"min": (lo * 1e3).tolist(), "max": (hi * 1e3).tolist()},
            "quality": {
                "inverted": report.inverted,
                "degenerate": report.degenerate,
                "slivers": report.slivers,
                "min_quality": report.min_quality,
                "median_quality": report.median_quality,
                "min_altitude_mm": report.min_altitude * 1e3,
                "median_altitude_mm": report.median_altitude * 1e3,
            },
        }
