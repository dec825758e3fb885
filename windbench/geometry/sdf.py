"""Signed distance to a closed triangle mesh, tabulated on a lattice and sampled trilinearly.

A mesh body answers the same two questions as the analytic bodies (signed distance d(p),
negative inside, and the outward normal) for every cloth vertex of every substep and every
wind particle piece, so the distance is computed once, when the scene is built
(:func:`sdf_lattice`), on a lattice of spacing h over the mesh's bounding box grown by
PAD_CELLS cells; the kernels then read it (:func:`lattice_distance`):

- d(p) is the trilinear interpolant of the eight lattice values around p, n = grad d / |grad d|
  (the interpolant's exact gradient). Where the true distance is smooth its error is at most
  ``h^2 / 8 (|d_xx| + |d_yy| + |d_zz|)``; on a surface of principal radii r1, r2 that is
  ``h^2 / 8 (1/r1 + 1/r2)``, e.g. 0.6 mm on a 4 cm arm at h = 1 cm, under the cloth's
  collision margin. Along sharp edges of the mesh it is O(h) on the inside only;
- outside the lattice d is the distance to the mesh's bounding box, a lower bound of the true
  distance, at least PAD_CELLS h there.

The lattice values: every lattice point within BAND_CELLS h of the surface gets its exact
distance, the minimum over the triangles whose bounding box grown by that band holds it
(closest point on a triangle: Ericson, Real-Time Collision Detection, 5.1.5), and its sign
from the angle-weighted pseudonormal of the closest feature (face, edge or vertex), which is
exact for a closed, consistently oriented mesh (Baerentzen & Aanaes 2005). Farther points
take their neighbours' closest triangles in eight sweeps over the lattice (a closest-point
transform: their distance is that to a real triangle, exact or a slight over-estimate) and
their sign from a neighbour: a lattice edge from a point farther than BAND_CELLS h >= h from
the surface cannot cross it, so neighbours there share a sign.

The first hit of a straight piece a + s e, s in [0, 1], on a mesh body (not convex, so the
convex bodies' root search does not apply) is found by sphere tracing on the interpolant:
|grad d| <= sqrt 3 (each partial derivative is a mean of lattice differences of a
1-Lipschitz function), so a step of d / sqrt 3 cannot pass the surface; steps are at least
h / MIN_STEP_PER_CELL, so only a sliver thinner than that could be missed; the first sign
change is then bisected (:func:`lattice_first_hit`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

PAD_CELLS = 3  # the lattice reaches this many spacings beyond the mesh's bounding box
BAND_CELLS = 2  # exact distances within this many spacings of the surface
HEADER = 7  # nx, ny, nz, origin (3), h: the lattice's entry in a fields array
MIN_STEP_PER_CELL = 4
ROOT_ITERATIONS = 60
SQRT3 = np.sqrt(3.0)
FACE, V0, V1, V2, E01, E12, E20 = 0, 1, 2, 3, 4, 5, 6  # closest feature of a triangle


class MeshTables(NamedTuple):
    """A closed mesh as the lattice kernels read it, with the pseudonormals of its features."""

    vertices: np.ndarray  # (n, 3)
    triangles: np.ndarray  # (m, 3)
    face_normal: np.ndarray  # (m, 3) unit
    triangle_edges: np.ndarray  # (m, 3) edge ids of (v0 v1, v1 v2, v2 v0)
    edge_normal: np.ndarray  # (E, 3) sum of the two faces' unit normals
    vertex_normal: np.ndarray  # (n, 3) angle-weighted sum of the faces' unit normals


@dataclass(frozen=True, eq=False)
class SDFLattice:
    """Signed distances ``values`` (nx, ny, nz) at ``origin + (i, j, k) h`` (metres)."""

    origin: np.ndarray
    spacing: float
    values: np.ndarray

    def entry(self) -> np.ndarray:
        """The lattice as one flat float64 row: HEADER numbers, then the values (C order)."""
        head = [*self.values.shape, *self.origin, self.spacing]
        return np.concatenate([np.asarray(head, dtype=np.float64), self.values.reshape(-1)])


def mesh_tables(vertices: np.ndarray, triangles: np.ndarray) -> MeshTables:
    """Face, edge and vertex pseudonormals of a closed, outward-oriented mesh."""
    x = [vertices[triangles[:, k]] for k in range(3)]
    cross = np.cross(x[1] - x[0], x[2] - x[0])
    norm = np.linalg.norm(cross, axis=1, keepdims=True)
    face = np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)
    corner = np.stack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]], axis=1)
    keys = np.sort(corner.reshape(-1, 2), axis=1)
    edges, edge_id = np.unique(keys, axis=0, return_inverse=True)
    edge_normal = np.zeros((edges.shape[0], 3))
    np.add.at(edge_normal, edge_id.reshape(-1), np.repeat(face, 3, axis=0))
    vertex_normal = np.zeros_like(vertices, dtype=np.float64)
    for k in range(3):  # the angle of each triangle at its corner k
        u = x[(k + 1) % 3] - x[k]
        v = x[(k + 2) % 3] - x[k]
        cos = np.einsum("ij,ij->i", u, v) / np.maximum(
            np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300
        )
        np.add.at(vertex_normal, triangles[:, k], np.arccos(np.clip(cos, -1, 1))[:, None] * face)
    return MeshTables(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(triangles, dtype=np.int64),
        face,
        edge_id.reshape(-1, 3).astype(np.int64),
        edge_normal,
        vertex_normal,
    )


@njit(cache=True, inline="always")
def _dot(u, v):
    """u . v of two 3-tuples."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


@njit(cache=True, inline="always")
def _along(a, s, u):
    """The point a + s u on the line through a along u."""
    return (a[0] + s * u[0], a[1] + s * u[1], a[2] + s * u[2])


@njit(cache=True)
def closest_on_triangle(p, a, b, c):
    """Closest point q of triangle abc to p (3-tuples) and its feature (FACE, V0..V2, E01,
    E12, E20): the Voronoi regions of the vertices, then the edges, else the face (Ericson
    5.1.5)."""
    ab = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    ac = (c[0] - a[0], c[1] - a[1], c[2] - a[2])
    d1 = _dot(ab, (p[0] - a[0], p[1] - a[1], p[2] - a[2]))
    d2 = _dot(ac, (p[0] - a[0], p[1] - a[1], p[2] - a[2]))
    if d1 <= 0.0 and d2 <= 0.0:
        return a, V0
    d3 = _dot(ab, (p[0] - b[0], p[1] - b[1], p[2] - b[2]))
    d4 = _dot(ac, (p[0] - b[0], p[1] - b[1], p[2] - b[2]))
    if d3 >= 0.0 and d4 <= d3:
        return b, V1
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return _along(a, d1 / (d1 - d3), ab), E01
    d5 = _dot(ab, (p[0] - c[0], p[1] - c[1], p[2] - c[2]))
    d6 = _dot(ac, (p[0] - c[0], p[1] - c[1], p[2] - c[2]))
    if d6 >= 0.0 and d5 <= d6:
        return c, V2
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return _along(a, d2 / (d2 - d6), ac), E20
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return _along(b, w, (c[0] - b[0], c[1] - b[1], c[2] - b[2])), E12
    denom = 1.0 / (va + vb + vc)
    v, w = vb * denom, vc * denom
    return (
        a[0] + ab[0] * v + ac[0] * w,
        a[1] + ab[1] * v + ac[1] * w,
        a[2] + ab[2] * v + ac[2] * w,
    ), FACE


@njit(cache=True)
def triangle_distance(mesh, t, p):
    """(|p - q|, sign of (p - q) . pseudonormal of q's feature) for triangle t; p a 3-tuple."""
    tri = mesh.triangles[t]
    x = mesh.vertices
    a = (x[tri[0], 0], x[tri[0], 1], x[tri[0], 2])
    b = (x[tri[1], 0], x[tri[1], 1], x[tri[1], 2])
    c = (x[tri[2], 0], x[tri[2], 1], x[tri[2], 2])
    q, feature = closest_on_triangle(p, a, b, c)
    if feature == FACE:
        n = mesh.face_normal[t]
    elif feature <= V2:
        n = mesh.vertex_normal[tri[feature - V0]]
    else:
        n = mesh.edge_normal[mesh.triangle_edges[t, feature - E01]]
    r = (p[0] - q[0], p[1] - q[1], p[2] - q[2])
    return np.sqrt(_dot(r, r)), 1 if _dot(r, n) >= 0.0 else -1


@njit(cache=True)
def band_pass(mesh, origin, h, band, dist, closest, sign):
    """Exact distance and sign at every lattice point within ``band`` of a triangle's box."""
    shape = dist.shape
    for t in range(mesh.triangles.shape[0]):
        lo = np.empty(3, dtype=np.int64)
        hi = np.empty(3, dtype=np.int64)
        for a in range(3):
            xs = mesh.vertices[mesh.triangles[t], a]
            lo[a] = max(0, int(np.ceil((xs.min() - band - origin[a]) / h)))
            hi[a] = min(shape[a] - 1, int(np.floor((xs.max() + band - origin[a]) / h)))
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    p = (origin[0] + i * h, origin[1] + j * h, origin[2] + k * h)
                    d, s = triangle_distance(mesh, t, p)
                    if d < dist[i, j, k]:
                        dist[i, j, k], closest[i, j, k], sign[i, j, k] = d, t, s


@njit(cache=True)
def sweep_pass(mesh, origin, h, band, dist, closest, sign):
    """Eight sweeps: a point beyond the band tries its upwind neighbours' closest triangles
    and takes a neighbour's sign (module docstring)."""
    nx, ny, nz = dist.shape
    for octant in range(8):
        si, sj, sk = 1 - 2 * (octant & 1), 1 - 2 * ((octant >> 1) & 1), 1 - 2 * (octant >> 2)
        for ii in range(nx):
            i = ii if si > 0 else nx - 1 - ii
            for jj in range(ny):
                j = jj if sj > 0 else ny - 1 - jj
                for kk in range(nz):
                    k = kk if sk > 0 else nz - 1 - kk
                    if dist[i, j, k] < band:
                        continue
                    p = (origin[0] + i * h, origin[1] + j * h, origin[2] + k * h)
                    for a in range(3):
                        ni, nj, nk = i - si * (a == 0), j - sj * (a == 1), k - sk * (a == 2)
                        if not (0 <= ni < nx and 0 <= nj < ny and 0 <= nk < nz):
                            continue
                        t = closest[ni, nj, nk]
                        if sign[ni, nj, nk] == 0 or t < 0:
                            continue
                        if sign[i, j, k] == 0:
                            sign[i, j, k] = sign[ni, nj, nk]
                        if t != closest[i, j, k]:
                            d, _ = triangle_distance(mesh, t, p)
                            if d < dist[i, j, k]:
                                dist[i, j, k], closest[i, j, k] = d, t


def sdf_lattice(vertices: np.ndarray, triangles: np.ndarray, spacing: float) -> SDFLattice:
    """The signed distance of a closed, outward-oriented mesh on a lattice of ``spacing`` m
    covering its bounding box and PAD_CELLS more spacings on every side."""
    mesh = mesh_tables(vertices, triangles)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    origin = lo - PAD_CELLS * spacing
    shape = tuple(int(n) for n in np.ceil((hi - lo) / spacing).astype(int) + 2 * PAD_CELLS + 1)
    dist = np.full(shape, np.inf)
    closest = np.full(shape, -1, dtype=np.int64)
    sign = np.zeros(shape, dtype=np.int8)
    band = BAND_CELLS * spacing
    band_pass(mesh, origin, spacing, band, dist, closest, sign)
    sign[dist >= band] = 0  # beyond the band the nearest triangle seen may not be the closest
    sweep_pass(mesh, origin, spacing, band, dist, closest, sign)
    return SDFLattice(origin, float(spacing), sign * dist)


@njit(cache=True)
def lattice_distance(fields, prm, px, py, pz, normal):
    """Signed distance at p from the lattice at ``fields[prm[0]:]``, outward normal in
    ``normal``; ``prm[1:7]`` the mesh's bounding box (lower, upper), used beyond the lattice."""
    off = int(prm[0])
    nx, ny, nz = int(fields[off]), int(fields[off + 1]), int(fields[off + 2])
    h = fields[off + 6]
    u = (px - fields[off + 3]) / h
    v = (py - fields[off + 4]) / h
    w = (pz - fields[off + 5]) / h
    if not (0.0 <= u <= nx - 1 and 0.0 <= v <= ny - 1 and 0.0 <= w <= nz - 1):
        return box_outside_distance(prm, px, py, pz, normal)
    i, j, k = min(int(u), nx - 2), min(int(v), ny - 2), min(int(w), nz - 2)
    fx, fy, fz = u - i, v - j, w - k
    base = off + HEADER + (i * ny + j) * nz + k
    sy, sx = nz, ny * nz
    c000, c001 = fields[base], fields[base + 1]
    c010, c011 = fields[base + sy], fields[base + sy + 1]
    c100, c101 = fields[base + sx], fields[base + sx + 1]
    c110, c111 = fields[base + sx + sy], fields[base + sx + sy + 1]
    # bilinear in (y, z) on the faces x = i and x = i + 1, then linear in x
    c00 = c000 + fz * (c001 - c000)
    c01 = c010 + fz * (c011 - c010)
    c10 = c100 + fz * (c101 - c100)
    c11 = c110 + fz * (c111 - c110)
    c0 = c00 + fy * (c01 - c00)
    c1 = c10 + fy * (c11 - c10)
    gx = c1 - c0
    gy = (1.0 - fx) * (c01 - c00) + fx * (c11 - c10)
    gz = (1.0 - fx) * ((1.0 - fy) * (c001 - c000) + fy * (c011 - c010)) + fx * (
        (1.0 - fy) * (c101 - c100) + fy * (c111 - c110)
    )
    g = np.sqrt(gx * gx + gy * gy + gz * gz)
    if g > 0.0:
        normal[0], normal[1], normal[2] = gx / g, gy / g, gz / g
    else:
        normal[0], normal[1], normal[2] = 0.0, 0.0, 1.0
    return c0 + fx * (c1 - c0)


@njit(cache=True)
def box_outside_distance(prm, px, py, pz, normal):
    """Distance from p to the box ``prm[1:4] .. prm[4:7]`` and the direction away from it
    (p outside the box; a point inside gets 0 and +z)."""
    d2 = 0.0
    for a, x in enumerate((px, py, pz)):
        excess = max(prm[1 + a] - x, 0.0, x - prm[4 + a])
        normal[a] = excess if x > prm[4 + a] else -excess
        d2 += excess * excess
    d = np.sqrt(d2)
    if d == 0.0:
        normal[0], normal[1], normal[2] = 0.0, 0.0, 1.0
        return 0.0
    normal[0], normal[1], normal[2] = normal[0] / d, normal[1] / d, normal[2] / d
    return d


@njit(cache=True, inline="always")
def _slab(lo, hi, a, e, s0, s1):
    """[s0, s1] cut to the s where lo <= a + s e <= hi (one axis)."""
    if e == 0.0:
        return (s0, s1) if lo <= a <= hi else (1.0, 0.0)
    t0, t1 = (lo - a) / e, (hi - a) / e
    return max(s0, min(t0, t1)), min(s1, max(t0, t1))


@njit(cache=True)
def _lattice_span(fields, prm, a, e):
    """The part [s0, s1] of a + s e, s in [0, 1], inside the lattice's box (s0 > s1: none)."""
    off = int(prm[0])
    h = fields[off + 6]
    s0, s1 = 0.0, 1.0
    lo = fields[off + 3 : off + 6]
    s0, s1 = _slab(lo[0], lo[0] + (fields[off] - 1.0) * h, a[0], e[0], s0, s1)
    s0, s1 = _slab(lo[1], lo[1] + (fields[off + 1] - 1.0) * h, a[1], e[1], s0, s1)
    return _slab(lo[2], lo[2] + (fields[off + 2] - 1.0) * h, a[2], e[2], s0, s1)


@njit(cache=True)
def lattice_first_hit(fields, prm, a, e, normal):
    """First s in [0, 1] with d(a + s e) <= 0 on a mesh body, or -1; outward normal there.

    Sphere tracing (module docstring), then bisection of the bracket to round-off, keeping
    the outside end. A point starting on or inside the surface hits at s = 0 only if it moves
    inward (as for the convex bodies). ``a``, ``e`` are 3-tuples.
    """
    length = np.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    s0, s1 = _lattice_span(fields, prm, a, e)
    if s0 > s1 or length == 0.0:
        return -1.0
    h = fields[int(prm[0]) + 6]
    f = lattice_distance(fields, prm, a[0] + s0 * e[0], a[1] + s0 * e[1], a[2] + s0 * e[2], normal)
    if f <= 0.0:
        inward = normal[0] * e[0] + normal[1] * e[1] + normal[2] * e[2] < -1e-12 * length
        return s0 if inward else -1.0
    min_step = h / (MIN_STEP_PER_CELL * length)
    lo = s0
    while lo < s1:
        hi = min(s1, lo + max(f / (SQRT3 * length), min_step))
        fh = lattice_distance(
            fields, prm, a[0] + hi * e[0], a[1] + hi * e[1], a[2] + hi * e[2], normal
        )
        if fh <= 0.0:
            for _ in range(ROOT_ITERATIONS):  # f(lo) > 0 >= f(hi)
                if (hi - lo) * length <= 1e-13 * (1.0 + length):
                    break
                mid = 0.5 * (lo + hi)
                x, y, z = a[0] + mid * e[0], a[1] + mid * e[1], a[2] + mid * e[2]
                if lattice_distance(fields, prm, x, y, z, normal) <= 0.0:
                    hi = mid
                else:
                    lo = mid
            lattice_distance(
                fields, prm, a[0] + lo * e[0], a[1] + lo * e[1], a[2] + lo * e[2], normal
            )
            return lo
        lo, f = hi, fh
    return -1.0
