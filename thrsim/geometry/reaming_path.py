"""Where a reaming case starts and ends, one rule for the solver and the learned simulator.

The reamer starts on its axis just clear of the bone (:data:`INITIAL_GAP_M`); a case ends when the
teeth's tip passes the patch's outer face (:func:`tip_exit_depth`), when a socket loses an element
of its medial wall or supported boundary (:func:`breach_reason`), or when no bone is left in the
reamer's path (:func:`bone_in_path`).
"""

from __future__ import annotations

import numpy as np

from thrsim.geometry.mesh import MEDIAL_WALL, SUPPORTED, TetMesh

#: the gap between the teeth and the nearest bone node where a case starts (m)
INITIAL_GAP_M = 5e-5
#: bisection steps of :func:`clear_start`: past the resolution of a double
_BISECTIONS = 80


def clear_start(nodes: np.ndarray, line_point: np.ndarray, axis: np.ndarray, reach_m: float) -> float:
    """The axial coordinate s on the line ``line_point + s·axis`` (the last before the sphere of radius
    ``reach_m`` about it touches ``nodes``, approached from behind); ValueError when none exists."""
    relative = nodes - line_point
    farthest = float(np.linalg.norm(relative, axis=1).max()) + reach_m
    # only nodes within reach of the line can touch the sphere, and in the bisection only those whose
    # touching stretch of the line meets the bracket; the margins keep every sign below exactly as
    # over all nodes (the others stay farther than reach_m from any centre tried, by far more than rounding)
    along = along_axis(relative, axis)
    across_sq = np.einsum("ij,ij->i", relative, relative) - along * along
    within = across_sq <= (reach_m + 1e-9) ** 2
    near, near_along = relative[within], along[within]
    near_half = np.sqrt(np.maximum(reach_m * reach_m - across_sq[within], 0.0))

    def clearance(s: float) -> float:
        if len(near) == 0:
            return float("inf")
        return float(np.linalg.norm(near - s * axis, axis=1).min()) - reach_m

    lo, hi = -2.0 * reach_m, 0.0
    if clearance(lo) <= 0:
        raise ValueError("the reamer cannot be placed clear of the bone along that axis")
    if clearance(hi) > 0:
        lo = hi
        while clearance(hi) > 0:
            if hi > farthest:
                raise ValueError("the reamer axis misses the bone: its teeth never reach it")
            hi += 0.25 * reach_m
    meets = (near_along - near_half <= hi + 1e-6) & (near_along + near_half >= lo - 1e-6)
    near = near[meets]
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if clearance(mid) > 0 else (lo, mid)
    return lo


def along_axis(points: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """points·axis written elementwise: no BLAS in anything that feeds the solver's decisions."""
    return points[..., 0] * axis[0] + points[..., 1] * axis[1] + points[..., 2] * axis[2]


#: how a socket is breached, in the order checked: the node set whose elements' loss means it
BREACHES = (("medial_wall_breached", MEDIAL_WALL), ("perforated", SUPPORTED))


def breach_faces(mesh: TetMesh, prepared: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The elements on each breach face of a socket (:data:`BREACHES`), less those a prepared cavity
    already removed."""
    touching = {name: np.isin(mesh.tets, mesh.node_sets[name]).any(axis=1) for _, name in BREACHES if name in mesh.node_sets}
    return {name: np.flatnonzero(on & (True if prepared is None else ~prepared)) for name, on in touching.items()}


def breach_reason(face_elements: dict[str, np.ndarray], active: np.ndarray) -> str | None:
    """The first breach (:data:`BREACHES`) whose face has lost an element, or None."""
    for reason, name in BREACHES:
        on_face = face_elements.get(name)
        if on_face is not None and not bool(active[on_face].all()):
            return reason
    return None


def tip_exit_depth(mesh: TetMesh, axis: np.ndarray) -> float | None:
    """How far along D the outer face lies under the teeth's tip; None when no bone is under it.

    Bone is under the tip when outer-face nodes lie within one mean edge length of the axis
    line s·D; the outermost of them (largest x·D) is where the tip leaves the bone. Shared by the
    solver and the learned simulator, so both end a case at the same place.
    """
    outer = mesh.fixed_nodes
    if len(outer) == 0:
        return None
    points = mesh.nodes[outer]
    along = along_axis(points, axis)
    lateral = np.linalg.norm(points - along[:, None] * axis, axis=1)
    under_tip = lateral <= mesh.mean_edge_length_m
    return float(along[under_tip].max()) if under_tip.any() else None


def bone_in_path(points: np.ndarray, centre: np.ndarray, axis: np.ndarray, outer_radius: float) -> bool:
    """Whether any of ``points`` (attached bone nodes, m) lies where the advancing dome can still meet it:
    in front of the head's equatorial plane and within the teeth's reach of the axis."""
    relative = points - centre
    along = along_axis(relative, axis)
    lateral_sq = (relative * relative).sum(axis=1) - along**2
    return bool(np.any((along > 0.0) & (lateral_sq < outer_radius**2)))
