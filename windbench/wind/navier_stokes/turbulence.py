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

The term is taken explicitly, in one Runge-Kutta-Legendre step (RKL1, Meyer, Balsara and
Aslam 2014) of as many stages s as keep nu_t dt / h^2 <= s (s + 1) / 2 SUBSTEP_LIMIT / (2 d)
(d active axes): stable at any nu_t, where forward Euler needs that many substeps of
SUBSTEP_LIMIT / (2 d) each, a number that grows as 1/h^2 (10 for the fence at 188 cells,
where RKL1 takes 4 stages). Solid cells have nu_t = 0. Each stage reads the faces'
viscosities from fields computed when nu_t changes (:func:`face_viscosity`).
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
def face_viscosity(nu, a, out):
    """out[I, J, K] = nu_t at padded face (I, J, K) of component a (:func:`_face_nu`),
    the ghost faces included: what :func:`eddy_diffusion` reads, computed when nu_t
    changes rather than seven times per face in every stage."""
    for I in prange(out.shape[0]):
        for J in range(out.shape[1]):
            for K in range(out.shape[2]):
                out[I, J, K] = _face_nu(nu, I, J, K, a)


def legendre_stages(r: float) -> int:
    """The stages s of one RKL1 step (:func:`legendre_stage`) that take a step r times the
    forward-Euler limit: the fewest with s (s + 1) / 2 >= r."""
    s = 1
    while s * (s + 1) < 2.0 * r:
        s += 1
    return s


def legendre_stage(j: int, s: int) -> tuple[float, float, float]:
    """(mu_j, nu_j, mu~_j) of stage j of the s-stage first-order Runge-Kutta-Legendre step
    (Meyer, Balsara and Aslam 2014, RKL1): Y_0 = q, Y_1 = Y_0 + mu~_1 dt L Y_0,
    Y_j = mu_j Y_(j-1) + nu_j Y_(j-2) + mu~_j dt L Y_(j-1), q_new = Y_s, with
    w_1 = 2 / (s^2 + s), mu~_1 = w_1, mu_j = (2 j - 1) / j, nu_j = (1 - j) / j,
    mu~_j = w_1 mu_j. Its amplification of an eigenmode L v = lambda v is the Legendre
    polynomial P_s(1 + w_1 lambda dt), within [-1, 1] for lambda dt in [-(s^2 + s), 0]:
    stable for s (s + 1) / 2 times the forward-Euler step, first order in time like it."""
    w1 = 2.0 / (s * s + s)
    if j == 1:
        return 1.0, 0.0, w1
    mu = (2.0 * j - 1.0) / j
    return mu, (1.0 - j) / j, w1 * mu


@threaded()
def eddy_diffusion(q, older, nu_face, axes, dt_h2, free, stage, out):
    """One RKL1 stage (:func:`legendre_stage`) of the eddy term of one component:
    out = mu q + nu older + mu~ dt/h^2 sum_b [nu_+ (q_+b - q) - nu_- (q - q_-b)] on its
    free faces, out = q elsewhere; ``stage`` = (mu, nu, mu~), (1, 0, 1) a forward-Euler
    step. nu_face: its faces' nu_t (:func:`face_viscosity`), nu_+ and nu_- between two
    faces the mean of theirs (so that the flux from a face to its neighbour is the
    neighbour's from it: the term conserves momentum inside and is a symmetric operator)."""
    for I in prange(q.shape[0]):
        _eddy_plane(q, older, nu_face, axes, dt_h2, free, stage, out, np.int64(I))


@njit(cache=True, error_model="numpy")
def _eddy_plane(q, older, nf, axes, dt_h2, free, stage, out, I):
    """Padded plane I of :func:`eddy_diffusion` (the parallel loop's body in a function of
    its own, as :func:`_strain_plane`); the ghost layer is copied."""
    P0, P1, P2 = q.shape
    mu, nu, rate = stage[0], stage[1], stage[2] * dt_h2
    for J in range(P1):
        if I == 0 or I == P0 - 1 or J == 0 or J == P1 - 1:
            for K in range(P2):
                out[I, J, K] = q[I, J, K]
            continue
        out[I, J, 0], out[I, J, P2 - 1] = q[I, J, 0], q[I, J, P2 - 1]
        for K in range(1, P2 - 1):
            qc = q[I, J, K]
            if not free[I, J, K]:
                out[I, J, K] = qc
                continue
            nc = nf[I, J, K]
            flux = 0.0
            if axes[0]:
                flux += 0.5 * (nc + nf[I + 1, J, K]) * (q[I + 1, J, K] - qc)
                flux -= 0.5 * (nc + nf[I - 1, J, K]) * (qc - q[I - 1, J, K])
            if axes[1]:
                flux += 0.5 * (nc + nf[I, J + 1, K]) * (q[I, J + 1, K] - qc)
                flux -= 0.5 * (nc + nf[I, J - 1, K]) * (qc - q[I, J - 1, K])
            if axes[2]:
                flux += 0.5 * (nc + nf[I, J, K + 1]) * (q[I, J, K + 1] - qc)
                flux -= 0.5 * (nc + nf[I, J, K - 1]) * (qc - q[I, J, K - 1])
            out[I, J, K] = mu * qc + nu * older[I, J, K] + rate * flux
