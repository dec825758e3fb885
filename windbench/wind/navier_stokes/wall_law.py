"""The rough ground (``scene.boundary.z_min: rough``): the wall law of the neutral surface
layer in place of a no-slip floor.

A log-law wind u(z) = (u_* / kappa) ln(z / z_0) over K = kappa u_* z (the
``mixing_length`` closure) carries the same stress K du/dz = u_*^2 at every height. A
no-slip floor resolves none of it: its ghost cell gives the first layer, at z_1 = h / 2,
the stress K(z_1) 2 u_1 / h = kappa u_* u_1 = u_*^2 ln(z_1 / z_0), a fraction of u_*^2
that changes with the grid (0.92 at h = 0.5 m, 0.22 at h = 0.25 m over z_0 = 0.1 m) and
vanishes once z_1 <= z_0; the wind near the ground then depends on the resolution, and
so does every wake behind a body standing on it. The rough ground applies instead the
stress of the log law at the first cell centre (Monin-Obukhov similarity in neutral
air; the wall model of Moeng 1984, J. Atmos. Sci. 41, 2052; Richards and Hoxey 1993,
J. Wind Eng. Ind. Aerodyn. 46, 145 for its equilibrium with the inflow),

    tau / rho = C_D |U_1| U_1,   C_D = (kappa / ln(z_1 / z_0))^2,

U_1 the horizontal wind of the first layer: at U_1 = u(z_1) this is u_*^2 at any h,
so the log-law inflow stays in equilibrium over the ground. The floor's ghost cells copy
the first layer (no viscous or eddy flux through it, :mod:`.boundaries`), and each step
the first layer's horizontal components lose the stress over its height h, implicitly
in the drag (stable at any step, never reversing the wind):

    u_1 <- u_1 / (1 + dt C_D |U_1| / h),

|U_1| from the old values of both components (the other one averaged from its four
faces around). The law needs z_1 > z_0 (the first cell centre above the roughness
elements, Blocken et al. 2007, Atmos. Environ. 41, 238): a finer grid is refused.
"""

from __future__ import annotations

import math

from numba import njit

from windbench.errors import ConfigError
from windbench.wind.surface_layer import KARMAN, ground_roughness

FIRST = 1  # the padded index of the first layer of cells along z


def drag_coefficient(scene, lower_z: float, h: float) -> float:
    """C_D = (kappa / ln(z_1 / z_0))^2 of the rough ground at the first cell centre
    z_1 = lower_z + h / 2 above the profile's ground (ConfigError if z_1 <= z_0)."""
    z0, ground = ground_roughness(scene.sources)
    z1 = lower_z + 0.5 * h - ground
    if z1 <= z0:
        raise ConfigError(
            "grid.resolution",
            f"puts the first cell centre {z1:.4g} m above the rough ground, not above its "
            f"roughness length z_0 = {z0:g} m (scene.boundary.z_min: rough needs h > "
            f"{2 * (z0 + ground - lower_z):.4g} m): use a coarser grid",
        )
    return (KARMAN / math.log(z1 / z0)) ** 2


@njit(cache=True)
def floor_drag(u, v, free_u, free_v, rate, scratch):
    """The wall law's step on the first layer (module docstring): u, v the padded x and y
    face arrays, ``rate`` = dt C_D / h (s/m), ``scratch`` a (u.shape[0], u.shape[1]) plane.
    Only free faces change."""
    for i in range(1, u.shape[0] - 1):
        for j in range(1, u.shape[1] - 1):
            vv = 0.25 * (v[i - 1, j, FIRST] + v[i, j, FIRST] + v[i - 1, j + 1, FIRST])
            vv += 0.25 * v[i, j + 1, FIRST]
            q = u[i, j, FIRST]
            scratch[i, j] = q / (1.0 + rate * math.sqrt(q * q + vv * vv))
    for i in range(1, v.shape[0] - 1):
        for j in range(1, v.shape[1] - 1):
            if not free_v[i, j, FIRST]:
                continue
            uu = 0.25 * (u[i, j - 1, FIRST] + u[i + 1, j - 1, FIRST] + u[i, j, FIRST])
            uu += 0.25 * u[i + 1, j, FIRST]
            q = v[i, j, FIRST]
            v[i, j, FIRST] = q / (1.0 + rate * math.sqrt(q * q + uu * uu))
    for i in range(1, u.shape[0] - 1):
        for j in range(1, u.shape[1] - 1):
            if free_u[i, j, FIRST]:
                u[i, j, FIRST] = scratch[i, j]
