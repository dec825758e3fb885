"""Triangles registered in the grid cells they cut, and segment/triangle intersection.

Paper §4.1.2: "each triangle of its representing mesh is registered in the fluid grid,
which means that the cell of the wind field occupied by the object is marked as occupied";
§4.2.2: each particle path piece "is then tested for collisions with the objects in the
scene". Registering every triangle in the cells it overlaps lets a path piece test only
the triangles of the cells it crosses: cost O(pieces x local triangles), not O(triangles).

The registration is a CSR table over flattened cells ``c = (i * ny + j) * nz + k``:
the triangles of cell c are ``items[start[c]:start[c + 1]]``. A triangle is registered in a
cell when they overlap (separating-axis test of Akenine-Möller, "Fast 3D triangle-box
overlap testing", 2001), so a triangle lying exactly on a cell face counts for both cells.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from windbench.arrays import copy_head


@njit(cache=True, inline="always")
def _axis_test(ax, ay, az, v, half):
    """True if the axis (ax, ay, az) separates the triangle (corners v = (x0, y0, z0, x1,
    ..., z2), box-centred) from the box."""
    p0 = ax * v[0] + ay * v[1] + az * v[2]
    p1 = ax * v[3] + ay * v[4] + az * v[5]
    p2 = ax * v[6] + ay * v[7] + az * v[8]
    r = half[0] * abs(ax) + half[1] * abs(ay) + half[2] * abs(az)
    return min(p0, p1, p2) > r or max(p0, p1, p2) < -r


@njit(cache=True, inline="always")
def _edge_separates(ex, ey, ez, v, half):
    """True if one of the three axes edge (ex, ey, ez) x a box axis separates them."""
    return (
        _axis_test(0.0, -ez, ey, v, half)
        or _axis_test(ez, 0.0, -ex, v, half)
        or _axis_test(-ey, ex, 0.0, v, half)
    )


@njit(cache=True)
def triangle_box_overlap(a, b, c, centre, half):
    """True if triangle abc and the axis-aligned box (centre, half-widths) overlap (SAT).
    In scalars (the corners as one tuple): small arrays made per test cost an allocation
    each, and the registration runs it for every triangle and cell it may cut."""
    v = (
        a[0] - centre[0], a[1] - centre[1], a[2] - centre[2],
        b[0] - centre[0], b[1] - centre[1], b[2] - centre[2],
        c[0] - centre[0], c[1] - centre[1], c[2] - centre[2],
    )  # fmt: skip
    for k in range(3):  # the box's face normals
        if min(v[k], v[3 + k], v[6 + k]) > half[k] or max(v[k], v[3 + k], v[6 + k]) < -half[k]:
            return False
    e0 = (v[3] - v[0], v[4] - v[1], v[5] - v[2])
    e1 = (v[6] - v[3], v[7] - v[4], v[8] - v[5])
    w = (-(v[0] - v[6]), -(v[1] - v[7]), -(v[2] - v[8]))  # -e2, e2 = v0 - v2
    nx = e0[1] * w[2] - e0[2] * w[1]  # n = e0 x (-e2)
    ny = e0[2] * w[0] - e0[0] * w[2]
    nz = e0[0] * w[1] - e0[1] * w[0]
    # the triangle's plane: n . x = n . v0
    r = half[0] * abs(nx) + half[1] * abs(ny) + half[2] * abs(nz)
    if abs(nx * v[0] + ny * v[1] + nz * v[2]) > r:
        return False
    # the nine edge x axis cross products
    return not (
        _edge_separates(e0[0], e0[1], e0[2], v, half)
        or _edge_separates(e1[0], e1[1], e1[2], v, half)
        or _edge_separates(-w[0], -w[1], -w[2], v, half)
    )


@njit(cache=True, inline="always")
def _cell_range(lo, hi, lower, h, n):
    """Cells [i0, i1] along one axis that the interval [lo, hi] touches, clamped to the grid."""
    i0 = int(np.floor((lo - lower) / h))
    i1 = int(np.floor((hi - lower) / h))
    return max(i0, 0), min(i1, n - 1)


@njit(cache=True)
def _overlap_keys(positions, triangles, lower, h, shape):
    """Keys ``cell * m + t`` of every overlap of a cell and triangle t (m triangles), in the
    order found. Cost O(triangles x cells each overlaps), independent of the grid size."""
    ny, nz = shape[1], shape[2]
    m = triangles.shape[0]
    half = np.full(3, 0.5 * h * (1.0 + 1e-9))
    centre = np.empty(3)
    rng = np.empty((3, 2), dtype=np.int64)
    keys = np.empty(4 * m + 16, dtype=np.int64)
    n = 0
    for t in range(m):
        a = positions[triangles[t, 0]]
        b = positions[triangles[t, 1]]
        c = positions[triangles[t, 2]]
        for k in range(3):
            lo = min(a[k], b[k], c[k])
            hi = max(a[k], b[k], c[k])
            rng[k, 0], rng[k, 1] = _cell_range(lo, hi, lower[k], h, shape[k])
        for i in range(rng[0, 0], rng[0, 1] + 1):
            for j in range(rng[1, 0], rng[1, 1] + 1):
                for k in range(rng[2, 0], rng[2, 1] + 1):
                    centre[0] = lower[0] + (i + 0.5) * h
                    centre[1] = lower[1] + (j + 0.5) * h
                    centre[2] = lower[2] + (k + 0.5) * h
                    if not triangle_box_overlap(a, b, c, centre, half):
                        continue
                    if n == keys.shape[0]:
                        grown = np.empty(2 * n, dtype=np.int64)
                        copy_head(grown, keys, keys.shape[0])
                        keys = grown
                    keys[n] = ((i * ny + j) * nz + k) * m + t
                    n += 1
    return keys[:n]


def triangle_cell_pairs(positions, triangles, lower, h, shape) -> np.ndarray:
    """Sorted keys ``cell * m + t`` of every overlap of a cell and triangle t (m triangles):
    the cells in order, each cell's triangles in order. Sorted by numpy: in a compiled
    kernel ``np.sort`` compiles numba's quicksort, about 1.7 CPU seconds in every fresh
    process (``experiments/compile_first_use.py``)."""
    return np.sort(_overlap_keys(positions, triangles, lower, h, shape))


def register_triangles(positions, triangles, lower, h, shape):
    """CSR (start ``(n_cells + 1,)``, items) of the triangles overlapping each cell."""
    n_cells = int(shape[0] * shape[1] * shape[2])
    keys = triangle_cell_pairs(positions, triangles, lower, h, shape)
    m = max(triangles.shape[0], 1)
    start = np.zeros(n_cells + 1, dtype=np.int64)
    start[1:] = np.cumsum(np.bincount(keys // m, minlength=n_cells))
    return start, keys % m


def triangle_cells(positions, triangles, grid):
    """Register cloth triangles in ``grid``: the CSR (start, items) of each cell's triangles."""
    return register_triangles(
        np.ascontiguousarray(positions, dtype=np.float64),
        np.ascontiguousarray(triangles, dtype=np.int64),
        np.asarray(grid.lower, dtype=np.float64),
        float(grid.h),
        np.asarray(grid.shape, dtype=np.int64),
    )


def occupied_cells(start, shape) -> np.ndarray:
    """Boolean ``shape`` mask of the cells with at least one registered triangle."""
    return (np.diff(start) > 0).reshape(tuple(shape))


@njit(cache=True)
def segment_triangle(p0, p1, a, b, c):
    """Fraction s in [0, 1] along p0 -> p1 where the segment meets triangle abc, or -1
    (3-vectors; :func:`segment_triangle_xyz` of their coordinates)."""
    return segment_triangle_xyz(
        (p0[0], p0[1], p0[2]), (p1[0], p1[1], p1[2]),
        (a[0], a[1], a[2]), (b[0], b[1], b[2]), (c[0], c[1], c[2]),
    )  # fmt: skip


@njit(cache=True)
def segment_triangle_xyz(p0, p1, a, b, c):
    """Fraction s in [0, 1] along p0 -> p1 where the segment meets the triangle a b c, or
    -1; the points as (x, y, z) tuples.

    Möller-Trumbore: solve p0 + s (p1 - p0) = a + u (b - a) + v (c - a), with u, v >= 0,
    u + v <= 1. A segment lying in the triangle's plane does not count as a hit. In
    scalars: it runs for every grid face beside the cloth and every particle path piece
    near it, where 3-vector temporaries cost a heap allocation each.
    """
    (x0, y0, z0), (x1, y1, z1) = p0, p1
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = a, b, c
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    pvx, pvy, pvz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x  # d x e2
    det = e1x * pvx + e1y * pvy + e1z * pvz
    d2 = dx * dx + dy * dy + dz * dz
    scale = np.sqrt(d2 * (e1x * e1x + e1y * e1y + e1z * e1z) * (e2x * e2x + e2y * e2y + e2z * e2z))
    if scale == 0.0 or abs(det) <= 1e-12 * scale:
        return -1.0
    inv = 1.0 / det
    tx, ty, tz = x0 - ax, y0 - ay, z0 - az
    u = (tx * pvx + ty * pvy + tz * pvz) * inv
    if u < 0.0 or u > 1.0:
        return -1.0
    qx, qy, qz = ty * e1z - tz * e1y, tz * e1x - tx * e1z, tx * e1y - ty * e1x  # t x e1
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return -1.0
    s = (e2x * qx + e2y * qy + e2z * qz) * inv
    if s < 0.0 or s > 1.0:
        return -1.0
    return s
