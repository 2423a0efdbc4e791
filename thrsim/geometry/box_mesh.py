"""Structured tetrahedral meshes of boxes and columns: a hex grid split into 5 or 6 tets per cell.

For verification problems and tests (patch test, wave in a column, single-element checks, the
CalculiX cross-check), where a known, regular (or deliberately distorted) mesh is wanted
without gmsh. Nodes are numbered x fastest, then y, then z; every tet is positively oriented.
``six`` (Kuhn / Freudenthal) splits each cube along its main diagonal into 6 congruent tets;
``five`` into a central tet and four corner tets, alternating in a checkerboard so that face
diagonals match. Node sets: ``xmin`` … ``zmax`` (the six faces), ``boundary`` and ``interior``.
"""

from __future__ import annotations

import numpy as np

from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.tet_metrics import signed_volumes

# local corner index c = i + 2j + 4k for the offsets (i, j, k) of the unit cube
_KUHN = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]], dtype=np.int64)
_FIVE_EVEN = np.array([[0, 1, 2, 4], [1, 3, 2, 7], [1, 4, 5, 7], [2, 6, 4, 7], [1, 2, 4, 7]], dtype=np.int64)
# the mirror pattern (x → 1 − x) for odd cells: corner c ↦ c ^ 1
_FIVE_ODD = _FIVE_EVEN ^ 1


def box_mesh(
    cells: tuple[int, int, int],
    size: tuple[float, float, float],
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
    scheme: str = "six",
    jitter: float = 0.0,
    seed: int = 0,
    fixed: str | None = None,
) -> TetMesh:
    """Tet mesh of the box ``origin + [0, size]`` with ``cells`` = (nx, ny, nz) hex cells.

    ``jitter`` moves every interior node by a uniform random offset of up to that fraction of
    the local cell size in each direction (a distorted mesh for patch tests; keep it below
    ~0.3 so no tet inverts). ``fixed`` names a node set to use as the mesh's fixed nodes.
    """
    nx, ny, nz = (int(c) for c in cells)
    if min(nx, ny, nz) < 1:
        raise ValueError(f"cells must be positive, got {cells}")
    if scheme not in ("six", "five"):
        raise ValueError(f"scheme must be 'six' or 'five', got {scheme!r}")
    xs = [np.linspace(o, o + s, n + 1) for o, s, n in zip(origin, size, (nx, ny, nz), strict=True)]
    gz, gy, gx = np.meshgrid(xs[2], xs[1], xs[0], indexing="ij")
    nodes = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])

    def node_id(i, j, k):
        return i + (nx + 1) * (j + (ny + 1) * k)

    ci, cj, ck = (index.ravel() for index in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"))
    corners = np.stack([node_id(ci + (c & 1), cj + ((c >> 1) & 1), ck + ((c >> 2) & 1)) for c in range(8)], axis=1)
    if scheme == "six":
        tets = corners[:, _KUHN].reshape(-1, 4)
    else:
        odd = ((ci + cj + ck) % 2).astype(bool)
        tets = np.where(odd[:, None, None], corners[:, _FIVE_ODD], corners[:, _FIVE_EVEN]).reshape(-1, 4)

    tol = 1e-9 * max(size)
    sets = {}
    for axis, name in enumerate("xyz"):
        sets[f"{name}min"] = np.flatnonzero(np.abs(nodes[:, axis] - origin[axis]) < tol)
        sets[f"{name}max"] = np.flatnonzero(np.abs(nodes[:, axis] - origin[axis] - size[axis]) < tol)
    boundary = np.unique(np.concatenate([sets[k] for k in list(sets)]))
    sets["boundary"] = boundary
    sets["interior"] = np.setdiff1d(np.arange(len(nodes)), boundary)

    if jitter > 0.0:
        rng = np.random.default_rng(seed)
        h = np.array([s / n for s, n in zip(size, (nx, ny, nz), strict=True)])
        inner = sets["interior"]
        nodes[inner] += rng.uniform(-jitter, jitter, size=(len(inner), 3)) * h

    # orient every tet positively (the Kuhn and five-tet patterns mix orientations)
    volume = signed_volumes(nodes, tets)
    flip = volume < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    if np.any(np.abs(signed_volumes(nodes, tets)) <= 0) or np.any(signed_volumes(nodes, tets) < 0):
        raise ValueError("jitter too large: a tet inverted")
    return TetMesh(nodes=nodes, tets=tets, node_sets=sets, fixed_nodes=sets[fixed] if fixed else np.zeros(0, dtype=np.int32))
