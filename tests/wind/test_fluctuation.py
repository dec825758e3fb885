"""Synthetic inflow turbulence (:mod:`windbench.wind.fluctuation`): divergence free by
construction (every mode's amplitude is normal to its wave vector), each component's
standard deviation is I |U|, the field is carried by the mean wind, and a seed fixes it."""

from __future__ import annotations

import numpy as np
import pytest

from windbench.wind.fluctuation import Fluctuation

U = np.array([6.0, 0.0, 0.0])


def test_every_mode_is_divergence_free():
    f = Fluctuation.build(0.2, 2.0, U, seed=3)
    np.testing.assert_allclose(np.sum(f.wave_vectors * f.directions, axis=1), 0, atol=1e-12)
    p, e = np.array([[1.0, 2.0, 3.0]]), 1e-6
    div = sum((f(p + e * np.eye(3)[i], 0.4) - f(p - e * np.eye(3)[i], 0.4))[0, i] for i in range(3))
    assert abs(div / (2 * e)) < 1e-6 * f.sigma * np.abs(f.wave_vectors).max()


def test_each_component_has_the_requested_intensity():
    f = Fluctuation.build(0.15, 1.0, U, seed=1, modes=400)
    points = np.random.default_rng(2).uniform(0, 200, (40000, 3))
    std = f(points, 0.0).std(axis=0)
    np.testing.assert_allclose(std, 0.15 * 6.0, rtol=0.1)


def test_frozen_turbulence_is_carried_by_the_mean_wind_and_seeded():
    f = Fluctuation.build(0.1, 2.0, U, seed=7)
    p = np.array([[5.0, 1.0, 2.0], [0.0, 3.0, 1.0]])
    np.testing.assert_allclose(f(p, 0.5), f(p - U * 0.5, 0.0), atol=1e-12)
    same = Fluctuation.build(0.1, 2.0, U, seed=7)
    other = Fluctuation.build(0.1, 2.0, U, seed=8)
    np.testing.assert_array_equal(f(p, 0.3), same(p, 0.3))
    assert not np.allclose(f(p, 0.3), other(p, 0.3))


@pytest.mark.parametrize("bad", [{"intensity": 1.5, "length_scale": 1}, {"intensity": 0.1}])
def test_bad_turbulence_settings_name_the_key(bad):
    from windbench.errors import ConfigError
    from windbench.wind.primitives import primitive_from_config

    spec = {"type": "uniform", "velocity": [6, 0, 0], "turbulence": bad}
    with pytest.raises(ConfigError, match=r"scene.sources\[0\].turbulence"):
        primitive_from_config(spec, "scene.sources[0]")
