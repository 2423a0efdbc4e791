"""Reading and writing tet meshes: meshio for the exchange formats, h5py for thrsim's own layout.

Exchange formats (.vtu, .msh, .inp and anything else meshio reads) carry coordinates in
millimetres by default (``units``), as CAD and ABAQUS users expect; thrsim's HDF5 layout is SI
(metres), the same ``/mesh`` group as a ground-truth case file (:mod:`thrsim.data.case_file`). Writes go to a
temporary name first and are renamed only when complete.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from typing import Literal

import h5py
import numpy as np

from thrsim.atomic import atomic_path, hdf5_in_memory
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import DEFAULT_MATERIAL_NAMES, MATERIAL_NAMES, TetMesh
from thrsim.hdf5_checks import read_dataset
from thrsim.provenance import package_versions

Units = Literal["mm", "m"]
UNIT_SCALE = {"mm": 1e-3, "m": 1.0}
WRITABLE_SUFFIXES = (".vtu", ".msh", ".inp", ".h5")
FIXED_SET = "fixed"


def read_mesh(path: str | Path, units: Units = "mm") -> TetMesh:
    """Read any tetrahedral mesh meshio reads (ABAQUS C3D4 .inp, Gmsh .msh, .vtu, ...) or a thrsim .h5.

    Only linear tets are accepted (quadratic tets keep their corner nodes); lower-dimensional
    cells (boundary triangles, lines) are ignored. Node sets come from ABAQUS NSETs or Gmsh
    physical groups; a set named ``fixed`` becomes the fixed nodes. Element materials come from
    ABAQUS ELSETs, Gmsh volume physical groups or ``material_<name>`` cell data named after a bone
    material (``cortical``, ``cancellous``). The mesh is validated.
    """
    path = Path(path)
    if not path.exists():
        raise ThrsimInputError(f"{path}: no such file")
    if not path.is_file():
        raise ThrsimInputError(f"{path}: not a file")
    mesh = _read_h5(path) if path.suffix.lower() in (".h5", ".hdf5") else _read_meshio(path, units)
    mesh.validate(source=str(path))
    return mesh


def _read_meshio(path: Path, units: Units) -> TetMesh:
    import meshio

    # meshio prints its reasons (stdout and stderr) and may call sys.exit(1) on a file it cannot
    # parse: capture both streams and turn every failure into one ThrsimInputError line
    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            raw = meshio.read(path)
    except (Exception, SystemExit) as error:  # many types for garbled input; all mean "unreadable"
        said = [line.strip().removeprefix("Error: ") for line in chatter.getvalue().splitlines() if line.strip()]
        text = str(error).strip() if not isinstance(error, SystemExit) else ""
        reason = text.splitlines()[0] if text else (said[0] if said else type(error).__name__)
        raise ThrsimInputError(f"{path}: cannot read mesh ({reason})") from None
    blocks = [block for block in raw.cells if block.type in ("tetra", "tetra10")]
    if not blocks:
        kinds = sorted({block.type for block in raw.cells}) or ["none"]
        raise ThrsimInputError(f"{path}: no tetrahedral elements (cell types: {', '.join(kinds)})")
    tets = np.concatenate([np.asarray(block.data)[:, :4] for block in blocks]).astype(np.int64)
    nodes = np.asarray(raw.points, dtype=np.float64)
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise ThrsimInputError(f"{path}: nodes are not three-dimensional")
    node_sets = {name: np.asarray(ids, dtype=np.int64).ravel() for name, ids in (raw.point_sets or {}).items()}
    node_sets.update(_gmsh_physical_node_sets(raw))
    for name in list(raw.point_data):
        if name.startswith("set_"):
            node_sets[name[4:]] = np.flatnonzero(np.asarray(raw.point_data[name]) > 0)
    # the fixed set (any case: ABAQUS names are case-insensitive) becomes the fixed nodes
    fixed_names = [name for name in node_sets if name.lower() == FIXED_SET]
    fixed_parts = [node_sets.pop(name) for name in fixed_names]
    fixed = np.unique(np.concatenate(fixed_parts)) if fixed_parts else np.zeros(0, dtype=np.int64)
    material, names = _materials(raw, blocks)
    return TetMesh(
        nodes=nodes * UNIT_SCALE[units], tets=tets, node_sets=node_sets, fixed_nodes=fixed, material=material, material_names=names
    )


def _materials(raw, tet_blocks) -> tuple[np.ndarray | None, tuple[str, ...]]:
    """Per-tet material tags from element sets, volume physical groups or flag cell data named after
    a bone material; (None, default names) when the file names none."""
    tet_index = [i for i, block in enumerate(raw.cells) if block.type in ("tetra", "tetra10")]
    members: dict[str, np.ndarray] = {}
    for name, per_block in (raw.cell_sets or {}).items():
        if name in MATERIAL_NAMES:
            members[name] = np.concatenate([_block_flags(raw, i, per_block[i]) for i in tet_index])
    for key, per_block in raw.cell_data.items():
        if key.startswith("material_") and key[9:] in MATERIAL_NAMES:
            members[key[9:]] = np.concatenate([np.asarray(per_block[i]).ravel() > 0 for i in tet_index])
    physical = raw.cell_data.get("gmsh:physical")
    for name, (tag, dim) in (raw.field_data or {}).items():
        if name in MATERIAL_NAMES and int(dim) == 3 and physical is not None:
            members[name] = np.concatenate([np.asarray(physical[i]).ravel() == int(tag) for i in tet_index])
    if not members:
        return None, DEFAULT_MATERIAL_NAMES
    names = tuple(name for name in MATERIAL_NAMES if name in members)
    material = np.full(sum(len(block.data) for block in tet_blocks), 255, dtype=np.uint8)
    for index, name in enumerate(names):
        material[members[name]] = index
    return material, names


def _block_flags(raw, block: int, ids) -> np.ndarray:
    flags = np.zeros(len(raw.cells[block].data), dtype=bool)
    if ids is not None and len(ids):
        flags[np.asarray(ids, dtype=np.int64)] = True
    return flags


def _gmsh_physical_node_sets(raw) -> dict[str, np.ndarray]:
    """Nodes of lower-dimensional cells grouped by Gmsh physical name."""
    names = {int(tag): name for name, (tag, _dim) in (raw.field_data or {}).items()}
    physical = raw.cell_data.get("gmsh:physical")
    if not names or physical is None:
        return {}
    sets: dict[str, list[np.ndarray]] = {}
    for block, tags in zip(raw.cells, physical, strict=True):
        if block.type in ("tetra", "tetra10"):
            continue
        for tag in np.unique(tags):
            if int(tag) in names:
                sets.setdefault(names[int(tag)], []).append(np.asarray(block.data)[tags == tag].ravel())
    return {name: np.unique(np.concatenate(parts)) for name, parts in sets.items()}


def _read_h5(path: Path) -> TetMesh:
    try:
        with h5py.File(path, "r") as f:
            if "mesh" not in f:
                raise ThrsimInputError(f"{path}: HDF5 file has no /mesh group")
            return read_mesh_group(f["mesh"])
    except (OSError, KeyError) as error:
        raise ThrsimInputError(f"{path}: cannot read HDF5 mesh ({error})") from None


# The /mesh group, shared by mesh files and ground-truth case files: its writer and reader.


def write_mesh_group(group: h5py.Group, mesh: TetMesh, compress: bool = False) -> None:
    """The ``/mesh`` group (nodes float64 m, tets int32, fixed_nodes int32) plus named node sets;
    ``compress``: gzip with byte shuffle (a learning pack's meshes, about half the bytes)."""
    options: dict = {"compression": "gzip", "compression_opts": 9, "shuffle": True} if compress else {}
    group.create_dataset("nodes", data=mesh.nodes.astype(np.float64), **options)
    group.create_dataset("tets", data=mesh.tets.astype(np.int32), **options)
    group.create_dataset("fixed_nodes", data=mesh.fixed_nodes.astype(np.int32))
    sets = group.create_group("node_sets")
    for name, ids in mesh.node_sets.items():
        sets.create_dataset(name, data=ids.astype(np.int32), **(options if len(ids) else {}))
    if mesh.material is not None:
        tags = group.create_dataset("material", data=mesh.material.astype(np.uint8), **options)
        tags.attrs["names"] = json.dumps(list(mesh.material_names))


def read_mesh_group(group: h5py.Group) -> TetMesh:
    """The mesh of a ``/mesh`` group written by :func:`write_mesh_group`, each dataset checked
    (:mod:`thrsim.hdf5_checks`) before it is read; ThrsimInputError names the file and the dataset."""
    source = group.file.filename
    sets = group.get("node_sets", {})
    if not isinstance(sets, (h5py.Group, dict)):
        raise ThrsimInputError(f"{source}: {group.name}/node_sets is a dataset, expected a group of node sets")
    node_sets = {name: read_dataset(sets, name, source, "iu", (None,)) for name in sets}
    fixed = read_dataset(group, "fixed_nodes", source, "iu", (None,)) if "fixed_nodes" in group else np.zeros(0, dtype=np.int32)
    nodes = read_dataset(group, "nodes", source, "f", (None, 3))
    tets = read_dataset(group, "tets", source, "iu", (None, 4))
    material, names = None, DEFAULT_MATERIAL_NAMES
    if "material" in group:
        material = read_dataset(group, "material", source, "u", (len(tets),))
        try:
            names = tuple(str(name) for name in json.loads(group["material"].attrs["names"]))
        except (KeyError, TypeError, ValueError):
            raise ThrsimInputError(f"{source}: {group.name}/material has no readable 'names' attribute (a JSON list of names)") from None
    return TetMesh(nodes=nodes, tets=tets, node_sets=node_sets, fixed_nodes=fixed, material=material, material_names=names)


def write_mesh(mesh: TetMesh, path: str | Path, units: Units = "mm", metadata: dict | None = None) -> Path:
    """Write by suffix (.vtu, .msh, .inp, .h5), atomically."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITABLE_SUFFIXES:
        raise ThrsimInputError(f"{path}: unsupported output format {suffix or '(none)'}; use one of {', '.join(WRITABLE_SUFFIXES)}")
    with atomic_path(path) as tmp:
        if suffix == ".h5":
            with hdf5_in_memory(tmp) as f:
                f.attrs["format"] = "thrsim-mesh"
                f.attrs["units"] = "m"
                f.attrs["versions"] = json.dumps(package_versions())
                f.attrs["metadata"] = json.dumps(metadata or {})
                write_mesh_group(f.create_group("mesh"), mesh)
        else:
            _write_meshio(mesh, tmp, suffix, units)
    return path


def _write_meshio(mesh: TetMesh, path: Path, suffix: str, units: Units) -> None:
    import meshio

    sets = {name: ids for name, ids in mesh.node_sets.items() if name.lower() != FIXED_SET}
    sets[FIXED_SET] = mesh.fixed_nodes
    points = mesh.nodes / UNIT_SCALE[units]
    cells = [("tetra", mesh.tets.astype(np.int64))]
    material = mesh.element_material
    if suffix == ".inp":
        elsets = {name: [np.flatnonzero(material == i)] for i, name in enumerate(mesh.material_names)} if mesh.material is not None else {}
        out = meshio.Mesh(points, cells, point_sets={name: ids.astype(np.int64) for name, ids in sets.items()}, cell_sets=elsets)
        meshio.write(path, out, file_format="abaqus")
    elif suffix == ".msh":
        # meshio's ASCII gmsh writer prints values with repr(): Python ints, not NumPy scalars
        flags = {f"set_{name}": _flag(mesh.n_nodes, ids).astype(object) for name, ids in sets.items()}
        physical = (material.astype(np.int32) + 1) if mesh.material is not None else np.ones(mesh.n_tets, dtype=np.int32)
        tags = {key: [physical] for key in ("gmsh:physical", "gmsh:geometrical")}
        names = {name: np.array([i + 1, 3]) for i, name in enumerate(mesh.material_names)} if mesh.material is not None else {}
        out = meshio.Mesh(points, cells, point_data=flags, cell_data=tags, field_data=names)
        meshio.write(path, out, file_format="gmsh22", binary=False)
    else:
        flags = {f"set_{name}": _flag(mesh.n_nodes, ids) for name, ids in sets.items()}
        cell_data = {}
        if mesh.material is not None:
            cell_data = {"material": [material.astype(np.int32)]}
            cell_data |= {f"material_{name}": [(material == i).astype(np.int32)] for i, name in enumerate(mesh.material_names)}
        meshio.write(path, meshio.Mesh(points, cells, point_data=flags, cell_data=cell_data), file_format="vtu")


def _flag(n: int, ids: np.ndarray) -> np.ndarray:
    flag = np.zeros(n, dtype=np.int32)
    flag[ids] = 1
    return flag
