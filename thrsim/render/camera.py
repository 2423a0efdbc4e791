"""Camera matrices (column vectors, OpenGL clip space) and framing of the bone patch."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thrsim.errors import ThrsimInputError


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """4×4 world → view matrix: the camera at ``eye`` looks at ``target`` with ``up`` upward."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    side = np.cross(forward, up)
    if np.linalg.norm(side) < 1e-9:  # looking along ``up``: any perpendicular will do
        side = np.cross(forward, np.array([1.0, 0.0, 0.0]) if abs(forward[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    side = side / np.linalg.norm(side)
    true_up = np.cross(side, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = side, true_up, -forward
    view[:3, 3] = -view[:3, :3] @ eye
    return view


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """4×4 perspective projection (symmetric frustum)."""
    f = 1.0 / np.tan(np.radians(fov_y_deg) / 2.0)
    proj = np.zeros((4, 4))
    proj[0, 0] = f / aspect
    proj[1, 1] = f
    proj[2, 2] = (far + near) / (near - far)
    proj[2, 3] = 2.0 * far * near / (near - far)
    proj[3, 2] = -1.0
    return proj


@dataclass(frozen=True)
class Camera:
    """Where the picture is taken from: ``view_direction`` is the way the camera looks."""

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y_deg: float = 30.0

    def matrix(self, aspect: float) -> np.ndarray:
        """World → clip space, float32, column-major as OpenGL reads it."""
        distance = float(np.linalg.norm(self.eye - self.target))
        proj = perspective(self.fov_y_deg, aspect, 0.05 * distance, 4.0 * distance)
        return (proj @ look_at(self.eye, self.target, self.up)).astype(np.float32)


def framing_camera(points: np.ndarray, view_direction, fov_y_deg: float = 30.0, margin: float = 1.1) -> Camera:
    """A camera looking along ``view_direction`` at the centre of ``points``, far enough back to see all of them."""
    direction = np.asarray(view_direction, dtype=np.float64).reshape(-1)
    if direction.shape != (3,) or not np.all(np.isfinite(direction)) or np.linalg.norm(direction) == 0:
        raise ThrsimInputError(f"view direction must be a finite non-zero 3-vector, got {view_direction!r}")
    direction = direction / np.linalg.norm(direction)
    points = np.asarray(points, dtype=np.float64)
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    radius = float(np.max(np.linalg.norm(points - centre, axis=1))) * margin
    distance = radius / np.sin(np.radians(fov_y_deg) / 2.0)
    up = np.array([0.0, 1.0, 0.0]) if abs(direction[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    return Camera(eye=centre - distance * direction, target=centre, up=up, fov_y_deg=fov_y_deg)
