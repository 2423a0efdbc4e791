"""The active zone: only the elements the reamer can reach are integrated; the rest of the bone is held as it is."""

from __future__ import annotations

import numpy as np

from thrsim.config import (
    BoneMaterial,
    BonePatchConfig,
    JohnsonCookDamage,
    JohnsonCookHardening,
    ReamerConfig,
    ReamingCaseConfig,
    SocketConfig,
    SolverConfig,
    head_diameter_for_size,
)
from thrsim.geometry.box_mesh import box_mesh
from thrsim.physics.explicit import ExplicitSolid
from thrsim.physics.reaming_case import ReamingCase


def _pressed_box():
    """A 4 mm cube of bone, bottom held, its top pushed down: every element strains."""
    mesh = box_mesh((4, 4, 4), (4e-3, 4e-3, 4e-3), fixed="zmin")
    solid = ExplicitSolid(mesh, BoneMaterial(), JohnsonCookHardening(), JohnsonCookDamage(), target_dt_s=None)
    top = np.flatnonzero(np.isclose(mesh.nodes[:, 2], mesh.nodes[:, 2].max()))
    return mesh, solid, top


def test_outside_the_zone_nothing_moves_or_changes():
    mesh, solid, top = _pressed_box()
    in_zone = mesh.centroids[:, 0] < 2e-3  # half the cube
    touched = solid.set_zone(in_zone)
    solid.external_force[top[touched[top]], 2] = -5.0
    for _ in range(200):
        solid.step()
    outside = ~in_zone
    assert np.all(solid.stress[outside] == 0.0) and np.any(solid.stress[in_zone] != 0.0)
    # nodes of outside elements never move; the zone's nodes shared with outside elements hold it
    held = np.zeros(mesh.n_nodes, dtype=bool)
    held[mesh.tets[outside].ravel()] = True
    assert np.all(solid.displacement[held] == 0.0)
    assert np.any(solid.displacement[~held] != 0.0)


def test_the_whole_zone_is_the_whole_solid():
    _, first, top = _pressed_box()
    _, second, _ = _pressed_box()
    second.set_zone(np.ones(len(second.active), dtype=bool))
    for solid in (first, second):
        solid.external_force[top, 2] = -5.0
        for _ in range(100):
            solid.step()
    # the zone's supports are only nodes shared with active elements outside it: none here
    assert np.array_equal(first.displacement, second.displacement) and np.array_equal(first.stress, second.stress)


def test_a_socket_case_integrates_a_small_share_of_the_bone():
    case = ReamingCaseConfig(
        inclination_deg=0.0, anteversion_deg=0.0, bone_kind="socket", socket=SocketConfig(element_size_mm=1.5), frames=1,
        reamer=ReamerConfig(head_diameter_mm=head_diameter_for_size(48.0)), solver=SolverConfig(zone_steps=200),
    )  # fmt: skip
    simulation = ReamingCase(case)
    assert simulation.zone_enabled
    active = simulation.select_zone(200)
    # a reamer one size up, seated on the native socket's rim, reaches the rim band only
    assert 0 < active < 0.5 * simulation.mesh.n_tets
    zone = simulation.solid.arrays.zone_elements
    distance = np.linalg.norm(simulation.mesh.centroids[zone] - simulation.centre, axis=1)
    assert distance.max() < simulation.reamer.outer_radius + simulation.zone_halo_m + 2 * 1.5e-3


def test_a_frame_reports_its_progress_at_each_choice_of_the_zone():
    """A whole-socket frame can take minutes: within it ``progress`` gets the share done, then the whole frame."""
    case = ReamingCaseConfig(
        inclination_deg=0.0, anteversion_deg=0.0, frames=2, solver=SolverConfig(active_zone="on", zone_steps=1500),
        bone=BonePatchConfig(element_size_mm=1.6),
    )  # fmt: skip
    simulation = ReamingCase(case)
    seen: list[tuple[float, int]] = []
    simulation.run(2, progress=lambda done, total: seen.append((done, total)))
    share = 1500 / simulation.steps_per_frame, 3000 / simulation.steps_per_frame
    expected = [share[0], share[1], 1, 1 + share[0], 1 + share[1], 2]
    assert np.allclose([done for done, _ in seen], expected) and {total for _, total in seen} == {2}
    assert [done for done, _ in seen if float(done).is_integer()] == [1, 2]  # whole frames only once recorded
