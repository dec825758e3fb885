"""The Poisson solve of the projection (paper §4.1.1, the Helmholtz-Hodge step of Stam
1999): conjugate gradients preconditioned by one geometric multigrid cycle (MGPCG,
McAdams, Sifakis and Teran 2010), on a face-weighted cell mask.

The unknown is psi = p dt / (rho h) on cell centres; the projected face velocity is
u_f - (psi_+ - psi_-). Each face carries a weight w_f in {0, 1}: 1 where air may cross,
0 where the normal velocity is prescribed (walls, inflow, bodies, cloth); outflow and
opening faces have w = 1 and a ghost psi = 0. Zero divergence in every air cell reads

    (A psi)_c = sum_faces w_f (psi_c - psi_nb) = b_c = -(sum of outward face velocities)_c,

a symmetric positive (semi-)definite system; changing which faces are open only rewrites
the weights (:meth:`MultigridPoisson.set_weights`).

Multigrid: cell-centred, every axis of >= 4 cells halved per level (an odd one to (n + 1)/2
cells, the last over one fine cell, faces beyond it closed; a periodic one only into an
even count: red and black must alternate across its seam); coarse face weight = mean of
the fine ones covered, the operator re-discretised with coefficient (h/H)^2 per axis;
restriction = sum over the children / a full block's count, prolongation P injection
(restriction = P^T times a constant); red-black successive over-relaxation x_c += omega
((b_c + sum_f w_f x_nb) / diag - x_c), omega = ``OMEGA`` on the coarse levels,
``FINE_OMEGA`` = 1 on the finest, the same sweeps reversed on the way up: the symmetric
positive definite preconditioner CG needs. The first coarse levels correct twice (a W,
``W_LEVELS``), the others once (a V); the cycle runs in single precision
(``PRECONDITIONER_DTYPE``), CG in double. Levels below ``SERIAL_CELLS`` cells run as one
compiled call on flat tables (:mod:`.coarse_levels`); those below
``threads.PARALLEL_CELLS`` the kernels' serial versions (:mod:`.threads`), the others
smooth slab by slab in a wavefront (:func:`smooth_by_slabs`: the same numbers in two
parallel loops instead of one per half sweep).

The kernels work row by row along z, each row classified once per weight change
(:func:`classify_rows`): ALL_OPEN rows use the constant 7-point stencil, ROW_CONSTANT rows
per-row coefficients, GENERAL rows the face weights cell by cell. Reductions sum by planes,
then the planes in order (:func:`ordered_sum`): the same numbers on any thread count.
Without a pressure boundary the constant is removed from the right-hand side and each
preconditioned residual. CG stops at ||r||_2 <= tol ||b||_2 (start: :mod:`.guess`).

The per-cell and per-row helpers are plain compiled functions that LLVM inlines; numba's
``inline="always"`` gave the same numbers and speed for twice the compile time
(``experiments/compile_times.py``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from windbench.wind.navier_stokes import threads
from windbench.wind.navier_stokes.coarse_levels import CoarseLevels
from windbench.wind.navier_stokes.flags import FAST_MATH
from windbench.wind.navier_stokes.threads import select, threaded

SERIAL_CELLS = 32768  # levels with fewer cells run on one thread (:mod:`.coarse_levels`)
PRE_SWEEPS = 2  # per level and direction
# Planes per slab of the smoother on the levels in the kernels' parallel versions
# (:func:`smooth_by_slabs`; at least 2 (2 PRE_SWEEPS) - 1): 128 KB per float32 field and
# slab at 64^3.
SLAB_PLANES = 8
# Levels whose coarse-grid correction is two cycles of the next level (a W on the first
# coarse levels, a V below): the fewest MGPCG iterations per solve for the least time on
# the fence from 32^3 to 128^3 (each choice timed with ``experiments/bench_ns.py``); a W
# on level 1 alone saves no iteration at 64^3 and 128^3, a W down to level 3 no more time.
W_LEVELS = (1, 2)
# Over-relaxation of the smoother on the coarse levels (OMEGA) and on the finest one
# (FINE_OMEGA), where most of the smoothing time goes and where Gauss-Seidel's loop (x_c
# not read) is cheaper than SOR's: over-relaxing the coarse levels alone saves nearly as
# many iterations at 128^3 as over-relaxing every level, without the finest level's
# slower loop.
OMEGA = 1.1
FINE_OMEGA = 1.0
# The multigrid cycle (the preconditioner) works in single precision: it only has to
# approximate A^-1; CG's vectors, residual and stopping test stay in double precision, so
# the pressure still meets the relative residual tolerance in float64. Half the bytes per
# sweep: the 128^3 levels do not fit in the cache. The face weights are exact in float32
# (0, 1 and means of them times powers of 1/4).
PRECONDITIONER_DTYPE = np.float32
# Cells per axis of the blocks whose net residual weighs a starting guess (two coarsenings:
# :meth:`MultigridPoisson.smooth_residual_norm`): the block size with the fewest iterations
# per step after the guess of :mod:`.guess` on the fence and two_flags_wall in a developed
# flow (blocks of 1, 2 and 4 timed with ``experiments/bench_ns.py``); a cell's own
# residual (blocks of 1) favours the guess whose error the cycle removes at once, not the
# one that costs the iterations.
GUESS_BLOCK = 4
# the smoother's (r, partial) when no dot is wanted (:func:`gauss_seidel`)
NO_DOT = (np.zeros((0, 0, 0)), np.zeros(0))


# What :func:`_operator_plane` computes: as run-time booleans (np.bool_), not constants, so
# that both share one compiled version (a constant True or False is a literal type, which
# numba compiles a version of the function for). Likewise the parallel loops hand their
# plane index on as np.int64: prange's own index is unsigned in the parallel version of
# the loop and signed in its first typing, and each would compile the callee once more.
RESIDUAL, OPERATOR = np.bool_(True), np.bool_(False)

# Row classes (:func:`classify_rows`): the kernels treat each row (i, j, :) by its class.
ALL_OPEN = 0  # interior row of an isotropic level, every face of its inner cells open
ROW_CONSTANT = 1  # each of the inner cells' six face weights the same all along the row
GENERAL = 2  # the rest: rows cut by a body or by cloth, rows without an open face


@njit(cache=True)
def _cell_face_weights(wx, wy, wz, i, j, k):
    """The six face weights of cell (i, j, k): -x, +x, -y, +y, -z, +z."""
    return wx[i, j, k], wx[i + 1, j, k], wy[i, j, k], wy[i, j + 1, k], wz[i, j, k], wz[i, j, k + 1]


@njit(cache=True)
def _row_neighbours(i, n, periodic):
    """(lower, upper) index of the rows beside row i on an axis of n rows, and a factor
    each, 1 where that neighbour exists (inside, or wrapped on a periodic axis) and 0 where
    it is the ghost x = 0 beyond a wall or an opening. A ghost's index is another row of
    the level (i + 1 or i - 1; i itself only when n == 1), read and multiplied by 0: the
    views of x then never alias the row being updated, whose overlap check would send the
    loop to its scalar version."""
    lower_in, upper_in = i > 0 or periodic, i < n - 1 or periodic
    im = (i - 1 if i > 0 else n - 1) if lower_in else min(i + 1, n - 1)
    ip = (i + 1 if i < n - 1 else 0) if upper_in else max(i - 1, 0)
    return im, 1.0 if lower_in else 0.0, ip, 1.0 if upper_in else 0.0


@njit(cache=True)
def _neighbour_rows(x, periodic, i, j):
    """Views of the rows beside row (i, j, :) along x and y (-x, +x, -y, +y), and their
    factors (:func:`_row_neighbours`). One view expression each, with a computed index:
    views chosen between x and a separate zero row by a condition made the loops about
    twice as slow (numba 0.68)."""
    im, fxm, ip, fxp = _row_neighbours(i, x.shape[0], periodic[0])
    jm, fym, jp, fyp = _row_neighbours(j, x.shape[1], periodic[1])
    return x[im, j], x[ip, j], x[i, jm], x[i, jp], (fxm, fxp, fym, fyp)


@njit(cache=True)
def _inner_rows(x, i, j):
    """Views of the rows beside an interior row (i, j, :) (0 < i < nx - 1, 0 < j < ny - 1):
    -x, +x, -y, +y, without a condition (the all-open rows' loops)."""
    return x[i - 1, j], x[i + 1, j], x[i, j - 1], x[i, j + 1]


@njit(cache=True)
def _weighted_sum(xc, xm, xp, ym, yp, wxm, wxp, wym, wyp, wz, f, k):
    """(sum_f w_f x_nb, diag = sum_f w_f) at inner cell 0 < k < nz - 1 of a GENERAL row,
    from the row views of x and of the face weights (which carry the level's (h/H)^2
    factor; a closed face has w = 0 and drops out of both sums) and the neighbour factors
    ``f`` (0 for a ghost: its face counts in diag, its value is 0)."""
    w0, w1, w2, w3, w4, w5 = wxm[k], wxp[k], wym[k], wyp[k], wz[k], wz[k + 1]
    s = f[0] * w0 * xm[k] + f[1] * w1 * xp[k] + f[2] * w2 * ym[k] + f[3] * w3 * yp[k]
    return s + w4 * xc[k - 1] + w5 * xc[k + 1], w0 + w1 + w2 + w3 + w4 + w5


@njit(cache=True)
def _end_sum(xc, xm, xp, ym, yp, ends, i, j, side):
    """(sum_f c_f x_nb, diag) at the end cell k = 0 (side 0) or k = nz - 1 (side 1) of row
    (i, j) from the compact table ``ends`` (:func:`classify_rows`: neighbour coefficients,
    0 for a ghost, and diag): the weight arrays are not touched by the ALL_OPEN and
    ROW_CONSTANT rows, and reading them for one cell per row missed the cache."""
    nz = xc.shape[0]
    k = 0 if side == 0 else nz - 1
    km = k - 1 if k > 0 else nz - 1  # (any index where the coefficient is 0)
    kp = k + 1 if k < nz - 1 else 0
    e = ends[i, j, side]
    s = e[0] * xm[k] + e[1] * xp[k] + e[2] * ym[k] + e[3] * yp[k] + e[4] * xc[km] + e[5] * xc[kp]
    return s, e[6]


@njit(cache=True)
def _ends(nz):
    """How many distinct end cells a row of nz cells has (one when nz == 1)."""
    return 2 if nz > 1 else 1


@njit(cache=True)
def classify_rows(wx, wy, wz, coef, periodic, rows, row_coef, ends):
    """After the weights change: each row's class (ALL_OPEN, ROW_CONSTANT, GENERAL) in
    ``rows``; for ROW_CONSTANT rows ``row_coef[i, j]`` = the neighbour coefficients of the
    inner cells (-x, +x, -y, +y: the face weight, 0 for a ghost; z), diag = the sum of the
    six face weights, and omega / diag (coef[6] = omega); for every row ``ends[i, j,
    side]`` = the six neighbour coefficients and diag of the end cell k = 0 (side 0) or
    nz - 1 (side 1). Rows without an open face are GENERAL (their cells are left alone)."""
    nx, ny, nz = rows.shape[0], rows.shape[1], wx.shape[2]
    isotropic = coef[0] == coef[1] and coef[1] == coef[2]
    for i in range(nx):
        fxm, fxp = _row_neighbours(i, nx, periodic[0])[1::2]
        for j in range(ny):
            fym, fyp = _row_neighbours(j, ny, periodic[1])[1::2]
            for side in range(2):
                k = 0 if side == 0 else nz - 1
                fzm, fzp = _row_neighbours(k, nz, periodic[2])[1::2]
                w = _cell_face_weights(wx, wy, wz, i, j, k)
                factor = (fxm, fxp, fym, fyp, fzm, fzp)
                for f in range(6):
                    ends[i, j, side, f] = w[f] * factor[f]
                ends[i, j, side, 6] = w[0] + w[1] + w[2] + w[3] + w[4] + w[5]
            w = _cell_face_weights(wx, wy, wz, i, j, min(1, nz - 1))
            constant = w[4] == w[5]
            for k in range(2, nz - 1):
                if _cell_face_weights(wx, wy, wz, i, j, k) != w:
                    constant = False
                    break
            diag = w[0] + w[1] + w[2] + w[3] + w[4] + w[5]
            interior = 0 < i < nx - 1 and 0 < j < ny - 1
            if not constant or diag == 0.0:
                rows[i, j] = GENERAL
            elif (
                isotropic
                and interior
                and w == (coef[0], coef[0], coef[0], coef[0], coef[0], coef[0])
            ):
                rows[i, j] = ALL_OPEN
            else:
                rows[i, j] = ROW_CONSTANT
            row_coef[i, j, 0], row_coef[i, j, 1] = w[0] * fxm, w[1] * fxp
            row_coef[i, j, 2], row_coef[i, j, 3] = w[2] * fym, w[3] * fyp
            row_coef[i, j, 4], row_coef[i, j, 5] = w[4], diag
            row_coef[i, j, 6] = coef[6] / diag if diag > 0.0 else 0.0


@njit(cache=True)
def _operator_plane(x, b, level, i, out, residual):
    """out = (b - A x)[i] if ``residual``, else (A x)[i] (b unread); ``out`` is a plane (a
    view of the output's plane i, or scratch); ``level`` the level's :class:`Stencil`.
    Each row class in a loop of its own (see :func:`_gs_plane`)."""
    wx, wy, wz, periodic, rows, row_coef, ends, coef = level
    sign = 1.0 if residual else -1.0
    c0, c1, c2 = coef[0], coef[1], coef[2]
    d_uniform = 2.0 * (c0 + c1 + c2)
    nz = x.shape[2]
    for j in range(x.shape[1]):
        if rows[i, j] != ALL_OPEN:
            continue
        xc, bc, oc = x[i, j], b[i, j], out[j]
        am, ap, bm, bp = _inner_rows(x, i, j)
        for k in range(1, nz - 1):  # contiguous, no weight reads: vectorised
            s = c0 * (am[k] + ap[k]) + c1 * (bm[k] + bp[k]) + c2 * (xc[k - 1] + xc[k + 1])
            oc[k] = (bc[k] if residual else 0.0) - sign * (d_uniform * xc[k] - s)
        _operator_row_ends(xc, bc, oc, am, ap, bm, bp, ends, i, j, residual)
    for j in range(x.shape[1]):
        if rows[i, j] != ROW_CONSTANT:
            continue
        xc, bc, oc = x[i, j], b[i, j], out[j]
        am, ap, bm, bp, _ = _neighbour_rows(x, periodic, i, j)
        r = row_coef[i, j]
        r0, r1, r2, r3, rz, d = r[0], r[1], r[2], r[3], r[4], r[5]
        for k in range(1, nz - 1):
            s = r0 * am[k] + r1 * ap[k] + r2 * bm[k] + r3 * bp[k] + rz * xc[k - 1] + rz * xc[k + 1]
            oc[k] = (bc[k] if residual else 0.0) - sign * (d * xc[k] - s)
        _operator_row_ends(xc, bc, oc, am, ap, bm, bp, ends, i, j, residual)
    for j in range(x.shape[1]):
        if rows[i, j] != GENERAL:
            continue
        xc, bc, oc = x[i, j], b[i, j], out[j]
        xm, xp, ym, yp, f = _neighbour_rows(x, periodic, i, j)
        wxm, wxp, wym, wyp, wzc = wx[i, j], wx[i + 1, j], wy[i, j], wy[i, j + 1], wz[i, j]
        for k in range(1, nz - 1):
            s, d = _weighted_sum(xc, xm, xp, ym, yp, wxm, wxp, wym, wyp, wzc, f, k)
            oc[k] = (bc[k] if residual else 0.0) - sign * (d * xc[k] - s)
        _operator_row_ends(xc, bc, oc, xm, xp, ym, yp, ends, i, j, residual)


@njit(cache=True)
def _operator_row_ends(xc, bc, oc, xm, xp, ym, yp, ends, i, j, residual):
    """The end cells k = 0 and nz - 1 of row (i, j) for :func:`_operator_plane`."""
    sign = 1.0 if residual else -1.0
    nz = xc.shape[0]
    for side in range(_ends(nz)):
        s, d = _end_sum(xc, xm, xp, ym, yp, ends, i, j, side)
        k = 0 if side == 0 else nz - 1
        oc[k] = (bc[k] if residual else 0.0) - sign * (d * xc[k] - s)


@threaded()
def residual(x, b, level, out):
    """out = b - A x; returns out . out, summed as :func:`dot` does (in the same pass)."""
    partial = np.empty(x.shape[0])
    for i in prange(x.shape[0]):
        _operator_plane(x, b, level, np.int64(i), out[i], RESIDUAL)
        partial[i] = _plane_dot(out, out, i)
    return ordered_sum(partial)


@threaded()
def apply_operator(x, level, out):
    """out = A x = sum_f c w_f (x_c - x_nb); returns x . A x, summed as :func:`dot` does
    (plane by plane while the plane is in cache: one pass less per CG iteration)."""
    partial = np.empty(x.shape[0])
    for i in prange(x.shape[0]):
        _operator_plane(x, x, level, np.int64(i), out[i], OPERATOR)
        partial[i] = _plane_dot(x, out, i)
    return ordered_sum(partial)


@njit(cache=True, fastmath=FAST_MATH)
def _gs_plane(x, b, level, i, colour):
    """One colour of plane i. Cells of one colour do not neighbour each other, so the
    order within a colour does not matter: each row class in a loop of its own (the other
    rows' code in the ALL_OPEN rows' loop keeps numba from optimising it), ALL_OPEN in
    functions of their own. The stores are written out in the loops: numba does not
    optimise a loop that calls an inlined helper storing into an array as well."""
    wx, wy, wz, periodic, rows, row_coef, ends, coef = level
    if coef[6] == 1.0:
        _constant_rows_gauss_seidel(x, b, rows, ends, coef, i, colour)
    else:
        _constant_rows_sor(x, b, rows, ends, coef, i, colour)
    nz = x.shape[2]
    keep, omega = coef[5], coef[6]
    for j in range(x.shape[1]):  # ROW_CONSTANT: per-row coefficients, no weight reads
        if rows[i, j] != ROW_CONSTANT:
            continue
        first = (i + j + colour) % 2
        xc, bc = x[i, j], b[i, j]
        am, ap, bm, bp, _ = _neighbour_rows(x, periodic, i, j)
        r = row_coef[i, j]
        r0, r1, r2, r3, rz, gain = r[0], r[1], r[2], r[3], r[4], r[6]
        for m in range((nz - 2 + first) // 2):
            k = 2 - first + 2 * m
            s = r0 * am[k] + r1 * ap[k] + r2 * bm[k] + r3 * bp[k] + rz * (xc[k - 1] + xc[k + 1])
            xc[k] = keep * xc[k] + gain * (bc[k] + s)
        _gs_row_ends(xc, bc, am, ap, bm, bp, ends, i, j, first, omega)
    for j in range(x.shape[1]):  # GENERAL: the face weights cell by cell
        if rows[i, j] != GENERAL:
            continue
        first = (i + j + colour) % 2
        xc, bc = x[i, j], b[i, j]
        xm, xp, ym, yp, f = _neighbour_rows(x, periodic, i, j)
        wxm, wxp, wym, wyp, wzc = wx[i, j], wx[i + 1, j], wy[i, j], wy[i, j + 1], wz[i, j]
        for m in range((nz - 2 + first) // 2):
            k = 2 - first + 2 * m
            s, d = _weighted_sum(xc, xm, xp, ym, yp, wxm, wxp, wym, wyp, wzc, f, k)
            if d > 0.0:  # (a cell without an open face is left alone)
                xc[k] += omega * ((bc[k] + s) / d - xc[k])
        _gs_row_ends(xc, bc, xm, xp, ym, yp, ends, i, j, first, omega)


@njit(cache=True)
def _constant_row(x, b, i, j, colour):
    """Row (i, j) for the ALL_OPEN smoother loops: the first k of this colour, how many
    inner cells of it (k = 2 - first, 4 - first, ... < nz - 1: counted, since a stepped
    range with run-time bounds compiles to a loop almost twice as slow), and views of the
    row, of b and of the neighbour rows taken without a condition."""
    first = (i + j + colour) % 2
    count = (x.shape[2] - 2 + first) // 2
    return first, count, x[i, j], b[i, j], _inner_rows(x, i, j)


@njit(cache=True, fastmath=FAST_MATH)
def _constant_rows_gauss_seidel(x, b, rows, ends, coef, i, colour):
    """One colour of the ALL_OPEN rows of plane i, omega = 1: x_c = (b_c + sum x_nb) / diag
    as gain b_c + gain c0 sum x_nb (coef[3], coef[4], in x's precision: float32 arithmetic
    throughout, rather than converting each value to float64 and back)."""
    gain, g = coef[3], coef[4]
    for j in range(x.shape[1]):
        if rows[i, j] == ALL_OPEN:
            first, count, xc, bc, (am, ap, bm, bp) = _constant_row(x, b, i, j, colour)
            for m in range(count):
                k = 2 - first + 2 * m
                nb = am[k] + ap[k] + bm[k] + bp[k] + xc[k - 1] + xc[k + 1]
                xc[k] = gain * bc[k] + g * nb
            _gs_row_ends(xc, bc, am, ap, bm, bp, ends, i, j, first, coef[6])


@njit(cache=True, fastmath=FAST_MATH)
def _constant_rows_sor(x, b, rows, ends, coef, i, colour):
    """:func:`_constant_rows_gauss_seidel` with over-relaxation: x_c = (1 - omega) x_c +
    omega (b_c + sum x_nb) / diag, 1 - omega in coef[5] (a loop of its own: reading x_c
    makes it slower than Gauss-Seidel's)."""
    gain, g, keep = coef[3], coef[4], coef[5]
    for j in range(x.shape[1]):
        if rows[i, j] == ALL_OPEN:
            first, count, xc, bc, (am, ap, bm, bp) = _constant_row(x, b, i, j, colour)
            for m in range(count):
                k = 2 - first + 2 * m
                nb = am[k] + ap[k] + bm[k] + bp[k] + xc[k - 1] + xc[k + 1]
                xc[k] = keep * xc[k] + gain * bc[k] + g * nb
            _gs_row_ends(xc, bc, am, ap, bm, bp, ends, i, j, first, coef[6])


@njit(cache=True)
def _gs_row_ends(xc, bc, xm, xp, ym, yp, ends, i, j, first, omega):
    """The end cells k = 0 and nz - 1 of row (i, j) if they have colour ``first``, from
    the views of the row and its neighbours."""
    nz = xc.shape[0]
    for side in range(_ends(nz)):
        k = 0 if side == 0 else nz - 1
        if k % 2 == first:
            s, d = _end_sum(xc, xm, xp, ym, yp, ends, i, j, side)
            if d > 0.0:  # (a cell without an open face is left alone)
                xc[k] += omega * ((bc[k] + s) / d - xc[k])


@threaded(fastmath=FAST_MATH)
def gauss_seidel(x, b, level, colour, halves, r, partial):
    """``halves`` half sweeps of red-black SOR (the level's omega, coef[6]) on A x = b,
    alternating colours from ``colour`` (cells with (i+j+k) % 2 == colour first), planes
    in parallel: a cycle's smoothing on one level is one call, not a Python call per half
    sweep.

    On a periodic x axis with an odd number of planes the last plane neighbours the first
    one in the same colour: it is done after the parallel loop (no race, bit-reproducible).

    With ``partial`` of one entry per plane (else empty): returns r . x after the last
    half sweep, each plane's share taken as soon as that sweep has finished the plane
    (no other plane writes it), summed by planes in order as :func:`dot` does: CG's r . M r
    without a pass of its own.
    """
    nx = x.shape[0]
    periodic = level[3]
    last = nx - 1 if (periodic[0] and nx % 2 == 1 and nx > 1) else nx
    with_dot = partial.shape[0] == nx
    for half in range(halves):
        c = (colour + half) % 2
        final = with_dot and half == halves - 1
        for i in prange(last):
            _gs_plane(x, b, level, np.int64(i), c)
            if final:
                partial[i] = _plane_dot(r, x, i)
        for i in range(last, nx):
            _gs_plane(x, b, level, i, c)
            if final:
                partial[i] = _plane_dot(r, x, i)
    return ordered_sum(partial) if with_dot else 0.0


@threaded(fastmath=FAST_MATH)
def smooth_by_slabs(x, b, level, colour, halves, r, partial, slabs):
    """:func:`gauss_seidel` slab by slab (``slabs``: :func:`slab_bounds`, where
    :func:`wavefront_fits`): a wavefront over each slab (:func:`_slab_wavefront`), then
    the wedges around the seams between slabs (:func:`_seam`), two parallel loops instead
    of one per half sweep. Every cell is updated from the same neighbour values as in the
    half sweeps one after the other, so the same bits, with one wake-up of the threads
    less per half sweep beyond the second (60-80 microseconds each under the passive
    wait, :mod:`windbench.runtime`) and each plane swept while it is in the cache."""
    n_slabs = slabs.shape[0] - 1
    for s in prange(n_slabs):
        _slab_wavefront(x, b, level, colour, halves, r, partial, slabs, np.int64(s))
    for s in prange(n_slabs):
        _seam(x, b, level, colour, halves, r, partial, slabs, np.int64(s))
    return ordered_sum(partial) if partial.shape[0] == x.shape[0] else 0.0


def wavefront_fits(slabs: np.ndarray, halves: int, periodic_x: bool) -> bool:
    """Whether :func:`smooth_by_slabs` can take ``halves`` half sweeps on ``slabs``: more
    than one slab, each of at least 2 halves - 1 planes (the seams' wedges then neither
    meet nor read each other's planes), and no periodic x axis of an odd number of
    planes."""
    sizes = np.diff(slabs)
    odd_wrap = bool(periodic_x) and int(slabs[-1]) % 2 == 1
    return len(sizes) > 1 and not odd_wrap and int(sizes.min()) >= 2 * halves - 1


@njit(cache=True)
def _has_seam_below(slabs, s, periodic_x):
    """Whether slab s has another slab below it (slab 0: the last one, on a periodic x)."""
    return s > 0 or periodic_x


@njit(cache=True, error_model="numpy")
def _slab_wavefront(x, b, level, colour, halves, r, partial, slabs, s):
    """The half sweeps of slab s's planes [lo, hi) that need no plane of another slab
    after its first half sweep: half sweep h on the planes lo + h c_lo <= i < hi - h c_hi,
    c = 1 at an end with another slab beyond it (a seam), 0 at a wall, so a trapezoid.

    Half sweep h of plane i reads the other colour on planes i - 1 and i + 1, which must
    have had half sweep h - 1 and not yet h + 1 (h itself changes the colour not read).
    The planes go as a wavefront: at step t, half sweep h on plane t - h, h = 0, 1, ...,
    so plane i + 1 has just had h - 1 and plane i - 1 has h + 1 still ahead. Across a
    seam the slabs run at once: the first half sweep of the plane beside it changes only
    the colour the other slab's plane does not read, and the planes beside a seam get no
    further half sweep here (:func:`_seam` finishes them)."""
    periodic = level[3]
    n_slabs = slabs.shape[0] - 1
    lo, hi = slabs[s], slabs[s + 1]
    cut_lo = 1 if _has_seam_below(slabs, s, periodic[0]) else 0
    cut_hi = 1 if (s < n_slabs - 1 or periodic[0]) else 0
    with_dot = partial.shape[0] == x.shape[0]
    for t in range(lo, hi + halves - 1):
        for h in range(halves):
            i = t - h
            if lo + h * cut_lo <= i < hi - h * cut_hi:
                _gs_plane(x, b, level, i, (colour + h) % 2)
                if with_dot and h == halves - 1:
                    partial[i] = _plane_dot(r, x, i)


@njit(cache=True, error_model="numpy")
def _seam(x, b, level, colour, halves, r, partial, slabs, s):
    """The half sweeps :func:`_slab_wavefront` left around the seam below slab s (none
    for slab 0 below a wall): after it, plane seam + m above the seam has had half sweeps
    0..m and plane seam - 1 - m below it 0..m, so half sweep h = 1, 2, ... goes on the h
    planes on either side nearest the seam, whose neighbours have then had h - 1 and,
    outside the wedge, exactly h (they are inside the slabs' trapezoids, which a
    neighbouring seam's wedge does not reach: 2 halves - 1 planes per slab at least)."""
    periodic = level[3]
    if not _has_seam_below(slabs, s, periodic[0]):
        return
    nx = x.shape[0]
    seam = slabs[s]
    with_dot = partial.shape[0] == nx
    for h in range(1, halves):
        for m in range(h):
            for i in ((seam - 1 - m) % nx, seam + m):
                _gs_plane(x, b, level, i, (colour + h) % 2)
                if with_dot and h == halves - 1:
                    partial[i] = _plane_dot(r, x, i)


def slab_bounds(planes: int, per_slab: int) -> np.ndarray:
    """The first plane of each slab of :func:`smooth_by_slabs`, then ``planes``: slabs of
    about ``per_slab`` planes (at least that many where there are two or more), as equal
    as they can be; one slab if per_slab <= 0."""
    count = 1 if per_slab <= 0 else max(1, planes // per_slab)
    return (np.arange(count + 1, dtype=np.int64) * planes) // count


@threaded()
def block_residual(x, b, level, m):
    """sum over the blocks of m x m x m cells of (the residual b - A x summed over the
    block)^2, blocks cut short at the far ends, summed by block planes in order. A block's
    sum is its net imbalance: the smooth part of the residual, which a multigrid cycle
    reduces slowest, while a part that changes sign from cell to cell cancels in it."""
    partial = np.empty(-(-x.shape[0] // m))
    for I in prange(partial.shape[0]):
        partial[I] = _block_plane(x, b, level, m, np.int64(I))
    return ordered_sum(partial)


@njit(cache=True, error_model="numpy")
def _block_plane(x, b, level, m, I):
    """The blocks of plane I of :func:`block_residual`: their squared sums, added up."""
    n0, n1, n2 = x.shape
    sums = np.zeros((-(-n1 // m), -(-n2 // m)))
    plane = np.empty((n1, n2), x.dtype)
    for i in range(m * I, min(m * I + m, n0)):
        _operator_plane(x, b, level, i, plane, RESIDUAL)
        for j in range(n1):
            for k in range(n2):
                sums[j // m, k // m] += plane[j, k]
    return (sums * sums).sum()


@threaded()
def residual_restrict(x, b, level, ratio, coarse):
    """coarse[I,J,K] = sum of the residual b - A x over the fine cells it covers, divided
    by the ratios' product (ratio 1 or 2 per axis): the mean of the children, and on an
    odd axis halved the last coarse cell's one child over 2, so that restriction stays
    one constant times the transpose of the prolongation (the cycle symmetric). The
    residual of the fine planes under one coarse plane goes to a scratch block and
    straight into the sum: it is never stored as a whole field (a write and a read of a
    fine field less per cycle)."""
    for I in prange(coarse.shape[0]):
        _restrict_plane(x, b, level, ratio, coarse, np.int64(I))


@njit(cache=True, error_model="numpy")
def _restrict_plane(x, b, level, ratio, coarse, I):
    """Coarse plane I of :func:`residual_restrict` (the parallel loop's body, in a function
    of its own: numba's parallel passes then analyse a call, not the inlined stencil; the
    error model is the one numba gives a parallel loop's body, so the same bits)."""
    n1, n2 = coarse.shape[1], coarse.shape[2]
    r0, r1, r2 = ratio[0], ratio[1], ratio[2]
    inv = 1.0 / (r0 * r1 * r2)
    planes = min(r0, x.shape[0] - r0 * I)  # fine planes under plane I: 1 at an odd end
    fine = np.empty((r0, x.shape[1], x.shape[2]), x.dtype)
    for a in range(planes):
        _operator_plane(x, b, level, r0 * I + a, fine[a], RESIDUAL)
    full = x.shape[2] // r2  # coarse cells along z with r2 children
    for J in range(n1):
        coarse[I, J, :] = 0.0
        for a in range(planes):
            for j in range(r1 * J, min(r1 * J + r1, x.shape[1])):
                for K in range(full):
                    acc = fine[a, j, r2 * K]
                    if r2 == 2:
                        acc += fine[a, j, r2 * K + 1]
                    coarse[I, J, K] += acc
                if full < n2:  # an odd axis halved: the last cell's one child
                    coarse[I, J, full] += fine[a, j, x.shape[2] - 1]
        for K in range(n2):
            coarse[I, J, K] *= inv


@threaded()
def prolong_add(coarse, ratio, fine):
    """fine += coarse value of the parent cell (injection; ratio 1 or 2 per axis, the last
    coarse cell of an odd axis halved the parent of one fine cell)."""
    n0, n1, n2 = fine.shape
    r0, r1, r2 = ratio[0], ratio[1], ratio[2]
    for i in prange(n0):
        for j in range(n1):
            I, J = i // r0, j // r1
            if r2 == 2:
                for K in range(n2 // 2):
                    c = coarse[I, J, K]
                    fine[i, j, 2 * K] += c
                    fine[i, j, 2 * K + 1] += c
                if n2 % 2:
                    fine[i, j, n2 - 1] += coarse[I, J, n2 // 2]
            else:
                for k in range(n2):
                    fine[i, j, k] += coarse[I, J, k]


@njit(cache=True)
def coarsen_weights(fine, a, ratio, coarse):
    """Coarse face weight = sum of the fine face weights it covers over their full count
    (faces normal to a): their mean, where faces beyond the far end of an odd axis halved
    count as closed. Coarse face I normal to a lies on fine face ratio_a I, the far
    boundary of an odd axis halved on the fine boundary face (one fine cell nearer)."""
    n0, n1, n2 = coarse.shape
    ra, rb, rc = ratio[0], ratio[1], ratio[2]
    f0, f1, f2 = fine.shape
    cnt = 1
    for ax in range(3):
        if ax != a:
            cnt *= ratio[ax]
    inv = 1.0 / cnt
    for I in prange(n0):
        for J in range(n1):
            for K in range(n2):
                acc = 0.0
                i0, j0, k0 = I * ra, J * rb, K * rc
                if a == 0:
                    i0 = min(i0, f0 - 1)
                elif a == 1:
                    j0 = min(j0, f1 - 1)
                else:
                    k0 = min(k0, f2 - 1)
                for x in range(min(1 if a == 0 else ra, f0 - i0)):
                    for y in range(min(1 if a == 1 else rb, f1 - j0)):
                        for z in range(min(1 if a == 2 else rc, f2 - k0)):
                            acc += fine[i0 + x, j0 + y, k0 + z]
                coarse[I, J, K] = acc * inv


@njit(cache=True)
def ordered_sum(partial):
    """sum of ``partial`` from the first entry to the last. Inside a parallel kernel numba
    turns ``partial.sum()`` into a reduction split over the threads, whose rounding then
    depends on the thread count (1e-12 apart between one and two threads); a plain loop
    in a function of its own stays serial."""
    total = 0.0
    for i in range(partial.shape[0]):
        total += partial[i]
    return total


@njit(cache=True)
def _plane_dot(a, b, i):
    """sum a[i] b[i] over plane i, rows in order."""
    acc = 0.0
    for j in range(a.shape[1]):
        for k in range(a.shape[2]):
            acc += a[i, j, k] * b[i, j, k]
    return acc


@threaded()
def dot(a, b):
    """sum a b, by planes then over the planes in order (the same bits on any thread count)."""
    partial = np.empty(a.shape[0])
    for i in prange(a.shape[0]):
        partial[i] = _plane_dot(a, b, i)
    return ordered_sum(partial)


@threaded()
def cg_update(alpha, p, q, x, r, r_low):
    """x += alpha p, r -= alpha q, r_low = r in r_low's precision (the next cycle's
    right-hand side, in the same pass); return r . r (by planes, thread-count independent).
    The arithmetic is float64 whatever the precision the vectors are stored in."""
    n0, n1, n2 = x.shape
    partial = np.empty(n0)
    for i in prange(n0):
        acc = 0.0
        for j in range(n1):
            for k in range(n2):
                x[i, j, k] += alpha * p[i, j, k]
                rr = r[i, j, k] - alpha * q[i, j, k]
                r[i, j, k] = rr
                r_low[i, j, k] = rr
                acc += rr * rr
        partial[i] = acc
    return ordered_sum(partial)


@threaded()
def xpby(x, beta, y):
    """y = x + beta y."""
    n0, n1, n2 = x.shape
    for i in prange(n0):
        for j in range(n1):
            for k in range(n2):
                y[i, j, k] = x[i, j, k] + beta * y[i, j, k]


def cast_copy(src, dst):
    """dst = src converted to dst's dtype (the preconditioner's precision and back; numpy:
    a copy or two per solve does not pay for compiling a kernel per pair of dtypes)."""
    np.copyto(dst, src, casting="same_kind")


@njit(cache=True)
def remove_mean(x, active):
    """x -= mean of x over active cells (the constant null space of pure-Neumann A)."""
    total = 0.0
    count = 0
    for idx in range(x.size):
        if active.flat[idx]:
            total += x.flat[idx]
            count += 1
    if count == 0:
        return
    mean = total / count
    for idx in range(x.size):
        if active.flat[idx]:
            x.flat[idx] -= mean


class Stencil(NamedTuple):
    """What the operator and smoother kernels read of a level: face weights per axis, the
    periodic flags, each row's class and coefficients, the end cells' table, and the
    per-axis coefficients with the smoother's factors (:class:`_Level`)."""

    wx: np.ndarray
    wy: np.ndarray
    wz: np.ndarray
    periodic: np.ndarray
    rows: np.ndarray
    row_coef: np.ndarray
    ends: np.ndarray
    coef: np.ndarray


class _Level:
    """One multigrid level: face weights, coefficient per axis, work arrays."""

    def __init__(self, shape, coef, periodic, dtype=np.float64, omega=OMEGA):
        self.shape = tuple(int(n) for n in shape)
        self.cells = int(np.prod(self.shape))
        c = np.asarray(coef, dtype=np.float64)
        gain = omega * 0.5 / c.sum()  # the smoother's factor omega / diag on all-open rows
        # (h/H)^2 per axis, then the smoother's gain, gain c0, 1 - omega and omega, in the
        # level's precision
        self.coef = np.array([c[0], c[1], c[2], gain, gain * c[0], 1.0 - omega, omega], dtype=dtype)
        self.periodic = periodic
        nx, ny, nz = self.shape
        self.w = [
            np.zeros((nx + 1, ny, nz), dtype),
            np.zeros((nx, ny + 1, nz), dtype),
            np.zeros((nx, ny, nz + 1), dtype),
        ]
        self.x = np.zeros(self.shape, dtype)
        self.b = np.zeros(self.shape, dtype)
        self.ratio = np.ones(3, dtype=np.int64)  # to the next coarser level
        # each row's class and coefficients, and its end cells' (classify_rows)
        self.rows = np.full((nx, ny), GENERAL, dtype=np.int8)
        self.row_coef = np.zeros((nx, ny, 7), dtype)
        self.ends = np.zeros((nx, ny, 2, 7), dtype)
        # small levels run in one compiled call per visit (:mod:`.coarse_levels`)
        self.small = np.prod(self.shape) < SERIAL_CELLS
        self.partial = np.zeros(nx)  # per-plane sums of the smoother's dot
        # the smoother's slabs (smooth_by_slabs): on the levels in the parallel versions
        on_threads = self.cells >= threads.PARALLEL_CELLS
        self.slabs = slab_bounds(nx, SLAB_PLANES if on_threads else 0)

    def args(self) -> Stencil:
        w = self.w
        return Stencil(
            w[0], w[1], w[2], self.periodic, self.rows, self.row_coef, self.ends, self.coef
        )

    def classify_rows(self):
        """After the weights change: the rows whose interior cells have every face open, and
        the compact table of the rows' end-cell weights."""
        classify_rows(*self.w, self.coef, self.periodic, self.rows, self.row_coef, self.ends)

    def smooth(self, x, b, sweeps, reverse, r=None) -> float:
        """``sweeps`` red-black sweeps, black first if ``reverse`` (one kernel call); with
        ``r`` (float64, the level's shape) returns r . x after them (:func:`gauss_seidel`,
        or :func:`smooth_by_slabs` where the level's slabs allow it)."""
        r, partial = NO_DOT if r is None else (r, self.partial)
        colour, halves = (1 if reverse else 0), 2 * sweeps
        if wavefront_fits(self.slabs, halves, self.periodic[0]):
            smoother = smooth_by_slabs.on(self.cells)
            return smoother(x, b, self.args(), colour, halves, r, partial, self.slabs)
        return gauss_seidel.on(self.cells)(x, b, self.args(), colour, halves, r, partial)


class MultigridPoisson:
    """MGPCG solver of A psi = b on a fixed grid whose face weights may change per step."""

    def __init__(self, shape, periodic, singular: bool, min_coarse: int = 4, dtype=np.float64):
        """``dtype``: CG's vectors r, p and A p (the solution x and the reductions stay in
        float64 whatever it is, see :func:`cg_update`)."""
        select(int(np.prod(shape)))  # the kernels' versions for this grid (threads.py)
        self.periodic = np.asarray(periodic, dtype=np.bool_)
        self.singular = singular
        levels = [_Level(shape, np.ones(3), self.periodic, PRECONDITIONER_DTYPE, FINE_OMEGA)]
        while True:
            cur = levels[-1]
            ratio = np.array(
                [
                    2 if n >= min_coarse and (n % 4 == 0 or not p) else 1
                    for n, p in zip(cur.shape, self.periodic, strict=True)
                ],
                dtype=np.int64,
            )
            if ratio.max() == 1:
                break
            cur.ratio = ratio
            coef = cur.coef[:3].astype(np.float64) / ratio.astype(float) ** 2
            coarse = [-(-n // r) for n, r in zip(cur.shape, ratio, strict=True)]
            levels.append(_Level(coarse, coef, self.periodic, PRECONDITIONER_DTYPE))
        self.levels = levels
        self.coarse_sweeps = 2 * max(levels[-1].shape) + 4
        # the small levels below the finest (the coarsest at least) run as one compiled
        # call per visit; the finest stays in the row kernels, which hold less per cell
        small = [n for n, lev in enumerate(levels) if lev.small and n > 0]
        self.first_small = small[0] if small else len(levels) - 1
        self.small = CoarseLevels(
            levels[self.first_small :], self.periodic, self.first_small, W_LEVELS,
            PRE_SWEEPS, self.coarse_sweeps, OMEGA,
        )  # fmt: skip
        fine = levels[0]
        self.active = np.zeros(fine.shape, dtype=np.bool_)
        self.r = np.zeros(fine.shape, dtype)
        self.z = np.zeros(fine.shape, dtype) if singular else None  # M r, constant removed
        self.p = np.zeros(fine.shape, dtype)
        self.q = np.zeros(fine.shape, dtype)
        self.rhs_norm = 0.0  # ||b||_2 of the last solve

    @property
    def fine(self) -> _Level:
        return self.levels[0]

    def set_weights(self, wx, wy, wz):
        """Install the fine face weights and coarsen them through the hierarchy."""
        fine = self.levels[0]
        for a, w in enumerate((wx, wy, wz)):
            fine.w[a][...] = w
        for lev, nxt in zip(self.levels[:-1], self.levels[1:], strict=True):
            for a in range(3):
                coarsen_weights(lev.w[a], a, lev.ratio, nxt.w[a])
        for lev in self.levels[1:]:  # the coarse operators' (h/H)^2 per axis
            for a in range(3):
                lev.w[a] *= lev.coef[a]
        for lev in self.levels[: max(self.first_small, 1)]:  # those that use the row kernels
            lev.classify_rows()
        self.small.set_weights()
        self.active[...] = self._diag_positive(fine)  # cells with an open face

    @staticmethod
    def _diag_positive(level) -> np.ndarray:
        w = level.w
        return (
            (w[0][:-1] + w[0][1:])
            + (w[1][:, :-1] + w[1][:, 1:])
            + (w[2][:, :, :-1] + w[2][:, :, 1:])
        ) > 0

    def vcycle(self, r, z) -> float:
        """z = M r: one symmetric multigrid cycle from a zero guess (V-shaped, W-shaped
        on the levels of W_LEVELS), in PRECONDITIONER_DTYPE; returns r . z."""
        rz, mr = self._precondition_float64(r)
        cast_copy(mr, z)
        return rz

    def _precondition_float64(self, r):
        """:meth:`_precondition` of an r not yet in the finest level's b."""
        cast_copy(r, self.levels[0].b)
        return self._precondition(r)

    def _precondition(self, r):
        """(r . M r, M r) with r already in the finest level's b (:func:`cg_update` puts
        it there). M r is the finest level's x itself (float32; the float64 kernels that
        read it convert each value as a float64 copy would hold it, so the same bits and
        two passes over a float64 field less per iteration), or, when A is singular, a
        float64 copy with the constant removed."""
        fine = self.levels[0]
        fine.x[...] = 0.0
        if not self.singular:
            rz = self._cycle(0, r)
            return (dot(r, fine.x) if rz is None else rz), fine.x
        self._cycle(0)
        cast_copy(fine.x, self.z)
        remove_mean(self.z, self.active)
        return dot(r, self.z), self.z

    def _cycle(self, n: int, r=None):
        """Level n from its current guess: smooth, correct from level n + 1 (twice on the
        W_LEVELS, each time from the coarse guess so far), smooth in reverse order. With
        ``r``, returns r . x from the last sweep (None where level n is a small level)."""
        if n == self.first_small:  # this level and those below: one compiled call
            self.small.cycle()
            return None
        lev = self.levels[n]
        nxt = self.levels[n + 1]
        lev.smooth(lev.x, lev.b, PRE_SWEEPS, reverse=False)
        residual_restrict.on(lev.cells)(lev.x, lev.b, lev.args(), lev.ratio, nxt.b)
        nxt.x[...] = 0.0
        for _ in range(2 if n in W_LEVELS else 1):
            self._cycle(n + 1)
        prolong_add.on(lev.cells)(nxt.x, lev.ratio, lev.x)
        return lev.smooth(lev.x, lev.b, PRE_SWEEPS, reverse=True, r=r)

    def smooth_residual_norm(self, x, b) -> float:
        """The 2-norm of the finest level's residual b - A x summed over blocks of
        GUESS_BLOCK^3 cells (:func:`block_residual`): how far a guess x is from the
        solution in the error that costs CG iterations (:mod:`.guess`)."""
        return float(np.sqrt(block_residual(x, b, self.fine.args(), GUESS_BLOCK)))

    def solve(self, x, b, tol: float, max_iterations: int, atol: float = 0.0):
        """Solve A x = b in place from the guess in x; return (iterations, relative residual).
        ``rhs_norm`` is then ||b||_2 (of b with its mean removed when A is singular)."""
        fine = self.levels[0]
        if self.singular:
            remove_mean(b, self.active)
            remove_mean(x, self.active)
        bnorm = np.sqrt(dot(b, b))
        self.rhs_norm = float(bnorm)
        r, p, q = self.r, self.p, self.q
        rnorm = np.sqrt(residual(x, b, fine.args(), r))
        if bnorm == 0.0 or bnorm <= atol:
            x[...] = 0.0
            return 0, 0.0
        if rnorm <= tol * bnorm:
            return 0, rnorm / bnorm
        rz, z = self._precondition_float64(r)
        cast_copy(z, p)
        it = 0
        while it < max_iterations:
            it += 1
            alpha = rz / apply_operator(p, fine.args(), q)  # p . A p
            rnorm = np.sqrt(cg_update(alpha, p, q, x, r, fine.b))
            if rnorm <= tol * bnorm:
                break
            rz_new, z = self._precondition(r)
            xpby(z, rz_new / rz, p)
            rz = rz_new
        return it, rnorm / bnorm
