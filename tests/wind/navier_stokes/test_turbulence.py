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
EULER = np.array([1.0, 0.0, 1.0])  # the RKL1 stage (mu, nu, mu~) of a forward-Euler step


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
    eddy, lap, faces = np.zeros_like(q), np.zeros_like(q), np.zeros_like(q)
    turbulence.face_viscosity(np.full(CELLS, nu), 1, faces)
    turbulence.eddy_diffusion(q, q, faces, AXES, dt / H**2, free, EULER, eddy)
    psi = np.zeros(CELLS)
    trapezoid.carried_field(q, 1, psi, 0.0, nu * dt / H**2, AXES, free, np.zeros(3, bool), lap)
    np.testing.assert_allclose(eddy, lap, rtol=0, atol=1e-13)


def test_variable_eddy_viscosity_is_a_symmetric_operator_that_conserves_momentum():
    """With nu_t varying from cell to cell, the eddy term L q = (eddy_diffusion(q) - q) /
    (dt/h^2) is a flux form whose flux between two faces is one coefficient times their
    difference: symmetric (x . L y = y . L x over the free faces, the others held at 0),
    and free of sources (the sum of L q over the free faces is the flux through the
    faces held, zero when q there equals its neighbours)."""
    rng = np.random.default_rng(3)
    shape = padded_shape(CELLS, 0)
    free = np.zeros(shape, dtype=np.uint8)
    free[1:-1, 1:-1, 1:-1] = 1
    faces = np.zeros(shape)
    turbulence.face_viscosity(rng.uniform(0.1, 2.0, CELLS), 0, faces)

    def op(q):
        out = np.zeros_like(q)
        turbulence.eddy_diffusion(q, q, faces, AXES, 1.0, free, EULER, out)
        return (out - q)[free == 1]

    x, y = (np.where(free == 1, rng.normal(size=shape), 0.0) for _ in range(2))
    assert np.dot(x[free == 1], op(y)) == pytest.approx(np.dot(y[free == 1], op(x)), rel=1e-12)
    inner = rng.normal(size=tuple(n - 2 for n in shape))
    q = np.pad(inner, 1, mode="edge")  # each held face equal to its free neighbour
    assert abs(op(q).sum()) <= 1e-12 * np.abs(op(q)).sum()


@pytest.mark.parametrize("s", [1, 2, 4, 9])
def test_rkl1_amplifies_a_mode_by_the_legendre_polynomial_and_is_stable(s):
    """The stages of legendre_stage applied to an eigenmode L v = lambda v multiply it by
    P_s(1 + w_1 lambda dt), w_1 = 2 / (s^2 + s) (Meyer, Balsara and Aslam 2014), whose
    modulus stays <= 1 over lambda dt in [-(s^2 + s), 0] and which matches exp(lambda dt)
    to first order for a slow mode."""
    w1 = 2.0 / (s * s + s)
    for z in np.linspace(-(s * s + s), 0.0, 97):
        older, y = 1.0, 1.0
        for j in range(1, s + 1):
            mu, nu, mut = turbulence.legendre_stage(j, s)
            older, y = y, mu * y + nu * (older if j > 1 else y) + mut * z * y
        assert y == pytest.approx(np.polynomial.legendre.legval(1 + w1 * z, [0] * s + [1]))
        assert abs(y) <= 1.0 + 1e-12
    z = -1e-3  # a slow mode: 1 + z + O(z^2)
    older, y = 1.0, 1.0
    for j in range(1, s + 1):
        mu, nu, mut = turbulence.legendre_stage(j, s)
        older, y = y, mu * y + nu * (older if j > 1 else y) + mut * z * y
    assert y == pytest.approx(np.exp(z), abs=1e-6)
    assert turbulence.legendre_stages(s * (s + 1) / 2) == s
    assert turbulence.legendre_stages(s * (s + 1) / 2 + 1e-9) == s + 1


def test_rkl1_stages_of_the_kernel_damp_a_grid_eigenmode_as_the_polynomial_says():
    """A product of sines vanishing on the held faces around the free ones is an
    eigenvector of the discrete eddy term with uniform nu_t, eigenvalue lambda = -4 nu /
    h^2 sum_b sin^2(pi k_b / (2 (n_b + 1))); the kernel's stages at the stability limit
    scale it by P_s(1 + w_1 lambda dt) exactly (to rounding)."""
    shape = padded_shape(CELLS, 2)
    n = [m - 2 for m in shape]  # free faces per axis
    free = np.zeros(shape, dtype=np.uint8)
    free[1:-1, 1:-1, 1:-1] = 1
    k = (n[0], 1, n[2])  # the stiffest mode along x and z, the slowest along y
    axes = [np.sin(np.pi * kb * np.arange(m + 2) / (m + 1)) for kb, m in zip(k, n, strict=True)]
    v = axes[0][:, None, None] * axes[1][None, :, None] * axes[2][None, None, :]
    nu = 0.7
    lam = (
        -4
        * nu
        / H**2
        * sum(np.sin(np.pi * kb / (2 * (m + 1))) ** 2 for kb, m in zip(k, n, strict=True))
    )
    faces = np.zeros(shape)
    turbulence.face_viscosity(np.full(CELLS, nu), 2, faces)
    s = 5
    dt = -(s * s + s) / lam  # the stages' stability limit for this mode
    older, y = v, v
    for j in range(1, s + 1):
        out = np.zeros_like(v)
        stage = np.array(turbulence.legendre_stage(j, s))
        turbulence.eddy_diffusion(y, older, faces, AXES, dt / H**2, free, stage, out)
        older, y = y, out
    factor = np.polynomial.legendre.legval(1 + 2.0 / (s * s + s) * lam * dt, [0] * s + [1])
    np.testing.assert_allclose(y, factor * v, atol=1e-10)


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
