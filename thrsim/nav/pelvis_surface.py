"""The synthetic pelvis's bone surface, built procedurally around its landmarks, for the trainer pages.

The surface is the zero level of a signed distance (mm, negative inside bone) in the pelvis model
frame of :mod:`thrsim.nav.pelvis`, so the bone passes through the landmarks the trainers use. Each
bone is a smooth union of spheres sampled along curves and surfaces, with radii that vary along
them (:class:`_PelvisDistance`); the left half is the right one mirrored across x = 0, so the
pelvis is one shape for either hip. Surface nets extract the zero level (:func:`_surface_nets`):
a closed surface of a few thousand triangles with smooth normals. Pure numerics;
:func:`surface_payload` is the binary form ``GET /api/pelvis`` serves.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import cache

import numpy as np
from scipy.spatial import cKDTree

from thrsim.nav.bone_frame import on_side
from thrsim.nav.pelvis import ACETABULUM_CENTRE_RIGHT, native_axis_right, synthetic_pelvis_landmarks

#: radius of the drawn acetabular socket (a 46 mm native socket, the layered socket's default)
SOCKET_RADIUS_MM = 23.0
#: the rim's flat face reaches at least this far from the socket's axis (the rim landmarks: 26 mm)
RIM_MM = 28.0
#: grid step of the surface extraction: sets the triangle count (about 3 × area / step²)
GRID_MM = 8.0
#: the surface is extracted this far outside the bone, then moved onto it: a plate thinner than
#: the grid step (the iliac wing, the rami) keeps its two faces in separate grid cells
INFLATE_MM = 3.0
#: fillet radius where two bones meet
BLEND_MM = 6.0
PAYLOAD_MAGIC = b"THRP"
PAYLOAD_VERSION = 1

_NEAREST = 4  # sphere centres consulted per point (radii vary slowly along a part)
_FAR_MM = 12.0  # farther from a part's surface than this, its distance is not needed


@dataclass(frozen=True)
class PelvisSurface:
    """A closed triangle surface in the pelvis model frame: vertices (V, 3) and normals (V, 3) in
    metres and unit vectors, triangles (T, 3) counter-clockwise seen from outside."""

    vertices: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray


def _spline(points: list[tuple[float, float, float]], samples: int) -> np.ndarray:
    """A Catmull-Rom curve through ``points`` (mm), ``samples`` points along it."""
    p = np.asarray(points, dtype=float)
    p = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    t = np.linspace(0.0, len(points) - 1.0, samples)
    i = np.minimum(t.astype(int), len(points) - 2)
    s = (t - i)[:, None]
    p0, p1, p2, p3 = p[i], p[i + 1], p[i + 2], p[i + 3]
    return 0.5 * (2 * p1 + (p2 - p0) * s + (2 * p0 - 5 * p1 + 4 * p2 - p3) * s**2 + (3 * p1 - p0 - 3 * p2 + p3) * s**3)


def _strand(points: list[tuple[float, float, float]], radii: list[float], step_mm: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Spheres along a smooth curve, their radii interpolated between the given ones."""
    rough = _spline(points, 200)
    length = float(np.linalg.norm(np.diff(rough, axis=0), axis=1).sum())
    n = max(8, int(length / step_mm))
    centres = _spline(points, n)
    radius = np.interp(np.linspace(0, 1, n), np.linspace(0, 1, len(radii)), radii)
    return centres, radius


def _sheet(lower: np.ndarray, upper: np.ndarray, bulge: np.ndarray, half_thickness, step_mm: float = 2.0):
    """Spheres over a surface lofted from ``lower`` to ``upper`` (same sample count), pushed along
    ``bulge`` (mm, full at mid-height); ``half_thickness(u, v)`` gives the radius (u along, v up)."""
    height = float(np.max(np.linalg.norm(upper - lower, axis=1)))
    rows = max(8, int(height / step_mm))
    v = np.linspace(0.0, 1.0, rows)[:, None, None]
    u = np.linspace(0.0, 1.0, len(lower))[None, :, None]
    surface = (1 - v) * lower[None] + v * upper[None] + np.sin(np.pi * v) * bulge
    radius = half_thickness(u[..., 0] + 0 * v[..., 0], v[..., 0] + 0 * u[..., 0])
    return surface.reshape(-1, 3), radius.ravel()


def _smooth_union(a: np.ndarray, b: np.ndarray, k: float = BLEND_MM) -> np.ndarray:
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return np.minimum(a, b) - h * h * k / 4.0


def _smooth_intersection(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    return -_smooth_union(-a, -b, k)


class _Spheres:
    """The signed distance of a union of spheres (approximately: the nearest few centres)."""

    def __init__(self, centres: np.ndarray, radii: np.ndarray):
        near_midline = centres[:, 0] < radii + _FAR_MM  # their mirrors reach the right half
        self.tree = cKDTree(np.vstack([centres, on_side(centres[near_midline], "left")]))
        self.radii = np.concatenate([radii, radii[near_midline]])
        self.reach = float(radii.max()) + _FAR_MM

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Beyond :data:`_FAR_MM` of the part: that distance (only the sign matters that far out)."""
        distance, index = self.tree.query(points, k=_NEAREST, distance_upper_bound=self.reach)
        found = index < len(self.radii)
        gap = np.where(found, distance - self.radii[np.where(found, index, 0)], _FAR_MM)
        return np.min(gap, axis=1)


class _PelvisDistance:
    """The signed distance (mm) of the whole pelvis at points (…, 3) in mm, model frame.

    * ilium: a wing lofted between the iliac crest (ASIS, tubercle, posterior crest, PSIS) and its
      lower border (AIIS, the roof over the acetabulum, the greater sciatic notch), bulging
      laterally (the gluteal surface) and thickest along the crest;
    * the acetabular body: a ball behind the socket, cut flat at the rim's plane (through the
      acetabular centre, across the native opening axis of :mod:`thrsim.nav.pelvis`) where the rim
      landmarks lie; the socket itself is a hemisphere of :data:`SOCKET_RADIUS_MM` open to the
      camera along that axis;
    * ischium: the posterior column down to the tuberosity, the ischial spine, the ischial ramus;
    * pubis: the superior and inferior rami around the obturator foramen, the body at the symphysis;
    * and the sacrum between the iliac wings.

    Parts meet through smooth minima (fillets of a few millimetres); the distance is evaluated at
    |x|, so the left half mirrors the right.
    """

    def __init__(self):
        lm = synthetic_pelvis_landmarks("right")

        def under(name: str, outward: tuple[float, float, float], depth: float) -> tuple[float, float, float]:
            """A part's centre line ``depth`` (its radius there) beneath a landmark, so its surface
            passes through the landmark facing ``outward``."""
            direction = np.asarray(outward) / np.linalg.norm(outward)
            return tuple(float(c) for c in lm[name] * 1e3 - depth * direction)  # type: ignore[return-value]

        centre = ACETABULUM_CENTRE_RIGHT * 1e3
        self.centre = centre
        self.axis = native_axis_right()
        lateral_bulge = np.array([9.0, 2.0, 0.0])
        crest = _spline(
            [
                under("asis_right", (0.0, 1.0, 0.1), 7.0),
                under("iliac_tubercle_right", (0.6, 0.0, 0.8), 8.0),
                under("iliac_crest_posterior_right", (0.0, -0.3, 0.95), 7.0),
                under("psis_right", (0.0, -0.9, 0.4), 7.0),
            ],
            120,
        )
        lower = _spline(
            [
                under("aiis_right", (0.3, 0.95, 0.0), 7.5),
                (94.0, -50.0, -30.0),
                (74.0, -96.0, -24.0),
                (56.0, -136.0, -8.0),
                (46.0, -158.0, 8.0),
            ],
            120,
        )
        spine_from = np.array([74.0, -80.0, -70.0])
        tuberosity = under("ischial_tuberosity", (0.0, -0.3, -0.95), 12.0)
        wing = _sheet(
            lower,
            crest,
            lateral_bulge,
            lambda u, v: 4.5 + 2.5 * v**4 + 3.0 * (1 - v) ** 3 + 1.5 * np.exp(-(((u - 0.25) / 0.12) ** 2)) * v**6,
        )
        self.parts = [
            _Spheres(*wing),
            # the acetabular body and the ilium's thick body above it, to the sciatic notch
            _Spheres(*_strand([tuple(centre - 6.0 * self.axis), (88.0, -62.0, -28.0), (70.0, -110.0, -14.0)], [31.0, 14.0, 10.0])),
            # ischium: posterior column, tuberosity, ramus forward to the inferior pubic ramus
            _Spheres(*_strand([(82.0, -66.0, -62.0), (72.0, -82.0, -92.0), (70.0, -74.0, -110.0), tuberosity], [12.0, 10.0, 11.0, 12.0])),
            _Spheres(*_strand([tuple(spine_from), under("ischial_spine", tuple(lm["ischial_spine"] * 1e3 - spine_from), 2.5)], [6.0, 2.5])),
            _Spheres(*_strand([tuberosity, (52.0, -48.0, -122.0), (30.0, -22.0, -116.0), (10.0, -12.0, -106.0)], [10.0, 6.5, 6.5, 9.0])),
            # pubis: superior ramus from the acetabulum to the tubercle, the body at the symphysis
            _Spheres(
                *_strand(
                    [(82.0, -14.0, -70.0), (52.0, -8.0, -82.0), under("pubic_right", (0.0, 1.0, 0.0), 8.0), (5.0, -14.0, -94.0)],
                    [11.0, 8.0, 8.0, 9.0],
                )
            ),
            _Spheres(*_strand([(5.0, -14.0, -92.0), (5.0, -14.0, -104.0)], [9.0, 9.0])),
            # sacrum: a plate concave forward between the wings, narrowing to the coccyx
            _Spheres(*self._sacrum()),
        ]

    @staticmethod
    def _sacrum() -> tuple[np.ndarray, np.ndarray]:
        v = np.linspace(0.0, 1.0, 70)[:, None]
        u = np.linspace(-1.0, 1.0, 45)[None, :]
        half_width = 50.0 * (1 - v) + 8.0 * v
        x = u * half_width
        y = -128.0 - 40.0 * v + 22.0 * v**2 - 6.0 * u**2
        z = 32.0 - 108.0 * v
        centres = np.stack(np.broadcast_arrays(x, y, z), axis=-1).reshape(-1, 3)
        radius = np.broadcast_to(13.0 * (1 - v) + 4.0 * v - 4.0 * u**2 * (1 - v), x.shape).ravel()
        keep = centres[:, 0] >= 0.0  # each sphere and its mirror: the right half suffices
        return centres[keep], radius[keep]

    def socket(self, points: np.ndarray) -> np.ndarray:
        """Distance to the open socket: the hemisphere below the rim plane, a cylinder beyond it,
        and the rim's flat face (out to :data:`RIM_MM`) clear of any other bone."""
        offset = points - self.centre
        along = offset @ self.axis
        radial = np.linalg.norm(offset - along[:, None] * self.axis, axis=1)
        hemisphere = np.where(along > 0.0, radial, np.linalg.norm(offset, axis=1)) - SOCKET_RADIUS_MM
        above_rim = np.maximum(radial - RIM_MM, -along)
        return np.minimum(hemisphere, above_rim)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        right = np.abs(points[:, 0])
        mirrored = np.column_stack([right, points[:, 1], points[:, 2]])
        parts = [part(mirrored) for part in self.parts]
        # the acetabular body ends at the rim's plane (a rounded edge)
        rim_plane = (mirrored - self.centre) @ self.axis
        parts[1] = _smooth_intersection(parts[1], rim_plane, 3.0)
        bone = parts[0]
        for part in parts[1:]:
            bone = _smooth_union(bone, part)
        return _smooth_intersection(bone, -self.socket(mirrored), 2.0)


def _surface_nets(distance, lower: np.ndarray, upper: np.ndarray, step: float):
    """Vertices (mm) and quads of the zero level of ``distance`` over the box, grid ``step``: one
    vertex per cell the surface crosses, moved onto the surface along the distance's gradient, and
    one quad per crossed grid edge."""
    axes = [np.arange(lo, hi + step, step) for lo, hi in zip(lower, upper, strict=True)]
    shape = tuple(len(a) for a in axes)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    values = distance(grid.reshape(-1, 3)).reshape(shape)
    inside = values < 0.0
    cells = np.array(shape) - 1
    # per cell: the mean of its edges' zero crossings
    total = np.zeros((*cells, 3))
    count = np.zeros(tuple(cells))
    corners = [(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    for a in corners:
        for b in corners:
            if sum(bb - aa for aa, bb in zip(a, b, strict=True)) != 1 or any(bb < aa for aa, bb in zip(a, b, strict=True)):
                continue
            sa = tuple(slice(o, o + n) for o, n in zip(a, cells, strict=True))
            sb = tuple(slice(o, o + n) for o, n in zip(b, cells, strict=True))
            fa, fb = values[sa], values[sb]
            crosses = (fa < 0.0) != (fb < 0.0)
            t = np.where(crosses, fa / np.where(crosses, fa - fb, 1.0), 0.0)
            point = grid[sa] + t[..., None] * (grid[sb] - grid[sa])
            total += np.where(crosses[..., None], point, 0.0)
            count += crosses
    active = count > 0
    index = np.full(tuple(cells), -1, dtype=np.int64)
    index[active] = np.arange(int(active.sum()))
    vertices = total[active] / count[active][:, None]
    quads = []
    for axis in range(3):
        # grid edges along ``axis`` that cross, away from the box's faces: four cells around each
        low, high = [slice(None)] * 3, [slice(None)] * 3
        low[axis], high[axis] = slice(0, -1), slice(1, None)
        crosses = inside[tuple(low)] != inside[tuple(high)]
        outward = inside[tuple(low)]  # the bone on the low side: the face looks toward +axis
        others = [(axis + 1) % 3, (axis + 2) % 3]  # (u, w, axis) right-handed: the quad turns about +axis
        edge = np.argwhere(crosses)
        ok = np.all([(edge[:, d] >= 1) & (edge[:, d] < cells[d]) for d in others], axis=0)
        edge = edge[ok]
        facing_up = outward[tuple(edge.T)]
        u, w = others
        around = []
        for du, dw in ((0, 0), (1, 0), (1, 1), (0, 1)):
            cell = edge.copy()
            cell[:, u] -= 1 - du
            cell[:, w] -= 1 - dw
            around.append(index[tuple(cell.T)])
        quad = np.stack(around, axis=1)
        quad[~facing_up] = quad[~facing_up][:, ::-1]
        quads.append(quad)
    return vertices, np.vstack(quads)


def _value_and_gradient(distance, points: np.ndarray, h: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """The distance at the points and its forward-difference gradient, in one evaluation."""
    steps = np.vstack([np.zeros(3), np.eye(3) * h])
    values = distance((points[None] + steps[:, None]).reshape(-1, 3)).reshape(4, -1)
    return values[0], ((values[1:] - values[0]) / h).T


@cache
def pelvis_surface(grid_mm: float = GRID_MM) -> PelvisSurface:
    """The pelvis's surface (computed once per grid step: about a second)."""
    distance = _PelvisDistance()
    inflated = lambda points: distance(points) - INFLATE_MM  # noqa: E731
    vertices, quads = _surface_nets(inflated, np.array([-150.0, -200.0, -145.0]), np.array([150.0, 35.0, 100.0]), grid_mm)
    for _ in range(2):  # onto the bone along the gradient (the second step's gradient: the normals)
        value, gradient = _value_and_gradient(distance, vertices)
        vertices = vertices - (value / np.maximum(np.sum(gradient**2, axis=1), 1e-9))[:, None] * gradient
    normals = gradient / np.maximum(np.linalg.norm(gradient, axis=1), 1e-12)[:, None]
    # each quad as two triangles across its shorter diagonal
    a, b, c, d = (vertices[quads[:, k]] for k in range(4))
    short = np.linalg.norm(a - c, axis=1) <= np.linalg.norm(b - d, axis=1)
    first = np.where(short[:, None], quads[:, [0, 1, 2]], quads[:, [0, 1, 3]])
    second = np.where(short[:, None], quads[:, [0, 2, 3]], quads[:, [1, 2, 3]])
    triangles = np.vstack([first, second])
    return PelvisSurface(vertices=vertices * 1e-3, normals=normals, triangles=triangles.astype(np.int64))


def surface_payload(surface: PelvisSurface) -> bytes:
    """``b"THRP"``, u32 version, u32 vertices, u32 triangles, then vertices (V×3 f32, m, model
    frame), normals (V×3 f32) and triangles (T×3 u32), little-endian."""
    header = PAYLOAD_MAGIC + struct.pack("<III", PAYLOAD_VERSION, len(surface.vertices), len(surface.triangles))
    return (
        header
        + np.ascontiguousarray(surface.vertices, dtype="<f4").tobytes()
        + np.ascontiguousarray(surface.normals, dtype="<f4").tobytes()
        + np.ascontiguousarray(surface.triangles, dtype="<u4").tobytes()
    )
