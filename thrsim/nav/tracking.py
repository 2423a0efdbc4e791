"""Optical tracking model: a camera's truncated-pyramid volume, marker visibility, occluders, noise.

The camera frame has +z along the view axis, x to the right, y down (a vision convention); poses
are ``T_world←camera`` and ``T_world←tool`` in metres. When a tool counts as tracked:
:class:`TrackingCamera`. Pure numerics, no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from thrsim.config import TrackingVolumeConfig
from thrsim.errors import ThrsimInputError
from thrsim.nav.rigid import check_pose, invert, rigid_fit, transform_points

# Ordered by what a trainee must fix first: move into the volume, then turn the tool, then clear
# the view.
REASONS: tuple[str, ...] = ("tracked", "outside_volume", "angle", "occluded")


@dataclass(frozen=True)
class Sphere:
    centre: np.ndarray
    radius: float

    def blocks(self, start: np.ndarray, end: np.ndarray) -> bool:
        """Whether the segment start→end passes through the sphere."""
        segment = end - start
        length2 = float(segment @ segment)
        along = 0.0 if length2 == 0.0 else float(np.clip((self.centre - start) @ segment / length2, 0.0, 1.0))
        return bool(np.linalg.norm(start + along * segment - self.centre) < self.radius)


@dataclass(frozen=True)
class Box:
    """Axis-aligned box in world coordinates (an arm, a lamp, a drape stand)."""

    minimum: np.ndarray
    maximum: np.ndarray

    def blocks(self, start: np.ndarray, end: np.ndarray) -> bool:
        """Slab test of the segment start→end against the box."""
        direction = end - start
        t_low, t_high = 0.0, 1.0
        for k in range(3):
            if abs(direction[k]) < 1e-15:
                if not self.minimum[k] <= start[k] <= self.maximum[k]:
                    return False
                continue
            t1 = (self.minimum[k] - start[k]) / direction[k]
            t2 = (self.maximum[k] - start[k]) / direction[k]
            t_low, t_high = max(t_low, min(t1, t2)), min(t_high, max(t1, t2))
            if t_low > t_high:
                return False
        return True


Occluder = Sphere | Box


@dataclass(frozen=True)
class ToolGeometry:
    """A rigid marker array: marker positions and mount normal in the tool frame (m).

    ``tip`` is the point of interest in the tool frame (probe tip, reamer head centre).
    """

    name: str
    markers: np.ndarray
    mount_normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    tip: np.ndarray = field(default_factory=lambda: np.zeros(3))


def _planar_array(spread: float) -> np.ndarray:
    # Asymmetric so the pose fit is unique, as on real passive arrays.
    return np.array([[0.0, 0.0, 0.0], [spread, 0.0, 0.0], [0.0, 1.4 * spread, 0.0], [0.6 * spread, 1.8 * spread, 0.0]]) - [
        0.4 * spread,
        0.8 * spread,
        0.0,
    ]


REFERENCE_FRAME = ToolGeometry("Reference", _planar_array(0.06))
PROBE = ToolGeometry("Probe", _planar_array(0.05), tip=np.array([0.0, -0.15, 0.0]))
REAMER = ToolGeometry("Reamer", _planar_array(0.06), tip=np.array([0.0, 0.0, -0.25]))


@dataclass(frozen=True)
class Visibility:
    tracked: bool
    reason: str  # one of REASONS
    angle_deg: float  # between mount normal and line of sight
    markers_inside: int

    def as_dict(self) -> dict:
        return {"tracked": self.tracked, "reason": self.reason, "angle_deg": self.angle_deg, "markers_inside": self.markers_inside}


@dataclass(frozen=True)
class TrackedSample:
    time_s: float
    visibility: Visibility
    pose: np.ndarray | None  # measured T_world←tool, None when not tracked


def look_at(position: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world←camera`` for a camera at ``position`` viewing ``target`` (y down ≈ −up)."""
    eye, centre, up_axis = (np.asarray(v, dtype=float) for v in (position, target, up))
    view = centre - eye
    if np.linalg.norm(view) == 0.0:
        raise ThrsimInputError("camera position and target coincide")
    view /= np.linalg.norm(view)
    right = np.cross(view, up_axis)
    if np.linalg.norm(right) < 1e-9:
        raise ThrsimInputError("camera up vector is parallel to the view direction")
    right /= np.linalg.norm(right)
    down = np.cross(view, right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, down, view])
    pose[:3, 3] = eye
    return pose


class TrackingCamera:
    """An optical tracker like an NDI Polaris Vega, with an adjustable pose.

    A tool is tracked when every marker lies inside the volume (depth between the near and far
    faces, lateral extents growing linearly from the near face to the far face), the angle between
    the tool's mount normal and its line of sight to the camera is at most
    ``max_marker_angle_deg`` (flat passive markers fade beyond ~45°), and no occluder cuts the line
    of sight from the camera's centre to any marker (a bar camera's two lenses, ~0.5 m apart,
    folded into one viewpoint).
    """

    def __init__(self, config: TrackingVolumeConfig = TrackingVolumeConfig(), pose: np.ndarray | None = None, seed: int | None = 0):
        self.config = config
        self.pose = check_pose(np.eye(4) if pose is None else pose, "camera pose")
        self._rng = np.random.default_rng(seed)

    @property
    def position(self) -> np.ndarray:
        return self.pose[:3, 3]

    @property
    def view_axis(self) -> np.ndarray:
        return self.pose[:3, 2]

    def contains(self, points_world: np.ndarray) -> np.ndarray:
        """Boolean mask: which world points (N×3, m) lie inside the tracking volume."""
        c = self.config
        local = transform_points(invert(self.pose), np.atleast_2d(points_world))
        depth = local[:, 2]
        near, far = c.near_mm / 1e3, c.far_mm / 1e3  # division keeps 950 mm exactly 0.95 m
        fraction = (depth - near) / (far - near)
        half_width = (c.near_half_width_mm + fraction * (c.far_half_width_mm - c.near_half_width_mm)) / 1e3
        half_height = (c.near_half_height_mm + fraction * (c.far_half_height_mm - c.near_half_height_mm)) / 1e3
        return (depth >= near) & (depth <= far) & (np.abs(local[:, 0]) <= half_width) & (np.abs(local[:, 1]) <= half_height)

    def observe(self, tool: ToolGeometry, tool_pose: np.ndarray, occluders: Sequence[Occluder] = ()) -> Visibility:
        """Whether ``tool`` at ``tool_pose`` (T_world←tool) is tracked, and if not, why."""
        tool_pose = check_pose(tool_pose, f"{tool.name} pose")
        markers = transform_points(tool_pose, tool.markers)
        inside = int(self.contains(markers).sum())
        normal = tool_pose[:3, :3] @ tool.mount_normal
        sight = self.position - markers.mean(axis=0)
        cosine = float(normal @ sight / (np.linalg.norm(normal) * np.linalg.norm(sight)))
        angle = float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
        if inside < len(markers):
            reason = "outside_volume"
        elif angle > self.config.max_marker_angle_deg:
            reason = "angle"
        elif any(o.blocks(self.position, m) for o in occluders for m in markers):
            reason = "occluded"
        else:
            reason = "tracked"
        return Visibility(tracked=reason == "tracked", reason=reason, angle_deg=angle, markers_inside=inside)

    def measure(self, tool: ToolGeometry, tool_pose: np.ndarray) -> np.ndarray:
        """A noisy measured pose: Gaussian noise on each marker (3-D RMS = ``noise_rms_mm``),
        then the rigid fit of the array to the noisy markers, as a real tracker solves it."""
        tool_pose = check_pose(tool_pose, f"{tool.name} pose")
        markers = transform_points(tool_pose, tool.markers)
        sigma = self.config.noise_rms_mm * 1e-3 / np.sqrt(3.0)
        if sigma == 0.0:
            return tool_pose
        noisy = markers + self._rng.normal(0.0, sigma, markers.shape)
        return rigid_fit(tool.markers, noisy).pose

    def track(
        self,
        tool: ToolGeometry,
        trajectory: Callable[[float], np.ndarray],
        duration_s: float,
        occluders: Sequence[Occluder] = (),
    ) -> Iterator[TrackedSample]:
        """Samples at the camera rate of a tool moving along ``trajectory(t) -> T_world←tool``."""
        count = int(np.floor(duration_s * self.config.rate_hz)) + 1
        for index in range(count):
            time_s = index / self.config.rate_hz
            pose = trajectory(time_s)
            visibility = self.observe(tool, pose, occluders)
            yield TrackedSample(time_s, visibility, self.measure(tool, pose) if visibility.tracked else None)
