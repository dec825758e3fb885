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

Where the wind's own solve closes the cloth (``navier_stokes`` with ``wind.coupling=
projection``) the force on a triangle is the jump of the air's pressure across it,
``(p_front - p_back) n A`` (:func:`pressure_forces`): the air that the cloth stops pushes
on it. With ``aero.subgrid_law`` the §3 law is added, on the relative velocity of the air
at the cloth (:func:`cloth_forces`): the part of the flow that the grid does not stop.
Where the grid resolves the cloth, the coupled air moves with it and that part is small
(a few per cent of a static plate's drag across a channel); a cloth that lies within one
layer of coarse cells closes few faces, the air passes through it, and the pressure jump
alone would leave it without the wind's force. In between, the law also sees some of the air
that the closed faces already stop (``experiments/results/projection_coupling.csv``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from windbench.config import AeroConfig

AeroParams = AeroConfig  # one class for the §3 coefficients: the schema of the aero.* keys


@njit(cache=True, inline="always")
def triangle_force(positions, a, b, c, vx, vy, vz, c_d, c_l, rho):
    """F_D + F_L on triangle (a, b, c) of ``positions`` with relative velocity (vx, vy, vz)."""
    e1x = positions[b, 0] - positions[a, 0]
    e1y = positions[b, 1] - positions[a, 1]
    e1z = positions[b, 2] - positions[a, 2]
    e2x = positions[c, 0] - positions[a, 0]
    e2y = positions[c, 1] - positions[a, 1]
    e2z = positions[c, 2] - positions[a, 2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    twice_area = np.sqrt(nx * nx + ny * ny + nz * nz)
    speed2 = vx * vx + vy * vy + vz * vz
    if twice_area == 0.0 or speed2 == 0.0:
        return 0.0, 0.0, 0.0
    area = 0.5 * twice_area
    speed = np.sqrt(speed2)
    vx, vy, vz = vx / speed, vy / speed, vz / speed
    nx, ny, nz = nx / twice_area, ny / twice_area, nz / twice_area
    ndotv = nx * vx + ny * vy + nz * vz
    if ndotv < 0.0:  # eq. (3.1): flip the normal towards v_rel
        nx, ny, nz, ndotv = -nx, -ny, -nz, -ndotv
    q = 0.5 * rho * speed2 * area * ndotv  # dynamic pressure x area x cos(theta)
    # u^ = (n~ x v^) x v^ = (n~ . v^) v^ - n~   (length cos(alpha), see module docstring)
    ux, uy, uz = ndotv * vx - nx, ndotv * vy - ny, ndotv * vz - nz
    return -c_d * q * vx + c_l * q * ux, -c_d * q * vy + c_l * q * uy, -c_d * q * vz + c_l * q * uz


@njit(cache=True, inline="always")
def _mean_relative(velocities, wind, a, b, c, k):
    """Component k of v_object - u averaged over the corners a, b, c."""
    vk = velocities[a, k] + velocities[b, k] + velocities[c, k]
    return (vk - wind[a, k] - wind[b, k] - wind[c, k]) / 3.0


@njit(cache=True)
def triangle_forces(positions, velocities, wind, triangles, c_d, c_l, rho, tri_out, vertex_out):
    """tri_out[t] = aerodynamic force on triangle t; vertex_out = its share at the corners.

    Wind and velocities are given per vertex; the triangle's velocity and wind are the means
    over its three vertices (the paper records the wind at the vertices, §4.1.2). Each
    triangle's force is shared equally by its corners: vertex_out[i] = sum_t F_t / 3.
    """
    vertex_out[:] = 0.0
    for t in range(triangles.shape[0]):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        # v_rel = v_object - u, averaged over the three corners
        vx = _mean_relative(velocities, wind, a, b, c, 0)
        vy = _mean_relative(velocities, wind, a, b, c, 1)
        vz = _mean_relative(velocities, wind, a, b, c, 2)
        f = triangle_force(positions, a, b, c, vx, vy, vz, c_d, c_l, rho)
        for k in range(3):
            tri_out[t, k] = f[k]
            share = f[k] / 3.0
            vertex_out[a, k] += share
            vertex_out[b, k] += share
            vertex_out[c, k] += share


def aerodynamic_forces(positions, velocities, wind, triangles, params: AeroConfig):
    """(per-triangle forces ``(m, 3)``, per-vertex forces ``(n, 3)``) in newtons."""
    tri = np.empty((triangles.shape[0], 3))
    vert = np.empty((positions.shape[0], 3))
    triangle_forces(
        np.ascontiguousarray(positions, dtype=np.float64),
        np.ascontiguousarray(velocities, dtype=np.float64),
        np.ascontiguousarray(wind, dtype=np.float64),
        np.ascontiguousarray(triangles, dtype=np.int64),
        float(params.drag_coefficient),
        float(params.lift_coefficient),
        float(params.air_density),
        tri,
        vert,
    )
    return tri, vert


def plate_coefficients(alpha, params: AeroConfig):
    """Drag and lift coefficients of the §3 law for a flat plate at angle of attack alpha.

    Normalised by 1/2 rho v^2 A: ``C_D sin(alpha)`` along the wind and
    ``C_L sin(alpha) cos(alpha)`` across it (see the module docstring for the reading).
    """
    alpha = np.asarray(alpha, dtype=float)
    return params.drag_coefficient * np.sin(alpha), (
        params.lift_coefficient * np.sin(alpha) * np.cos(alpha)
    )


def pressure_forces(loads, triangles, n_vertices: int, params: AeroConfig):
    """(per-triangle, per-vertex) forces (N) of the pressure jump across each triangle:
    ``rho x loads`` (loads: the wind's force over the air density, m^4 s^-2, see
    :meth:`windbench.wind.base.WindField.cloth_pressure_loads`), shared equally by the three
    corners."""
    tri = float(params.air_density) * np.asarray(loads, dtype=np.float64)
    vert = np.zeros((n_vertices, 3))
    for k in range(3):
        np.add.at(vert, triangles[:, k], tri / 3.0)
    return tri, vert


def cloth_forces(positions, velocities, wind, triangles, loads, params: AeroConfig):
    """(per-triangle, per-vertex) forces (N) on the cloth: the §3 law
    (:func:`aerodynamic_forces`) without ``loads``; with them (``wind.coupling=projection``)
    the pressure jump (:func:`pressure_forces`), plus the §3 law when
    ``params.subgrid_law`` (module docstring)."""
    if loads is None:
        return aerodynamic_forces(positions, velocities, wind, triangles, params)
    tri, vert = pressure_forces(loads, triangles, positions.shape[0], params)
    if params.subgrid_law:
        law_tri, law_vert = aerodynamic_forces(positions, velocities, wind, triangles, params)
        tri, vert = tri + law_tri, vert + law_vert
    return tri, vert
