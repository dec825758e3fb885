"""Aerodynamic drag and lift on cloth triangles (paper §3, after Shinya & Fournier 1992).

For triangle i with unit normal n_hat, area A and relative velocity
``v_rel = v_object - u`` (object velocity minus wind; eq. above 3.1):

- eq. (3.1): cloth has no inside, so the normal is flipped towards the relative velocity,
  ``n~ = n_hat if n_hat . v_rel > 0 else -n_hat``;
- drag:  ``F_D = 1/2 C_D rho |v_rel|^2 A (n~ . v^) (-v^)``,  v^ = v_rel / |v_rel|;
- lift:  ``F_L = 1/2 C_L rho |v_rel|^2 A cos(theta) u^``,  u^ = (n~ x v^) x v^.

How the lift law is read. As printed, ``u^ = (n~ x v^) x v^ = (n~.v^) v^ - n~`` is *not*
a unit vector: its length is ``|n~ x v^| = cos(alpha)``, alpha being the angle of attack
between v_rel and the face. If theta were the angle to the face (= alpha) and u^ were
normalised, a plate edge-on to the wind (alpha = 0) would feel the full lift
``1/2 C_L rho v^2 A`` — physically wrong, since a flat plate at zero incidence has no lift.
We read theta as the angle between v_rel and the face *normal*, so ``cos(theta) = n~ . v^
= sin(alpha)``, the same projection that scales the drag, and keep u^ as printed
(length cos(alpha)). Then

    |F_D| = 1/2 C_D rho v^2 A sin(alpha),   |F_L| = 1/2 C_L rho v^2 A sin(alpha) cos(alpha),

lift vanishes edge-on and face-on and peaks at 45 degrees, the shape of thin-plate data
(Hoerner: normal force C_N(alpha), lift C_N cos(alpha), drag C_N sin(alpha)). u^ is
perpendicular to v_rel and lies in the plane of v_rel and n~, as the paper requires.
With no wind (u = 0) the same law is air resistance on a moving plate.

Each triangle's force is shared equally by its three vertices, so the vertex forces sum
to the triangle force. Zero relative velocity or zero area gives zero force, never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

RHO_AIR = 1.2  # kg/m^3


@dataclass(frozen=True)
class AeroParams:
    """Coefficients of the paper's §3 force law (SI units)."""

    drag_coefficient: float = 1.2  # C_D; Hoerner: 1.17 for a square plate normal to the flow
    lift_coefficient: float = 0.6  # C_L
    air_density: float = RHO_AIR  # rho, kg/m^3


@njit(cache=True, inline="always")
def triangle_force(x0, x1, x2, v_rel, c_d, c_l, rho, out):
    """out = F_D + F_L on one triangle with corners x0..x2 and relative velocity v_rel."""
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    e1 = x1 - x0
    e2 = x2 - x0
    nx = e1[1] * e2[2] - e1[2] * e2[1]
    ny = e1[2] * e2[0] - e1[0] * e2[2]
    nz = e1[0] * e2[1] - e1[1] * e2[0]
    twice_area = np.sqrt(nx * nx + ny * ny + nz * nz)
    speed2 = v_rel[0] * v_rel[0] + v_rel[1] * v_rel[1] + v_rel[2] * v_rel[2]
    if twice_area == 0.0 or speed2 == 0.0:
        return
    area = 0.5 * twice_area
    speed = np.sqrt(speed2)
    vx, vy, vz = v_rel[0] / speed, v_rel[1] / speed, v_rel[2] / speed
    nx, ny, nz = nx / twice_area, ny / twice_area, nz / twice_area
    ndotv = nx * vx + ny * vy + nz * vz
    if ndotv < 0.0:  # eq. (3.1): flip the normal towards v_rel
        nx, ny, nz, ndotv = -nx, -ny, -nz, -ndotv
    q = 0.5 * rho * speed2 * area * ndotv  # dynamic pressure x area x cos(theta)
    # u^ = (n~ x v^) x v^ = (n~ . v^) v^ - n~   (length cos(alpha), see module docstring)
    ux, uy, uz = ndotv * vx - nx, ndotv * vy - ny, ndotv * vz - nz
    out[0] = -c_d * q * vx + c_l * q * ux
    out[1] = -c_d * q * vy + c_l * q * uy
    out[2] = -c_d * q * vz + c_l * q * uz


@njit(cache=True)
def triangle_forces(positions, velocities, wind, triangles, c_d, c_l, rho, out):
    """out[t] = aerodynamic force on triangle t; wind and velocities given per vertex.

    The triangle's velocity and wind are the means over its three vertices (the paper
    records the wind at the vertices, §4.1.2).
    """
    for t in range(triangles.shape[0]):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        v_rel = np.empty(3)
        for k in range(3):
            v_rel[k] = (
                velocities[a, k]
                + velocities[b, k]
                + velocities[c, k]
                - wind[a, k]
                - wind[b, k]
                - wind[c, k]
            ) / 3.0
        triangle_force(positions[a], positions[b], positions[c], v_rel, c_d, c_l, rho, out[t])


@njit(cache=True)
def scatter_to_vertices(triangles, tri_forces, n_vertices):
    """Vertex forces: each triangle's force shared equally by its three corners."""
    out = np.zeros((n_vertices, 3))
    for t in range(triangles.shape[0]):
        for j in range(3):
            for k in range(3):
                out[triangles[t, j], k] += tri_forces[t, k] / 3.0
    return out


def aerodynamic_forces(positions, velocities, wind, triangles, params: AeroParams):
    """(per-triangle forces ``(m, 3)``, per-vertex forces ``(n, 3)``) in newtons."""
    tri = np.empty((triangles.shape[0], 3))
    triangle_forces(
        np.ascontiguousarray(positions, dtype=np.float64),
        np.ascontiguousarray(velocities, dtype=np.float64),
        np.ascontiguousarray(wind, dtype=np.float64),
        np.ascontiguousarray(triangles, dtype=np.int64),
        params.drag_coefficient,
        params.lift_coefficient,
        params.air_density,
        tri,
    )
    return tri, scatter_to_vertices(triangles.astype(np.int64), tri, positions.shape[0])


def plate_coefficients(alpha, params: AeroParams):
    """Drag and lift coefficients of the §3 law for a flat plate at angle of attack alpha.

    Normalised by 1/2 rho v^2 A: ``C_D sin(alpha)`` along the wind and
    ``C_L sin(alpha) cos(alpha)`` across it (see the module docstring for the reading).
    """
    alpha = np.asarray(alpha, dtype=float)
    return params.drag_coefficient * np.sin(alpha), (
        params.lift_coefficient * np.sin(alpha) * np.cos(alpha)
    )
