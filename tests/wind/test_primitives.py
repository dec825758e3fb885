"""Flow primitives (paper §4.2.1): potential flows, so div w = 0 and curl w = 0 off the core."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from windbench.errors import ConfigError
from windbench.wind.primitives import Primitive, primitive_from_config, superpose

SOURCE = Primitive("source", center=(0.3, -0.2, 0.1), strength=2.5, core_radius=0.05)
SINK = Primitive("sink", center=(0.3, -0.2, 0.1), strength=2.5, core_radius=0.05)
VORTEX = Primitive(
    "vortex", center=(0.1, 0.2, -0.3), axis=(1.0, 2.0, 2.0), strength=3.0, core_radius=0.05
)
UNIFORM = Primitive("uniform", velocity=(6.0, -1.0, 0.5))


def jacobian(prims, x, eps=1e-5):
    """J[i, j] = d w_i / d x_j by central differences."""
    J = np.empty((3, 3))
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        J[:, j] = (superpose(prims, [x + d])[0] - superpose(prims, [x - d])[0]) / (2 * eps)
    return J


@pytest.mark.parametrize("prim", [SOURCE, SINK, VORTEX, UNIFORM], ids=lambda p: p.kind)
def test_divergence_and_curl_vanish_away_from_the_core(prim):
    rng = np.random.default_rng(1)
    for _ in range(20):
        x = rng.uniform(-2, 2, 3)
        if np.linalg.norm(x - np.asarray(prim.center)) < 0.6:
            continue
        J = jacobian([prim], x)
        scale = np.linalg.norm(superpose([prim], [x])[0]) / np.linalg.norm(x - prim.center) + 1e-12
        assert abs(np.trace(J)) < 1e-6 * scale + 1e-9
        curl = np.array([J[2, 1] - J[1, 2], J[0, 2] - J[2, 0], J[1, 0] - J[0, 1]])
        assert np.linalg.norm(curl) < 1e-6 * scale + 1e-9


def test_vortex_has_its_circulation_and_is_finite_on_the_axis():
    # Stokes: the circulation around a loop far outside the core is Gamma.
    v = Primitive("vortex", center=(0, 0, 0), axis=(0, 0, 1), strength=3.0, core_radius=0.1)
    theta = np.linspace(0, 2 * np.pi, 2001)[:-1]
    r = 2.0
    pts = np.stack([r * np.cos(theta), r * np.sin(theta), np.zeros_like(theta)], axis=1)
    tangent = np.stack([-np.sin(theta), np.cos(theta), np.zeros_like(theta)], axis=1)
    circulation = np.sum((superpose([v], pts) * tangent).sum(1)) * r * (theta[1] - theta[0])
    assert circulation == pytest.approx(3.0, rel=1e-9)
    assert np.all(np.isfinite(superpose([v], [[0, 0, 0], [0, 0, 5.0], [1e-9, 0, 0]])))


def test_source_flux_through_a_sphere_is_its_strength():
    # Gauss: the flux of w through any sphere well outside the core equals m.
    rng = np.random.default_rng(2)
    n = rng.normal(size=(200000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    R = 1.5
    w = superpose([SOURCE], np.asarray(SOURCE.center) + R * n)
    flux = (w * n).sum(1).mean() * 4 * np.pi * R**2
    assert flux == pytest.approx(SOURCE.strength, rel=1e-9)


def test_source_is_radially_symmetric_and_sink_is_its_negative():
    c = np.asarray(SOURCE.center)
    d = np.array([0.7, -0.4, 0.9])
    w_plus, w_minus = superpose([SOURCE], [c + d, c - d])
    np.testing.assert_allclose(w_plus, -w_minus, rtol=1e-14)
    np.testing.assert_allclose(np.cross(w_plus, d), 0, atol=1e-14)  # radial
    assert w_plus @ d > 0
    np.testing.assert_allclose(superpose([SINK], [c + d]), -superpose([SOURCE], [c + d]))


def test_uniform_field_is_exactly_constant():
    pts = np.random.default_rng(3).uniform(-100, 100, (50, 3))
    assert np.all(superpose([UNIFORM], pts) == np.array(UNIFORM.velocity))


@settings(max_examples=30, deadline=None)
@given(st.floats(-3, 3), st.lists(st.floats(-5, 5), min_size=3, max_size=3))
def test_superposition_is_linear(a, x):
    x = np.array([x])
    both = superpose([SOURCE, VORTEX, UNIFORM], x)
    parts = superpose([SOURCE], x) + superpose([VORTEX], x) + superpose([UNIFORM], x)
    np.testing.assert_allclose(both, parts, rtol=1e-12, atol=1e-12)
    scaled = Primitive(
        "vortex",
        VORTEX.center,
        VORTEX.axis,
        strength=a * VORTEX.strength,
        core_radius=VORTEX.core_radius,
    )
    np.testing.assert_allclose(superpose([scaled], x), a * superpose([VORTEX], x), atol=1e-12)


def test_bad_primitive_config_names_the_key():
    with pytest.raises(ConfigError, match=r"scene.sources\[0\].type: must be one of"):
        primitive_from_config({"type": "tornado"}, "scene.sources[0]")
    with pytest.raises(ConfigError, match=r"core_radius"):
        primitive_from_config({"type": "source", "center": [0, 0, 0], "core_radius": -1}, "s")
    with pytest.raises(ConfigError, match=r"unknown key"):
        primitive_from_config({"type": "uniform", "velocity": [1, 0, 0], "speed": 3}, "s")


def test_log_and_power_profiles_give_the_reference_wind_at_the_reference_height():
    log = primitive_from_config(
        {"type": "uniform", "velocity": [6.0, 0.0, 0.0],
         "profile": {"type": "log", "roughness": 0.03, "reference_height": 10.0}},
        "s",
    )  # fmt: skip
    z = np.array([0.01, 0.03, 1.0, 10.0, 20.0])
    pts = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    expected = np.where(z > 0.03, np.log(np.maximum(z, 0.03) / 0.03) / np.log(10.0 / 0.03), 0.0)
    np.testing.assert_allclose(superpose([log], pts)[:, 0], 6.0 * expected, rtol=1e-12)
    power = primitive_from_config(
        {"type": "uniform", "velocity": [0.0, 4.0, 0.0],
         "profile": {"type": "power", "exponent": 0.14, "reference_height": 10.0, "ground": 1.0}},
        "s",
    )  # fmt: skip
    w = superpose([power], np.array([[0.0, 0.0, 11.0], [0.0, 0.0, 6.0], [0.0, 0.0, 0.5]]))
    np.testing.assert_allclose(w[:, 1], [4.0, 4.0 * 0.5**0.14, 0.0], rtol=1e-12)


@pytest.mark.parametrize(
    ("profile", "key"),
    [
        ({"type": "cubic", "reference_height": 1}, "s.profile.type"),
        ({"type": "log", "roughness": 2.0, "reference_height": 1.0}, "s.profile.reference_height"),
        ({"type": "log", "roughness": -1, "reference_height": 1.0}, "s.profile.roughness"),
        ({"type": "power", "reference_height": 1.0}, "s.profile.exponent"),
    ],
)
def test_bad_profiles_name_the_key(profile, key):
    spec = {"type": "uniform", "velocity": [6.0, 0.0, 0.0], "profile": profile}
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        primitive_from_config(spec, "s")
