"""Pressure projection on the MAC grid (paper §4.1.1, Stam 1999 step 4).

The projection makes the velocity divergence free: solve the Poisson equation
A psi = -(h div u* - target) for psi (the pressure p dt / (rho h) in cell units), then
u = u* - (psi_+ - psi_-) on every free face (Chorin 1968). On the MAC grid the discrete
divergence (sum of the outward face velocities) and gradient (difference of the two
cells beside a face) are adjoint, so the projection is an orthogonal projection. The
Poisson matrix is assembled from per-face weights (:func:`face_weights`: 1 open, 0 closed
by a wall, a body or cloth) and solved by :mod:`.multigrid`.

Also here: the divergence figures the step records and the cell-centred view of the
staggered field.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from windbench.wind.navier_stokes.boundaries import cells_beside
from windbench.wind.navier_stokes.multigrid import ordered_sum
from windbench.wind.navier_stokes.threads import threaded


@njit(cache=True, inline="always")
def _outward_flux(u, v, w, i, j, k):
    """Sum of the outward face velocities of cell (i, j, k) = h div u there (MAC)."""
    return (
        u[i + 2, j + 1, k + 1]
        - u[i + 1, j + 1, k + 1]
        + v[i + 1, j + 2, k + 1]
        - v[i + 1, j + 1, k + 1]
        + w[i + 1, j + 1, k + 2]
        - w[i + 1, j + 1, k + 1]
    )


@threaded()
def face_flux(u, v, w, target, out):
    """out_c = h div u - target_c = sum of outward face velocities of cell c - target_c."""
    nx, ny, nz = out.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                out[i, j, k] = _outward_flux(u, v, w, i, j, k) - target[i, j, k]


@threaded()
def divergence_norms(u, v, w, target, solid):
    """(max, sum of squares, count) of h div u - target over the air cells, by planes (on
    threads for a large grid, :mod:`.threads`), the squares summed over the planes in
    order: the same bits either way."""
    nx = solid.shape[0]
    peak = np.zeros(nx)
    squares = np.zeros(nx)
    count = np.zeros(nx, dtype=np.int64)
    for i in prange(nx):
        peak[i], squares[i], count[i] = _divergence_plane(u, v, w, target, solid, np.int64(i))
    return peak.max(), ordered_sum(squares), count.sum()


@njit(cache=True, error_model="numpy")
def _divergence_plane(u, v, w, target, solid, i):
    """(max, sum of squares, count) of |h div u - target| over the air cells of plane i
    (a function of its own, with the error model numba gives a parallel loop's body: the
    same bits whether its caller runs the planes in parallel or not)."""
    top, sq, cnt = 0.0, 0.0, 0
    for j in range(solid.shape[1]):
        for k in range(solid.shape[2]):
            if solid[i, j, k]:
                continue
            d = abs(_outward_flux(u, v, w, i, j, k) - target[i, j, k])
            top = max(top, d)
            sq += d * d
            cnt += 1
    return top, sq, cnt


def largest_magnitude(q) -> float:
    """max |q|, from numpy's max and min of q (no array of |q|: a once-per-step figure,
    where numpy's reductions beat a serial loop)."""
    return max(float(q.max()), -float(q.min()))


@njit(cache=True, inline="always")
def face_cells(I, J, K, a, nx, ny, nz, wrap):
    """The cells beside the padded face (I, J, K) of component a on an nx x ny x nz grid:
    (i+, j+, k+, whether that cell exists, i-, j-, k-, whether it exists), the - cell
    wrapped across the face if ``wrap`` (periodic axis a). A missing cell is the ghost
    psi = 0 beyond an opening or outflow face. Indices only: the kernels read psi
    themselves, since an inlined helper that takes an array in their loops kept numba's
    reference counting there in their serial versions (:mod:`.threads`)."""
    ip, jp, kp, im, jm, km = cells_beside(I, J, K, a)
    along = ip if a == 0 else (jp if a == 1 else kp)  # index of the + cell
    plus_in = along < (nx if a == 0 else (ny if a == 1 else nz))
    if along >= 1:
        return ip, jp, kp, plus_in, im, jm, km, True
    if wrap:
        return ip, jp, kp, plus_in, im % nx, jm % ny, km % nz, True
    return ip, jp, kp, plus_in, im, jm, km, False


@njit(cache=True, inline="always")
def psi_difference(psi, a, I, J, K, periodic):
    """psi_+ - psi_- across the padded face (I, J, K) of component a (:func:`face_cells`;
    for code outside the threaded kernels' loops)."""
    nx, ny, nz = psi.shape
    ip, jp, kp, plus_in, im, jm, km, minus_in = face_cells(I, J, K, a, nx, ny, nz, periodic[a])
    return (psi[ip, jp, kp] if plus_in else 0.0) - (psi[im, jm, km] if minus_in else 0.0)


@threaded()
def subtract_gradient(q, a, psi, free, periodic):
    """q_f -= psi_+ - psi_- on the free faces of component a (the projection)."""
    P0, P1, P2 = q.shape
    nx, ny, nz = psi.shape
    wrap = periodic[a]
    for I in prange(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                if free[I, J, K]:
                    ip, jp, kp, p_in, im, jm, km, m_in = face_cells(I, J, K, a, nx, ny, nz, wrap)
                    plus = psi[ip, jp, kp] if p_in else 0.0
                    q[I, J, K] -= plus - (psi[im, jm, km] if m_in else 0.0)


@njit(cache=True)
def cell_centred(u, v, w, solid, out):
    """out = mean of the two faces per axis at each cell centre; 0 in solid cells."""
    nx, ny, nz = solid.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                if solid[i, j, k]:
                    out[i, j, k, 0] = 0.0
                    out[i, j, k, 1] = 0.0
                    out[i, j, k, 2] = 0.0
                    continue
                out[i, j, k, 0] = 0.5 * (u[i + 1, j + 1, k + 1] + u[i + 2, j + 1, k + 1])
                out[i, j, k, 1] = 0.5 * (v[i + 1, j + 1, k + 1] + v[i + 1, j + 2, k + 1])
                out[i, j, k, 2] = 0.5 * (w[i + 1, j + 1, k + 1] + w[i + 1, j + 1, k + 2])


def face_weights(free, a, periodic, out):
    """Poisson face weights of axis a (unpadded faces) from the free-face mask."""
    n0, n1, n2 = out.shape
    out[...] = free[1 : n0 + 1, 1 : n1 + 1, 1 : n2 + 1]
    if periodic[a] and out.shape[a] == 2:  # one periodic cell: the face meets itself
        out[...] = 0.0
    elif periodic[a]:  # the duplicate last face carries the first one's weight
        last, first = [slice(None)] * 3, [slice(None)] * 3
        last[a], first[a] = out.shape[a] - 1, 0
        out[tuple(last)] = out[tuple(first)]
