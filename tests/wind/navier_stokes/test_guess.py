"""The pressure solve's extrapolated starting guess (windbench.wind.navier_stokes.guess)
against answers known without the code: the polynomial through the last solutions
reproduces a pressure that is quadratic in time exactly, so the solve from it needs no
iteration; a change of time step or a projection that is no time step falls back to the
warm start."""

from __future__ import annotations

import numpy as np
import pytest

from tests.wind.navier_stokes.poisson_reference import operator_numpy
from windbench.wind.navier_stokes.guess import PressureGuess
from windbench.wind.navier_stokes.multigrid import MultigridPoisson

SHAPE = (8, 6, 10)


def _series(rng, steps):
    """psi^n = f + n g + n^2 h, n = 0 .. steps - 1: random fields f, g, h."""
    f, g, h = (rng.standard_normal(SHAPE) for _ in range(3))
    return [f + n * g + n * n * h for n in range(steps)]


def test_the_guess_extends_a_quadratic_series_exactly():
    psi_n = _series(np.random.default_rng(1), 5)
    guess, psi = PressureGuess(SHAPE), np.zeros(SHAPE)
    for n, exact in enumerate(psi_n):
        guess.start(psi, 0.01)
        if n == 0:
            assert np.array_equal(psi, np.zeros(SHAPE))  # nothing solved yet: psi as it was
        elif n == 2:
            np.testing.assert_allclose(psi, 2 * psi_n[1] - psi_n[0], atol=1e-12)  # linear
        elif n >= 3:
            np.testing.assert_allclose(psi, exact, atol=1e-9)  # the quadratic: exact
        psi[...] = exact  # the solve's answer
        guess.solved_step(0.01)


@pytest.mark.parametrize("change", ["dt", "no_time_step"])
def test_a_new_time_step_restarts_from_the_warm_start(change):
    psi_n = _series(np.random.default_rng(2), 5)
    guess, psi = PressureGuess(SHAPE), np.zeros(SHAPE)
    for exact in psi_n[:4]:
        guess.start(psi, 0.01)
        psi[...] = exact
        guess.solved_step(0.01)
    dt = 0.02 if change == "dt" else None
    guess.start(psi, dt)
    assert np.array_equal(psi, psi_n[3])  # psi of the other step kept as it is
    guess.solved_step(dt)
    guess.start(psi, 0.01 if dt is None else dt)
    assert np.array_equal(psi, psi_n[3])  # one solution of this step: still the warm start


def test_the_solve_from_the_guess_of_a_quadratic_series_needs_no_iteration():
    """Walls all round (the singular problem): b^n = A psi^n for psi^n quadratic in n; the
    warm start needs iterations at every step, the guess none from the fourth solve."""
    rng = np.random.default_rng(3)
    solver = MultigridPoisson(SHAPE, np.zeros(3, bool), singular=True)
    w = [np.ones(x.shape) for x in solver.fine.w]
    for a in range(3):
        np.moveaxis(w[a], a, 0)[[0, -1]] = 0.0
    solver.set_weights(*w)
    psi_n = [x - x.mean() for x in _series(rng, 6)]
    guess, psi, iterations = PressureGuess(SHAPE), np.zeros(SHAPE), []
    for exact in psi_n:
        b = operator_numpy(exact, w, (False,) * 3)
        guess.start(psi, 0.01)
        iterations.append(solver.solve(psi, b, 1e-6, 50)[0])
        guess.solved_step(0.01)
    assert min(iterations[:3]) > 0 and iterations[3:] == [0, 0, 0]
