"""Pictures of the bone being reamed: the remaining tets coloured by α, the reamer's dome over them.

:class:`BoneRenderer` keeps one mesh on the GPU and draws any α state of it, by the thesis's
geometry-shader pipeline (``method="thesis"``) or by the boundary faces only (``"faces"``, the
default); see :mod:`thrsim.render.shaders`. Coordinates go to the GPU in millimetres (the
screen-space derivatives that light the faces stay well inside float32 there).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from thrsim.atomic import atomic_path
from thrsim.errors import ThrsimInputError
from thrsim.geometry.adjacency import exposed_faces
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.tet_metrics import TET_FACES
from thrsim.render import shaders
from thrsim.render.camera import Camera, framing_camera
from thrsim.render.context import offscreen_context

Method = Literal["faces", "thesis"]
BACKGROUND = (0.97, 0.97, 0.97)
#: α at which the colour map starts; removed elements (α below the threshold) are not drawn
ALPHA_LOW = 0.3
_ALPHA_TEXTURE_WIDTH = 1024


@dataclass(frozen=True)
class ReamerView:
    """The reamer as drawn: its head centre (m), cutting direction D and the teeth's reach (m)."""

    centre: np.ndarray
    axis: np.ndarray
    radius_m: float


def colour_lookup(name: str = "viridis") -> np.ndarray:
    """(256, 3) uint8 colour map for α from the threshold (first texel) to 1 (last)."""
    from matplotlib import colormaps

    return (np.asarray(colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3]) * 255.0 + 0.5).astype(np.uint8)


def dome(centre_mm: np.ndarray, axis: np.ndarray, radius_mm: float, rings: int = 16, segments: int = 48) -> np.ndarray:
    """Triangles (T, 3, 3) of the reamer's cutting hemisphere: pole at centre + radius·D."""
    axis = axis / np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    polar = np.linspace(0.0, 0.5 * np.pi, rings + 1)
    azimuth = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    grid = centre_mm + radius_mm * (
        np.sin(p)[..., None] * (np.cos(a)[..., None] * e1 + np.sin(a)[..., None] * e2) + np.cos(p)[..., None] * axis
    )
    quads = np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]], axis=2)
    return np.concatenate([quads[:, :, [0, 1, 2]], quads[:, :, [0, 2, 3]]]).reshape(-1, 3, 3)


class BoneRenderer:
    """One mesh on an offscreen OpenGL context; :meth:`image` draws an α state of it."""

    def __init__(self, mesh: TetMesh, width: int = 800, height: int = 600, threshold: float = 0.3, samples: int = 4):
        if not (16 <= width <= 8192 and 16 <= height <= 8192):
            raise ThrsimInputError(f"image size must lie in 16..8192 pixels a side, got {width}×{height}")
        self.mesh = mesh
        self.width, self.height = int(width), int(height)
        self.threshold = float(threshold)
        import moderngl

        self.ctx = offscreen_context()
        ctx = self.ctx
        self._nodes_mm = np.ascontiguousarray(mesh.nodes * 1e3, dtype=np.float32)
        self._tets = np.ascontiguousarray(mesh.tets, dtype=np.int32)
        self._colour_map = ctx.texture((256, 1), 3, colour_lookup().tobytes())
        self._colour_map.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._faces_program = ctx.program(vertex_shader=shaders.FACES_VERTEX, fragment_shader=shaders.FRAGMENT)
        self._thesis_program = ctx.program(
            vertex_shader=shaders.THESIS_VERTEX, geometry_shader=shaders.THESIS_GEOMETRY, fragment_shader=shaders.FRAGMENT
        )
        self._reamer_program = ctx.program(vertex_shader=shaders.REAMER_VERTEX, fragment_shader=shaders.REAMER_FRAGMENT)
        self._node_buffer = ctx.buffer(self._nodes_mm.tobytes())
        self._tet_buffer = ctx.buffer(self._tets.tobytes())
        self._tet_array = ctx.vertex_array(
            self._thesis_program, [(self._node_buffer, "3f", "in_position")], index_buffer=self._tet_buffer, index_element_size=4
        )
        rows = -(-mesh.n_tets // _ALPHA_TEXTURE_WIDTH)
        self._alpha_texture = ctx.texture((_ALPHA_TEXTURE_WIDTH, rows), 1, dtype="f4")
        self._alpha_texels = np.zeros(_ALPHA_TEXTURE_WIDTH * rows, dtype=np.float32)
        colour = ctx.renderbuffer((self.width, self.height), 4, samples=samples)
        depth = ctx.depth_renderbuffer((self.width, self.height), samples=samples)
        self._draw_target = ctx.framebuffer(colour, depth)
        self._resolved = ctx.framebuffer(ctx.renderbuffer((self.width, self.height), 4)) if samples else self._draw_target
        self.primitives = 0  # triangles submitted by the last image (faces) or emitted at most (thesis)

    # ------------------------------------------------------------------ drawing
    def default_camera(self, axis=None) -> Camera:
        """Look into the cavity along the reamer axis D (default: along −z, from the surgeon's side)."""
        direction = np.array([0.0, 0.0, -1.0]) if axis is None else np.asarray(axis, dtype=np.float64)
        return framing_camera(self._nodes_mm, direction)

    def image(
        self, alpha: np.ndarray, camera: Camera | None = None, method: Method = "faces", reamer: ReamerView | None = None
    ) -> np.ndarray:
        """(height, width, 3) uint8 picture of the elements with α ≥ threshold."""
        alpha = np.asarray(alpha, dtype=np.float32).reshape(-1)
        if alpha.shape != (self.mesh.n_tets,):
            raise ThrsimInputError(f"α has {alpha.size} values, the mesh {self.mesh.n_tets} elements")
        if not np.all(np.isfinite(alpha)):
            raise ThrsimInputError("α holds NaN or infinite values")
        camera = camera or self.default_camera(None if reamer is None else reamer.axis)
        mvp = camera.matrix(self.width / self.height)
        towards_camera = (camera.eye - camera.target) / np.linalg.norm(camera.eye - camera.target)
        ctx = self.ctx
        self._draw_target.use()
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.BLEND)
        self._draw_target.clear(*BACKGROUND, 1.0, depth=1.0)
        self._colour_map.use(location=0)
        if method == "thesis":
            self._draw_thesis(alpha, mvp, towards_camera)
        elif method == "faces":
            self._draw_faces(alpha, mvp, towards_camera)
        else:
            raise ThrsimInputError(f"unknown drawing method {method!r}: choose faces or thesis")
        if reamer is not None:
            self._draw_reamer(reamer, mvp, towards_camera)
        if self._resolved is not self._draw_target:
            ctx.copy_framebuffer(self._resolved, self._draw_target)
        raw = self._resolved.read(components=3, alignment=1)
        return np.flipud(np.frombuffer(raw, dtype=np.uint8).reshape(self.height, self.width, 3)).copy()

    def _shared_uniforms(self, program, mvp: np.ndarray, towards_camera: np.ndarray) -> None:
        program["mvp"].write(mvp.T.tobytes())
        program["light_direction"].value = tuple(float(v) for v in towards_camera)
        if "colour_map" in program:
            program["colour_map"].value = 0
            program["alpha_low"].value = ALPHA_LOW

    def _draw_thesis(self, alpha: np.ndarray, mvp: np.ndarray, towards_camera: np.ndarray) -> None:
        program = self._thesis_program
        self._alpha_texels[: len(alpha)] = alpha
        self._alpha_texture.write(self._alpha_texels.tobytes())
        self._alpha_texture.use(location=1)
        self._shared_uniforms(program, mvp, towards_camera)
        program["alpha_texture"].value = 1
        program["alpha_width"].value = _ALPHA_TEXTURE_WIDTH
        program["threshold"].value = self.threshold
        self._tet_array.render(self.ctx.LINES_ADJACENCY)
        self.primitives = 4 * int(np.count_nonzero(alpha >= self.threshold))

    def _draw_faces(self, alpha: np.ndarray, mvp: np.ndarray, towards_camera: np.ndarray) -> None:
        tet, face = exposed_faces(self.mesh.adjacency, alpha >= self.threshold)
        self.primitives = int(len(tet))
        if len(tet) == 0:
            return
        corners = self._nodes_mm[self._tets[tet[:, None], TET_FACES[face]]]  # (F, 3, 3)
        vertices = np.empty((len(tet), 3, 4), dtype=np.float32)
        vertices[:, :, :3] = corners
        vertices[:, :, 3] = alpha[tet][:, None]
        buffer = self.ctx.buffer(vertices.tobytes())
        program = self._faces_program
        self._shared_uniforms(program, mvp, towards_camera)
        array = self.ctx.vertex_array(program, [(buffer, "3f 1f", "in_position", "in_alpha")])
        array.render(self.ctx.TRIANGLES)
        array.release()
        buffer.release()

    def _draw_reamer(self, reamer: ReamerView, mvp: np.ndarray, towards_camera: np.ndarray) -> None:
        """A translucent dome: the cavity under it stays visible."""
        axis = np.asarray(reamer.axis, dtype=np.float64)
        triangles = dome(np.asarray(reamer.centre, dtype=np.float64) * 1e3, axis, reamer.radius_m * 1e3).astype(np.float32)
        ctx = self.ctx
        ctx.enable(ctx.BLEND)
        ctx.blend_func = ctx.SRC_ALPHA, ctx.ONE_MINUS_SRC_ALPHA
        ctx.depth_mask = False
        program = self._reamer_program
        program["mvp"].write(mvp.T.tobytes())
        program["light_direction"].value = tuple(float(v) for v in towards_camera)
        program["tint"].value = (0.62, 0.64, 0.68, 0.28)
        buffer = ctx.buffer(triangles.tobytes())
        array = ctx.vertex_array(program, [(buffer, "3f", "in_position")])
        array.render(ctx.TRIANGLES)
        array.release()
        buffer.release()
        ctx.depth_mask = True
        ctx.disable(ctx.BLEND)

    # ------------------------------------------------------------------ lifetime
    def release(self) -> None:
        self.ctx.release()

    def __enter__(self) -> BoneRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def save_png(image: np.ndarray, path: str | os.PathLike) -> Path:
    """Write an (H, W, 3) uint8 image as PNG, atomically."""
    from PIL import Image

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ThrsimInputError(f"{path}: give a .png name")
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(tmp, format="PNG")
    return path
