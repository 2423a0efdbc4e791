"""The offscreen renderer on real EGL: both drawing paths agree, removed bone disappears, bad input is refused."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from thrsim.config import BonePatchConfig
from thrsim.errors import ThrsimInputError
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.render import BoneRenderer, ReamerView, save_png
from thrsim.render.bone import BACKGROUND

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def mesh():
    return generate_bone_patch(BonePatchConfig(element_size_mm=1.0))


@pytest.fixture(scope="module")
def renderer(mesh):
    with BoneRenderer(mesh, 320, 240, samples=0) as r:
        yield r


def reamed_state(mesh, depth_mm: float, seed: int = 0) -> np.ndarray:
    """α varying across the patch, with the elements inside a reamer sphere pushed ``depth_mm`` in removed."""
    rng = np.random.default_rng(seed)
    centroids = mesh.centroids
    alpha = (0.35 + 0.6 * rng.random(mesh.n_tets)).astype(np.float32)
    centre = np.array([0.0, 0.0, -depth_mm * 1e-3])
    alpha[np.linalg.norm(centroids - centre, axis=1) < 22.9e-3] = 0.0
    return alpha


def bone_pixels(image: np.ndarray) -> np.ndarray:
    background = np.round(np.array(BACKGROUND) * 255).astype(int)
    return np.abs(image.astype(int) - background).max(axis=2) > 3


@pytest.mark.parametrize("depth_mm", [-0.5, 0.0, 0.6])
def test_the_thesis_pipeline_and_the_boundary_faces_draw_the_same_picture(renderer, mesh, depth_mm):
    alpha = reamed_state(mesh, depth_mm)
    faces = renderer.image(alpha, method="faces")
    faces_primitives = renderer.primitives
    thesis = renderer.image(alpha, method="thesis")
    assert bone_pixels(faces).mean() > 0.2  # the patch fills a good part of the frame
    differ = np.abs(faces.astype(int) - thesis.astype(int)).max(axis=2) > 2
    assert differ.mean() < 0.005, f"{differ.mean():.4f} of the pixels differ"
    assert faces_primitives < 0.6 * renderer.primitives  # the boundary is a fraction of every tet's faces


def test_reaming_deeper_changes_the_picture_and_removed_bone_is_not_drawn(renderer, mesh):
    shallow = renderer.image(reamed_state(mesh, -0.5))
    deep = renderer.image(reamed_state(mesh, 0.6))
    assert (np.abs(shallow.astype(int) - deep.astype(int)).max(axis=2) > 10).mean() > 0.05
    gone = renderer.image(np.zeros(mesh.n_tets, dtype=np.float32))
    assert not bone_pixels(gone).any() and renderer.primitives == 0
    thesis_gone = renderer.image(np.zeros(mesh.n_tets, dtype=np.float32), method="thesis")
    assert not bone_pixels(thesis_gone).any()


def test_the_reamer_is_drawn_translucent_over_the_bone(renderer, mesh):
    alpha = reamed_state(mesh, 0.3)
    plain = renderer.image(alpha)
    axis = np.array([0.0, 0.0, -1.0])
    with_reamer = renderer.image(alpha, reamer=ReamerView(np.array([0.0, 0.0, -1.0e-3]), axis, 22.9e-3))
    changed = np.abs(plain.astype(int) - with_reamer.astype(int)).max(axis=2) > 3
    assert changed.mean() > 0.3
    # translucent: the bone's colours still show through (the picture is not one flat tint)
    assert len(np.unique(with_reamer[bone_pixels(plain)].reshape(-1, 3), axis=0)) > 50


def test_png_is_written_atomically_and_reads_back(renderer, mesh, tmp_path):
    image = renderer.image(reamed_state(mesh, 0.3))
    path = save_png(image, tmp_path / "bone.png")
    assert np.array_equal(np.asarray(Image.open(path).convert("RGB")), image)
    assert [p.name for p in tmp_path.iterdir()] == ["bone.png"]
    with pytest.raises(ThrsimInputError, match="png"):
        save_png(image, tmp_path / "bone.jpg")


def test_bad_states_and_sizes_are_refused(renderer, mesh):
    with pytest.raises(ThrsimInputError, match="elements"):
        renderer.image(np.ones(mesh.n_tets - 1))
    bad = np.ones(mesh.n_tets, dtype=np.float32)
    bad[3] = np.nan
    with pytest.raises(ThrsimInputError, match="NaN"):
        renderer.image(bad)
    with pytest.raises(ThrsimInputError, match="method"):
        renderer.image(np.ones(mesh.n_tets), method="raytrace")
    with pytest.raises(ThrsimInputError, match="image size"):
        BoneRenderer(mesh, 4, 4)
