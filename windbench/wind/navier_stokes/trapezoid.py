"""The explicit parts of the second-order step (``wind.advection=second_order``; see
:meth:`windbench.wind.navier_stokes.backend.NavierStokesWind._advect_diffuse_second_order`),
each one pass over a velocity component:

- the field carried along the characteristics, w = u^n - (dt/2) grad p^n + nu dt/2 lap u^n
  (:func:`carried_field`: the previous projection's psi, scaled to (dt/2) grad p^n, and the
  explicit half of Crank-Nicolson viscosity);
- the velocity that moves it, extrapolated to the middle of the step,
  u^n+1/2 = 3/2 u^n - 1/2 u^n-1 (:func:`midpoint_velocity`, in place).
"""

from __future__ import annotations

from numba import prange

from windbench.wind.navier_stokes.diffusion import _neighbour_sum
from windbench.wind.navier_stokes.flags import FAST_MATH
from windbench.wind.navier_stokes.projection import face_cells
from windbench.wind.navier_stokes.threads import threaded


@threaded(fastmath=FAST_MATH)
def carried_field(q, a, psi, scale, beta, axes, free, periodic, out):
    """out = q + beta sum_nb (q_nb - q) - scale (psi_+ - psi_-) on the free faces of
    component a, out = q on every other element (refill the ghosts afterwards); beta =
    nu dt / (2 h^2), ``scale`` turns psi into (dt/2) grad p^n (0: no pressure term).
    Laid out as :func:`.diffusion.jacobi_first_sweep` (whole planes copied, then the free
    inner faces) and reading psi itself (:func:`.projection.face_cells`), so that its
    serial version runs as fast as its parallel one (threads.py)."""
    P0, P1, P2 = q.shape
    nx, ny, nz = psi.shape
    wrap = periodic[a]
    d = 2.0 * (axes[0] + axes[1] + axes[2])
    all_axes = axes[0] != 0 and axes[1] != 0 and axes[2] != 0
    for I in prange(P0):
        for J in range(P1):
            qc, oc = q[I, J], out[I, J]
            for K in range(P2):
                oc[K] = qc[K]
        inner = (1, P1 - 1) if 0 < I < P0 - 1 else (0, 0)  # no inner rows in a ghost plane
        for J in range(inner[0], inner[1]):
            qc, oc, fc = q[I, J], out[I, J], free[I, J]
            xm, xp, ym, yp = q[I - 1, J], q[I + 1, J], q[I, J - 1], q[I, J + 1]
            for K in range(1, P2 - 1):
                if not fc[K]:
                    continue
                if all_axes:
                    nb = (xm[K] + xp[K]) + (ym[K] + yp[K]) + (qc[K - 1] + qc[K + 1])
                else:
                    nb = _neighbour_sum(xm, xp, ym, yp, qc, K, axes, all_axes)
                value = qc[K] + beta * (nb - d * qc[K])
                if scale != 0.0:
                    ip, jp, kp, p_in, im, jm, km, m_in = face_cells(I, J, K, a, nx, ny, nz, wrap)
                    plus = psi[ip, jp, kp] if p_in else 0.0
                    value -= scale * (plus - (psi[im, jm, km] if m_in else 0.0))
                oc[K] = value


@threaded(fastmath=FAST_MATH)
def midpoint_velocity(q, previous):
    """previous = 3/2 q - 1/2 previous (u^n+1/2 from u^n and u^n-1), in place, ghosts too."""
    P0, P1, P2 = q.shape
    for I in prange(P0):
        for J in range(P1):
            for K in range(P2):
                previous[I, J, K] = 1.5 * q[I, J, K] - 0.5 * previous[I, J, K]
