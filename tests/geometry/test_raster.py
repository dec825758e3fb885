"""Triangle registration in grid cells and segment/triangle intersection."""

import numpy as np
import pytest

from windbench.geometry.raster import occupied_cells, segment_triangle, triangle_cells
from windbench.grid import Grid


def brute_force_cells(x, tris, grid, n=40):
    """Cells hit by dense samples of each triangle (a subset of the overlapping cells)."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    keep = (u + v) <= 1
    u, v = u[keep], v[keep]
    hit = np.zeros(grid.shape, bool)
    for a, b, c in x[tris]:
        p = a + u[:, None] * (b - a) + v[:, None] * (c - a)
        idx = np.floor((p - grid.lower) / grid.h).astype(int)
        ok = np.all((idx >= 0) & (idx < grid.shape), axis=1)
        hit[tuple(idx[ok].T)] = True
    return hit


def test_registration_covers_every_cell_a_triangle_passes_through_and_no_far_cell():
    grid = Grid.from_domain([0, 0, 0], [4, 3, 2], 16)
    rng = np.random.default_rng(5)
    x = rng.uniform([0.2, 0.2, 0.2], [3.8, 2.8, 1.8], (30, 3))
    tris = np.arange(30).reshape(10, 3)
    start, items = triangle_cells(x, tris, grid)
    marked = occupied_cells(start, grid.shape)
    sampled = brute_force_cells(x, tris, grid)
    assert np.all(marked[sampled])  # conservative
    # every registered cell is within one cell diagonal of its triangle's plane and bounds
    for cell in np.argwhere(marked):
        c = np.ravel_multi_index(tuple(cell), grid.shape)
        centre = grid.lower + (cell + 0.5) * grid.h
        for t in items[start[c] : start[c + 1]]:
            a, b, cc = x[tris[t]]
            n = np.cross(b - a, cc - a)
            n /= np.linalg.norm(n)
            assert abs((centre - a) @ n) <= np.sqrt(3) / 2 * grid.h + 1e-12
            assert np.all(centre >= np.minimum.reduce([a, b, cc]) - grid.h)
            assert np.all(centre <= np.maximum.reduce([a, b, cc]) + grid.h)


def test_axis_aligned_sheet_marks_one_slab():
    grid = Grid.from_domain([0, 0, 0], [4, 4, 4], 8)
    x = np.array([[1.1, 0, 0], [1.1, 4, 0], [1.1, 4, 4], [1.1, 0, 4]])
    start, _ = triangle_cells(x, np.array([[0, 1, 2], [0, 2, 3]]), grid)
    marked = occupied_cells(start, grid.shape)
    assert marked[2].all() and marked.sum() == 64


@pytest.mark.parametrize(
    "p0, p1, expected",
    [
        ([0, 0.2, 0.2], [2, 0.2, 0.2], 0.5),  # through the interior
        ([2, 0.2, 0.2], [0, 0.2, 0.2], 0.5),  # either direction
        ([0, 0.8, 0.8], [2, 0.8, 0.8], -1.0),  # beside the hypotenuse
        ([0, 0.2, 0.2], [0.9, 0.2, 0.2], -1.0),  # stops short
        ([1, 0.1, 0.1], [1, 0.5, 0.1], -1.0),  # in the plane
    ],
)
def test_segment_triangle(p0, p1, expected):
    a, b, c = np.array([[1.0, 0, 0], [1.0, 1, 0], [1.0, 0, 1]])
    s = segment_triangle(np.asarray(p0, float), np.asarray(p1, float), a, b, c)
    assert s == pytest.approx(expected)
