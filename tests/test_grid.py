"""Grid: consistency, cell centres, trilinear sampling (exact on linear fields)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from windbench.errors import ConfigError
from windbench.grid import Grid


def test_cubic_cells_along_the_longest_axis():
    g = Grid.from_domain([0, 0, 0], [8, 4, 2], 16)
    assert g.h == 0.5 and g.shape == (16, 8, 4)
    np.testing.assert_allclose(g.upper, [8, 4, 2])
    assert g.cell_centres()[0, 0, 0].tolist() == [0.25, 0.25, 0.25]


def test_thin_axis_keeps_one_cell():
    g = Grid.from_domain([0, 0, 0], [2 * np.pi, 0.1, 2 * np.pi], 32)
    assert g.shape == (32, 1, 32)


def test_grid_rejects_too_few_cells_and_inconsistent_geometry():
    with pytest.raises(ConfigError, match="grid.resolution: must be at least 4"):
        Grid.from_domain([0, 0, 0], [1, 1, 1], 3)
    with pytest.raises(ValueError, match="spacing must be positive"):
        Grid((0.0, 0.0, 0.0), (2, 2, 2), 0.0)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=12, max_size=12), st.integers(0, 2**31 - 1))
def test_trilinear_sampling_reproduces_any_linear_field(coeffs, seed):
    A = np.array(coeffs[:9]).reshape(3, 3)
    b = np.array(coeffs[9:])
    g = Grid.from_domain([-1.0, 0.5, 2.0], [3.0, 2.5, 4.0], 8)
    field = g.cell_centres() @ A.T + b
    pts = np.random.default_rng(seed).uniform(g.centre_origin, g.upper - g.h / 2, (64, 3))
    np.testing.assert_allclose(g.sample(field, pts), pts @ A.T + b, atol=1e-11)


def test_sampling_is_clamped_outside_the_centre_lattice():
    g = Grid.from_domain([0, 0, 0], [4, 4, 4], 4)
    field = g.cell_centres()[..., :1].copy()  # f = x
    out = g.sample(field, [[-10.0, 2.0, 2.0], [10.0, 2.0, 2.0], [0.1, 2.0, 2.0]])
    np.testing.assert_allclose(out[:, 0], [0.5, 3.5, 0.5])


def test_cell_index_and_contains():
    g = Grid.from_domain([0, 0, 0], [4, 2, 2], 4)
    np.testing.assert_array_equal(
        g.cell_index([[0.1, 0.1, 1.9], [3.99, 1.5, 0.0]]), [[0, 0, 1], [3, 1, 0]]
    )
    assert g.contains([[4.0, 2.0, 2.0], [4.1, 1.0, 1.0]]).tolist() == [True, False]
