"""The pressure solve's starting guess (windbench.wind.navier_stokes.guess) against
answers known without the code: the polynomial through the last solutions reproduces a
pressure that is quadratic in time exactly, so the solve from it needs no iteration; a
pressure that flips from step to step is better guessed by the last solution, which the
guess then keeps; a change of time step or a projection that is no time step falls back
to the warm start. With A = I and b the exact solution, ||b - A x|| is the distance to
it."""

from __future__ import annotations

import numpy as np
import pytest

from tests.wind.navier_stokes.poisson_reference import operator_numpy
from windbench.wind.navier_stokes.guess import PressureGuess
from windbench.wind.navier_stokes.multigrid import MultigridPoisson

SHAPE = (8, 6, 10)
DT = 0.01


def _series(rng, steps, flip=False):
    """psi^n = f + n g + n^2 h (n = 0 .. steps - 1), or f + (-1)^n g with ``flip``."""
    f, g, h = (rng.standard_normal(SHAPE) for _ in range(3))
    if flip:
        return [f + (-1) ** n * g for n in range(steps)]
    return [f + n * g + n * n * h for n in range(steps)]


def _run(series, guess, dt=DT):
    """Each step's guess (a copy) with the series as the solves' answers."""
    psi, guesses = np.zeros(SHAPE), []
    for exact in series:
        guess.start(psi, dt, lambda x, e=exact: float(np.linalg.norm(x - e)))
        guesses.append(psi.copy())
        psi[...] = exact  # the solve's answer
        guess.solved_step(dt)
    return guesses


def test_the_guess_extends_a_quadratic_series_exactly():
    series = _series(np.random.default_rng(1), 6)
    guesses = _run(series, PressureGuess(SHAPE))
    assert np.array_equal(guesses[0], np.zeros(SHAPE))  # nothing solved yet: psi as it was
    assert np.array_equal(guesses[1], series[0])  # one solution: the warm start
    linear = 2 * series[1] - series[0]
    nearer = min((linear, series[1]), key=lambda x: np.linalg.norm(x - series[2]))
    np.testing.assert_array_equal(guesses[2], nearer)
    for n in range(3, 6):
        np.testing.assert_allclose(guesses[n], series[n], atol=1e-9)  # the quadratic


def test_a_flipping_series_keeps_the_warm_start():
    series = _series(np.random.default_rng(2), 6, flip=True)
    guess = PressureGuess(SHAPE)
    guesses = _run(series, guess)
    for n in range(1, 6):
        assert np.array_equal(guesses[n], series[n - 1])
    assert guess.extrapolated == 0


@pytest.mark.parametrize("change", ["dt", "no_time_step"])
def test_a_new_time_step_restarts_from_the_warm_start(change):
    series = _series(np.random.default_rng(3), 5)
    guess = PressureGuess(SHAPE)
    _run(series[:4], guess)
    dt = 0.02 if change == "dt" else None
    psi, exact = series[3].copy(), series[4]
    for _ in range(2):  # no solution yet of the new step, then one
        guess.start(psi, dt, lambda x: float(np.linalg.norm(x - exact)))
        assert np.array_equal(psi, series[3])  # kept as it is
        guess.solved_step(dt)
        dt = DT if dt is None else dt


def test_previous_is_the_warm_start_alone():
    series = _series(np.random.default_rng(4), 5)
    guesses = _run(series, PressureGuess(SHAPE, "previous"))
    for n in range(1, 5):
        assert np.array_equal(guesses[n], series[n - 1])


def test_the_solve_from_the_guess_of_a_quadratic_series_needs_no_iteration():
    """Walls all round (the singular problem): b^n = A psi^n for psi^n quadratic in n; the
    warm start needs iterations at every step, the guess none from the fourth solve."""
    solver = MultigridPoisson(SHAPE, np.zeros(3, bool), singular=True)
    w = [np.ones(x.shape) for x in solver.fine.w]
    for a in range(3):
        np.moveaxis(w[a], a, 0)[[0, -1]] = 0.0
    solver.set_weights(*w)
    series = [x - x.mean() for x in _series(np.random.default_rng(5), 6)]
    guess, psi, iterations = PressureGuess(SHAPE), np.zeros(SHAPE), []
    for exact in series:
        b = operator_numpy(exact, w, (False,) * 3)
        guess.start(psi, DT, lambda x, b=b: solver.smooth_residual_norm(x, b))
        iterations.append(solver.solve(psi, b, 1e-6, 50)[0])
        guess.solved_step(DT)
    assert min(iterations[:3]) > 0 and iterations[3:] == [0, 0, 0]
