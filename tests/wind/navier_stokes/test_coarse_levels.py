"""The small multigrid levels in flat per-cell tables (windbench.wind.navier_stokes.coarse_levels)
against answers known without the code: the operator written out with numpy, a
Gauss-Seidel update solved by hand, the mean of the children, and the symmetry of the
preconditioner that conjugate gradients needs."""

from __future__ import annotations

import numpy as np
import pytest

from tests.wind.navier_stokes.poisson_reference import operator_numpy
from windbench.wind.navier_stokes import coarse_levels
from windbench.wind.navier_stokes import multigrid as pressure
from windbench.wind.navier_stokes.coarse_levels import CoarseLevels
from windbench.wind.navier_stokes.multigrid import _Level

SHAPE = (6, 4, 8)


def _weights(rng, shape, periodic):
    """Open faces with random fractional weights, closed domain walls on non-periodic axes
    and a closed patch (a body)."""
    w = [rng.uniform(0.5, 1.0, tuple(n + (a == b) for b, n in enumerate(shape))) for a in range(3)]
    for a in range(3):
        if not periodic[a]:
            np.moveaxis(w[a], a, 0)[[0, -1]] = 0.0
    w[0][2:4, 1:3, 2:5] = 0.0
    return w


def _two_levels(rng, periodic):
    fine = _Level(SHAPE, np.ones(3), np.array(periodic))
    coarse = _Level(tuple(n // 2 for n in SHAPE), np.full(3, 0.25), np.array(periodic))
    fine.ratio = np.full(3, 2, dtype=np.int64)
    fine.w = _weights(rng, fine.shape, periodic)
    coarse.w = _weights(rng, coarse.shape, periodic)
    small = CoarseLevels([fine, coarse], np.array(periodic), 0, (), 1, 3, pressure.OMEGA)
    small.set_weights()
    x, b = rng.random(SHAPE), rng.random(SHAPE)  # a guess and a right-hand side
    fine.x[...], fine.b[...] = x, b
    return fine, coarse, small, x, b


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True)])
def test_a_red_half_sweep_solves_each_red_open_cell_for_its_neighbours(periodic):
    fine, _, small, x0, b = _two_levels(np.random.default_rng(0), periodic)
    start, split, _ = small.ranges[0]
    coarse_levels.half_sweep(
        small.x, small.b, small.nb, small.w, small.inv, small.order[start:split], pressure.OMEGA
    )
    diag = sum(
        np.take(fine.w[a], np.arange(SHAPE[a]) + s, axis=a) for a in range(3) for s in (0, 1)
    )
    nb_sum = diag * x0 - operator_numpy(x0, fine.w, periodic)
    solved = (b + nb_sum) / np.where(diag > 0, diag, 1.0)
    red = (np.indices(SHAPE).sum(axis=0) % 2) == 0
    expected = np.where(red & (diag > 0), x0 + pressure.OMEGA * (solved - x0), x0)
    np.testing.assert_allclose(fine.x, expected, rtol=1e-13, atol=1e-13)
    assert small.x[-1] == 0.0  # the zero slot (the ghost beyond a wall) is never written


@pytest.mark.parametrize("periodic", [(False, False, False), (True, True, False)])
def test_the_restricted_residual_is_the_mean_of_the_childrens_residuals(periodic):
    rng = np.random.default_rng(1)
    fine, coarse, small, x, b = _two_levels(rng, periodic)
    coarse.x[...] = 7.0  # the coarse cycle starts from zero
    (first, count), (cfirst, ccount) = small.blocks
    coarse_levels.residual_restrict(
        small.x, small.b, small.nb, small.w, small.diag, small.parent,
        first, count, cfirst, ccount, small.mean[0],
    )  # fmt: skip
    r = b - operator_numpy(x, fine.w, periodic)
    expected = r.reshape(3, 2, 2, 2, 4, 2).mean(axis=(1, 3, 5))
    np.testing.assert_allclose(coarse.b, expected, rtol=1e-12, atol=1e-12)
    assert not coarse.x.any()
    coarse.x[...] = rng.random(coarse.shape)  # prolongation by injection adds the parent
    before = fine.x.copy()
    coarse_levels.prolong(small.x, small.parent, first, count)
    parent = coarse.x.repeat(2, 0).repeat(2, 1).repeat(2, 2)
    np.testing.assert_array_equal(fine.x, (before + parent).astype(fine.x.dtype))


def test_the_multigrid_preconditioner_is_symmetric():
    """CG needs M = M^T: r1 . M r2 == r2 . M r1 (float32 cycle, so to float32 precision),
    with the top level in row kernels and the levels below in coarse_levels."""
    shape = (64, 32, 32)
    rng = np.random.default_rng(2)
    solver = pressure.MultigridPoisson(shape, np.zeros(3, bool), singular=False)
    assert 0 < solver.first_small < len(solver.levels) - 1
    w = [np.ones(tuple(n + (a == b) for b, n in enumerate(shape))) for a in range(3)]
    w[0][20:30, 8:20, 10:16] = 0.0  # a body
    solver.set_weights(*w)
    r1, r2 = rng.standard_normal(shape), rng.standard_normal(shape)
    z1, z2 = np.empty(shape), np.empty(shape)
    solver.vcycle(r1, z1)
    solver.vcycle(r2, z2)
    a, b = float(np.sum(r2 * z1)), float(np.sum(r1 * z2))
    assert a == pytest.approx(b, rel=1e-5)
    assert float(np.sum(r1 * z1)) > 0  # and positive


def test_neighbours_wrap_on_periodic_axes_and_meet_the_zero_slot_at_walls():
    table = coarse_levels.neighbour_table((3, 2, 2), (True, False, False), 10, 99)
    index = 10 + np.arange(12).reshape(3, 2, 2)
    assert table[index[0, 0, 0] - 10, 0] == index[2, 0, 0]  # -x of i = 0 wraps to i = 2
    assert table[index[2, 1, 1] - 10, 1] == index[0, 1, 1]  # +x of i = 2 wraps to i = 0
    assert table[index[0, 0, 0] - 10, 2] == 99  # -y beyond a wall: the zero slot
    assert table[index[0, 1, 0] - 10, 2] == index[0, 0, 0]
    assert table[index[1, 0, 1] - 10, 5] == 99  # +z beyond a wall
