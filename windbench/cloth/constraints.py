"""XPBD constraint projections of the cloth (Macklin, Mueller, Chentanez 2016).

Each constraint C(p) = 0 with compliance alpha = 1/k is projected by
``dlambda = (-C - alpha~ lambda) / (sum_k w_k |grad_k C|^2 + alpha~)``,
``p_k += w_k dlambda grad_k C``, ``alpha~ = alpha / h^2`` (w: inverse masses, h: substep;
the stiffness mapping is in :mod:`windbench.cloth.topology`):

- distance constraints ``C = |p_i - p_j| - L``: the stretch edges thread by thread
  (:func:`solve_chains`: the linearised system of a whole thread is tridiagonal, solved
  exactly by the Thomas algorithm, cf. Deul et al. 2018, so one pass carries a pin's pull
  along the thread), the shear edges one by one (:func:`project_shear_edges`);
  ``solve_chains`` with ``limit`` is the strain limit (Provot 1995): only edges longer than
  ``(1 + limit) L`` are constraints, rigid, brought to that length;
- bending hinges ``C = theta - theta_0``, theta the dihedral angle
  ``atan2((nA x nB) . e^, nA . nB)`` with the gradient of Bridson et al. 2003
  (:func:`project_hinge`);
- long-range attachments (tethers, Kim, Chentanez, Mueller 2012): a vertex may not be
  farther from its nearest pin than in the rest shape (:func:`project_tethers`);
- stiffness-proportional (Rayleigh) damping of the constraint rates ``dC/dt = grad C . v``
  with coefficient ``c = damping * k``, implicit over the frame (:func:`damp_velocities`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def fast_atan2(y, x):
    """atan2(y, x) from the polynomial of Abramowitz & Stegun 4.4.49 (|error| <= 2e-8 rad).

    atan(a) = a (1 + sum_k c_k a^2k) on [0, 1] with a = min/max of |x|, |y|, then the octant
    symmetries; cheaper than the libm call in the hinge loop. The
    polynomial is evaluated by Estrin's scheme (powers s^2, s^4 computed beside the pairs)
    rather than Horner's: the same terms in a third of the dependent multiply-adds.
    """
    ax, ay = abs(x), abs(y)
    mx = max(ax, ay)
    if mx == 0.0:
        return 0.0
    a = min(ax, ay) / mx
    s = a * a
    s2 = s * s
    s4 = s2 * s2
    q0 = (1.0 - 0.3333314528 * s) + s2 * (0.1999355085 - 0.1420889944 * s)
    q1 = (0.1065626393 - 0.0752896400 * s) + s2 * (0.0429096138 - 0.0161657367 * s)
    r = a * (q0 + s4 * (q1 + s4 * 0.0028662257))
    if ay > ax:
        r = 0.5 * math.pi - r
    if x < 0.0:
        r = math.pi - r
    if y < 0.0:
        r = -r
    return r


@njit(cache=True, inline="always")
def _wrap_angle(a):
    """a mapped to (-pi, pi]."""
    while a > math.pi:
        a -= 2.0 * math.pi
    while a <= -math.pi:
        a += 2.0 * math.pi
    return a


@njit(cache=True, inline="always")
def hinge_gradient(p, i0, i1, i2, i3, grad):
    """Gradient ``grad`` (4, 3) of the dihedral angle of hinge (x0, x1 | x2, x3) = p[i0..i3].

    theta = atan2((nA x nB) . e^, nA . nB), e = x1 - x0, nA = e x (x2 - x0),
    nB = (x0 - x1) x (x3 - x1); d theta/d x2 = -|e| nA/|nA|^2, d theta/d x3 = -|e| nB/|nB|^2,
    the edge vertices share them by the projections of x2, x3 on the edge (Bridson et al.
    2003), so the gradient sums to zero. Returns False (grad untouched) for a degenerate
    hinge.
    """
    ex, ey, ez = p[i1, 0] - p[i0, 0], p[i1, 1] - p[i0, 1], p[i1, 2] - p[i0, 2]
    el2 = ex * ex + ey * ey + ez * ez
    ax, ay, az = p[i2, 0] - p[i0, 0], p[i2, 1] - p[i0, 1], p[i2, 2] - p[i0, 2]
    bx, by, bz = p[i3, 0] - p[i1, 0], p[i3, 1] - p[i1, 1], p[i3, 2] - p[i1, 2]
    # nA = e x a ; nB = (-e) x b
    nax, nay, naz = ey * az - ez * ay, ez * ax - ex * az, ex * ay - ey * ax
    nbx, nby, nbz = -(ey * bz - ez * by), -(ez * bx - ex * bz), -(ex * by - ey * bx)
    na2 = nax * nax + nay * nay + naz * naz
    nb2 = nbx * nbx + nby * nby + nbz * nbz
    if not (el2 > 0.0 and na2 > 1e-30 * el2 * el2 and nb2 > 1e-30 * el2 * el2):
        return False
    el = math.sqrt(el2)
    sa, sb = -el / na2, -el / nb2
    alpha2 = (ax * ex + ay * ey + az * ez) / el2
    alpha3 = ((bx + ex) * ex + (by + ey) * ey + (bz + ez) * ez) / el2
    grad[2, 0], grad[2, 1], grad[2, 2] = sa * nax, sa * nay, sa * naz
    grad[3, 0], grad[3, 1], grad[3, 2] = sb * nbx, sb * nby, sb * nbz
    for k in range(3):
        grad[0, k] = -(1.0 - alpha2) * grad[2, k] - (1.0 - alpha3) * grad[3, k]
        grad[1, k] = -alpha2 * grad[2, k] - alpha3 * grad[3, k]
    return True


@njit(cache=True)
def hinge_weights(x, inv_mass, hinges):
    """S_b = sum_q w_q |grad_q theta_b|^2 of every hinge at positions x (0 if degenerate):
    with alpha~ its compliance over h^2, S / alpha~ = (omega h)^2 of the hinge's own
    oscillation, i.e. how far one substep is from resolving it."""
    out = np.zeros(hinges.shape[0])
    grad = np.empty((4, 3))
    for b in range(hinges.shape[0]):
        if hinge_gradient(x, hinges[b, 0], hinges[b, 1], hinges[b, 2], hinges[b, 3], grad):
            acc = 0.0
            for q in range(4):
                w = inv_mass[hinges[b, q]]
                acc += w * (grad[q, 0] ** 2 + grad[q, 1] ** 2 + grad[q, 2] ** 2)
            out[b] = acc
    return out


@njit(cache=True, inline="always")
def project_hinge(p, inv_mass, i0, i1, i2, i3, rest, alpha):
    """One XPBD projection of the bending hinge (i0, i1 | i2, i3) of rest angle ``rest``.

    C = theta - theta_0 with the gradient of :func:`hinge_gradient` written out in
    scalars: g2 = -|e| nA/|nA|^2, g3 = -|e| nB/|nB|^2, g0 = -(1-a2) g2 - (1-a3) g3,
    g1 = -a2 g2 - a3 g3 (a = projection of the opposite vertex on the edge);
    dlambda = -C / (sum w |g|^2 + alpha~)  (lambda starts at 0: one pass per substep).
    Five divisions (one in the atan2) and one square root per hinge.
    """
    w0, w1, w2, w3 = inv_mass[i0], inv_mass[i1], inv_mass[i2], inv_mass[i3]
    if w0 + w1 + w2 + w3 == 0.0:
        return
    ex, ey, ez = p[i1, 0] - p[i0, 0], p[i1, 1] - p[i0, 1], p[i1, 2] - p[i0, 2]
    el2 = ex * ex + ey * ey + ez * ez
    ax, ay, az = p[i2, 0] - p[i0, 0], p[i2, 1] - p[i0, 1], p[i2, 2] - p[i0, 2]
    bx, by, bz = p[i3, 0] - p[i1, 0], p[i3, 1] - p[i1, 1], p[i3, 2] - p[i1, 2]
    nax, nay, naz = ey * az - ez * ay, ez * ax - ex * az, ex * ay - ey * ax
    nbx, nby, nbz = ez * by - ey * bz, ex * bz - ez * bx, ey * bx - ex * by
    na2 = nax * nax + nay * nay + naz * naz
    nb2 = nbx * nbx + nby * nby + nbz * nbz
    tiny = 1e-30 * el2 * el2
    if el2 == 0.0 or na2 <= tiny or nb2 <= tiny:
        return
    el = math.sqrt(el2)
    cx = nay * nbz - naz * nby
    cy = naz * nbx - nax * nbz
    cz = nax * nby - nay * nbx
    nab = nax * nbx + nay * nby + naz * nbz
    # theta = atan2((nA x nB) . e / |e|, nA . nB) = atan2((nA x nB) . e, |e| nA . nB)
    c = _wrap_angle(fast_atan2(cx * ex + cy * ey + cz * ez, el * nab) - rest)
    inv_el2, inv_na2, inv_nb2 = 1.0 / el2, 1.0 / na2, 1.0 / nb2
    a2 = (ax * ex + ay * ey + az * ez) * inv_el2
    a3 = ((bx + ex) * ex + (by + ey) * ey + (bz + ez) * ez) * inv_el2
    sa, sb = -el * inv_na2, -el * inv_nb2
    # sum_q w_q |g_q|^2 with |g2|^2 = el2/na2, |g3|^2 = el2/nb2, g2.g3 = sa sb nA.nB
    q22, q33, q23 = el2 * inv_na2, el2 * inv_nb2, sa * sb * nab
    b0, b1 = 1.0 - a2, 1.0 - a3
    wsum = (
        w0 * (b0 * b0 * q22 + b1 * b1 * q33 + 2.0 * b0 * b1 * q23)
        + w1 * (a2 * a2 * q22 + a3 * a3 * q33 + 2.0 * a2 * a3 * q23)
        + w2 * q22
        + w3 * q33
    )
    denom = wsum + alpha
    if denom == 0.0 or denom == np.inf:
        return
    dl = -c / denom
    # p_q += w_q dlambda g_q, with g2 = sa nA, g3 = sb nB
    da, db = dl * sa, dl * sb
    f0a, f0b, f1a, f1b = w0 * b0 * da, w0 * b1 * db, w1 * a2 * da, w1 * a3 * db
    f2, f3 = w2 * da, w3 * db
    p[i0, 0] -= f0a * nax + f0b * nbx
    p[i0, 1] -= f0a * nay + f0b * nby
    p[i0, 2] -= f0a * naz + f0b * nbz
    p[i1, 0] -= f1a * nax + f1b * nbx
    p[i1, 1] -= f1a * nay + f1b * nby
    p[i1, 2] -= f1a * naz + f1b * nbz
    p[i2, 0] += f2 * nax
    p[i2, 1] += f2 * nay
    p[i2, 2] += f2 * naz
    p[i3, 0] += f3 * nbx
    p[i3, 1] += f3 * nby
    p[i3, 2] += f3 * nbz


# Strain limiting: a thread is solved again only when one of its edges is longer than
# (1 + (1 + LIMIT_SLACK) limit) L, and then its edges longer than (1 + limit) L are brought
# to that length, so the threads that sit at the limit are not solved pass after pass.
LIMIT_SLACK = 0.1


@njit(cache=True)
def solve_chains(p, inv_mass, chain_ptr, chain_vert, rest, alpha, scale, lam, work, limit=0.0):
    """One direct XPBD solve of each chain of distance constraints, in place.

    Chain c (``chain_ptr``, ``chain_vert`` of :func:`~windbench.cloth.topology.thread_chains`)
    is the path v_0 .. v_m of its edges e_k = (v_k, v_k+1), C_k = |p_v(k+1) - p_v(k)| - L_k,
    grad C_k = +-n_k (n_k the unit edge direction). The linearised XPBD system of the chain,
    ``(J W J^T + alpha~) dlambda = -C - alpha~ lambda``, is tridiagonal: diagonal
    ``w_k + w_k+1 + alpha~_k``, off-diagonal ``-w_v(k+1) n_k . n_k+1`` between consecutive
    edges; the Thomas algorithm solves it exactly in O(m) (no pivoting: the matrix is
    diagonally dominant), then ``p_v += w_v sum_k dlambda_k grad_v C_k``. An edge with
    ``scale`` 0 (two pins, zero stiffness) or zero length is an identity row (dlambda 0).
    A chain of one edge is the plain XPBD edge projection. ``work`` (E, 5): n, c', r'.

    With ``limit`` > 0 it is the strain limit instead (module docstring): only the edges longer than (1 + limit) L_k are constraints, C_k =
    |p_v(k+1) - p_v(k)| - (1 + limit) L_k with no compliance and no multiplier (``alpha``
    and ``lam`` unread), the others identity rows, and a chain without such an edge is
    skipped. Returns how many chains it solved in that mode (0 otherwise).
    """
    solved = 0
    trigger = 1.0 + (1.0 + LIMIT_SLACK) * limit  # a chain is solved above this stretch
    trigger2 = trigger * trigger
    for c in range(chain_ptr.shape[0] - 1):
        e0, e1 = chain_ptr[c], chain_ptr[c + 1]
        if limit > 0.0:  # strain limit: skip the chains that keep it
            over = False
            for e in range(e0, e1):
                a, b = chain_vert[e + c], chain_vert[e + c + 1]
                dx, dy, dz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
                over |= scale[e] != 0.0 and dx * dx + dy * dy + dz * dz > trigger2 * rest[e] ** 2
            if not over:
                continue
            solved += 1
        inv_den = 0.0  # 1 / pivot of the previous row
        for e in range(e0, e1):  # forward elimination
            a, b = chain_vert[e + c], chain_vert[e + c + 1]
            dx, dy, dz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
            ln = math.sqrt(dx * dx + dy * dy + dz * dz)
            target = rest[e] * (1.0 + limit)
            if scale[e] == 0.0 or ln == 0.0 or (limit > 0.0 and ln <= target):
                work[e, 0] = work[e, 1] = work[e, 2] = 0.0  # an identity row
                diag, rhs = 1.0, 0.0
            else:
                inv_ln = 1.0 / ln
                work[e, 0], work[e, 1], work[e, 2] = dx * inv_ln, dy * inv_ln, dz * inv_ln
                if limit > 0.0:  # -C, rigid
                    diag, rhs = inv_mass[a] + inv_mass[b], target - ln
                else:  # -C - alpha~ lambda
                    diag = inv_mass[a] + inv_mass[b] + alpha[e]
                    rhs = rest[e] - ln - alpha[e] * lam[e]
            if e > e0:  # off-diagonal -w_a n_(k-1) . n_k with the previous edge
                off = -inv_mass[a] * (
                    work[e - 1, 0] * work[e, 0]
                    + work[e - 1, 1] * work[e, 1]
                    + work[e - 1, 2] * work[e, 2]
                )
                cp = off * inv_den  # c'_(k-1)
                work[e - 1, 3] = cp
                diag -= off * cp
                rhs -= off * work[e - 1, 4]
            inv_den = 1.0 / diag
            work[e, 4] = rhs * inv_den  # r'_k
        dl = 0.0
        for e in range(e1 - 1, e0 - 1, -1):  # back substitution and the position update
            dl = work[e, 4] if e == e1 - 1 else work[e, 4] - work[e, 3] * dl
            if limit == 0.0:
                lam[e] += dl
            a, b = chain_vert[e + c], chain_vert[e + c + 1]
            sa, sb = inv_mass[a] * dl, inv_mass[b] * dl
            for k in range(3):
                p[b, k] += sb * work[e, k]
                p[a, k] -= sa * work[e, k]
    return solved


@njit(cache=True, inline="always")
def limit_edge(p, inv_mass, i, j, rest, limit, trigger2):
    """Strain limit of one edge (Provot 1995): if it is longer than ``sqrt(trigger2) L``, bring
    it to ``(1 + limit) L`` as a rigid constraint, ``dlambda = -C / (w_i + w_j)``. Returns
    whether it moved the edge."""
    dx, dy, dz = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
    ln2 = dx * dx + dy * dy + dz * dz
    w = inv_mass[i] + inv_mass[j]
    if w == 0.0 or ln2 <= trigger2 * rest * rest:
        return False
    ln = math.sqrt(ln2)
    s = ((1.0 + limit) * rest - ln) / (w * ln)
    si, sj = inv_mass[i] * s, inv_mass[j] * s
    p[i, 0] += si * dx
    p[i, 1] += si * dy
    p[i, 2] += si * dz
    p[j, 0] -= sj * dx
    p[j, 1] -= sj * dy
    p[j, 2] -= sj * dz
    return True


@njit(cache=True)
def limit_edges(p, inv_mass, edges, rest, first, last, limit, moved, stamps):
    """One strain-limit pass edge by edge over ``edges[first:last]`` (:func:`limit_edge`, a
    trigger of ``1 + (1 + LIMIT_SLACK) limit`` as for the chains), in place; the vertices it
    moves are flagged in ``moved``. Returns how many edges it moved.

    ``stamps`` = (per vertex, per edge, clock (1,)) int64: an edge remembers the clock of
    its last test and a vertex the clock of its last move; an edge whose two vertices have
    not moved since its test still keeps the limit and is not tested again (the same
    result; an edge stamp of -1 forces the test)."""
    trigger = 1.0 + (1.0 + LIMIT_SLACK) * limit
    trigger2 = trigger * trigger
    vertex_stamp, edge_stamp, clock = stamps
    projected = 0
    for e in range(first, last):
        i, j = edges[e, 0], edges[e, 1]
        tested = edge_stamp[e]
        if tested >= 0 and vertex_stamp[i] < tested and vertex_stamp[j] < tested:
            continue
        clock[0] += 1
        edge_stamp[e] = clock[0]
        if limit_edge(p, inv_mass, i, j, rest[e], limit, trigger2):
            projected += 1
            moved[i] = moved[j] = True
            vertex_stamp[i] = vertex_stamp[j] = clock[0]
    return projected


@njit(cache=True)
def project_shear_edges(p, inv_mass, edges, rest, alpha, scale, lam, first):
    """One XPBD projection of each edge from ``first`` on (the shear edges), in order.

    C = |p_i - p_j| - L, dlambda = (-C - alpha~ lambda) / (w_i + w_j + alpha~), with
    ``scale`` = 1 / (w_i + w_j + alpha~) (0: the edge cannot move).
    """
    for e in range(first, edges.shape[0]):
        if scale[e] == 0.0:
            continue
        i, j = edges[e, 0], edges[e, 1]
        dx, dy, dz = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
        ln = math.sqrt(dx * dx + dy * dy + dz * dz)
        if ln == 0.0:
            continue
        inv_ln = 1.0 / ln
        dl = (rest[e] - ln - alpha[e] * lam[e]) * scale[e]
        lam[e] += dl
        si, sj = inv_mass[i] * dl * inv_ln, inv_mass[j] * dl * inv_ln
        p[i, 0] += si * dx
        p[i, 1] += si * dy
        p[i, 2] += si * dz
        p[j, 0] -= sj * dx
        p[j, 1] -= sj * dy
        p[j, 2] -= sj * dz


@njit(cache=True)
def project_hinges(p, inv_mass, hinges, rest, alpha):
    """One XPBD projection of every bending hinge (:func:`project_hinge`), in order."""
    for b in range(hinges.shape[0]):
        i0, i1, i2, i3 = hinges[b, 0], hinges[b, 1], hinges[b, 2], hinges[b, 3]
        project_hinge(p, inv_mass, i0, i1, i2, i3, rest[b], alpha[b])


@njit(cache=True)
def project_tethers(p, inv_mass, anchor, length):
    """Long-range attachments: |p_i - p_anchor(i)| <= L_i, the rest distance to the
    nearest pin (anchor -1: none); a vertex farther out is moved onto that sphere."""
    for i in range(p.shape[0]):
        a = anchor[i]
        if a < 0 or inv_mass[i] == 0.0:
            continue
        dx, dy, dz = p[i, 0] - p[a, 0], p[i, 1] - p[a, 1], p[i, 2] - p[a, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > length[i] * length[i]:
            s = length[i] / math.sqrt(d2)
            p[i, 0] = p[a, 0] + s * dx
            p[i, 1] = p[a, 1] + s * dy
            p[i, 2] = p[a, 2] + s * dz


@njit(cache=True)
def damp_velocities(x, v, inv_mass, edges, edge_c, hinges, hinge_c, dt):
    """Stiffness-proportional (Rayleigh) damping of the frame's velocities, in place.

    For each constraint C with damping coefficient c = damping * k, the rate dC/dt = g . v
    (g = grad C) is reduced implicitly over dt, dC/dt' = dC/dt / (1 + dt c S), S = sum w |g|^2,
    by the impulse v_q += w_q g_q (dC/dt' - dC/dt) / S. Rigid motions have dC/dt = 0, so
    they are never damped, and a cloth at rest (v = 0) is left exactly where it is.
    """
    grad = np.empty((4, 3))
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        s_w = inv_mass[i] + inv_mass[j]
        if edge_c[e] == 0.0 or s_w == 0.0:
            continue
        dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        ln = math.sqrt(dx * dx + dy * dy + dz * dz)
        if ln == 0.0:
            continue
        nx, ny, nz = dx / ln, dy / ln, dz / ln
        rate = nx * (v[i, 0] - v[j, 0]) + ny * (v[i, 1] - v[j, 1]) + nz * (v[i, 2] - v[j, 2])
        k = dt * edge_c[e] * s_w
        d = -rate * k / (1.0 + k) / s_w
        v[i, 0] += inv_mass[i] * d * nx
        v[i, 1] += inv_mass[i] * d * ny
        v[i, 2] += inv_mass[i] * d * nz
        v[j, 0] -= inv_mass[j] * d * nx
        v[j, 1] -= inv_mass[j] * d * ny
        v[j, 2] -= inv_mass[j] * d * nz
    for b in range(hinges.shape[0]):
        if hinge_c[b] == 0.0:
            continue
        if not hinge_gradient(x, hinges[b, 0], hinges[b, 1], hinges[b, 2], hinges[b, 3], grad):
            continue
        rate = 0.0
        s_w = 0.0
        for q in range(4):
            w = inv_mass[hinges[b, q]]
            for c in range(3):
                rate += grad[q, c] * v[hinges[b, q], c]
                s_w += w * grad[q, c] * grad[q, c]
        if s_w == 0.0:
            continue
        k = dt * hinge_c[b] * s_w
        d = -rate * k / (1.0 + k) / s_w
        for q in range(4):
            w = inv_mass[hinges[b, q]]
            for c in range(3):
                v[hinges[b, q], c] += w * d * grad[q, c]


@njit(cache=True)
def edge_stretch(x, edges, rest, limit):
    """(max_e |x_i - x_j| / L_e - 1, how many edges are longer than (1 + limit) L_e) over
    the edges (i, j) of ``edges`` (as many as ``rest``)."""
    top = -np.inf
    over = 0
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        s = math.sqrt(dx * dx + dy * dy + dz * dz) / rest[e] - 1.0
        top = max(top, s)
        over += s > limit
    return top, over
