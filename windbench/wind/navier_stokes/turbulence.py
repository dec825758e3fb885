"""Eddy viscosity (``wind.turbulence``): turbulent eddies mix momentum like a viscosity,
du/dt = div(nu_t grad u) (the transpose part div(nu_t grad u^T), zero for uniform nu_t, is
left out), in one of two closures:

- ``mixing_length``: the atmospheric surface layer's K-theory, nu_t(z) = l(z)^2 |dU/dz|
  with U(z) the undisturbed wind of the scene's sources and Prandtl's mixing length
  l = kappa z over the ground, limited aloft as 1/l = 1/(kappa z) + 1/lambda (Blackadar
  1962; lambda = ``wind.mixing_length_limit``). Over a log-law profile this is the
  equilibrium K = kappa u_* z; it is fixed in time, a Reynolds-averaged closure whose wind
  is the time mean of the turbulent one (the "K = K_0" scheme that Wilson 1985 found
  nearly as good as second-order closures behind a windbreak). A wind without shear
  (uniform sources) has none.
- ``smagorinsky``: nu_t = (C_s h)^2 |S|, |S| = sqrt(2 S_ij S_ij), the resolved strain's
  subgrid eddies (Smagorinsky 1963; C_s = ``wind.smagorinsky_constant``, Lilly 1967),
  vanishing as the grid is refined; strain rates on the MAC grid at cell centres.

The term is taken explicitly, in as many equal substeps as keep nu_t dt / h^2 <=
SUBSTEP_LIMIT / (2 d) (d active axes): stable at any nu_t. Solid cells have nu_t = 0.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from windbench.wind.navier_stokes.boundaries import cells_beside
from windbench.wind.navier_stokes.threads import threaded


@njit(cache=True, inline="always")
def _centre(q, a, i, j, k):
    """Component a at the centre of cell (i, j, k) (one ghost cell beyond the grid)."""
    if a == 0:
        return 0.5 * (q[i + 1, j + 1, k + 1] + q[i + 2, j + 1, k + 1])
    if a == 1:
        return 0.5 * (q[i + 1, j + 1, k + 1] + q[i + 1, j + 2, k + 1])
    return 0.5 * (q[i + 1, j + 1, k + 1] + q[i + 1, j + 1, k + 2])


SUBSTEP_LIMIT = 0.9


@threaded()
def eddy_viscosity(u, v, w, solid, axes, h, length2, out):
    """out = l^2 |S| per cell (m^2/s), l^2 = ``length2[k]`` of the cell's layer (the
    Smagorinsky closure: (C_s h)^2), 0 in solids. Derivatives along an inactive axis
    (``axes[b] = 0``) are zero."""
    for i in prange(solid.shape[0]):
        _strain_plane(u, v, w, solid, axes, h, length2, out, np.int64(i))


@njit(cache=True, error_model="numpy")
def _strain_plane(u, v, w, solid, axes, h, length2, out, i):
    """Cell plane i of :func:`eddy_viscosity` (its parallel loop's body in a function of
    its own, with the error model numba gives such a body: less to compile, same bits)."""
    ny, nz = solid.shape[1], solid.shape[2]
    for j in range(ny):
        for k in range(nz):
            if solid[i, j, k]:
                out[i, j, k] = 0.0
                continue
            sxx = (u[i + 2, j + 1, k + 1] - u[i + 1, j + 1, k + 1]) * axes[0]
            syy = (v[i + 1, j + 2, k + 1] - v[i + 1, j + 1, k + 1]) * axes[1]
            szz = (w[i + 1, j + 1, k + 2] - w[i + 1, j + 1, k + 1]) * axes[2]
            dudy = 0.5 * (_centre(u, 0, i, j + 1, k) - _centre(u, 0, i, j - 1, k)) * axes[1]
            dudz = 0.5 * (_centre(u, 0, i, j, k + 1) - _centre(u, 0, i, j, k - 1)) * axes[2]
            dvdx = 0.5 * (_centre(v, 1, i + 1, j, k) - _centre(v, 1, i - 1, j, k)) * axes[0]
            dvdz = 0.5 * (_centre(v, 1, i, j, k + 1) - _centre(v, 1, i, j, k - 1)) * axes[2]
            dwdx = 0.5 * (_centre(w, 2, i + 1, j, k) - _centre(w, 2, i - 1, j, k)) * axes[0]
            dwdy = 0.5 * (_centre(w, 2, i, j + 1, k) - _centre(w, 2, i, j - 1, k)) * axes[1]
            sxy = 0.5 * (dudy + dvdx)
            sxz = 0.5 * (dudz + dwdx)
            syz = 0.5 * (dvdz + dwdy)
            ss = sxx * sxx + syy * syy + szz * szz + 2.0 * (sxy * sxy + sxz * sxz + syz * syz)
            out[i, j, k] = length2[k] * math.sqrt(2.0 * ss) / h  # differences per cell: / h


@njit(cache=True, inline="always")
def _clamp(i, n):
    """Index i held inside 0..n-1 (a one-sided difference at the grid's edge)."""
    return min(max(i, 0), n - 1)


@njit(cache=True, inline="always")
def _face_nu(nu, I, J, K, a):
    """nu_t at face (I, J, K) of component a (ghosts included): the mean of its two cells,
    a cell beyond the grid replaced by the nearest one inside (nu_t extends unchanged)."""
    nx, ny, nz = nu.shape
    ip, jp, kp, im, jm, km = cells_beside(I, J, K, a)
    plus = nu[_clamp(ip, nx), _clamp(jp, ny), _clamp(kp, nz)]
    minus = nu[_clamp(im, nx), _clamp(jm, ny), _clamp(km, nz)]
    return 0.5 * (plus + minus)


@threaded()
def eddy_diffusion(q, a, nu, axes, dt_h2, free, out):
    """out = q + dt/h^2 sum_b [nu_+ (q_+b - q) - nu_- (q - q_-b)] on the free faces of
    component a (nu between two faces: the mean of theirs), out = q elsewhere."""
    P0, P1, P2 = q.shape
    for I in prange(P0):
        for J in range(P1):
            for K in range(P2):
                out[I, J, K] = q[I, J, K]
    for I in prange(1, P0 - 1):
        _eddy_plane(q, a, nu, axes, dt_h2, free, out, np.int64(I))


@njit(cache=True, error_model="numpy")
def _eddy_plane(q, a, nu, axes, dt_h2, free, out, I):
    """Padded plane I of :func:`eddy_diffusion`'s update (the parallel loop's body in a
    function of its own, as :func:`_strain_plane`)."""
    for J in range(1, q.shape[1] - 1):
        for K in range(1, q.shape[2] - 1):
            if not free[I, J, K]:
                continue
            qc = q[I, J, K]
            nc = _face_nu(nu, I, J, K, a)
            flux = 0.0
            for b in range(3):
                if axes[b] == 0:
                    continue
                e0, e1, e2 = int(b == 0), int(b == 1), int(b == 2)
                n_plus = 0.5 * (nc + _face_nu(nu, I + e0, J + e1, K + e2, a))
                n_minus = 0.5 * (nc + _face_nu(nu, I - e0, J - e1, K - e2, a))
                flux += n_plus * (q[I + e0, J + e1, K + e2] - qc)
                flux -= n_minus * (qc - q[I - e0, J - e1, K - e2])
            out[I, J, K] = qc + dt_h2 * flux
