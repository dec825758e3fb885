"""Semi-Lagrangian advection of the staggered velocity (paper §4.1.1, Stam 1999), and the
limited MacCormack scheme (Selle et al. 2008) as the less dissipative option.

Each face value is carried along the characteristic: q_new(x) = q(x - d(x)), with the
backtrace displacement d given by the second-order midpoint rule (RK2)

    x_mid = x - dt/2 u(x),   d(x) = dt u(x_mid),

and q(x - d) interpolated trilinearly in q's padded lattice (ghost layer filled by
:mod:`windbench.wind.navier_stokes.boundaries`). The displacement is computed once per cell centre
(:func:`_backtrace_plane`: u(x) the mean of the cell's two faces per axis, u(x_mid)
interpolated from the staggered components) and every face takes the mean of the
displacements of the two cells it separates (:func:`advect`). For a linear velocity field this is exactly the
RK2 backtrace of the face itself (d is then linear in x; tested); for a smooth one it
differs from it by O(h^2), so the backtrace stays second order. Backtraced
points leaving the domain are wrapped on periodic axes and clamped onto the boundary
otherwise, where the ghost layer gives the wall/inflow value; midpoints of the ghost cells
beyond a non-periodic face read the ghost layer (the boundary condition's extension).

MacCormack: q^ = A_dt(q), q~ = A_-dt(q^), q_new = q^ + (q - q~)/2, clamped to the min/max
of the eight lattice values that the forward backtrace interpolated from (the limiter that
keeps it stable, :func:`maccormack_correct`), or clamped only where q is not smooth
(:func:`maccormack_correct_smooth`, the second-order scheme's limiter).

Positions are cell coordinates and velocities cells per step. The three components are
carried in one pass over the planes, the displacements kept in a two-plane ring per thread
(:func:`advect`) rather than stored as a field.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from windbench.wind.navier_stokes.flags import FAST_MATH
from windbench.wind.navier_stokes.threads import threaded

ONE = np.uint64(1)  # index arithmetic on unsigned indices must stay unsigned
# The face components' axes as int64 values: a literal 0, 1 or 2 would compile
# :func:`_carry_plane` once per component.
AXES = (np.int64(0), np.int64(1), np.int64(2))


@njit(cache=True, inline="always")
def _locate(f, npad):
    """Lower index (unsigned, see :func:`_trilinear`) and weight of lattice coordinate f
    on a padded axis of npad samples, clamped onto the lattice. (Written out rather than
    calling :func:`_locate_inside`: inlined that way, fast math contracts the backtrace
    differently and changes its last bits.)"""
    f = min(max(f, 0.0), npad - 1.0)
    i0 = min(int(f), npad - 2)
    return np.uint64(i0), f - i0


@njit(cache=True, inline="always")
def _locate_inside(f, npad):
    """:func:`_locate` for a coordinate already on the lattice (0 <= f <= npad - 1), as
    after :func:`_keep_inside`: without the clamp, the same numbers."""
    i0 = min(int(f), npad - 2)
    return np.uint64(i0), f - i0


@njit(cache=True, inline="always")
def _trilinear(q, i, j, k, fx, fy, fz):
    """q trilinearly interpolated in the lattice cell (i, j, k) at weights (fx, fy, fz).
    The indices are unsigned (:func:`_locate`), so numba leaves out its wrap-around test
    for negative indices on each read: the same numbers with fewer instructions. The
    weights are cast to q's precision, so that a float32 field (``wind.precision``) is
    interpolated in float32 rather than each of its eight values converted to double
    (float64: a no-op, the same bits)."""
    i1, j1, k1 = i + ONE, j + ONE, k + ONE
    in_precision = q.dtype.type
    fx, fy, fz = in_precision(fx), in_precision(fy), in_precision(fz)
    c00 = q[i, j, k] + fx * (q[i1, j, k] - q[i, j, k])
    c10 = q[i, j1, k] + fx * (q[i1, j1, k] - q[i, j1, k])
    c01 = q[i, j, k1] + fx * (q[i1, j, k1] - q[i, j, k1])
    c11 = q[i, j1, k1] + fx * (q[i1, j1, k1] - q[i, j1, k1])
    c0 = c00 + fy * (c10 - c00)
    c1 = c01 + fy * (c11 - c01)
    return c0 + fz * (c1 - c0)


@njit(cache=True, inline="always")
def _bounds(q, i, j, k):
    """(min, max) of the eight lattice values of lattice cell (i, j, k) (unsigned indices,
    as :func:`_locate` gives them)."""
    lo = q[i, j, k]
    hi = lo
    for di in range(2):
        for dj in range(2):
            for dk in range(2):
                v = q[i + np.uint64(di), j + np.uint64(dj), k + np.uint64(dk)]
                lo = min(lo, v)
                hi = max(hi, v)
    return lo, hi


@njit(cache=True, inline="always")
def _keep_inside(p, n, periodic):
    """Wrap cell coordinate p into [0, n) on a periodic axis of n cells, else clamp it into
    [0, n]; points already inside (nearly all) take one comparison."""
    if 0.0 <= p <= n:
        return p
    if periodic:
        return _wrap(p, n, True)
    return min(max(p, 0.0), n)


@njit(cache=True, inline="always")
def velocity_at(u, v, w, x, y, z):
    """The staggered velocity (u, v, w) at cell coordinates (x, y, z).

    Component a's padded lattice has its element 0 at cell coordinate -1 along a (a face
    beyond the ghost) and -1/2 across a (a ghost cell centre), so each axis needs only two
    locations, "face" (x + 1) and "centre" (x + 1/2), shared by the three components.
    """
    iF, fF = _locate(x + 1.0, u.shape[0])
    iC, fC = _locate(x + 0.5, v.shape[0])
    jF, gF = _locate(y + 1.0, v.shape[1])
    jC, gC = _locate(y + 0.5, u.shape[1])
    kF, hF = _locate(z + 1.0, w.shape[2])
    kC, hC = _locate(z + 0.5, u.shape[2])
    return (
        _trilinear(u, iF, jC, kC, fF, gC, hC),
        _trilinear(v, iC, jF, kC, fC, gF, hC),
        _trilinear(w, iC, jC, kF, fC, gC, hF),
    )


@njit(cache=True, inline="always")
def at_face(q, b, a, I, J, K):
    """Velocity component b (padded array q) at the centre of face (I, J, K) of component a:
    the stored value when b == a, else the mean of the four b-faces around that point."""
    if b == a:
        return q[I, J, K]
    # along a the point lies between cells I-1 and I; along b between faces J and J+1
    Im, Jm, Km = I - int(a == 0), J - int(a == 1), K - int(a == 2)
    Ib, Jb, Kb = int(b == 0), int(b == 1), int(b == 2)
    return 0.25 * (
        q[I, J, K] + q[I + Ib, J + Jb, K + Kb] + q[Im, Jm, Km] + q[Im + Ib, Jm + Jb, Km + Kb]
    )


@njit(cache=True, inline="always")
def _wrap(p, n, periodic):
    """p wrapped into [0, n) on a periodic axis of n cells, else unchanged."""
    if periodic and not 0.0 <= p < n:
        return p - n * math.floor(p / n)
    return p


@njit(cache=True)
def maccormack_correct(q, q_hat, q_tilde, qmin, qmax, out):
    """out = clamp(q^ + (q - q~)/2, qmin, qmax) on the interior (Selle et al. 2008)."""
    P0, P1, P2 = q.shape
    for I in prange(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                val = q_hat[I, J, K] + 0.5 * (q[I, J, K] - q_tilde[I, J, K])
                out[I, J, K] = min(max(val, qmin[I, J, K]), qmax[I, J, K])


SMOOTH_RATIO = 2.0  # second differences within this factor of each other: smooth


@njit(cache=True, inline="always")
def _second_differences_agree(q, I, J, K, b):
    """True if the three second differences of q along axis b centred at face (I, J, K)
    and its two neighbours have one strict sign and lie within SMOOTH_RATIO of each other
    (or all vanish: an axis along which q is constant). False where the five-point stencil
    leaves the padded array."""
    e = (int(b == 0), int(b == 1), int(b == 2))
    n = q.shape[b]
    c = I if b == 0 else (J if b == 1 else K)
    if c < 2 or c > n - 3:
        return False
    lo, hi, zeros, pos, neg = math.inf, 0.0, 0, 0, 0
    for s in (-1, 0, 1):
        i, j, k = I + s * e[0], J + s * e[1], K + s * e[2]
        d2 = q[i - e[0], j - e[1], k - e[2]] - 2.0 * q[i, j, k] + q[i + e[0], j + e[1], k + e[2]]
        if d2 > 0.0:
            pos += 1
        elif d2 < 0.0:
            neg += 1
        else:
            zeros += 1
        lo, hi = min(lo, abs(d2)), max(hi, abs(d2))
    if zeros == 3:
        return True
    return (pos == 3 or neg == 3) and hi <= SMOOTH_RATIO * lo


@njit(cache=True)
def maccormack_correct_smooth(q, q_hat, q_tilde, qmin, qmax, axes, out):
    """out = q^ + (q - q~)/2, clamped to [qmin, qmax] only where q is not smooth.

    The clamp of Selle et al. (2008) cuts every smooth extremum that falls between lattice
    points (an O(h^2) error per step, first order over a run at fixed CFL). Here a value
    outside the bounds is kept when q is smooth around the face: along every axis the
    second differences at the face and its two neighbours share one sign and agree within
    SMOOTH_RATIO (a resolved extremum, as in the extremum-preserving limiter of Colella &
    Sekora 2008); near a jump or a kink (walls, bodies, under-resolved shear) they change
    sign or size and the value is clamped. ``axes[b] = 0``: axis b carries no derivative
    (a one-cell periodic axis of a 2D problem) and is not tested."""
    P0, P1, P2 = q.shape
    for I in prange(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                val = q_hat[I, J, K] + 0.5 * (q[I, J, K] - q_tilde[I, J, K])
                lo, hi = qmin[I, J, K], qmax[I, J, K]
                if lo <= val <= hi:
                    out[I, J, K] = val
                elif (
                    (axes[0] == 0 or _second_differences_agree(q, I, J, K, 0))
                    and (axes[1] == 0 or _second_differences_agree(q, I, J, K, 1))
                    and (axes[2] == 0 or _second_differences_agree(q, I, J, K, 2))
                ):
                    out[I, J, K] = val
                else:
                    out[I, J, K] = min(max(val, lo), hi)


@njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _backtrace_plane(u, v, w, ci, cells, periodic, dt_h, out):
    """out[cj, ck] = the RK2 backtrace displacement dt u(x_c - dt/2 u(x_c)) at the centre
    x_c of every padded cell (ci, cj, ck) of plane ci, ghost cells included, in cells:
    u(x_c) the mean of the cell's two faces per axis, u at the midpoint interpolated from
    the staggered components (:func:`velocity_at`). ``dt_h`` = dt / h."""
    n0, n1, n2 = cells[0], cells[1], cells[2]
    half = 0.5 * dt_h
    x = ci - 0.5  # the centre of cell ci - 1
    for cj in range(n1 + 2):
        y = cj - 0.5
        for ck in range(n2 + 2):
            z = ck - 0.5
            uc = 0.5 * (u[ci, cj, ck] + u[ci + 1, cj, ck])
            vc = 0.5 * (v[ci, cj, ck] + v[ci, cj + 1, ck])
            wc = 0.5 * (w[ci, cj, ck] + w[ci, cj, ck + 1])
            um, vm, wm = velocity_at(
                u,
                v,
                w,
                _wrap(x - half * uc, n0, periodic[0]),
                _wrap(y - half * vc, n1, periodic[1]),
                _wrap(z - half * wc, n2, periodic[2]),
            )
            out[cj, ck, 0] = dt_h * um
            out[cj, ck, 1] = dt_h * vm
            out[cj, ck, 2] = dt_h * wm


@njit(cache=True, inline="always")
def _carry_row(q, a, I, J, lo, hi, Jm, cells, periodic, dst, bounds):
    """out[I, J, K] = q(x - d) along row (I, J) of component a's faces (padded indices;
    face (I, J, K) separates the padded cells (I, J, K) - e_a and (I, J, K)): d the mean
    of the two cells' displacements, read from the planes ``lo`` (row Jm, K - 1 for
    a = 2) and ``hi`` (row J). Positions in cell coordinates (world = lower + h x); a
    backtraced point is kept inside (:func:`_keep_inside`) and interpolated trilinearly.
    ``dst`` = (out, qmin, qmax): the result and, with ``bounds``, the limiter's bounds."""
    out, qmin, qmax = dst
    P0, P1, P2 = q.shape
    n0, n1, n2 = cells[0], cells[1], cells[2]
    s0 = -1.0 if a == 0 else -0.5
    s1 = -1.0 if a == 1 else -0.5
    s2 = -1.0 if a == 2 else -0.5
    e2 = int(a == 2)
    x, y = s0 + I, s1 + J
    for K in range(1, P2 - 1):
        Km = K - e2
        dx = 0.5 * (hi[J, K, 0] + lo[Jm, Km, 0])
        dy = 0.5 * (hi[J, K, 1] + lo[Jm, Km, 1])
        dz = 0.5 * (hi[J, K, 2] + lo[Jm, Km, 2])
        bx = _keep_inside(x - dx, n0, periodic[0]) - s0
        by = _keep_inside(y - dy, n1, periodic[1]) - s1
        bz = _keep_inside(s2 + K - dz, n2, periodic[2]) - s2
        i, fx = _locate_inside(bx, P0)
        j, fy = _locate_inside(by, P1)
        k, fz = _locate_inside(bz, P2)
        out[I, J, K] = _trilinear(q, i, j, k, fx, fy, fz)
        if bounds:
            qlo, qhi = _bounds(q, i, j, k)  # the cell just interpolated in
            qmin[I, J, K] = qlo
            qmax[I, J, K] = qhi


@njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _carry_plane(q, a, I, lo, hi, cells, periodic, out, qmin, qmax, bounds):
    """:func:`_carry_row` over the rows J of plane I of component a's faces; a v-face (a =
    1) separates the cells of rows J - 1 and J of one plane, the others cells of one row.
    Called, not inlined (like :func:`_backtrace_plane`), with the caller's compiler flags:
    one compiled copy serves the three components instead of three inlined ones, the same
    bits."""
    e1 = int(a == 1)
    for J in range(1, q.shape[1] - 1):
        _carry_row(q, a, I, J, lo, hi, J - e1, cells, periodic, (out, qmin, qmax), bounds)


@njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _advect_planes(u, v, w, cells, periodic, dt_h, src, out, qmin, qmax, bounds, span):
    """One thread's run of :func:`advect`: the u-face planes span[0] .. span[1] - 1 with
    the v- and w-faces of their cell planes, displacements in a ring of two planes. A
    function of its own rather than the parallel loop's body, which numba's parallel
    passes would otherwise analyse with every helper inlined (most of its compile time)."""
    start, end = span
    planes = cells[0] + 1
    ring = np.empty((2, cells[1] + 2, cells[2] + 2, 3))
    _backtrace_plane(u, v, w, start - 1, cells, periodic, dt_h, ring[(start - 1) % 2])
    for I in range(start, end):
        hi = ring[I % 2]
        lo = ring[(I - 1) % 2]
        _backtrace_plane(u, v, w, I, cells, periodic, dt_h, hi)
        _carry_plane(src[0], AXES[0], I, lo, hi, cells, periodic, out[0], qmin[0], qmax[0], bounds)
        if I < planes:  # the v- and w-faces of cell plane I
            _carry_plane(
                src[1], AXES[1], I, hi, hi, cells, periodic, out[1], qmin[1], qmax[1], bounds
            )
            _carry_plane(
                src[2], AXES[2], I, hi, hi, cells, periodic, out[2], qmin[2], qmax[2], bounds
            )


@threaded()
def advect(u, v, w, cells, periodic, dt_h, chunks, src, out, qmin, qmax, bounds):
    """out[a] = src[a](x - d) at every interior face of component a = 0, 1, 2 (tuples of
    the three padded arrays), d the RK2 backtrace displacement of the velocity (u, v, w)
    over dt_h = dt / h (negative for the MacCormack back step): computed once per cell
    centre, ghost cells included, and a face takes the mean of its two cells'.

    The planes of u-faces I = 1 .. n0 + 1 are split into ``chunks`` runs (one per thread),
    each done in order with its cells' displacements in a ring of two planes: plane I of
    cells is backtraced (:func:`_backtrace_plane`), then the u-faces between cell planes
    I - 1 and I and the v- and w-faces of plane I are carried (:func:`_carry_row`). The
    displacements never go to memory as a field (a 3-value-per-cell array written and read
    three times before; same bits). ``bounds``: also store in qmin[a]/qmax[a] the min/max
    of the eight values each face was interpolated from (the MacCormack limiter).
    """
    planes = cells[0] + 1
    chunks = max(1, min(chunks, planes))
    for c in prange(chunks):
        k = np.int64(c)
        span = (1 + (k * planes) // chunks, 1 + ((k + 1) * planes) // chunks)
        _advect_planes(u, v, w, cells, periodic, dt_h, src, out, qmin, qmax, bounds, span)
