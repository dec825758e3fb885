"""Eddy viscosity (:mod:`windbench.wind.navier_stokes.turbulence`) against closed forms: a
linear shear has |S| equal to its shear rate; with a uniform nu_t the eddy term is the
discrete Laplacian times nu_t; Blackadar's mixing length tends to kappa z near the ground
and to lambda aloft."""

from __future__ import annotations

import numpy as np
import pytest

from windbench.wind import surface_layer
from windbench.wind.navier_stokes import trapezoid, turbulence
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
    psi = np.zeros(CELLS)
    trapezoid.carried_field(q, 1, psi, 0.0, nu * dt / H**2, AXES, free, np.zeros(3, bool), lap)
    np.testing.assert_allclose(eddy, lap, rtol=0, atol=1e-13)


def test_blackadar_mixing_length_limits():
    z = (np.arange(4000) + 0.5) * 0.01
    length = surface_layer.blackadar_length(z, 5.0)
    assert length[0] == pytest.approx(surface_layer.KARMAN * z[0], rel=1e-3)
    assert length[-1] == pytest.approx(1.0 / (1.0 / (surface_layer.KARMAN * z[-1]) + 0.2))
    assert np.all(np.diff(length) > 0) and length[-1] < 5.0


def test_surface_layer_viscosity_of_a_log_law_is_kappa_ustar_z():
    """Over u(z) = (u*/kappa) ln(z/z0), with l = kappa z (lambda far above), the
    equilibrium eddy viscosity is K = kappa u* z."""
    ustar, z = 0.4, np.array([0.5, 1.0, 2.0, 5.0])
    shear = ustar / (surface_layer.KARMAN * z)
    k = surface_layer.surface_layer_viscosity(z, shear, limit=1e12)
    np.testing.assert_allclose(k, surface_layer.KARMAN * ustar * z, rtol=1e-9)


def test_the_backend_takes_k_from_its_sources_profile_and_none_from_a_uniform_wind():
    from windbench.cli import compose_config
    from windbench.simulate import prepare
    from windbench.wind import make_wind

    def nu_t(scene, resolution):
        cfg = compose_config(
            ["wind=navier_stokes", f"scene={scene}", f"grid.resolution={resolution}"]
        )
        setup = prepare(cfg)
        return make_wind(cfg.wind, setup.scene, setup.grid), setup

    fence, setup = nu_t("fence", 48)
    z = setup.grid.axes()[2]
    ustar = surface_layer.KARMAN * 6.0 / np.log(10.0 / 0.1)  # the fence's log law
    expected = surface_layer.blackadar_length(z, 40.0) * ustar / (surface_layer.KARMAN * z)
    expected = surface_layer.blackadar_length(z, 40.0) * expected  # l^2 |dU/dz|
    column = fence.nu_t[1, 1, :]  # upwind of the fence: air in every layer
    np.testing.assert_allclose(column, expected, rtol=1e-4)
    assert fence.nu_t[fence.solid.astype(bool)].max() == 0.0
    flag, _ = nu_t("flag", 16)
    assert flag.nu_t is None  # a uniform wind has no shear, no eddy viscosity
