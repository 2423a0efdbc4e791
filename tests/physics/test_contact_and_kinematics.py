"""Contact stiffness scaled to the step, the friction cap, and BLAS-free tet gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim.config import STICK_FRACTION, ReamingCaseConfig, contact_stability_terms
from thrsim.physics.contact import (
    ContactArrays,
    ContactLaw,
    ReamerPose,
    ReamerTeeth,
    contact_step_work,
    keep_previous_increment,
    reamer_contact,
)
from thrsim.physics.explicit import SolidArrays
from thrsim.physics.tet_kinematics import shape_gradients

HEAD_RADIUS = 0.0225


def _one_node(mass: float, position: np.ndarray, velocity=(0.0, 0.0, 0.0)) -> SolidArrays:
    """The arrays the contact kernel reads, for a single free node."""
    one, node3 = np.zeros(1), np.zeros((1, 3))
    return SolidArrays(
        tets=np.zeros((0, 4), dtype=np.int64), zone_elements=np.zeros(0, dtype=np.int64), zone_nodes=np.arange(1),
        contact_nodes=np.arange(1), material=np.zeros(0, dtype=np.int64), grads=np.zeros((0, 4, 3)), volume=np.zeros(0), char_length=np.zeros(0),
        bulk_viscosity=np.zeros(0), offsets=np.zeros(2, dtype=np.int64),
        entries=np.zeros(0, dtype=np.int64), support_stiffness=one.copy(), held=np.zeros(1, dtype=np.bool_),
        active=np.zeros(0, dtype=np.uint8), accounted=np.zeros(0, dtype=np.bool_), stress=np.zeros((0, 6)),
        peeq=np.zeros(0), damage=np.zeros(0), initiation=np.zeros(0), plastic_work=np.zeros(0), damage_work=np.zeros(0),
        viscous_work=np.zeros(0), viscous_pressure=np.zeros(0), static_flow_stress=np.zeros(0), static_flow_peeq=np.zeros(0),
        element_force=np.zeros((0, 4, 3)),
        nodal_mass=np.array([mass]), inverse_mass=np.array([1.0 / mass]), elements_at_node=np.ones(1, dtype=np.int64),
        velocity=np.array([velocity], dtype=float), displacement=node3.copy(), du=node3.copy(),
        external_force=node3.copy(), cutting_damage=one.copy(), debris=np.zeros(7),
    )  # fmt: skip


def _contact(mass: float, depth: float, dt: float, penalty_factor: float, velocity=(0.0, 0.0, 0.0), omega=0.0, friction=0.3):
    """Force on a node ``depth`` inside a toothless head centred at the origin, on its equator (+x),
    where a spin ω about +z moves the surface along +y at ω·R."""
    teeth = ReamerTeeth(HEAD_RADIUS, HEAD_RADIUS, 1e-4, np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))
    pose = ReamerPose(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), 0.0, omega)
    law = ContactLaw(penalty_factor, 0.0, friction, dt, np.array([5e8]))
    out = ContactArrays.zeros(1)
    touching = reamer_contact(np.array([[HEAD_RADIUS - depth, 0.0, 0.0]]), _one_node(mass, None, velocity), pose, teeth, law, out)
    return touching, out


@pytest.mark.parametrize("mass, dt", [(1e-4, 4e-6), (6e-4, 4e-6), (6e-4, 2e-6), (2e-5, 1e-6)])
def test_penalty_gives_the_same_omega_dt_whatever_the_node_mass_and_step(mass, dt):
    beta = 0.4
    touching, out = _contact(mass, 1e-6, dt, beta)
    assert touching == 1
    stiffness = np.linalg.norm(out.force[0]) / 1e-6
    assert stiffness == pytest.approx(beta * mass / dt**2, rel=1e-9)
    assert math.sqrt(stiffness / mass) * dt == pytest.approx(math.sqrt(beta), rel=1e-9)
    np.testing.assert_allclose(out.normal_force[0] / np.linalg.norm(out.normal_force[0]), [1.0, 0.0, 0.0], atol=1e-12)
    assert out.penalty_energy[0] == pytest.approx(0.5 * stiffness * 1e-12, rel=1e-9)


def test_friction_is_coulomb_while_slipping_and_capped_below_the_one_step_stick_force():
    mass, dt, depth, beta = 6e-4, 4e-6, 1e-6, 0.4
    normal_force = beta * mass / dt**2 * depth
    # a fast spinning head: the slip is large, friction is μ·f_n
    _, out = _contact(mass, depth, dt, beta, omega=100.0)
    assert out.force[0, 1] == pytest.approx(0.3 * normal_force, rel=1e-6)  # dragged along the spin
    assert out.force[0, 0] == pytest.approx(normal_force, rel=1e-6)
    # a slow slip: Coulomb would reverse it within a step; the cap allows half the stopping force
    slip = 1e-4
    _, out = _contact(mass, depth, dt, beta, velocity=(0.0, 0.0, slip))
    stick_cap = 0.5 * mass * slip / dt
    assert stick_cap < 0.3 * normal_force
    assert -out.force[0, 2] == pytest.approx(stick_cap, rel=1e-9)


def _tooth_cut(polar_deg: float, volume: float, friction: float = 0.3, cutting_energy: float = 2e8, depth: float = 1e-6):
    """One tet whose node 0 is pressed ``depth`` (1 µm) into a single tooth (azimuth 0, the x–z meridian) of a
    reamer spinning at 100 rad/s about +z; its other nodes are far outside. Returns the contact
    output and the node's slip speed."""
    edge_axis, edge = 0.02265, 2.5e-4
    teeth = ReamerTeeth(0.0225, edge_axis, edge, np.ones(1), np.zeros(1), np.radians([3.0]), np.radians([86.0]))
    direction = np.array([math.sin(math.radians(polar_deg)), 0.0, math.cos(math.radians(polar_deg))])
    nodes = np.array([direction * (edge_axis + edge - depth), [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]])
    mass, dt = 6e-4, 4e-6
    solid = _one_node(mass, None)._replace(
        tets=np.array([[0, 1, 2, 3]], dtype=np.int64), zone_elements=np.arange(1), zone_nodes=np.arange(4),
        contact_nodes=np.arange(4), material=np.zeros(1, dtype=np.int64), volume=np.array([volume]), active=np.ones(1, dtype=np.uint8),
        offsets=np.array([0, 1, 2, 3, 4], dtype=np.int64), entries=np.arange(4, dtype=np.int64),
        nodal_mass=np.full(4, mass), inverse_mass=np.full(4, 1 / mass), velocity=np.zeros((4, 3)),
        displacement=np.zeros((4, 3)), cutting_damage=np.zeros(4),
    )  # fmt: skip
    pose = ReamerPose(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), 0.0, 100.0)
    out = ContactArrays.zeros(4)
    assert reamer_contact(nodes, solid, pose, teeth, ContactLaw(0.4, 0.0, friction, dt, np.array([cutting_energy])), out) == 1
    return out, 100.0 * nodes[0, 0], dt


@pytest.mark.parametrize("polar_deg, volume", [(20.0, 1.7e-11), (60.0, 1.7e-11), (60.0, 5e-11)])
def test_a_tooth_cuts_the_volume_its_friction_work_pays_for(polar_deg, volume):
    cutting_energy = 2e8
    out, slip, dt = _tooth_cut(polar_deg, volume, cutting_energy=cutting_energy)
    normal = np.linalg.norm(out.normal_force[0])
    friction_work = 0.3 * normal * slip * dt  # Coulomb while slipping: μ·f_n over the step's slip
    # every element at the node gains W/(u_c·ΣV): the volume-weighted damage is exactly W/u_c
    assert out.cutting_damage[0] * volume == pytest.approx(friction_work / cutting_energy, rel=1e-6)
    assert not out.cutting_damage[1:].any()
    # no friction, no cutting: the teeth remove bone only through the work they do on it
    out, _, _ = _tooth_cut(polar_deg, volume, friction=0.0)
    assert not out.cutting_damage.any()


def test_the_cut_follows_coulomb_friction_where_the_stick_cap_binds():
    """A node pressed deep into a tooth (a flank ploughing through it), where the one-step stick cap
    limits the friction actually applied, still cuts what Coulomb friction pays for: relative to
    μ·f_n the cap shrinks with Δt, and must not make the removal depend on the step."""
    volume, mass = 1.7e-11, 6e-4
    out, slip, dt = _tooth_cut(60.0, volume, depth=1e-4)
    normal = np.linalg.norm(out.normal_force[0])
    applied = np.linalg.norm(out.force[0] - out.normal_force[0])
    assert applied == pytest.approx(STICK_FRACTION * mass / dt * slip, rel=1e-9)
    assert applied < 0.5 * 0.3 * normal  # the cap binds
    assert out.cutting_damage[0] * volume == pytest.approx(0.3 * normal * slip * dt / 2e8, rel=1e-6)


def test_below_its_edge_a_tooth_pushes_sideways_and_the_head_outward():
    """A node in the corner where a tooth's flank meets the head: the flank pushes it across the
    ridge, the head outward, at right angles; the round edge never pushes it into the head."""
    edge_axis, edge, head = 0.02265, 2.5e-4, 0.0225
    teeth = ReamerTeeth(head, edge_axis, edge, np.ones(1), np.zeros(1), np.radians([3.0]), np.radians([86.0]))
    polar = math.radians(40.0)
    outward = np.array([math.sin(polar), 0.0, math.cos(polar)])
    # 5 µm inside the head, 0.2 mm across the ridge (y) from the meridian plane of the tooth
    position = outward * (head - 5e-6) * math.cos(2e-4 / head) + np.array([0.0, 2e-4, 0.0])
    pose = ReamerPose(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), 0.0, 0.0)
    out = ContactArrays.zeros(1)
    assert reamer_contact(position[None, :], _one_node(6e-4, None), pose, teeth, ContactLaw(0.4, 0.0, 0.3, 4e-6, np.array([5e8])), out) == 1
    normal_force = out.normal_force[0]
    radial = position / np.linalg.norm(position)
    assert normal_force @ radial > 0  # the head pushes out
    assert normal_force[1] > 0  # the flank pushes across, away from the ridge
    sideways = normal_force - (normal_force @ radial) * radial
    assert abs(sideways @ radial) < 1e-12 and sideways[1] > 0


def test_the_smooth_head_cuts_nothing():
    touching, out = _contact(6e-4, 1e-6, 4e-6, 0.4, omega=100.0)
    assert touching == 1 and out.force[0, 1] > 0  # friction drags the node along
    assert out.cutting_damage[0] == 0.0


def test_contact_settings_that_break_the_stable_step_are_refused():
    normal, tangential = contact_stability_terms(0.7, 0.4, 0.2)
    assert max(normal, tangential) < 3.6
    with pytest.raises(ValueError, match="stable step"):
        ReamingCaseConfig(inclination_deg=15, anteversion_deg=30, solver={"safety_factor": 0.9})
    with pytest.raises(ValueError, match="stable step"):
        ReamingCaseConfig(inclination_deg=15, anteversion_deg=30, contact={"penalty_factor": 1.5})
    for bad in (
        {"hold": {"effective_mass_kg": 0}}, {"hold": {"axial_damping_n_s_m": 0}}, {"contact": {"penalty_factor": -1}},
        {"contact": {"specific_cutting_energy_j_m3": 0}},
    ):  # fmt: skip
        with pytest.raises(ValueError):
            ReamingCaseConfig(inclination_deg=15, anteversion_deg=30, **bad)


@settings(max_examples=50, deadline=None)
@given(st.integers(min_value=0, max_value=10_000))
def test_closed_form_gradients_match_the_inverse_jacobian_and_reproduce_linear_fields(seed):
    rng = np.random.default_rng(seed)
    nodes = rng.normal(size=(4, 3)) * 1e-3
    tets = np.array([[0, 1, 2, 3]])
    edges = nodes[1:] - nodes[0]
    if abs(np.linalg.det(edges)) < 1e-12:  # a degenerate draw (volume below 1e-12 mm³·6)
        return
    grads = shape_gradients(nodes, tets)[0]
    reference = np.linalg.inv(edges).T
    np.testing.assert_allclose(grads[1:], reference, rtol=1e-9, atol=1e-9 * np.abs(reference).max())
    np.testing.assert_allclose(grads.sum(axis=0), 0.0, atol=1e-9 * np.abs(grads).max())
    # a linear field u = A x is differentiated exactly: Σ_a u_a ⊗ ∇N_a = A
    a = rng.normal(size=(3, 3))
    np.testing.assert_allclose((nodes @ a.T).T @ grads, a, rtol=1e-9, atol=1e-9)


def test_a_convergence_study_can_halve_the_step_with_the_scaled_mass_held():
    """``mass_scaling_dt_s`` scales the mass for its own step: the same masses at half the step; a
    step beyond that mass's stable one is refused."""
    from thrsim.config import BoneMaterial, JohnsonCookDamage, JohnsonCookHardening
    from thrsim.geometry.box_mesh import box_mesh
    from thrsim.physics.explicit import ExplicitSolid

    mesh = box_mesh((3, 3, 3), (2e-3, 2e-3, 2e-3), scheme="six", jitter=0.2, seed=1)
    laws = (BoneMaterial(), JohnsonCookHardening(), JohnsonCookDamage())
    scaled = ExplicitSolid(mesh, *laws, target_dt_s=4e-6)
    held = ExplicitSolid(mesh, *laws, target_dt_s=2e-6, mass_scaling_dt_s=4e-6)
    lighter = ExplicitSolid(mesh, *laws, target_dt_s=2e-6)
    assert held.dt == 2e-6 and np.array_equal(held.nodal_mass, scaled.nodal_mass)
    assert lighter.nodal_mass.sum() < 0.3 * scaled.nodal_mass.sum()  # the scaled mass goes as Δt²
    with pytest.raises(ValueError, match="exceeds the stable step"):
        ExplicitSolid(mesh, *laws, target_dt_s=4e-6, mass_scaling_dt_s=2e-6)


def test_the_contact_work_on_a_node_closes_with_its_half_step_kinetic_energy():
    """A free node driven by a contact force that changes every step (central differences): the
    booked work on the bone equals its kinetic energy at half steps to round-off (trapezoidal
    rule); booked through the step's own increment alone it would be f·Δt²·a/2 a step too much."""
    mass, dt, steps = 2e-6, 4e-6, 400
    out, nodes, axis, work = ContactArrays.zeros(1), np.arange(1), np.array([0.0, 0.0, 1.0]), np.zeros(4)
    velocity, du, one_sided = np.zeros(3), np.zeros((1, 3)), 0.0
    for n in range(steps):
        out.force[0] = [0.3 * math.sin(0.05 * n), 0.0, 1.0 + 0.5 * math.cos(0.11 * n)]  # N
        keep_previous_increment(out, nodes, du)
        velocity = velocity + dt * out.force[0] / mass
        du = (dt * velocity)[None, :]
        contact_step_work(out, nodes, du, axis, 0.0, 0.0, dt, work)
        one_sided += float(out.force[0] @ du[0])
    kinetic = 0.5 * mass * float(velocity @ velocity)
    assert work[1] == pytest.approx(kinetic, rel=1e-12)
    assert one_sided - kinetic > 1e-3 * kinetic  # what the one-sided pairing booked beyond it
