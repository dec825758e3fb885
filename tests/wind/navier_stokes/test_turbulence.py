"""Eddy viscosity (:mod:`windbench.wind.navier_stokes.turbulence`) against closed forms: a
linear shear has |S| equal to its shear rate; with a uniform nu_t the eddy term is the
discrete Laplacian times nu_t; Blackadar's mixing length tends to kappa z near the ground
and to lambda aloft."""

from __future__ import annotations

import numpy as np
import pytest

from windbench.wind.navier_stokes import diffusion, turbulence
from windbench.wind.navier_stokes.boundaries import padded_shape

CELLS = (6, 5, 7)
H = 0.5
AXES = np.array([1, 1, 1], dtype=np.int64)


def _shear(rate):
    """Padded MAC components of u = rate z, v = w = 0 (z of u-faces: cell centres)."""
    u = np.zeros(padded_shape(CELLS, 0))
    z = (np.arange(u.shape[2]) - 0.5) * H  # padded index K: centre of cell K - 1
    u[...] = rate * z
    return u, np.zeros(padded_shape(CELLS, 1)), np.zeros(padded_shape(CELLS, 2))


def test_a_linear_shear_has_nu_t_equal_to_l2_times_its_rate():
    rate, length2 = 3.0, np.full(CELLS[2], 0.04)
    out = np.zeros(CELLS)
    solid = np.zeros(CELLS, dtype=np.uint8)
    solid[0, 0, 0] = 1
    turbulence.eddy_viscosity(*_shear(rate), solid, AXES, H, length2, out)
    assert out[0, 0, 0] == 0.0  # no eddies inside a body
    np.testing.assert_allclose(out[1:, 1:, :], 0.04 * rate, rtol=1e-12)


def test_uniform_eddy_viscosity_is_the_laplacian_times_nu():
    rng = np.random.default_rng(0)
    q = rng.normal(size=padded_shape(CELLS, 1))
    free = np.zeros(q.shape, dtype=np.uint8)
    free[1:-1, 1:-1, 1:-1] = 1
    nu, dt = 0.3, 0.01
    eddy, lap = np.zeros_like(q), np.zeros_like(q)
    turbulence.eddy_diffusion(q, 1, np.full(CELLS, nu), AXES, dt / H**2, free, eddy)
    diffusion.explicit_step(q, lap, nu * dt / H**2, AXES, free)
    np.testing.assert_allclose(eddy, lap, rtol=0, atol=1e-13)


def test_blackadar_mixing_length_limits():
    l2 = turbulence.mixing_lengths("mixing_length", (1, 1, 4000), 0.01, 0.17, 5.0)
    length = np.sqrt(l2)
    z = (np.arange(4000) + 0.5) * 0.01
    assert length[0] == pytest.approx(turbulence.KARMAN * z[0], rel=1e-3)
    assert length[-1] == pytest.approx(1.0 / (1.0 / (turbulence.KARMAN * z[-1]) + 0.2))
    assert np.all(np.diff(length) > 0) and length[-1] < 5.0
    smag = turbulence.mixing_lengths("smagorinsky", (1, 1, 3), 0.5, 0.17, 5.0)
    np.testing.assert_allclose(smag, (0.17 * 0.5) ** 2)
