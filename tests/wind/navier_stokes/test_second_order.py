"""The second-order step (``wind.advection=second_order``) against answers known without
the code: the Taylor-Green vortex decays at exp(-2 nu t) and the scheme's error falls by
four when h and dt are halved together; its limiter leaves a resolved extremum alone and
clamps a jump; the explicit half of Crank-Nicolson is the discrete Laplacian."""

from __future__ import annotations

import math

import numpy as np
import pytest

from experiments.validation_ns.problems import taylor_green
from windbench.wind.navier_stokes import advection, trapezoid


def _orders(sizes):
    rows = [taylor_green(n, "second_order", dt=0.5 * 2 * math.pi / n)[0] for n in sizes]
    rate = [abs(r["rate_rel_error"]) for r in rows]
    linf = [r["linf_rel_error"] for r in rows]
    return (
        [math.log2(a / b) for a, b in zip(rate, rate[1:], strict=False)],
        [math.log2(a / b) for a, b in zip(linf, linf[1:], strict=False)],
        rows,
    )


def test_taylor_green_decay_rate_and_error_converge_at_second_order():
    """16 -> 32 cells at CFL 0.5: the decay-rate error and the L-inf error both fall by
    about four (order >= 1.8); the first-order schemes fall by about two."""
    rate, linf, rows = _orders([16, 32])
    assert rate[0] >= 1.8 and linf[0] >= 1.8, (rate, linf)
    assert abs(rows[-1]["rate_rel_error"]) < 0.03


@pytest.mark.slow
def test_taylor_green_second_order_from_16_to_64_cells():
    rate, linf, _ = _orders([16, 32, 64])
    assert min(rate) >= 1.8 and min(linf) >= 1.8, (rate, linf)


def _pair(values):
    """A padded component array (5 x 5 x n) repeating ``values`` along the last axis."""
    q = np.zeros((5, 5, len(values)))
    q[...] = np.asarray(values, dtype=float)
    return q


def _correct(q, hat_value, k):
    """The smooth-limited MacCormack value at face (2, 2, k) when q^ overshoots there."""
    hat, tilde = q.copy(), q.copy()
    hat[2, 2, k] = hat_value
    qmin, qmax = q - 0.01, q + 0.01  # bounds of a cell around each face
    qmin[2, 2, k], qmax[2, 2, k] = q[2, 2, k] - 0.1, q[2, 2, k]
    out = np.zeros_like(q)
    axes = np.array([0, 0, 1], dtype=np.int64)  # only z varies
    advection.maccormack_correct_smooth(q, hat, tilde, qmin, qmax, axes, out)
    return out[2, 2, k], qmax[2, 2, k]


def test_the_limiter_keeps_a_smooth_extremum_and_clamps_a_jump():
    smooth = _pair(np.cos(0.3 * (np.arange(11) - 5)))  # resolved maximum at k = 5
    value, bound = _correct(smooth, smooth[2, 2, 5] + 0.004, 5)
    assert value == pytest.approx(smooth[2, 2, 5] + 0.004) and value > bound
    jump = _pair([0.0] * 5 + [1.0] * 6)  # a step between k = 4 and k = 5
    value, bound = _correct(jump, 1.2, 5)
    assert value == bound == 1.0


def test_explicit_half_is_the_discrete_laplacian_of_a_quadratic():
    """q = x^2 + 3 y^2 (lattice units) has sum_nb (q_nb - q) = 2 + 6 everywhere inside
    (no pressure term: scale 0)."""
    x, y, z = np.meshgrid(np.arange(6.0), np.arange(7.0), np.arange(8.0), indexing="ij")
    q = x**2 + 3 * y**2 + z
    free = np.zeros(q.shape, dtype=np.uint8)
    free[1:-1, 1:-1, 1:-1] = 1
    out = np.zeros_like(q)
    beta = 0.05
    psi = np.zeros((4, 5, 6))
    trapezoid.carried_field(q, 0, psi, 0.0, beta, np.array([1, 1, 1]), free, np.zeros(3, bool), out)
    inner = (slice(1, -1),) * 3
    np.testing.assert_allclose(out[inner], q[inner] + beta * 8.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out[0], q[0])  # ghosts and prescribed faces: copied


def test_the_carried_field_subtracts_the_scaled_pressure_gradient_and_the_midpoint_extrapolates():
    """With no viscosity, w = q - scale (psi_+ - psi_-) across x-faces: psi = 2 x (cells)
    gives a difference of 2 on every face between two cells; u^n+1/2 = 3/2 u^n - 1/2 u^n-1
    is exact for a velocity linear in time."""
    shape = (4, 5, 6)  # cells; u-faces padded (7, 7, 8)
    psi = np.broadcast_to(2.0 * np.arange(shape[0])[:, None, None], shape).copy()
    q = np.ones((shape[0] + 3, shape[1] + 2, shape[2] + 2))
    free = np.zeros(q.shape, dtype=np.uint8)
    free[2:-2, 1:-1, 1:-1] = 1  # faces between two cells
    out = np.zeros_like(q)
    trapezoid.carried_field(q, 0, psi, 0.25, 0.0, np.array([1, 1, 1]), free, np.zeros(3, bool), out)
    np.testing.assert_allclose(out[2:-2, 1:-1, 1:-1], 1.0 - 0.25 * 2.0)
    np.testing.assert_array_equal(out[1], q[1])  # a face that is not free keeps its value
    now, before = np.full((3, 3, 3), 5.0), np.full((3, 3, 3), 4.0)  # u = 4 + t
    trapezoid.midpoint_velocity(now, before)
    np.testing.assert_allclose(before, 5.5)
