"""Implicit viscous diffusion of one staggered velocity component (paper §4.1.1, Stam 1999).

Backward Euler for du/dt = nu lap u on the MAC faces:

    (1 + 6 alpha) q_f - alpha sum_{6 neighbours} q_nb = q0_f,   alpha = nu dt / h^2,

solved by one Jacobi sweep from q0 out of place (:func:`jacobi_first_sweep`: it also
finds the field's scale, so the right-hand side needs no copy pass; at air's viscosity
it is the only sweep up to 128^3 cells of the scaling scene), then red-black Gauss-Seidel
until the error bound of a contraction, rho / (1 - rho) times the largest update of the
last sweep, is below ``tol`` times the field's scale: the Jacobi factor rho = 2 alpha d /
(1 + 2 alpha d) (d active axes) is the max-norm contraction of the Jacobi sweep and
bounds that of a Gauss-Seidel sweep on this diagonally dominant M-matrix
(:func:`error_bound_factor`). The ghost layer carries the boundary conditions (no-slip:
ghost = 2 U_wall - interior, i.e. the wall value sits on the wall; slip/outflow: zero
normal gradient), and is refilled after every half sweep so the boundary condition is
implicit too. Faces whose value is prescribed (normal faces on walls and inflow, faces
touching a body, cloth-blocked faces) are not updated. Unconditionally stable: the matrix is diagonally dominant.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from windbench.wind.navier_stokes.flags import FAST_MATH
from windbench.wind.navier_stokes.threads import threaded


def error_bound_factor(alpha: float, active_axes: int) -> float:
    """rho / (1 - rho) with rho = 2 alpha d / (1 + 2 alpha d): the distance of the last
    iterate from the exact implicit solution is at most this times the last sweep's largest
    update (a contraction's a-posteriori bound, max norm)."""
    return 2.0 * alpha * active_axes  # rho / (1 - rho) simplifies to 2 alpha d


@njit(cache=True)
def _plane(q, q0, I, colour, alpha, axes, free):
    """Gauss-Seidel update of the faces of colour ``colour`` in the padded plane I.

    Row by row along K: the four neighbour rows are views found once per row and the
    faces of one colour are counted (K = first + 2 m), which compiles to a loop about
    twice as fast as a stepped range with run-time bounds; all three axes active (3D)
    takes the branch-free stencil."""
    P1, P2 = q.shape[1], q.shape[2]
    change = 0.0
    inv = 1.0 / (1.0 + 2.0 * alpha * (axes[0] + axes[1] + axes[2]))
    all_axes = axes[0] != 0 and axes[1] != 0 and axes[2] != 0
    for J in range(1, P1 - 1):
        qc, q0c, fc = q[I, J], q0[I, J], free[I, J]
        xm, xp, ym, yp = q[I - 1, J], q[I + 1, J], q[I, J - 1], q[I, J + 1]
        first = 1 + (I + J + 1 + colour) % 2  # (I + J + K) % 2 == colour
        for m in range((P2 - first) // 2):  # K = first, first + 2, ... <= P2 - 2
            K = first + 2 * m
            if not fc[K]:
                continue
            # q = (q0 + alpha sum nb) / (1 + 2 alpha d), d = number of active axes
            nb = _neighbour_sum(xm, xp, ym, yp, qc, K, axes, all_axes)
            new = (q0c[K] + alpha * nb) * inv
            change = max(change, abs(new - qc[K]))
            qc[K] = new
    return change


@threaded()
def gauss_seidel_half(q, q0, colour, alpha, axes, free, changes):
    """One colour of a red-black sweep; ``changes[I]`` = largest update in plane I.

    Neighbours across a periodic boundary are read from the ghost layer (refilled between
    half sweeps), so no two threads ever touch the same value: bit-reproducible.
    ``axes[b] = 0`` drops axis b: a one-cell periodic axis, whose neighbours are the face
    itself (the 2D problems), so its terms cancel exactly.
    """
    for I in prange(1, q.shape[0] - 1):  # (a signed index: one compiled _plane, see multigrid)
        changes[I] = _plane(q, q0, np.int64(I), colour, alpha, axes, free)


@njit(cache=True, inline="always")
def _neighbour_sum(xm, xp, ym, yp, qc, K, axes, all_axes):
    """sum of the neighbours of face K along the active axes (all three: branch-free)."""
    if all_axes:
        return (xm[K] + xp[K]) + (ym[K] + yp[K]) + (qc[K - 1] + qc[K + 1])
    nb = 0.0
    if axes[0]:
        nb += xm[K] + xp[K]
    if axes[1]:
        nb += ym[K] + yp[K]
    if axes[2]:
        nb += qc[K - 1] + qc[K + 1]
    return nb


@threaded(fastmath=FAST_MATH)
def jacobi_first_sweep(q0, out, alpha, axes, free, changes, peaks):
    """The first sweep from the guess q0 (the right-hand side itself), out of place:
    out = (q0 + alpha sum_nb q0) / (1 + 2 alpha d) on the free faces, out = q0 on every
    other element (prescribed faces, ghosts: refill them from out afterwards).
    ``changes[I]``: the largest update in padded plane I; ``peaks[I]``: the largest |q0|
    there (the field's scale for the stopping test).

    Each plane is copied whole, then its free inner faces updated, the 3D stencil in a
    loop of its own: in one loop over every row that branched on ghost rows, the kernel's
    serial version kept numba's reference counting in the loop (:mod:`.threads`)."""
    P0, P1, P2 = q0.shape
    inv = 1.0 / (1.0 + 2.0 * alpha * (axes[0] + axes[1] + axes[2]))
    all_axes = axes[0] != 0 and axes[1] != 0 and axes[2] != 0
    for I in prange(P0):
        change, peak = 0.0, 0.0
        for J in range(P1):
            qc, oc = q0[I, J], out[I, J]
            for K in range(P2):
                oc[K] = qc[K]
                peak = max(peak, abs(qc[K]))
        inner = (1, P1 - 1) if 0 < I < P0 - 1 else (0, 0)  # no inner rows in a ghost plane
        for J in range(inner[0], inner[1]):
            qc, oc, fc = q0[I, J], out[I, J], free[I, J]
            xm, xp, ym, yp = q0[I - 1, J], q0[I + 1, J], q0[I, J - 1], q0[I, J + 1]
            if all_axes:
                for K in range(1, P2 - 1):
                    if fc[K]:
                        nb = (xm[K] + xp[K]) + (ym[K] + yp[K]) + (qc[K - 1] + qc[K + 1])
                        new = (qc[K] + alpha * nb) * inv
                        oc[K] = new
                        change = max(change, abs(new - qc[K]))
            else:
                for K in range(1, P2 - 1):
                    if fc[K]:
                        nb = _neighbour_sum(xm, xp, ym, yp, qc, K, axes, all_axes)
                        new = (qc[K] + alpha * nb) * inv
                        oc[K] = new
                        change = max(change, abs(new - qc[K]))
        changes[I], peaks[I] = change, peak
