"""Aerodynamic forces (paper §3): drag, lift, eq. (3.1) normal flip, air resistance."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from windbench.aero import aerodynamic_forces, cloth_forces, plate_coefficients
from windbench.config import AeroConfig

P = AeroConfig(drag_coefficient=1.17, lift_coefficient=0.6, air_density=1.2)
SQUARE = np.array([[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1.0]])  # unit plate in x = 0
SQUARE_TRIS = np.array([[0, 1, 2], [0, 2, 3]])


def plate_force(positions, tris, wind, velocity=(0, 0, 0)):
    n = positions.shape[0]
    tri, vert = aerodynamic_forces(
        positions,
        np.tile(velocity, (n, 1)).astype(float),
        np.tile(wind, (n, 1)).astype(float),
        tris,
        P,
    )
    return tri.sum(0), vert


def rotate_z(points, angle):
    c, s = np.cos(angle), np.sin(angle)
    return points @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T


def test_plate_normal_to_the_wind_gets_exactly_the_drag_law():
    v = 7.0
    F, _ = plate_force(SQUARE, SQUARE_TRIS, (v, 0, 0))
    expected = 0.5 * P.drag_coefficient * P.air_density * v**2 * 1.0
    assert F[0] == pytest.approx(expected, rel=1e-14)
    assert F[1] == 0.0 and F[2] == 0.0  # no lift face-on


def test_plate_parallel_to_the_wind_feels_nothing():
    F, _ = plate_force(SQUARE, SQUARE_TRIS, (0, 5.0, 0))
    np.testing.assert_allclose(F, 0.0, atol=1e-12)


def test_lift_at_45_degrees_is_perpendicular_to_v_rel_in_the_plane_of_v_rel_and_normal():
    alpha = np.pi / 4
    plate = rotate_z(SQUARE, -alpha)  # normal (cos a, -sin a, 0): 45 degrees to the wind
    wind = np.array([6.0, 0, 0])
    F, _ = plate_force(plate, SQUARE_TRIS, wind)
    q = 0.5 * P.air_density * 36.0
    v_rel = -wind / 6.0
    drag = (F @ -v_rel) * -v_rel
    lift = F - drag
    assert np.linalg.norm(drag) == pytest.approx(q * P.drag_coefficient * np.sin(alpha), rel=1e-12)
    assert np.linalg.norm(lift) == pytest.approx(
        q * P.lift_coefficient * np.sin(alpha) * np.cos(alpha), rel=1e-12
    )
    assert abs(lift @ v_rel) < 1e-12  # perpendicular to v_rel
    normal = np.cross(plate[1] - plate[0], plate[2] - plate[0])
    assert abs(lift @ np.cross(normal, v_rel)) < 1e-12  # in the plane of v_rel and n


def test_flipping_the_winding_changes_nothing():
    wind = (4.0, 1.0, -2.0)
    plate = rotate_z(SQUARE, 0.3)
    a, _ = plate_force(plate, SQUARE_TRIS, wind)
    b, _ = plate_force(plate, SQUARE_TRIS[:, ::-1], wind)
    np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)


def test_moving_plate_in_still_air_is_decelerated():
    velocity = np.array([2.0, 0.5, 0.0])
    F, _ = plate_force(rotate_z(SQUARE, 0.2), SQUARE_TRIS, (0, 0, 0), velocity)
    assert F @ velocity < 0
    # Galilean invariance: moving plate in still air = still plate in the opposite wind
    G, _ = plate_force(rotate_z(SQUARE, 0.2), SQUARE_TRIS, -velocity)
    np.testing.assert_allclose(F, G, rtol=1e-14)


def test_zero_relative_velocity_and_degenerate_triangles_give_zero_not_nan():
    F, _ = plate_force(SQUARE, SQUARE_TRIS, (1, 2, 3), (1, 2, 3))
    assert np.all(F == 0)
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    F, _ = plate_force(line, np.array([[0, 1, 2]]), (0, 0, 5))
    assert np.all(F == 0)


def test_plate_coefficients_follow_the_drag_and_lift_laws():
    cd, cl = plate_coefficients(np.array([0.0, np.pi / 4, np.pi / 2]), P)
    np.testing.assert_allclose(cd, [0, P.drag_coefficient / np.sqrt(2), P.drag_coefficient])
    np.testing.assert_allclose(cl, [0, P.lift_coefficient / 2, 0], atol=1e-16)


finite = st.floats(-10, 10, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    arrays(float, (3, 3), elements=finite),
    arrays(float, (3, 3), elements=finite),
    arrays(float, (3, 3), elements=finite),
)
def test_random_triangles_give_finite_forces_whose_vertex_shares_sum_to_the_total(x, v, u):
    tri, vert = aerodynamic_forces(x, v, u, np.array([[0, 1, 2]]), P)
    assert np.all(np.isfinite(tri)) and np.all(np.isfinite(vert))
    np.testing.assert_allclose(vert.sum(0), tri[0], rtol=1e-12, atol=1e-9)
    # the force never pushes along the relative velocity (it only resists or lifts)
    v_rel = v.mean(0) - u.mean(0)
    assert tri[0] @ v_rel <= 1e-9 * (1 + np.linalg.norm(tri[0]) * np.linalg.norm(v_rel))


def test_cloth_forces_add_the_law_to_the_pressure_jump_when_asked():
    """:func:`cloth_forces`: the §3 law alone without pressure loads; with them
    (``wind.coupling=projection``) the jump, shared equally by the corners, plus the law
    for ``subgrid_law``: the unit plate face-on to 7 m/s gets the law's 1/2 C_D rho v^2
    more than the jump alone, and each corner a third of each triangle's force."""
    wind = np.tile((7.0, 0.0, 0.0), (4, 1))
    still = np.zeros((4, 3))
    loads = np.array([[3.0, 0.0, 0.0], [5.0, 0.0, 0.0]])  # m^4 s^-2 per triangle
    law = 0.5 * P.drag_coefficient * P.air_density * 7.0**2
    alone = cloth_forces(SQUARE, still, wind, SQUARE_TRIS, None, P)[0].sum(0)
    assert alone[0] == pytest.approx(law, rel=1e-14)
    jump = P.air_density * 8.0
    for subgrid, expected in ((True, jump + law), (False, jump)):
        params = AeroConfig(1.17, 0.6, 1.2, subgrid_law=subgrid)
        tri, vert = cloth_forces(SQUARE, still, wind, SQUARE_TRIS, loads, params)
        assert tri.sum(0)[0] == pytest.approx(expected, rel=1e-14)
        np.testing.assert_allclose(vert.sum(0), tri.sum(0), rtol=1e-14)
    pressure_only = cloth_forces(
        SQUARE, still, wind, SQUARE_TRIS, loads, AeroConfig(subgrid_law=False)
    )
    np.testing.assert_allclose(pressure_only[1][1], P.air_density * 3.0 / 3.0 * np.array([1, 0, 0]))
