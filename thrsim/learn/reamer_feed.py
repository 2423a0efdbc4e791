"""How the reamer moves when nothing prescribes its position: the regressor's advance, resting on the bone.

The regressor [7.3.4] predicts the advance along D from the depth, γ, θ and the force; it knows
nothing of the bone, so on its own it cannot see the solver's rim drop (at γ ≈ 0 the reamer rests
on the rim while the teeth cut it, then drops once it is gone). A hand-held reamer pushed into
the bone does not hover over a cavity: it rests on the bone that is left. So the reamer advances
by the regressor's prediction or, where that would leave it clear of the bone, by as much as
brings at least ``support_nodes`` nodes of the remaining bone into the teeth's dome (the
half-ball of the teeth's reach in front of the head's equatorial plane), whichever is more.
``SUPPORT_NODES`` = 20 never moves the reamer further than the solver did on its own bone (the
docs' Learned simulator page). No push: the reamer stays. Outside the pushes it learned the
regressor reads the nearest; beyond a half-circle of tilt directions it reads the mirror image.
"""

from __future__ import annotations

import numpy as np

from thrsim.geometry.mesh import TetMesh
from thrsim.learn.advance import ArrayRegressor, feature_row
from thrsim.learn.graph import attached_nodes

SUPPORT_NODES = 20


def advance_to_support(
    points: np.ndarray, centre: np.ndarray, axis: np.ndarray, teeth_radius_m: float, support_nodes: int = SUPPORT_NODES
) -> float:
    """Smallest advance s ≥ 0 along ``axis`` after which ``support_nodes`` of ``points`` lie in the
    teeth's dome (|p − c − s·D| ≤ R and (p − c − s·D)·D ≥ 0); inf when fewer can ever get there.

    Point p enters the dome at s = a − √(a² − |r|² + R²) with r = p − c and a = r·D (the sphere's
    near crossing; the far one is behind the equatorial plane). Points behind the plane (a < 0)
    never enter, since advancing moves them further behind.
    """
    rel = points - centre
    along = rel @ axis
    disc = along * along - np.einsum("ij,ij->i", rel, rel) + teeth_radius_m * teeth_radius_m
    reachable = (along >= 0.0) & (disc >= 0.0)
    if int(reachable.sum()) < support_nodes:
        return float("inf")
    entry = along[reachable] - np.sqrt(disc[reachable])
    return max(0.0, float(np.partition(entry, support_nodes - 1)[support_nodes - 1]))


def mirrored_anteversion_deg(anteversion_deg: float, learned_deg: tuple[float, float] | None) -> float:
    """θ as a regressor that learned only the half-circle ``learned_deg`` ⊂ [0°, 180°] reads it: a
    direction beyond at its mirror image 360° − θ. The bone and the reamer's teeth are symmetric
    about the plane through the socket's axis at θ 0° and 180° (the thesis's grid sweeps only that
    half for this reason); the spin's sense is not, which this reading ignores. A regressor read
    beyond its data extrapolates: an RBF regressor at θ 330° advanced a 230 N reamer 13 mm/s."""
    if learned_deg is None or not (0.0 <= learned_deg[0] and learned_deg[1] <= 180.0):
        return anteversion_deg
    folded = anteversion_deg % 360.0
    return 360.0 - folded if folded > 180.0 else folded


class ReamerFeed:
    """The advance of one autonomous frame: regressor, then rest on the bone (see the module)."""

    def __init__(
        self,
        regressor: ArrayRegressor,
        mesh: TetMesh,
        teeth_radius_m: float,
        threshold: float,
        support_nodes: int = SUPPORT_NODES,
        force_range_n: tuple[float, float] | None = None,
        anteversion_range_deg: tuple[float, float] | None = None,
    ):
        """``force_range_n``, ``anteversion_range_deg``: the pushes and tilt directions θ the regressor
        learned (None: read it at any)."""
        self.regressor = regressor
        self.force_range_n = force_range_n
        self.anteversion_range_deg = anteversion_range_deg
        self.tets, self.nodes = np.asarray(mesh.tets), np.asarray(mesh.nodes)
        self.teeth_radius_m = teeth_radius_m
        self.threshold = threshold
        self.support_nodes = support_nodes
        self.last_rested = False

    def advance_m(
        self,
        alpha: np.ndarray,
        centre: np.ndarray,
        start: np.ndarray,
        axis: np.ndarray,
        inclination_deg: float,
        anteversion_deg: float,
        force_n: float,
        impulse_n_s: float,
    ) -> float:
        """Advance along ``axis`` (m) for the next frame, from the bone state ``alpha``, the reamer
        centre and the push impulse since the reamer was placed at ``start``."""
        if not force_n > 0.0:
            self.last_rested = False
            return 0.0
        # outside the pushes it learned the regressor reads the nearest and the push scales its advance
        learned = force_n if self.force_range_n is None else min(max(force_n, self.force_range_n[0]), self.force_range_n[1])
        direction = mirrored_anteversion_deg(anteversion_deg, self.anteversion_range_deg)
        row = feature_row(float((centre - start) @ axis), inclination_deg, direction, learned, impulse_n_s)
        predicted = float(self.regressor.predict(row)[0]) * 1e-3 * force_n / learned
        attached = attached_nodes(self.tets, alpha >= self.threshold, len(self.nodes))
        rest = advance_to_support(self.nodes[attached], centre, axis, self.teeth_radius_m, self.support_nodes)
        # no bone left to rest on: the case ends there (passed through), the regressor's advance stands
        self.last_rested = bool(np.isfinite(rest) and rest > predicted)
        return rest if self.last_rested else predicted
