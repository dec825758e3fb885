"""Semi-Lagrangian advection of the staggered velocity (paper §4.1.1, Stam 1999), and the
limited MacCormack scheme (Selle et al. 2008) as the less dissipative option.

Each face value is carried along the characteristic: q_new(x) = q(x_back), with the
backtrace x_back found by the second-order midpoint rule (RK2)

    x_mid = x - dt/2 u(x),   x_back = x - dt u(x_mid),

and q(x_back) interpolated trilinearly in q's padded lattice (ghost layer filled by
:mod:`windbench.wind.boundaries`). Points leaving the domain are wrapped on periodic axes
and clamped onto the boundary otherwise, where the ghost layer gives the wall/inflow value.

MacCormack: q^ = A_dt(q), q~ = A_-dt(q^), q_new = q^ + (q - q~)/2, clamped to the min/max
of the eight lattice values that the forward backtrace interpolated from (the limiter that
keeps it stable); second order in space and time where the field is smooth.
"""

from __future__ import annotations

from numba import njit, prange


@njit(cache=True, inline="always")
def _locate(p, origin, h, npad):
    """Lower lattice index and weight of coordinate p on a padded axis of npad samples."""
    f = min(max((p - origin) / h, 0.0), npad - 1.0)  # clamped onto the lattice
    i0 = min(int(f), npad - 2)
    return i0, f - i0


@njit(cache=True, inline="always")
def interp(q, ox, oy, oz, h, px, py, pz):
    """q trilinearly interpolated at (px, py, pz); q[I,J,K] sits at origin + h (I, J, K)."""
    i, fx = _locate(px, ox, h, q.shape[0])
    j, fy = _locate(py, oy, h, q.shape[1])
    k, fz = _locate(pz, oz, h, q.shape[2])
    c00 = q[i, j, k] + fx * (q[i + 1, j, k] - q[i, j, k])
    c10 = q[i, j + 1, k] + fx * (q[i + 1, j + 1, k] - q[i, j + 1, k])
    c01 = q[i, j, k + 1] + fx * (q[i + 1, j, k + 1] - q[i, j, k + 1])
    c11 = q[i, j + 1, k + 1] + fx * (q[i + 1, j + 1, k + 1] - q[i, j + 1, k + 1])
    c0 = c00 + fy * (c10 - c00)
    c1 = c01 + fy * (c11 - c01)
    return c0 + fz * (c1 - c0)


@njit(cache=True, inline="always")
def corner_bounds(q, ox, oy, oz, h, px, py, pz):
    """(min, max) of the eight lattice values around (px, py, pz)."""
    i, _ = _locate(px, ox, h, q.shape[0])
    j, _ = _locate(py, oy, h, q.shape[1])
    k, _ = _locate(pz, oz, h, q.shape[2])
    lo = q[i, j, k]
    hi = lo
    for di in range(2):
        for dj in range(2):
            for dk in range(2):
                v = q[i + di, j + dj, k + dk]
                lo = min(lo, v)
                hi = max(hi, v)
    return lo, hi


@njit(cache=True, inline="always")
def _keep_inside(p, lo, length, periodic):
    """Wrap p into [lo, lo + length) on a periodic axis, else clamp it into [lo, lo + length]."""
    if periodic:
        return lo + (p - lo) % length
    return min(max(p, lo), lo + length)


@njit(cache=True, inline="always")
def velocity_at(u, v, w, origins, h, px, py, pz):
    """The staggered velocity (u, v, w) interpolated at a world point."""
    return (
        interp(u, origins[0, 0], origins[0, 1], origins[0, 2], h, px, py, pz),
        interp(v, origins[1, 0], origins[1, 1], origins[1, 2], h, px, py, pz),
        interp(w, origins[2, 0], origins[2, 1], origins[2, 2], h, px, py, pz),
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


@njit(cache=True, parallel=True)
def advect(q, a, u, v, w, origins, lower, extent, periodic, h, dt, out, qmin, qmax, bounds):
    """out = q(x_back) at every interior face of component a (RK2 backtrace over dt).

    ``bounds``: also store the min/max of the eight values interpolated from in qmin/qmax
    (for the MacCormack limiter). ``dt`` may be negative (the MacCormack back step).
    """
    P0, P1, P2 = q.shape
    ox, oy, oz = origins[a, 0], origins[a, 1], origins[a, 2]
    for I in prange(1, P0 - 1):
        px = ox + h * I
        for J in range(1, P1 - 1):
            py = oy + h * J
            for K in range(1, P2 - 1):
                pz = oz + h * K
                # the velocity at the face itself: no interpolation needed
                ux = at_face(u, 0, a, I, J, K)
                uy = at_face(v, 1, a, I, J, K)
                uz = at_face(w, 2, a, I, J, K)
                mx = _keep_inside(px - 0.5 * dt * ux, lower[0], extent[0], periodic[0])
                my = _keep_inside(py - 0.5 * dt * uy, lower[1], extent[1], periodic[1])
                mz = _keep_inside(pz - 0.5 * dt * uz, lower[2], extent[2], periodic[2])
                ux, uy, uz = velocity_at(u, v, w, origins, h, mx, my, mz)
                bx = _keep_inside(px - dt * ux, lower[0], extent[0], periodic[0])
                by = _keep_inside(py - dt * uy, lower[1], extent[1], periodic[1])
                bz = _keep_inside(pz - dt * uz, lower[2], extent[2], periodic[2])
                out[I, J, K] = interp(q, ox, oy, oz, h, bx, by, bz)
                if bounds:
                    lo, hi = corner_bounds(q, ox, oy, oz, h, bx, by, bz)
                    qmin[I, J, K] = lo
                    qmax[I, J, K] = hi


@njit(cache=True)
def maccormack_correct(q, q_hat, q_tilde, qmin, qmax, out):
    """out = clamp(q^ + (q - q~)/2, qmin, qmax) on the interior (Selle et al. 2008)."""
    P0, P1, P2 = q.shape
    for I in prange(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                val = q_hat[I, J, K] + 0.5 * (q[I, J, K] - q_tilde[I, J, K])
                out[I, J, K] = min(max(val, qmin[I, J, K]), qmax[I, J, K])
