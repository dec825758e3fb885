"""Rigid bodies: signed distances and normals against closed-form answers."""

import numpy as np
import pytest

from windbench.errors import ConfigError
from windbench.geometry.bodies import body_from_config, distances, inside

BOX = body_from_config({"type": "box", "min": [0, 0, 0], "max": [2, 1, 1]}, "b")
CAPSULE = body_from_config({"type": "capsule", "a": [0, 0, 0], "b": [0, 0, 2], "radius": 0.5}, "c")
CYLINDER = body_from_config(
    {"type": "cylinder", "a": [0, 0, 0], "b": [0, 0, 2], "radius": 0.5}, "y"
)
PLANE = body_from_config({"type": "plane", "point": [0, 0, 1], "normal": [0, 0, 2]}, "p")


@pytest.mark.parametrize(
    "body, point, dist, normal",
    [
        (BOX, [1, 0.5, 0.5], -0.5, [0, 0, 1]),  # centre: nearest faces at 0.5, first wins
        (BOX, [3, 0.5, 0.5], 1.0, [1, 0, 0]),
        (BOX, [3, 2, 0.5], np.sqrt(2), [np.sqrt(0.5), np.sqrt(0.5), 0]),
        (CAPSULE, [2, 0, 1], 1.5, [1, 0, 0]),
        (CAPSULE, [0, 0, 3], 0.5, [0, 0, 1]),
        (CAPSULE, [0, 0.3, 1], -0.2, [0, 1, 0]),
        (CYLINDER, [2, 0, 1], 1.5, [1, 0, 0]),
        (CYLINDER, [0, 0, 3], 1.0, [0, 0, 1]),
        (CYLINDER, [1.5, 0, 3], np.sqrt(2), [np.sqrt(0.5), 0, np.sqrt(0.5)]),
        (CYLINDER, [0, 0.1, 1.9], -0.1, [0, 0, 1]),
        (PLANE, [5, -3, 0.25], -0.75, [0, 0, 1]),
    ],
)
def test_signed_distance_and_normal(body, point, dist, normal):
    d, n = distances([body], [point])
    assert d[0] == pytest.approx(dist, abs=1e-12)
    if body is not BOX or dist > 0:
        np.testing.assert_allclose(n[0], normal, atol=1e-12)
    assert np.linalg.norm(n[0]) == pytest.approx(1.0)


def test_distance_is_one_lipschitz_and_inside_matches_sign():
    rng = np.random.default_rng(0)
    p = rng.uniform(-2, 3, (400, 3))
    q = p + rng.normal(scale=0.05, size=p.shape)
    for body in (BOX, CAPSULE, CYLINDER, PLANE):
        dp, _ = distances([body], p)
        dq, _ = distances([body], q)
        assert np.all(np.abs(dp - dq) <= np.linalg.norm(p - q, axis=1) + 1e-12)
        np.testing.assert_array_equal(inside([body], p), dp < 0)


def test_union_takes_the_nearest_body():
    d, _ = distances([BOX, PLANE], [[1, 0.5, 0.9]])
    assert d[0] == pytest.approx(-0.1)


def test_bad_bodies_name_the_key():
    with pytest.raises(ConfigError, match=r"bodies\[2\].radius: must be > 0"):
        body_from_config(
            {"type": "capsule", "a": [0, 0, 0], "b": [0, 0, 1], "radius": 0}, "scene.bodies[2]"
        )
    with pytest.raises(ConfigError, match=r"max: must exceed"):
        body_from_config({"type": "box", "min": [0, 0, 0], "max": [1, 0, 1]}, "b")
