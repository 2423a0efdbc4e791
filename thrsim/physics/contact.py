"""Penalty contact between bone nodes and the rigid rotating reamer (head sphere + tooth capsules).

Written here: no library offers contact of a mesh against an analytic, spinning, toothed body.
Every node still attached to an active element is a candidate, interior ones included, so
every element can be cut [5.3.1]. For a node at p, with the reamer centre c and the reamer
basis (e1, e2, D) turned to the current spin angle:

* head: penetration g = R − |p − c|, normal (p − c)/|p − c|;
* tooth k: the edge axis is an arc of radius R_a in the meridian half-plane at azimuth ψ_k,
  between polar angles φ_start and φ_end; the closest arc point is found by clamping the
  node's polar angle in that half-plane, and g = r_edge − distance.

The deepest of these contacts acts. Normal force f_n = k·g + 2ξ√(k·m)·(−v_rel·n), never
pulling (f_n ≥ 0); Coulomb friction μ·f_n against the relative sliding velocity, regularised
below ``SLIP_REGULARISATION_M_S`` so a sticking node feels a viscous rather than a chattering
force. The relative velocity uses the reamer surface velocity ω D × (p − c) + ṡ D.
"""

from __future__ import annotations

import math

from numba import njit, prange

SLIP_REGULARISATION_M_S = 1e-3


@njit(parallel=True, cache=True)
def reamer_contact(
    nodes, displacement, velocity, inverse_mass, nodal_mass, centre, e1, e2, axis, axial_speed, omega,
    head_radius, edge_axis_radius, edge_radius, tooth_cos, tooth_sin, tooth_start, tooth_end,
    stiffness, damping_ratio, friction, force,
):  # fmt: skip
    """Write each node's contact force into ``force`` (N, 3); return how many nodes are in contact.

    Totals (the force on the bone, the power of the contact forces) are left to the caller to
    sum over ``force`` in a fixed order: a floating-point reduction across threads would make
    results depend on the thread count.
    """
    reach = edge_axis_radius + edge_radius
    tooth_shell = edge_axis_radius - edge_radius
    contacts = 0
    for node in prange(len(inverse_mass)):
        force[node, 0] = 0.0
        force[node, 1] = 0.0
        force[node, 2] = 0.0
        if inverse_mass[node] == 0.0:  # orphaned: every element at this node is gone
            continue
        qx = nodes[node, 0] + displacement[node, 0] - centre[0]
        qy = nodes[node, 1] + displacement[node, 1] - centre[1]
        qz = nodes[node, 2] + displacement[node, 2] - centre[2]
        r = math.sqrt(qx * qx + qy * qy + qz * qz)
        if r >= reach or r == 0.0:
            continue
        depth = head_radius - r
        nx, ny, nz = qx / r, qy / r, qz / r
        if r > tooth_shell:
            # node in the teeth's shell: express it in the spinning reamer frame
            lx = qx * e1[0] + qy * e1[1] + qz * e1[2]
            ly = qx * e2[0] + qy * e2[1] + qz * e2[2]
            lz = qx * axis[0] + qy * axis[1] + qz * axis[2]
            for k in range(len(tooth_cos)):
                across = -lx * tooth_sin[k] + ly * tooth_cos[k]
                if abs(across) >= edge_radius:
                    continue
                along = lx * tooth_cos[k] + ly * tooth_sin[k]
                polar = math.atan2(along, lz)
                polar = min(max(polar, tooth_start[k]), tooth_end[k])
                a_along = edge_axis_radius * math.sin(polar)
                a_z = edge_axis_radius * math.cos(polar)
                d_along = along - a_along
                d_z = lz - a_z
                distance = math.sqrt(d_along * d_along + across * across + d_z * d_z)
                tooth_depth = edge_radius - distance
                if tooth_depth > depth and distance > 0.0:
                    depth = tooth_depth
                    # normal back in the bone frame: (d_along·e_ψ + across·e_⊥ + d_z·D)/distance
                    ux = (d_along * tooth_cos[k] - across * tooth_sin[k]) / distance
                    uy = (d_along * tooth_sin[k] + across * tooth_cos[k]) / distance
                    uz = d_z / distance
                    nx = ux * e1[0] + uy * e2[0] + uz * axis[0]
                    ny = ux * e1[1] + uy * e2[1] + uz * axis[1]
                    nz = ux * e1[2] + uy * e2[2] + uz * axis[2]
        if depth <= 0.0:
            continue
        # reamer surface velocity at the node: ω D × (p − c) + ṡ D
        wx = omega * (axis[1] * qz - axis[2] * qy) + axial_speed * axis[0]
        wy = omega * (axis[2] * qx - axis[0] * qz) + axial_speed * axis[1]
        wz = omega * (axis[0] * qy - axis[1] * qx) + axial_speed * axis[2]
        rx = velocity[node, 0] - wx
        ry = velocity[node, 1] - wy
        rz = velocity[node, 2] - wz
        normal_speed = rx * nx + ry * ny + rz * nz
        fn = stiffness * depth - 2.0 * damping_ratio * math.sqrt(stiffness * nodal_mass[node]) * normal_speed
        if fn <= 0.0:
            continue
        tx = rx - normal_speed * nx
        ty = ry - normal_speed * ny
        tz = rz - normal_speed * nz
        slip = math.sqrt(tx * tx + ty * ty + tz * tz)
        ft = friction * fn * min(1.0, slip / SLIP_REGULARISATION_M_S) / slip if slip > 0.0 else 0.0
        fx = fn * nx - ft * tx
        fy = fn * ny - ft * ty
        fz = fn * nz - ft * tz
        force[node, 0] = fx
        force[node, 1] = fy
        force[node, 2] = fz
        contacts += 1
    return contacts



@njit(cache=True)
def contact_totals(force, velocity):
    """Total force on the bone and the power of the contact forces, summed in node order
    (deterministic whatever the thread count)."""
    fx = fy = fz = power = 0.0
    for node in range(len(force)):
        fx += force[node, 0]
        fy += force[node, 1]
        fz += force[node, 2]
        power += force[node, 0] * velocity[node, 0] + force[node, 1] * velocity[node, 1] + force[node, 2] * velocity[node, 2]
    return fx, fy, fz, power
