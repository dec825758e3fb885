"""The pieces the animations and Fig. 6 are drawn from, against answers known by hand:
triangle pressure, front/back means, the gust front, lee against wind not yet arrived."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from windbench.grid import Grid
from windbench.report.frames import (
    FRONT_BAND,
    RunFrames,
    front_passes,
    gust_front,
    side_pressure,
    triangle_areas,
    triangle_pressure,
    unreached_kinds,
    wind_direction,
)
from windbench.simulate import reached_box
from windbench.wind.primitives import Primitive

X = np.array([1.0, 0.0, 0.0])


def test_pressure_is_force_over_area_of_each_triangle():
    pos = np.array([[0, 0, 0], [3, 0, 0], [0, 4, 0], [0, 0, 2]], dtype=float)
    tris = np.array([[0, 1, 2], [0, 1, 3]])
    np.testing.assert_allclose(triangle_areas(pos, tris), [6.0, 3.0])
    force = np.array([[0.0, 0.0, 12.0], [0.0, -9.0, 0.0]])
    np.testing.assert_allclose(triangle_pressure(force, pos, tris), [2.0, 3.0])
    # frames stacked in front: the same per frame
    stacked = triangle_pressure(np.stack([force, 2 * force]), np.stack([pos, pos]), tris)
    np.testing.assert_allclose(stacked, [[2.0, 3.0], [4.0, 6.0]])


def _two_plates():
    """Two unit squares across the wind, one at x = 0 (front) and one at x = 1 (back)."""
    square = np.array([[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1]], dtype=float)
    pos = np.concatenate([square, square + X])
    tris = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    return pos, tris


def test_front_and_back_pressure_are_area_weighted_means_of_each_side():
    pos, tris = _two_plates()
    force = np.array([[3.0, 0, 0], [1.0, 0, 0], [0.5, 0, 0], [0.0, 0.3, 0.4]])  # N
    front, back = side_pressure(force, pos, tris, X)
    assert front == pytest.approx(4.0 / 1.0)  # (3 + 1) N over 1 m^2
    assert back == pytest.approx(1.0 / 1.0)  # (0.5 + 0.5) N over 1 m^2
    # the wind from the other side swaps front and back
    assert side_pressure(force, pos, tris, -X) == pytest.approx((1.0, 4.0))


def test_wind_direction_is_the_sum_of_the_uniform_sources():
    scene = SimpleNamespace(
        sources=(
            Primitive("uniform", velocity=(3.0, 0.0, 0.0)),
            Primitive("uniform", velocity=(0.0, 4.0, 0.0)),
            Primitive("vortex", center=(1.0, 1.0, 1.0), strength=2.0, core_radius=0.3),
        )
    )
    np.testing.assert_allclose(wind_direction(scene), [0.6, 0.8, 0.0])
    opposing = SimpleNamespace(
        sources=(
            Primitive("uniform", velocity=(4.0, 0.0, 0.0)),
            Primitive("uniform", velocity=(-4.0, 0.0, 0.0)),
        )
    )
    assert wind_direction(opposing) is None


def test_gust_front_is_the_farthest_corner_of_the_reached_box():
    box = np.array([[0.5, 0.0, 0.0], [2.0, 1.0, 3.0]])
    assert gust_front(box, X) == 2.0
    d = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    assert gust_front(box, d) == pytest.approx(3.0 / np.sqrt(2))
    assert gust_front(np.full((2, 3), np.nan), X) == -np.inf  # nothing reached


def test_reached_box_spans_the_centres_of_the_marked_cells():
    grid = Grid((0.0, 0.0, 0.0), (4, 3, 2), 0.5)
    cells = np.zeros(grid.shape, dtype=bool)
    cells[1, 0, 1] = cells[2, 2, 1] = True
    np.testing.assert_allclose(reached_box(cells, grid), [[0.75, 0.25, 0.75], [1.25, 1.25, 0.75]])
    assert np.isnan(reached_box(np.zeros(grid.shape, dtype=bool), grid)).all()


def _slice_centres(nx, ny, h=1.0):
    x, y = np.meshgrid((np.arange(nx) + 0.5) * h, (np.arange(ny) + 0.5) * h, indexing="ij")
    return np.stack([x, y, np.zeros_like(x)], axis=-1)


def test_unmarked_cells_behind_the_front_are_lee_and_beyond_it_not_arrived():
    # wind along x; the gust front at x = 5.5; a wall in rows y >= 2 stopped it at x = 2
    centres = _slice_centres(8, 4)
    reached = centres[..., 0] <= 5.5
    reached[:, 2:] &= centres[:, 2:, 0] < 2.0
    lee, later = unreached_kinds(reached, centres, (X, 5.5))
    assert not (lee & reached).any() and not (later & reached).any()
    np.testing.assert_array_equal(lee, ~reached & (centres[..., 0] <= 5.5))
    np.testing.assert_array_equal(later, centres[..., 0] > 5.5)
    # no single wind direction: nothing is called lee
    lee, later = unreached_kinds(reached, centres, None)
    assert not lee.any() and (later == ~reached).all()


def _frames(reach_x, reached):
    k, (nx, ny) = len(reach_x), reached.shape[1:]
    reach = np.array([[[0.5, 0.5, 0.0], [x, ny - 0.5, 0.0]] for x in reach_x])
    return RunFrames(
        path=Path("run.nc"),
        times=0.1 * np.arange(1, k + 1),
        speed=np.zeros((k, nx, ny)),
        reached=reached,
        reach=reach,
        force=np.zeros((k, 0, 3)),
        positions=np.zeros((k, 0, 3)),
        triangles=np.zeros((0, 3), dtype=np.int64),
        vertex_cloth=np.zeros(0, dtype=np.int64),
        slice_z=0.0,
        x=(np.arange(nx) + 0.5),
        y=(np.arange(ny) + 0.5),
        h=1.0,
    )


def test_a_ragged_front_leaves_the_cells_just_behind_it_not_arrived():
    nx, ny = 10, 3
    reached = np.zeros((1, nx, ny), dtype=bool)
    reached[0, :4] = True
    reached[0, 7, 0] = True  # one fast particle: the front is at x = 7.5
    lee, later = _frames([7.5], reached).unreached(0, X)
    x = _slice_centres(nx, ny)[..., 0]
    # unmarked and more than FRONT_BAND cells behind the front: lee; the rest not arrived
    np.testing.assert_array_equal(lee, ~reached[0] & (x <= 7.5 - FRONT_BAND))
    np.testing.assert_array_equal(later, ~reached[0] & (x > 7.5 - FRONT_BAND))


def test_front_passes_a_box_when_it_lies_beyond_its_far_corner():
    frames = _frames([1.5, 3.5, 5.5, 7.5], np.zeros((4, 10, 3), dtype=bool))
    assert front_passes(frames, [2.0, 0.0, 0.0], [5.0, 3.0, 1.0], X) == pytest.approx(0.3)
    assert np.isnan(front_passes(frames, [2.0, 0.0, 0.0], [8.0, 3.0, 1.0], X))
