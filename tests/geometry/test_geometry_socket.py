"""The layered anatomical socket at coarse element sizes: layers, node sets, materials in every format, mirror."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from checkout_cli import run_thrsim

from thrsim.config import SocketConfig
from thrsim.geometry.mesh import ARTICULAR, CANCELLOUS, CORTICAL, MEDIAL_WALL, RIM, SUPPORTED, WINDOW_SIDE
from thrsim.geometry.mesh_io import read_mesh, write_mesh
from thrsim.geometry.socket import dome_direction, fossa_axis, generate_socket, medial_wall_offset_mm

#: coarse enough for seconds, fine enough to resolve a 1 mm cortex
COARSE = SocketConfig(element_size_mm=0.9, coarse_element_size_mm=3.0)
TOL_M = 1e-8


@pytest.fixture(scope="module")
def socket():
    return generate_socket(COARSE)


def test_node_sets_lie_on_their_surfaces(socket):
    radius_mm = np.linalg.norm(socket.nodes, axis=1) * 1e3
    along_fossa_mm = socket.nodes @ fossa_axis(COARSE) * 1e3
    articular = socket.node_sets[ARTICULAR]
    # the cavity face: the articular sphere, or the fossa recess just behind it
    assert radius_mm[articular].min() >= 23.0 - 1e-5
    assert radius_mm[articular].max() <= 23.0 + COARSE.fossa_depth_mm + 1e-5
    on_sphere = np.abs(radius_mm[articular] - 23.0) < 1e-5
    assert on_sphere.mean() > 0.5 and (radius_mm[articular] > 25.9).sum() > 20  # the fossa floor is meshed
    np.testing.assert_allclose(along_fossa_mm[socket.node_sets[MEDIAL_WALL]], medial_wall_offset_mm(COARSE), atol=1e-5)
    np.testing.assert_allclose(socket.nodes[socket.node_sets[RIM], 2], 0.0, atol=TOL_M)
    assert np.array_equal(socket.fixed_nodes, socket.node_sets[SUPPORTED])
    # nothing inside the cavity, nothing above the rim, nothing beyond the medial wall
    assert radius_mm.min() >= 23.0 - 1e-5
    assert socket.nodes[:, 2].max() <= TOL_M
    assert along_fossa_mm.max() <= medial_wall_offset_mm(COARSE) + 1e-5


def _cortical_share(mesh, direction: np.ndarray, depth_mm: tuple[float, float]) -> float:
    """Share of cortical elements among those within 10° of ``direction`` and between these radii."""
    centroids = mesh.centroids * 1e3
    radius = np.linalg.norm(centroids, axis=1)
    near = centroids @ direction / radius > math.cos(math.radians(10))
    band = near & (radius > 23.0 + depth_mm[0]) & (radius < 23.0 + depth_mm[1])
    assert band.sum() > 10
    return float((mesh.element_material[band] == 0).mean())


def test_layers(socket):
    assert socket.material_names == (CORTICAL, CANCELLOUS)
    counts = socket.material_counts()
    assert counts[CORTICAL] > 1000 and counts[CANCELLOUS] > 1000
    dome = dome_direction(COARSE)
    # under the dome: the subchondral plate (2.5 mm there), then cancellous bone
    assert _cortical_share(socket, dome, (0.0, 2.0)) > 0.9
    assert _cortical_share(socket, dome, (3.5, 6.0)) < 0.1
    # the plate is thinner toward the inferior rim (about 0.9 mm): at 1.5-2.5 mm depth it is cancellous there
    inferior = np.array([0.0, -math.sin(math.radians(75)), -math.cos(math.radians(75))])
    assert _cortical_share(socket, inferior, (1.5, 2.5)) < 0.2
    # the medial cortex lies along the pelvic face behind the fossa
    along = socket.centroids @ fossa_axis(COARSE) * 1e3
    wall = medial_wall_offset_mm(COARSE)
    lateral = np.linalg.norm(socket.centroids * 1e3 - along[:, None] * fossa_axis(COARSE), axis=1)
    cortex = (along > wall - 0.5) & (lateral < 8.0)
    behind_floor = (along > 23.0 + COARSE.fossa_depth_mm + 0.8) & (along < wall - 1.5) & (lateral < 8.0)
    assert (socket.element_material[cortex] == 0).mean() > 0.9
    assert (socket.element_material[behind_floor] == 1).mean() > 0.9


def test_deterministic_and_left_is_the_mirror():
    config = SocketConfig(element_size_mm=2.0, coarse_element_size_mm=4.0)
    first, second = generate_socket(config), generate_socket(config)
    assert np.array_equal(first.nodes, second.nodes) and np.array_equal(first.tets, second.tets)
    assert np.array_equal(first.material, second.material)
    left = generate_socket(config.model_copy(update={"side": "left"}))
    np.testing.assert_array_equal(left.nodes[:, 0], -first.nodes[:, 0])
    assert np.array_equal(left.material, first.material)
    assert (left.volumes > 0).all()


@pytest.mark.parametrize("suffix", [".h5", ".vtu", ".msh", ".inp"])
def test_materials_and_node_sets_survive_every_format(tmp_path, suffix):
    mesh = generate_socket(SocketConfig(element_size_mm=2.0, coarse_element_size_mm=4.0))
    back = read_mesh(write_mesh(mesh, tmp_path / f"socket{suffix}"))
    assert back.material_names == mesh.material_names
    assert np.array_equal(back.element_material, mesh.element_material)
    assert {name: len(ids) for name, ids in back.node_sets.items()} == {name: len(ids) for name, ids in mesh.node_sets.items()}
    assert np.array_equal(back.fixed_nodes, mesh.fixed_nodes)


def test_cli_reports_materials_and_node_sets():
    result = run_thrsim("mesh", "--bone", "socket", "--element-size", "2", "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["bone"] == "socket"
    assert set(summary["materials"]) == {CORTICAL, CANCELLOUS} and min(summary["materials"].values()) > 0
    assert {ARTICULAR, MEDIAL_WALL, SUPPORTED, RIM} <= set(summary["node_sets"])


@pytest.mark.parametrize(
    "args, says",
    [
        (("--socket-diameter", "70"), "socket_diameter_mm"),
        (("--socket-diameter", "38"), "socket_diameter_mm"),
        (("--thickness", "3"), "--bone patch"),
    ],
)
def test_cli_refuses_bad_socket_settings(tmp_path, args, says):
    out = tmp_path / "socket.h5"
    result = run_thrsim("mesh", "--bone", "socket", *args, "--out", str(out))
    assert result.returncode == 2 and says in result.stderr and "Traceback" not in result.stderr
    assert not out.exists()


def test_a_layer_that_cannot_exist_is_refused():
    with pytest.raises(ValueError, match="subchondral"):
        SocketConfig(subchondral_thickness_mm=1.0, subchondral_dome_excess_mm=1.0)
    with pytest.raises(ValueError):
        SocketConfig(medial_wall_distance_mm=0.0)


@pytest.mark.parametrize(("polar", "azimuth"), [(0.0, 90.0), (45.0, 90.0), (80.0, 180.0)])
def test_a_window_is_the_socket_within_its_cone(polar, azimuth):
    """A window keeps the layered wall within its cone (nothing outside it), with its layers and its
    cut faces held apart from the supported boundary."""
    config = COARSE.model_copy(update={"window_polar_deg": polar, "window_azimuth_deg": azimuth, "window_half_angle_deg": 12.0})
    window = generate_socket(config)
    direction = np.array(config.window_direction)
    assert abs(np.linalg.norm(direction) - 1.0) < 1e-12
    cosine = window.centroids @ direction / np.linalg.norm(window.centroids, axis=1)
    assert cosine.min() >= math.cos(math.radians(12.0)) - 1e-9
    # the window's cavity face lies on the socket's, and both materials are there
    radius_mm = np.linalg.norm(window.nodes[window.node_sets[ARTICULAR]], axis=1) * 1e3
    assert radius_mm.min() >= 23.0 - 1e-5 and len(radius_mm) > 50
    assert set(np.unique(window.material)) == {0, 1}
    # its cone faces are held but are not the supported boundary a perforation goes through
    side = window.node_sets[WINDOW_SIDE]
    assert len(side) > 50
    side_cosine = window.nodes[side] @ direction / np.linalg.norm(window.nodes[side], axis=1)
    np.testing.assert_allclose(side_cosine, math.cos(math.radians(12.0)), atol=1e-6)
    assert np.isin(side, window.fixed_nodes).all() and np.isin(window.node_sets[SUPPORTED], window.fixed_nodes).all()
    whole = generate_socket(COARSE)
    assert window.n_tets < 0.2 * whole.n_tets


def test_cli_window(tmp_path):
    done = run_thrsim("mesh", "--bone", "socket", "--element-size", "0.9", "--window", "45,90,12", "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["node_sets"][WINDOW_SIDE] > 50 and summary["materials"][CORTICAL] > 0
    for bad, says in (("95,0", "polar angle"), ("45", "POLAR,AZIMUTH"), ("45,0,0", "half-angle"), ("a,b", "POLAR,AZIMUTH")):
        refused = run_thrsim("mesh", "--bone", "socket", "--window", bad, "--out", str(tmp_path / "w.msh"))
        assert refused.returncode == 2 and says in refused.stderr and "Traceback" not in refused.stderr
        assert len(refused.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "w.msh").exists()
    patch = run_thrsim("mesh", "--window", "45,0")
    assert patch.returncode == 2 and "--bone socket" in patch.stderr
