"""Implicit viscous diffusion of one staggered velocity component (paper §4.1.1, Stam 1999).

Backward Euler for du/dt = nu lap u on the MAC faces:

    (1 + 6 alpha) q_f - alpha sum_{6 neighbours} q_nb = q0_f,   alpha = nu dt / h^2,

solved by red-black Gauss-Seidel until the error bound of a contraction, rho / (1 - rho)
times the largest update of the last sweep, is below ``tol`` times the field's scale:
the Jacobi factor rho = 2 alpha d / (1 + 2 alpha d) (d active axes) bounds the max-norm
contraction of a Gauss-Seidel sweep on this diagonally dominant M-matrix
(:func:`error_bound_factor`). The ghost layer carries the boundary conditions (no-slip:
ghost = 2 U_wall - interior, i.e. the wall value sits on the wall; slip/outflow: zero
normal gradient), and is refilled after every half sweep so the boundary condition is
implicit too. Faces whose value is prescribed (normal faces on walls and inflow, faces
touching a body, cloth-blocked faces) are not updated. Unconditionally stable: the matrix is diagonally dominant.
"""

from __future__ import annotations

from numba import njit, prange


def error_bound_factor(alpha: float, active_axes: int) -> float:
    """rho / (1 - rho) with rho = 2 alpha d / (1 + 2 alpha d): the distance of the last
    iterate from the exact implicit solution is at most this times the last sweep's largest
    update (a contraction's a-posteriori bound, max norm)."""
    return 2.0 * alpha * active_axes  # rho / (1 - rho) simplifies to 2 alpha d


@njit(cache=True)
def _plane(q, q0, I, colour, alpha, axes, free):
    """Gauss-Seidel update of the faces of colour ``colour`` in the padded plane I."""
    P0, P1, P2 = q.shape
    change = 0.0
    inv = 1.0 / (1.0 + 2.0 * alpha * (axes[0] + axes[1] + axes[2]))
    for J in range(1, P1 - 1):
        for K in range(1 + (I + J + 1 + colour) % 2, P2 - 1, 2):  # (I + J + K) % 2 == colour
            if not free[I, J, K]:
                continue
            # q = (q0 + alpha sum nb) / (1 + 2 alpha d), d = number of active axes
            nb = 0.0
            if axes[0]:
                nb += q[I - 1, J, K] + q[I + 1, J, K]
            if axes[1]:
                nb += q[I, J - 1, K] + q[I, J + 1, K]
            if axes[2]:
                nb += q[I, J, K - 1] + q[I, J, K + 1]
            new = (q0[I, J, K] + alpha * nb) * inv
            change = max(change, abs(new - q[I, J, K]))
            q[I, J, K] = new
    return change


@njit(cache=True, parallel=True)
def gauss_seidel_half(q, q0, colour, alpha, axes, free, changes):
    """One colour of a red-black sweep; ``changes[I]`` = largest update in plane I.

    Neighbours across a periodic boundary are read from the ghost layer (refilled between
    half sweeps), so no two threads ever touch the same value: bit-reproducible.
    ``axes[b] = 0`` drops axis b: a one-cell periodic axis, whose neighbours are the face
    itself (the 2D problems), so its terms cancel exactly.
    """
    for I in prange(1, q.shape[0] - 1):
        changes[I] = _plane(q, q0, I, colour, alpha, axes, free)
