"""The pressure solve's starting guess: the last solutions extrapolated in time, where
that starts nearer the solution than the last one alone.

The projection's Poisson solve (:mod:`.multigrid`) stops at a residual relative to the
right-hand side, so the iterations it needs grow with the initial error. Between two
steps of a developing flow the pressure changes smoothly, and the previous solution
alone (a warm start) leaves the change of one step as the error. With the last three
solutions psi^(n-1), psi^(n-2), psi^(n-3) of the same time step, the quadratic through
them (backward differences)

    psi^n ~ 3 psi^(n-1) - 3 psi^(n-2) + psi^(n-3)

leaves an error of third order in dt where psi is smooth in time (linear, 2 psi^(n-1) -
psi^(n-2), with two). It amplifies what is not smooth: a part of psi that flips from
step to step (a flapping cloth's imprint, a wake's eddies) comes back up to seven times
as large. So the solve starts from whichever of the two, extrapolation or warm start,
leaves the smaller residual summed over blocks of 4^3 cells
(:meth:`~.multigrid.MultigridPoisson.smooth_residual_norm`, two residual passes a step):
the smooth error, which costs the iterations, where the residual of each cell would
favour the guess with the smaller error from cell to cell, which the multigrid cycle
removes at once (``multigrid.GUESS_BLOCK`` has the figures). The solve still stops at
the same relative residual, so only the iteration count changes
(``experiments/bench_ns.py`` times both, ``wind.pressure_guess``: ``extrapolate``, or
``previous`` for the warm start alone).
psi holds dt p / (rho h): a solve after a change of the time step, or after a
projection that is no time step (an initial condition), starts again from the warm
start.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import prange

from windbench.wind.navier_stokes.threads import threaded

GUESSES = ("extrapolate", "previous")  # wind.pressure_guess
# The guess from the last 1, 2 or 3 solutions: coefficients of psi^(n-1), psi^(n-2),
# psi^(n-3) (the polynomial through them at the next step).
EXTRAPOLATION = ((1.0, 0.0, 0.0), (2.0, -1.0, 0.0), (3.0, -3.0, 1.0))


@threaded()
def extrapolate(x, newer, older, c0, c1, c2, out):
    """out = c0 x + c1 newer + c2 older, cell by cell."""
    n0, n1, n2 = x.shape
    for i in prange(n0):
        for j in range(n1):
            for k in range(n2):
                out[i, j, k] = c0 * x[i, j, k] + c1 * newer[i, j, k] + c2 * older[i, j, k]


@threaded()
def shift(x, older, trial, take):
    """older = x, then x = trial if ``take``, cell by cell (one pass: the caller then
    swaps the roles of its newer and older fields)."""
    n0, n1, n2 = x.shape
    for i in prange(n0):
        for j in range(n1):
            for k in range(n2):
                older[i, j, k] = x[i, j, k]
                if take:
                    x[i, j, k] = trial[i, j, k]


class PressureGuess:
    """The solutions of the last steps (model: ``kind``, one of GUESSES; state: the
    history fields, how many solutions of the current time step they hold, and how many
    solves started from the extrapolation)."""

    def __init__(self, shape: tuple[int, ...], kind: str = GUESSES[0]):
        self.order = len(EXTRAPOLATION) if kind == "extrapolate" else 1
        history = shape if self.order > 1 else (0, 0, 0)
        self.newer = np.zeros(history)  # psi^(n-2)
        self.older = np.zeros(history)  # psi^(n-3)
        self.trial = np.zeros(history)  # the extrapolation
        self.solved = 0  # solutions of time step ``dt`` held: psi itself and the two above
        self.dt: float | None = None
        self.extrapolated = 0

    def start(
        self, psi: np.ndarray, dt: float | None, residual_norm: Callable[[np.ndarray], float]
    ) -> None:
        """Turn ``psi`` (the last solution) into the guess for the solve of a step ``dt``
        (None: a projection that is no time step, started from psi as it is): the
        extrapolation if its ``residual_norm`` (a guess's distance from the solution) is
        the smaller."""
        if dt is None or dt != self.dt:  # psi is dt p / (rho h): no series to extend
            self.solved, self.dt = 0, dt
        held = min(self.solved, self.order)
        if held == 0 or self.order == 1:  # psi as it is: the warm start
            return
        take = False
        if held > 1:
            extrapolate(psi, self.newer, self.older, *EXTRAPOLATION[held - 1], self.trial)
            take = residual_norm(self.trial) < residual_norm(psi)
        shift(psi, self.older, self.trial, take)
        self.newer, self.older = self.older, self.newer
        self.extrapolated += take

    def solved_step(self, dt: float | None) -> None:
        """Count the solve just made (none for a projection that is no time step)."""
        self.solved = 0 if dt is None else self.solved + 1
