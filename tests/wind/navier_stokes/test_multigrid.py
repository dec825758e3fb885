"""Pressure-solver kernels (windbench.wind.navier_stokes.multigrid) against answers known without the
code: the operator A x = sum_f w_f (x_c - x_nb) written out with numpy, a Gauss-Seidel
update solved by hand, numpy's dot product."""

from __future__ import annotations

import numpy as np
import pytest

from tests.wind.navier_stokes.poisson_reference import operator_numpy as _operator_numpy
from windbench.wind.navier_stokes import multigrid as pressure
from windbench.wind.navier_stokes.multigrid import _Level

SHAPE = (10, 8, 12)


def _level(rng, periodic=(False, False, False), omega=pressure.OMEGA, shape=SHAPE) -> _Level:
    """A level with open faces except a closed block (a body) and closed domain walls, in
    the solver's own precision (the kernels' types as a solve calls them: one compiled
    version for the solver and the tests)."""
    dtype = pressure.PRECONDITIONER_DTYPE
    lev = _Level(shape, np.ones(3), np.array(periodic), dtype=dtype, omega=omega)
    for a in range(3):
        lev.w[a][...] = 1.0
        if not periodic[a]:
            lo = [slice(None)] * 3
            lo[a] = 0
            lev.w[a][tuple(lo)] = 0.0
    lev.w[0][3:5, 2:5, 4:9] = 0.0  # a closed patch of x faces: rows off the fast path
    lev.w[2][6:8, 1:3, 2:6] = rng.random((2, 2, 4))  # fractional (coarse-level-like) weights
    lev.classify_rows()
    return lev


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True)])
def test_operator_and_residual_match_the_stencil_written_out(periodic):
    rng = np.random.default_rng(0)
    lev = _level(rng, periodic)
    assert set(np.unique(lev.rows)) == {0, 1, 2}  # every row class is exercised
    x, b = rng.random(SHAPE), rng.random(SHAPE)
    expected = _operator_numpy(x, lev.w, periodic)
    out = np.empty(SHAPE)
    xax = pressure.apply_operator(x, lev.args(), out)
    # the level's tables (diag, end-cell coefficients) hold float32 sums of the weights
    np.testing.assert_allclose(out, expected, rtol=1e-6, atol=1e-6)
    assert xax == pressure.dot(x, out)  # the fused x . A x: the same sum, the same bits
    pressure.residual(x, b, lev.args(), out)
    np.testing.assert_allclose(out, b - expected, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("m", [1, 4])
def test_block_residual_sums_the_residual_over_blocks(m):
    """The squared block sums of b - A x (numpy), blocks of m^3 cells; the 10-plane axis
    ends in a block of 2 planes, the 8 rows in two whole blocks."""
    rng = np.random.default_rng(4)
    lev = _level(rng, (False, False, False))
    x, b = rng.random(SHAPE), rng.random(SHAPE)
    r = b - _operator_numpy(x, lev.w, (False,) * 3)
    padded = np.zeros([-(-n // m) * m for n in SHAPE])
    padded[: SHAPE[0], : SHAPE[1], : SHAPE[2]] = r
    p0, p1, p2 = (n // m for n in padded.shape)
    sums = padded.reshape(p0, m, p1, m, p2, m).sum(axis=(1, 3, 5))
    got = pressure.block_residual(x, b, lev.args(), m)
    np.testing.assert_allclose(got, (sums * sums).sum(), rtol=1e-6)


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True)])
def test_row_classes_follow_the_face_weights(periodic):
    """ALL_OPEN: an interior row whose inner cells have every face open; ROW_CONSTANT: each
    of the inner cells' six face weights the same along the row (the rows at the domain
    faces, the fractional patch's neighbours); GENERAL: the rest."""
    lev = _level(np.random.default_rng(1), periodic)
    w0, w1, w2 = lev.w
    inner = slice(1, SHAPE[2] - 1)
    expected = np.zeros(SHAPE[:2], int)
    for i in range(SHAPE[0]):
        for j in range(SHAPE[1]):
            faces = np.array(
                [
                    w0[i, j, inner],
                    w0[i + 1, j, inner],
                    w1[i, j, inner],
                    w1[i, j + 1, inner],
                    w2[i, j, 1 : SHAPE[2] - 1],
                    w2[i, j, 2 : SHAPE[2]],
                ]
            )
            interior = 0 < i < SHAPE[0] - 1 and 0 < j < SHAPE[1] - 1
            if not np.all(faces == faces[:, :1]) or not np.all(faces[4] == faces[5]):
                expected[i, j] = pressure.GENERAL
            elif interior and np.all(faces == 1.0):
                expected[i, j] = pressure.ALL_OPEN
            else:
                expected[i, j] = pressure.ROW_CONSTANT
    np.testing.assert_array_equal(lev.rows, expected)


@pytest.mark.parametrize(
    "omega, periodic",
    [
        (pressure.FINE_OMEGA, (False, False, False)),
        (pressure.OMEGA, (False, False, False)),
        (1.3, (False, False, False)),
        (pressure.FINE_OMEGA, (True, False, True)),
    ],
)
def test_gauss_seidel_fast_path_and_multi_sweep_calls_solve_the_same_cells(omega, periodic):
    """A red half sweep moves each red cell by omega towards (b + sum w x_nb) / diag, with
    black neighbours unchanged (Gauss-Seidel's and SOR's loops); one call of four half
    sweeps gives the numbers of four calls."""
    rng = np.random.default_rng(2)
    lev = _level(rng, periodic, omega=omega)
    # the smoother works on the preconditioner's vectors: single precision
    x0, b = (rng.random(SHAPE).astype(lev.x.dtype) for _ in range(2))
    x = x0.copy()
    no_dot = pressure.NO_DOT
    pressure.gauss_seidel(x, b, lev.args(), 0, 1, *no_dot)  # one red half sweep
    diag = sum(  # sum_f w_f: the diagonal of A
        np.take(lev.w[a], np.arange(SHAPE[a]) + s, axis=a) for a in range(3) for s in (0, 1)
    )
    red = (np.indices(SHAPE).sum(axis=0) % 2) == 0
    nb_sum = diag * x0 - _operator_numpy(x0, lev.w, periodic)
    solved = (b + nb_sum) / np.where(diag > 0, diag, 1.0)
    expected = np.where(red & (diag > 0), x0 + omega * (solved - x0), x0)
    np.testing.assert_allclose(x, expected, rtol=1e-6, atol=1e-6)  # float32 rounding
    single, multi = x0.copy(), x0.copy()
    for colour in (1, 0, 1, 0):
        pressure.gauss_seidel(single, b, lev.args(), colour, 1, *no_dot)
    pressure.gauss_seidel(multi, b, lev.args(), 1, 4, *no_dot)
    np.testing.assert_array_equal(single, multi)
    # asked for r . x, the same sweeps return it (taken plane by plane as they finish)
    dotted, r = x0.copy(), rng.random(SHAPE)
    rx = pressure.gauss_seidel(dotted, b, lev.args(), 1, 4, r, np.zeros(SHAPE[0]))
    np.testing.assert_array_equal(dotted, multi)
    assert rx == pytest.approx(float(np.sum(r * multi)), rel=1e-13)


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True)])
@pytest.mark.parametrize("halves", [1, 2, 4])
def test_sweeping_by_slabs_gives_the_bits_of_the_plain_sweeps(periodic, halves):
    """The slabs' wavefronts and seams update every cell from the same neighbour values
    as the half sweeps one after the other: the same bits, and the same r . x, in the
    serial and the parallel version, with a body cut by a seam. It does not apply to
    slabs too thin for the half sweeps, nor to a periodic axis of an odd number of
    planes."""
    shape = (22, 8, 12)
    rng = np.random.default_rng(5)
    lev = _level(rng, periodic, shape=shape)
    lev.w[1][6:9, 3:5, 5:8] = 0.0  # a body across the seam at plane 7
    lev.classify_rows()
    x0, b = (rng.random(shape).astype(lev.x.dtype) for _ in range(2))
    r = rng.random(shape)
    slabs = pressure.slab_bounds(shape[0], 7)
    np.testing.assert_array_equal(slabs, [0, 7, 14, 22])
    assert pressure.wavefront_fits(slabs, halves, periodic[0])
    assert not pressure.wavefront_fits(slabs, 5, periodic[0])  # 7 < 2 x 5 - 1 planes
    assert not pressure.wavefront_fits(np.array([0, 7, 14, 21]), 1, True)  # odd, periodic
    assert not pressure.wavefront_fits(lev.slabs, 1, False)  # a small level: one slab
    plain = x0.copy()
    expected = pressure.gauss_seidel.serial(plain, b, lev.args(), 1, halves, r, np.zeros(22))
    for version in (pressure.smooth_by_slabs.serial, pressure.smooth_by_slabs.parallel):
        x = x0.copy()
        rx = version(x, b, lev.args(), 1, halves, r, np.zeros(shape[0]), slabs)
        np.testing.assert_array_equal(x, plain)
        assert rx == expected


def test_dot_and_cg_update_match_numpy():
    rng = np.random.default_rng(3)
    p, q, x, r = (rng.random(SHAPE) for _ in range(4))
    assert pressure.dot(p, q) == pytest.approx(float(np.sum(p * q)), rel=1e-13)
    x_ref, r_ref = x + 0.3 * p, r - 0.3 * q
    r_low = np.zeros(SHAPE, np.float32)
    rr = pressure.cg_update(0.3, p, q, x, r, r_low)
    np.testing.assert_array_equal(r_low, r_ref.astype(np.float32))
    np.testing.assert_allclose(x, x_ref, rtol=1e-15)
    np.testing.assert_allclose(r, r_ref, rtol=1e-15)
    assert rr == pytest.approx(float(np.sum(r_ref**2)), rel=1e-13)
    # r . z with z in float32 (the preconditioned residual): each value converted exactly
    assert pressure.dot(r, r_low) == pressure.dot(r, r_low.astype(np.float64))


def test_mgpcg_with_a_single_precision_v_cycle_reaches_double_precision_accuracy():
    """A manufactured problem: b = A psi for a known psi (closed walls and a closed block,
    so A is singular and psi is taken with zero mean). The V-cycle works in float32, CG in
    float64: the relative residual still goes far below float32's resolution, and the
    solution matches psi to within the conditioning of A times that residual."""
    shape = (16, 16, 16)
    rng = np.random.default_rng(4)
    w = [np.ones(tuple(n + (a == b) for b, n in enumerate(shape))) for a in range(3)]
    for a in range(3):  # closed domain walls
        np.moveaxis(w[a], a, 0)[[0, -1]] = 0.0
    w[0][5:9, 4:12, 6:10] = 0.0  # x faces of a body
    solver = pressure.MultigridPoisson(shape, np.zeros(3, bool), singular=True)
    solver.set_weights(*w)
    assert all(lev.x.dtype == np.float32 for lev in solver.levels)
    psi = rng.standard_normal(shape)
    psi -= psi.mean()
    b = _operator_numpy(psi, w, (False,) * 3)
    x = np.zeros(shape)
    iterations, residual = solver.solve(x, b, 1e-10, 100)
    assert residual <= 1e-10 and iterations <= 14  # 11 measured
    x -= x.mean()
    assert np.linalg.norm(x - psi) <= 1e-8 * np.linalg.norm(psi)  # 1.7e-10 measured


ODD = (9, 5, 11)  # every axis odd: halved to 5 x 3 x 6, each last cell over one fine cell


def _padded(a, shape):
    """``a`` zero-padded at the far ends to ``shape``."""
    return np.pad(a, [(0, n - m) for n, m in zip(shape, a.shape, strict=True)])


def test_transfers_on_odd_axes_sum_the_children_present_and_inject_back():
    """Restriction = the residual summed over the fine cells present under each coarse
    cell / 8 (the missing children of a cut block count 0), prolongation = injection into
    the fine cells present: restriction is P^T / 8 on any shape."""
    rng = np.random.default_rng(7)
    lev = _level(rng, shape=ODD)
    ratio = np.full(3, 2, dtype=np.int64)
    coarse_shape = tuple(-(-n // 2) for n in ODD)
    x = rng.standard_normal(ODD).astype(lev.x.dtype)
    b = rng.standard_normal(ODD).astype(lev.x.dtype)
    coarse = np.full(coarse_shape, 5.0, dtype=lev.x.dtype)
    pressure.residual_restrict(x, b, lev.args(), ratio, coarse)
    r = b - _operator_numpy(x.astype(np.float64), lev.w, (False,) * 3)
    blocks = _padded(r, tuple(2 * n for n in coarse_shape))
    expected = blocks.reshape(5, 2, 3, 2, 6, 2).sum(axis=(1, 3, 5)) / 8
    np.testing.assert_allclose(coarse, expected, rtol=1e-5, atol=1e-5)
    c = rng.standard_normal(coarse_shape).astype(lev.x.dtype)
    fine = np.zeros(ODD, dtype=lev.x.dtype)
    pressure.prolong_add(c, ratio, fine)
    injected = c.repeat(2, 0).repeat(2, 1).repeat(2, 2)[: ODD[0], : ODD[1], : ODD[2]]
    np.testing.assert_array_equal(fine, injected)


def test_coarse_face_weights_on_odd_axes_close_the_faces_beyond_the_grid():
    """A coarse face's weight is the mean over the 4 fine faces a full block gives it,
    faces beyond the grid counted as closed; the far boundary face of an odd axis is the
    fine boundary face."""
    rng = np.random.default_rng(8)
    ratio = np.full(3, 2, dtype=np.int64)
    coarse_shape = tuple(-(-n // 2) for n in ODD)
    for a in range(3):
        fine = rng.uniform(0.5, 1.0, tuple(n + (a == b) for b, n in enumerate(ODD)))
        out = np.zeros(tuple(n + (a == b) for b, n in enumerate(coarse_shape)))
        pressure.coarsen_weights(fine, a, ratio, out)
        faces = np.take(fine, np.minimum(2 * np.arange(coarse_shape[a] + 1), ODD[a]), axis=a)
        across = [2 * n if b != a else n for b, n in enumerate(out.shape)]
        full = _padded(faces, tuple(across))
        expected = (
            full.reshape(
                [m for b, n in enumerate(out.shape) for m in ((n, 2) if b != a else (n, 1))]
            ).sum(axis=(1, 3, 5))
            / 4
        )
        np.testing.assert_allclose(out, expected, rtol=1e-12)


@pytest.mark.parametrize("periodic", [(False, False, False), (False, True, False)])
def test_odd_axes_are_halved_and_the_preconditioner_stays_symmetric(periodic):
    """The two_flags_wall grid of experiment=paper at 80 cells, 80 x 13 x 20, doubled
    along y (26 -> 13) so that an odd axis appears on a level of the row kernels: every
    level halves every axis of >= 4 cells (down to at most 3 cells), a periodic one only
    into an even count, and the cycle is symmetric positive definite (r1 . M r2 == r2 .
    M r1, float32 precision; a periodic axis of 13 cells on the coarse levels broke this,
    0.26 % apart: red-black colours meet across its seam)."""
    shape = (80, 26, 20)
    rng = np.random.default_rng(9)
    solver = pressure.MultigridPoisson(shape, np.array(periodic), singular=False)
    shapes = [lev.shape for lev in solver.levels]
    y = (26, 26) if periodic[1] else (13, 7)
    assert shapes[:3] == [(80, 26, 20), (40, y[0], 10), (20, y[1], 5)]
    assert max(shapes[-1][0], shapes[-1][2]) <= 3 and shapes[-1][1] in (26, 2)
    assert solver.first_small == 1  # the odd axis goes through the row kernels' transfers
    w = [np.ones(tuple(n + (a == b) for b, n in enumerate(shape))) for a in range(3)]
    w[0][30:40, 5:15, 6:12] = 0.0  # a body
    w[0][-1] = 1.0  # an outflow at the far x end (ghost psi = 0): A is definite
    solver.set_weights(*w)
    r1, r2 = rng.standard_normal(shape), rng.standard_normal(shape)
    z1, z2 = np.empty(shape), np.empty(shape)
    solver.vcycle(r1, z1)
    solver.vcycle(r2, z2)
    assert float(np.sum(r2 * z1)) == pytest.approx(float(np.sum(r1 * z2)), rel=1e-5)
    assert float(np.sum(r1 * z1)) > 0


def test_mgpcg_on_a_grid_of_odd_axes_converges_like_an_even_one():
    """A manufactured problem b = A psi on the paper's two_flags_wall grid at 80 cells
    (80 x 13 x 20, an outflow at the far x end) and on the even 80 x 16 x 20: the odd grid
    needs no more than two iterations more, and both recover psi."""
    iterations = {}
    for shape in ((80, 13, 20), (80, 16, 20)):
        rng = np.random.default_rng(10)
        w = [np.ones(tuple(n + (a == b) for b, n in enumerate(shape))) for a in range(3)]
        for a in range(3):
            np.moveaxis(w[a], a, 0)[[0, -1]] = 0.0
        w[0][-1] = 1.0  # outflow
        w[0][30:34, 2:9, 6:14] = 0.0  # a wall across the flow
        solver = pressure.MultigridPoisson(shape, np.zeros(3, bool), singular=False)
        solver.set_weights(*w)
        psi = rng.standard_normal(shape)
        b = _operator_numpy(psi, w, (False,) * 3)
        x = np.zeros(shape)
        iterations[shape[1]], residual = solver.solve(x, b, 1e-10, 100)
        assert residual <= 1e-10
        assert np.linalg.norm(x - psi) <= 1e-7 * np.linalg.norm(psi)
    assert iterations[13] <= iterations[16] + 2, iterations
