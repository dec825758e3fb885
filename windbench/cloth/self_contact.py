"""Self-collision and cloth-cloth collision: vertices against triangles through a spatial hash.

The paper's cloth system [MKE03] keeps cloth from passing through itself. All cloth pieces
of a scene are one mesh here (:class:`~windbench.cloth.model.ClothModel`), so one pass
handles a flag folding on itself and two flags touching alike. It is thickness-based, not
continuous: a vertex i closer than ``cloth.thickness`` to a triangle (a, b, c) it does not
belong to, with its projection q = sum_k beta_k x_k inside the triangle, is pushed back to
the thickness on the side it lay on at the start of the substep (sign s of its distance to
the triangle's plane then):

    C = s (x_i - q) . n - thickness < 0,   den = w_i + sum_k beta_k^2 w_k,
    dx_i = -C w_i s n / den,   dx_k = C beta_k w_k s n / den.

A vertex that crosses a triangle within one substep is thus brought back while it lies
within REACH x thickness of the triangle's plane. Two edges that cross without a vertex near a
triangle (a sheet draped over another's border) are kept apart the same way at their
closest points (:func:`push_edges`, n = e1 x e2).

Broad phase: a spatial hash (:func:`build_hash`) of the triangles' boxes grown by
REACH x thickness plus half the longest edge on a lattice of cells ``cell`` wide (the mean rest edge length, at
least REACH x thickness), rebuilt every substep; a vertex reads the bucket of its own cell, an edge that of its
midpoint. Two
cells that share a bucket only add candidates, which the exact test rejects.

The figure :func:`self_intersections` counts intersecting triangle pairs: two triangles
without a common vertex of which an edge of one crosses the other (segment-triangle test,
Moeller-Trumbore), through the same hash.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

TABLE_PER_TRIANGLE = 2  # hash buckets per triangle
REACH = 4.0  # a vertex this many thicknesses behind a triangle is brought back
_P1, _P2, _P3 = 73856093, 19349663, 83492791  # Teschner et al. 2003 hash primes


class SelfContact(NamedTuple):
    """The fixed tables of the self-contact pass."""

    on: bool  # cloth.self_collision
    triangles: np.ndarray  # (m, 3) global vertex ids, every cloth
    thickness: float  # m
    cell: float  # m: hash cell size


def self_contact_model(rest, triangles, on: bool, thickness: float) -> SelfContact:
    """:class:`SelfContact` with the cell size of the module docstring."""
    tri = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    if tri.shape[0]:
        sides = np.linalg.norm(rest[tri[:, [1, 2, 0]]] - rest[tri], axis=2)
        mean_edge = float(sides.mean())
    else:
        mean_edge = 1.0
    return SelfContact(bool(on), tri, float(thickness), max(mean_edge, REACH * thickness, 1e-6))


@njit(cache=True, inline="always")
def _bucket(ix, iy, iz, size):
    return ((ix * _P1) ^ (iy * _P2) ^ (iz * _P3)) % size


@njit(cache=True, inline="always")
def _cell_range(p, tri, grow, cell):
    """Lowest and highest cell indices (3,) of the box of triangle ``tri`` grown by ``grow``."""
    lo, hi = np.empty(3, np.int64), np.empty(3, np.int64)
    for a in range(3):
        low = min(p[tri[0], a], p[tri[1], a], p[tri[2], a]) - grow
        high = max(p[tri[0], a], p[tri[1], a], p[tri[2], a]) + grow
        lo[a], hi[a] = np.int64(np.floor(low / cell)), np.int64(np.floor(high / cell))
    return lo, hi


@njit(cache=True)
def build_hash(p, triangles, grow, cell):
    """(start (size + 1,), entries): the triangles whose box grown by ``grow`` meets a cell,
    bucket by bucket (counting sort): bucket k holds entries[start[k]:start[k + 1]]."""
    size = max(1, TABLE_PER_TRIANGLE * triangles.shape[0])
    start = np.zeros(size + 1, np.int64)
    for f in range(triangles.shape[0]):
        lo, hi = _cell_range(p, triangles[f], grow, cell)
        for ix in range(lo[0], hi[0] + 1):
            for iy in range(lo[1], hi[1] + 1):
                for iz in range(lo[2], hi[2] + 1):
                    start[_bucket(ix, iy, iz, size) + 1] += 1
    for k in range(size):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    entries = np.empty(start[size], np.int64)
    for f in range(triangles.shape[0]):
        lo, hi = _cell_range(p, triangles[f], grow, cell)
        for ix in range(lo[0], hi[0] + 1):
            for iy in range(lo[1], hi[1] + 1):
                for iz in range(lo[2], hi[2] + 1):
                    k = _bucket(ix, iy, iz, size)
                    entries[fill[k]] = f
                    fill[k] += 1
    return start, entries


@njit(cache=True, inline="always")
def _plane(p, tri):
    """(nx, ny, nz, 2 A): unit normal of triangle ``tri`` at ``p`` and twice its area."""
    a, b, c = tri[0], tri[1], tri[2]
    e1x, e1y, e1z = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
    e2x, e2y, e2z = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    area2 = np.sqrt(nx * nx + ny * ny + nz * nz)
    if area2 > 0.0:
        nx, ny, nz = nx / area2, ny / area2, nz / area2
    return nx, ny, nz, area2


@njit(cache=True, inline="always")
def _height(p, tri, i, nx, ny, nz):
    """(x_i - x_tri[0]) . n."""
    a = tri[0]
    return (p[i, 0] - p[a, 0]) * nx + (p[i, 1] - p[a, 1]) * ny + (p[i, 2] - p[a, 2]) * nz


@njit(cache=True, inline="always")
def _barycentric(p, tri, i, nx, ny, nz, area2):
    """Barycentric coordinates of the projection of vertex i on the plane of ``tri``:
    beta_k = ((x_b - x_a) x (x_i - x_a)) . n / 2A over the edge a-b opposite corner k."""
    out = np.empty(3)
    for k in range(3):
        a, b = tri[(k + 1) % 3], tri[(k + 2) % 3]
        ux, uy, uz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
        wx, wy, wz = p[i, 0] - p[a, 0], p[i, 1] - p[a, 1], p[i, 2] - p[a, 2]
        cx, cy, cz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        out[k] = (cx * nx + cy * ny + cz * nz) / area2
    return out


@njit(cache=True)
def push_vertex(p, xp, inv_mass, i, tri, thickness):
    """The vertex-triangle contact of vertex i and triangle ``tri`` (module docstring).
    Returns C (0 when they do not touch)."""
    nx, ny, nz, area2 = _plane(p, tri)
    if area2 == 0.0:
        return 0.0
    dist = _height(p, tri, i, nx, ny, nz)
    if abs(dist) >= REACH * thickness:
        return 0.0
    beta = _barycentric(p, tri, i, nx, ny, nz, area2)
    if beta[0] < 0.0 or beta[1] < 0.0 or beta[2] < 0.0:
        return 0.0
    mx, my, mz, a0 = _plane(xp, tri)
    side = _height(xp, tri, i, mx, my, mz) if a0 > 0.0 else dist
    s = 1.0 if (side if side != 0.0 else dist) >= 0.0 else -1.0
    c = s * dist - thickness
    if c >= 0.0:
        return 0.0
    den = inv_mass[i]
    for k in range(3):
        den += beta[k] * beta[k] * inv_mass[tri[k]]
    if den <= 0.0:
        return 0.0
    g = -c * s / den
    n = (nx, ny, nz)
    for a in range(3):
        p[i, a] += g * inv_mass[i] * n[a]
        for k in range(3):
            p[tri[k], a] -= g * beta[k] * inv_mass[tri[k]] * n[a]
    return c


@njit(cache=True, inline="always")
def _apart(p, a, b, c, d, gap):
    """Whether the boxes of the points {a, b} and {c, d} of ``p`` (d = c for a point) are
    more than ``gap`` apart along an axis: the cheap rejection before an exact test."""
    for k in range(3):
        if max(p[a, k], p[b, k]) + gap < min(p[c, k], p[d, k]):
            return True
        if min(p[a, k], p[b, k]) - gap > max(p[c, k], p[d, k]):
            return True
    return False


@njit(cache=True, inline="always")
def _outside_box(p, tri, i, gap):
    """Whether vertex i lies outside the box of triangle ``tri`` grown by ``gap``."""
    for k in range(3):
        x = p[i, k]
        if x + gap < min(p[tri[0], k], p[tri[1], k], p[tri[2], k]):
            return True
        if x - gap > max(p[tri[0], k], p[tri[1], k], p[tri[2], k]):
            return True
    return False


@njit(cache=True, inline="always")
def _segment_parameters(p, i, j, k, l):
    """(s, u, |gap|^2) of the closest points p_i + s (p_j - p_i), p_k + u (p_l - p_k) of two
    edges (clamped to [0, 1]; parallel edges: s = 0), in scalars: it runs for every
    candidate pair."""
    d1x, d1y, d1z = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
    d2x, d2y, d2z = p[l, 0] - p[k, 0], p[l, 1] - p[k, 1], p[l, 2] - p[k, 2]
    rx, ry, rz = p[i, 0] - p[k, 0], p[i, 1] - p[k, 1], p[i, 2] - p[k, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    b = d1x * d2x + d1y * d2y + d1z * d2z
    c = d1x * rx + d1y * ry + d1z * rz
    f = d2x * rx + d2y * ry + d2z * rz
    den = a * e - b * b
    s = min(1.0, max(0.0, (b * f - c * e) / den)) if den > 1e-12 * a * e else 0.0
    u = (b * s + f) / e if e > 0.0 else 0.0
    if u < 0.0:
        u, s = 0.0, (min(1.0, max(0.0, -c / a)) if a > 0.0 else 0.0)
    elif u > 1.0:
        u, s = 1.0, (min(1.0, max(0.0, (b - c) / a)) if a > 0.0 else 0.0)
    gx, gy, gz = rx + s * d1x - u * d2x, ry + s * d1y - u * d2y, rz + s * d1z - u * d2z
    return s, u, gx * gx + gy * gy + gz * gz


@njit(cache=True)
def push_edges(p, xp, inv_mass, i, j, k, l, thickness):
    """The edge-edge contact of edges i-j and k-l: their closest points q1, q2 (both inside
    the edges) kept ``thickness`` apart along n = e1 x e2 on the side they lay on at the
    start of the substep: C = s (q1 - q2) . n - thickness, the four vertices moved with
    their barycentric weights and inverse masses. Returns C (0 when they do not touch)."""
    s, u, gap2 = _segment_parameters(p, i, j, k, l)
    if s <= 0.0 or s >= 1.0 or u <= 0.0 or u >= 1.0 or gap2 >= thickness * thickness:
        return 0.0  # apart, or nearest at an end point: the vertex-triangle contacts' business
    n = np.cross(p[j] - p[i], p[l] - p[k])
    norm = np.sqrt(np.dot(n, n))
    if norm == 0.0:
        return 0.0
    n /= norm
    gap = (1.0 - s) * p[i] + s * p[j] - (1.0 - u) * p[k] - u * p[l]
    dist = np.dot(gap, n)
    if abs(dist) >= thickness or np.dot(gap, gap) >= thickness * thickness:
        return 0.0
    before = (1.0 - s) * xp[i] + s * xp[j] - (1.0 - u) * xp[k] - u * xp[l]
    side = np.dot(before, n)
    sgn = 1.0 if (side if side != 0.0 else dist) >= 0.0 else -1.0
    c = sgn * dist - thickness
    w = np.array([(1.0 - s), s, -(1.0 - u), -u])
    ids = np.array([i, j, k, l])
    den = 0.0
    for a in range(4):
        den += w[a] * w[a] * inv_mass[ids[a]]
    if c >= 0.0 or den <= 0.0:
        return 0.0
    g = -c * sgn / den
    for a in range(4):
        for b in range(3):
            p[ids[a], b] += g * w[a] * inv_mass[ids[a]] * n[b]
    return c


@njit(cache=True)
def _edge_contacts(sc, edges, inv_mass, p, xp, start, entries):
    """Every edge against the edges of the triangles hashed in the cell of its midpoint
    (:func:`push_edges`; the hash grows the triangles' boxes by half the longest edge, so
    that cell holds every triangle within the reach of any point of the edge)."""
    _, triangles, thickness, cell = sc
    size = start.shape[0] - 1
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        if inv_mass[i] + inv_mass[j] == 0.0:
            continue
        k = _bucket(
            np.int64(np.floor(0.5 * (p[i, 0] + p[j, 0]) / cell)),
            np.int64(np.floor(0.5 * (p[i, 1] + p[j, 1]) / cell)),
            np.int64(np.floor(0.5 * (p[i, 2] + p[j, 2]) / cell)),
            size,
        )
        for m in range(start[k], start[k + 1]):
            tri = triangles[entries[m]]
            for t in range(3):
                a, b = tri[t], tri[(t + 1) % 3]
                if a == i or a == j or b == i or b == j or min(a, b) < min(i, j):
                    continue  # each pair of edges from the edge with the lower id
                if not _apart(p, i, j, a, b, thickness):
                    push_edges(p, xp, inv_mass, i, j, a, b, thickness)


@njit(cache=True)
def _longest(p, edges):
    """The length of the longest edge at ``p``."""
    top = 0.0
    for e in range(edges.shape[0]):
        d2 = 0.0
        for a in range(3):
            d2 += (p[edges[e, 0], a] - p[edges[e, 1], a]) ** 2
        top = max(top, d2)
    return np.sqrt(top)


@njit(cache=True)
def self_contacts(sc, edges, inv_mass, p, xp):
    """One pass of vertex-triangle contacts over every vertex, then of edge-edge contacts
    over every edge (module docstring)."""
    _, triangles, thickness, cell = sc
    if triangles.shape[0] == 0:
        return
    start, entries = build_hash(p, triangles, REACH * thickness + 0.5 * _longest(p, edges), cell)
    size = start.shape[0] - 1
    for i in range(p.shape[0]):
        k = _bucket(
            np.int64(np.floor(p[i, 0] / cell)),
            np.int64(np.floor(p[i, 1] / cell)),
            np.int64(np.floor(p[i, 2] / cell)),
            size,
        )
        for j in range(start[k], start[k + 1]):
            tri = triangles[entries[j]]
            if tri[0] == i or tri[1] == i or tri[2] == i:
                continue
            if inv_mass[i] == 0.0 and inv_mass[tri[0]] + inv_mass[tri[1]] + inv_mass[tri[2]] == 0:
                continue
            if _outside_box(p, tri, i, REACH * thickness):
                continue
            push_vertex(p, xp, inv_mass, i, tri, thickness)
    _edge_contacts(sc, edges, inv_mass, p, xp, start, entries)


@njit(cache=True)
def segment_crosses(p, i, j, a, b, c):
    """Whether the segment x_i-x_j meets the triangle x_a x_b x_c (Moeller-Trumbore, in
    scalars: it runs for every candidate pair)."""
    dx, dy, dz = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
    e1x, e1y, e1z = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
    e2x, e2y, e2z = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
    hx, hy, hz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * hx + e1y * hy + e1z * hz
    if abs(det) < 1e-300:
        return False
    sx, sy, sz = p[i, 0] - p[a, 0], p[i, 1] - p[a, 1], p[i, 2] - p[a, 2]
    u = (sx * hx + sy * hy + sz * hz) / det
    if u < 0.0 or u > 1.0:
        return False
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) / det
    if v < 0.0 or u + v > 1.0:
        return False
    t = (e2x * qx + e2y * qy + e2z * qz) / det
    return 0.0 <= t <= 1.0


@njit(cache=True, inline="always")
def _share_vertex(a, b):
    for u in range(3):
        for v in range(3):
            if a[u] == b[v]:
                return True
    return False


@njit(cache=True)
def triangles_cross(p, a, b):
    """Whether an edge of triangle ``a`` crosses triangle ``b`` or one of b's crosses a."""
    for k in range(3):
        if segment_crosses(p, a[k], a[(k + 1) % 3], b[0], b[1], b[2]):
            return True
        if segment_crosses(p, b[k], b[(k + 1) % 3], a[0], a[1], a[2]):
            return True
    return False


@njit(cache=True, inline="always")
def _boxes_apart(p, a, b):
    """Whether the boxes of triangles ``a`` and ``b`` do not meet."""
    for k in range(3):
        if max(p[a[0], k], p[a[1], k], p[a[2], k]) < min(p[b[0], k], p[b[1], k], p[b[2], k]):
            return True
        if min(p[a[0], k], p[a[1], k], p[a[2], k]) > max(p[b[0], k], p[b[1], k], p[b[2], k]):
            return True
    return False


@njit(cache=True)
def _crossing_pairs(p, triangles, cell):
    """Keys f * m + g (f < g) of the intersecting triangle pairs, with repeats."""
    m = triangles.shape[0]
    start, entries = build_hash(p, triangles, 0.0, cell)
    size = start.shape[0] - 1
    found = [np.int64(0) for _ in range(0)]
    for f in range(m):
        lo, hi = _cell_range(p, triangles[f], 0.0, cell)
        for ix in range(lo[0], hi[0] + 1):
            for iy in range(lo[1], hi[1] + 1):
                for iz in range(lo[2], hi[2] + 1):
                    k = _bucket(ix, iy, iz, size)
                    for j in range(start[k], start[k + 1]):
                        g = entries[j]
                        if g <= f or _share_vertex(triangles[f], triangles[g]):
                            continue
                        if _boxes_apart(p, triangles[f], triangles[g]):
                            continue
                        if triangles_cross(p, triangles[f], triangles[g]):
                            found.append(f * m + g)
    return np.array(found, dtype=np.int64)


def self_intersections(sc: SelfContact, positions) -> int:
    """The number of intersecting pairs of triangles without a common vertex (module
    docstring), all cloths together."""
    if sc.triangles.shape[0] < 2:
        return 0
    x = np.ascontiguousarray(positions, dtype=np.float64)
    return int(np.unique(_crossing_pairs(x, sc.triangles, sc.cell)).size)
