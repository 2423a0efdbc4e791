"""The rigid acetabular reamer: a hemispherical head carrying cutting teeth.

Reamer frame: origin at the centre of the head sphere (the reamer's *position*, as in the case
files), local +z along the axis D, pointing from the reamer into the bone, so the cutting dome is
the hemisphere z ≥ 0 with its pole at (0, 0, R). Each tooth's cutting edge is an arc along a
meridian, modelled for contact as a ridge standing ``protrusion`` proud of the head
(:mod:`thrsim.physics.contact`); tooth k sits at evenly spaced polar angles φ_k and at azimuth
ψ_k = k × golden angle (137.5°), so every point of the profile between 10° and 80° from the pole
is swept by 5–6 teeth per revolution. Mass: the thesis's solid steel head, or a hollow one with a
wall thickness; teeth are not counted. The layout's numbers: the docs' Physics page (Reamer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from thrsim import portable_math as pm
from thrsim.config import ReamerConfig

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


@dataclass(frozen=True)
class ReamerGeometry:
    """Head and tooth arcs of the rigid reamer, in metres and radians, in the reamer frame."""

    head_radius: float
    edge_radius: float
    edge_axis_radius: float
    tooth_azimuth: np.ndarray  # (T,) ψ_k
    tooth_polar_start: np.ndarray  # (T,) arc start, from the pole
    tooth_polar_end: np.ndarray  # (T,) arc end
    mass_kg: float
    axial_inertia_kg_m2: float

    @property
    def tooth_count(self) -> int:
        return len(self.tooth_azimuth)

    @property
    def tooth_polar_centre(self) -> np.ndarray:
        return 0.5 * (self.tooth_polar_start + self.tooth_polar_end)

    @property
    def outer_radius(self) -> float:
        """Furthest reach of the teeth from the head centre."""
        return self.edge_axis_radius + self.edge_radius

    def tooth_points(self, samples: int = 8) -> np.ndarray:
        """(T, samples, 3) points along each edge's axis arc, for renderers and plots."""
        s = np.linspace(0.0, 1.0, samples)
        polar = self.tooth_polar_start[:, None] + s[None, :] * (self.tooth_polar_end - self.tooth_polar_start)[:, None]
        psi = self.tooth_azimuth[:, None]
        r = self.edge_axis_radius
        return np.stack([r * np.sin(polar) * np.cos(psi), r * np.sin(polar) * np.sin(psi), r * np.cos(polar)], axis=-1)


def build_reamer(config: ReamerConfig | None = None) -> ReamerGeometry:
    """Lay out the teeth and compute the head's mass from its geometry and steel density."""
    config = config or ReamerConfig()
    radius = config.head_radius
    edge_radius = config.tooth_edge_radius_mm * 1e-3
    axis_radius = radius + config.tooth_protrusion_mm * 1e-3 - edge_radius
    k = np.arange(config.tooth_count)
    first, last = math.radians(config.tooth_first_polar_deg), math.radians(config.tooth_last_polar_deg)
    centre = first + (last - first) * k / max(config.tooth_count - 1, 1)
    half_span = 0.5 * config.tooth_length_mm * 1e-3 / axis_radius
    start = np.clip(centre - half_span, 0.0, math.pi / 2)
    end = np.clip(centre + half_span, 0.0, math.pi / 2)
    azimuth = np.mod(k * GOLDEN_ANGLE, 2 * math.pi)

    inner = 0.0 if config.wall_thickness_mm is None else radius - config.wall_thickness_mm * 1e-3
    mass = config.density_kg_m3 * (2 * math.pi / 3) * (radius**3 - inner**3)
    # hemisphere (solid or shell) about its symmetry axis: I = (2/5) m (R⁵ − r⁵)/(R³ − r³)
    inertia = 0.4 * mass * (radius**5 - inner**5) / (radius**3 - inner**3)
    return ReamerGeometry(
        head_radius=radius,
        edge_radius=edge_radius,
        edge_axis_radius=axis_radius,
        tooth_azimuth=azimuth,
        tooth_polar_start=start,
        tooth_polar_end=end,
        mass_kg=mass,
        axial_inertia_kg_m2=inertia,
    )


def frame_rotation(axis: np.ndarray, spin_angle: float = 0.0) -> np.ndarray:
    """Rotation matrix taking reamer-frame vectors to the bone frame.

    Local +z maps to the unit ``axis`` D; the local x axis is the bone-frame direction
    orthogonal to D closest to +x (or +y when D ∥ x), then turned by ``spin_angle`` about D.
    """
    # elementwise sums rather than BLAS dot products: the frame feeds the solver, which must
    # give the same bits on every x86-64 machine
    d = np.asarray(axis, dtype=float)
    d = d / math.sqrt(float((d * d).sum()))
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - d * float((helper * d).sum())
    e1 /= math.sqrt(float((e1 * e1).sum()))
    e2 = np.cross(d, e1)
    c, s = pm.cos(spin_angle), pm.sin(spin_angle)
    return np.stack([c * e1 + s * e2, -s * e1 + c * e2, d], axis=1)
