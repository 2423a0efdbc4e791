"""The gmsh acetabular patch at a coarse element size: node sets, orientation, determinism, mirror."""

from __future__ import annotations

import math

import numpy as np
import pytest
from checkout_cli import checkout_env
from geometry_helpers import COARSE_MM

from thrsim.config import BonePatchConfig
from thrsim.geometry.bone_patch import generate_bone_patch
from thrsim.geometry.mesh import INNER, OUTER, SIDE

TOL_M = 1e-9  # gmsh puts boundary nodes on the exact OpenCASCADE surfaces, then snapped to a 1 nm grid
#: the grid moves a node by ≤ √3/2 nm, ≤ 2.3e-6° seen from the centre 22 mm away
TOL_DEG = 5e-6


def polar_from_minus_z_deg(points):
    return np.degrees(np.arccos(-points[:, 2] / np.linalg.norm(points, axis=1)))


def test_node_sets_lie_on_their_surfaces(coarse_patch):
    mesh = coarse_patch
    radius = np.linalg.norm(mesh.nodes, axis=1)
    assert set(mesh.node_sets) == {INNER, OUTER, SIDE}
    np.testing.assert_allclose(radius[mesh.node_sets[OUTER]], 24e-3, atol=TOL_M)
    np.testing.assert_allclose(radius[mesh.node_sets[INNER]], 22e-3, atol=TOL_M)
    np.testing.assert_allclose(polar_from_minus_z_deg(mesh.nodes[mesh.node_sets[SIDE]]), 19.0, atol=TOL_DEG)
    # every node inside the shell and the cone; the patch sits around −z
    assert radius.min() >= 22e-3 - TOL_M and radius.max() <= 24e-3 + TOL_M
    assert polar_from_minus_z_deg(mesh.nodes).max() <= 19.0 + TOL_DEG
    assert np.all(mesh.nodes[:, 2] < 0)
    # the pole of both spheres is meshed: surfaces are complete, not just rims
    assert len(mesh.node_sets[INNER]) > 50 and len(mesh.node_sets[OUTER]) > 50


def test_volumes_positive_and_total_volume(coarse_patch):
    mesh = coarse_patch
    assert 1000 < mesh.n_tets < 4000
    assert np.all(mesh.volumes > 0)
    report = mesh.validate()
    assert report.valid
    exact = 2 * math.pi / 3 * (1 - math.cos(math.radians(19))) * (24.0**3 - 22.0**3) * 1e-9
    assert mesh.volumes.sum() == pytest.approx(exact, rel=0.02)


def test_boundary_faces_lie_on_the_tagged_surfaces(coarse_patch):
    mesh = coarse_patch
    tagged = np.zeros(mesh.n_nodes, dtype=bool)
    for ids in mesh.node_sets.values():
        tagged[ids] = True
    assert tagged[mesh.adjacency.boundary_faces].all()


def test_fixed_nodes_are_the_outer_face(coarse_patch):
    # the side faces are held elastically by the solver (thrsim.physics.support), not fixed here
    mesh = coarse_patch
    np.testing.assert_array_equal(mesh.fixed_nodes, mesh.node_sets[OUTER])
    assert len(np.setdiff1d(mesh.node_sets[SIDE], mesh.node_sets[OUTER])) > 0


def test_generation_is_deterministic(coarse_patch):
    again = generate_bone_patch(BonePatchConfig(element_size_mm=COARSE_MM))
    np.testing.assert_array_equal(again.nodes, coarse_patch.nodes)
    np.testing.assert_array_equal(again.tets, coarse_patch.tets)
    for name in coarse_patch.node_sets:
        np.testing.assert_array_equal(again.node_sets[name], coarse_patch.node_sets[name])


def test_left_is_the_mirror_across_x(coarse_patch):
    right = coarse_patch
    left = generate_bone_patch(BonePatchConfig(element_size_mm=COARSE_MM, side="left"))
    assert (left.n_nodes, left.n_tets) == (right.n_nodes, right.n_tets)
    np.testing.assert_array_equal(left.nodes, right.nodes * [-1, 1, 1])
    assert np.all(left.volumes > 0)
    np.testing.assert_allclose(left.volumes, right.volumes)
    assert left.validate().valid
    for name in right.node_sets:
        np.testing.assert_array_equal(left.node_sets[name], right.node_sets[name])
    np.testing.assert_array_equal(left.fixed_nodes, right.fixed_nodes)
    assert len(left.adjacency.pairs) == len(right.adjacency.pairs)
    assert right.mirrored().mirrored().volumes == pytest.approx(right.volumes)


def test_element_size_controls_the_count():
    finer = generate_bone_patch(BonePatchConfig(element_size_mm=0.8))
    coarser = generate_bone_patch(BonePatchConfig(element_size_mm=1.2))
    assert finer.n_tets > 1.5 * coarser.n_tets


def test_meshing_keeps_python_signal_dispositions():
    # gmsh resets SIGPIPE to its C default; a later write to a closed socket in the same process
    # (a tracker hanging up on the server) must raise, not kill the process
    import subprocess
    import sys

    code = (
        "import socket\n"
        "from thrsim.config import BonePatchConfig\n"
        "from thrsim.geometry.bone_patch import generate_bone_patch\n"
        "generate_bone_patch(BonePatchConfig(element_size_mm=1.2))\n"
        "a, b = socket.socketpair(); b.close()\n"
        "try:\n"
        "    a.sendall(b'x' * 100000); a.sendall(b'x' * 100000)\n"
        "except BrokenPipeError:\n"
        "    print('broken pipe raised')\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=checkout_env())
    assert result.returncode == 0 and "broken pipe raised" in result.stdout
