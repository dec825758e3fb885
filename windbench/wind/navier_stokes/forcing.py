"""Body forces on the MAC grid (paper §4.1, the f of equation 4.2).

- a uniform acceleration ``wind.body_force``: u += f dt on every free face;
- the interior flow primitives (vortex, source, sink; paper §4.2.1) acting on the air
  inside their core: u += (1 - exp(-k dt)) chi_i (w_i - u), chi_i = exp(-(d/r_i)^2), an
  exact exponential relaxation toward w_i at rate k = ``wind.source_relaxation``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from windbench.wind.primitives import SINK, SOURCE, primitive_velocity


@njit(cache=True)
def add_force(q, free, dv):
    """q += dv on the free faces (dv = f_a dt, a uniform body force)."""
    P0, P1, P2 = q.shape
    for I in prange(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                if free[I, J, K]:
                    q[I, J, K] += dv


@njit(cache=True)
def relax_to_primitives(q, a, origin, h, kinds, params, radii, factor, free):
    """q += factor chi_i (w_i,a - q) per interior primitive i, chi_i = exp(-(d/r_i)^2)."""
    P0, P1, P2 = q.shape
    for I in prange(1, P0 - 1):
        wi = np.empty(3)
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                if not free[I, J, K]:
                    continue
                px = origin[0] + h * I
                py = origin[1] + h * J
                pz = origin[2] + h * K
                for p in range(kinds.shape[0]):
                    prm = params[p]
                    rx, ry, rz = px - prm[0], py - prm[1], pz - prm[2]
                    if kinds[p] == SOURCE or kinds[p] == SINK:
                        d2 = rx * rx + ry * ry + rz * rz
                    else:  # vortex: distance from the axis line
                        along = rx * prm[3] + ry * prm[4] + rz * prm[5]
                        d2 = rx * rx + ry * ry + rz * rz - along * along
                    chi = np.exp(-d2 / (radii[p] * radii[p]))
                    if chi < 1e-6:
                        continue
                    primitive_velocity(kinds[p], prm, px, py, pz, wi)
                    q[I, J, K] += factor * chi * (wi[a] - q[I, J, K])
