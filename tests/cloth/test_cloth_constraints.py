"""Constraint projections of the XPBD cloth against answers known without the code: a
straight chain solved exactly, the strain limit, springs hanging at their static
elongation, the hinge step along the angle gradient, tethers onto their spheres, a shear
edge brought to its length with its centre of mass kept, atan2."""

from __future__ import annotations

import numpy as np
import pytest

from windbench.cloth.constraints import (
    edge_stretch,
    fast_atan2,
    limit_edges,
    project_hinge,
    project_shear_edges,
    project_tethers,
    solve_chains,
)
from windbench.cloth.topology import dihedral_angles


def _vertical_chain(rest, inv_mass, alpha):
    """Arguments of solve_chains for one chain down the z axis: vertex k joins edge k-1, k."""
    m = len(rest)
    scale = 1.0 / (inv_mass[:-1] + inv_mass[1:] + alpha)
    ptr, verts = np.array([0, m]), np.arange(m + 1)
    return ptr, verts, rest, alpha, scale, np.zeros(m), np.empty((m, 5))


def test_one_chain_solve_makes_a_straight_inextensible_chain_exact():
    rng = np.random.default_rng(1)
    m = 12
    rest = rng.uniform(0.05, 0.1, m)
    for inv_mass in (np.r_[0.0, rng.uniform(0.5, 2.0, m)], rng.uniform(0.5, 2.0, m + 1)):
        # collinear start: every edge 30% too long or too short, the first vertex a pin or not
        seg = rest * rng.uniform(0.7, 1.3, m)
        p = np.zeros((m + 1, 3))
        p[1:, 2] = -np.cumsum(seg)
        x = p.copy()
        solve_chains(p, inv_mass, *_vertical_chain(rest, inv_mass, np.zeros(m)))
        # along a line the constraints are linear: one direct solve satisfies them all
        np.testing.assert_allclose(-np.diff(p[:, 2]), rest, rtol=1e-12)
        np.testing.assert_array_equal(p[:, :2], 0.0)
        if inv_mass[0] == 0.0:  # hanging from the pin: each vertex at the rest path length
            np.testing.assert_allclose(p[1:, 2], -np.cumsum(rest), rtol=1e-12)
        else:  # free: the mass-weighted centre does not move (momentum conserved)
            mass = 1.0 / inv_mass
            assert mass @ p[:, 2] == pytest.approx(mass @ x[:, 2], rel=1e-12)


def test_strain_limit_brings_the_over_stretched_edges_of_a_chain_to_the_limit():
    """Limit mode of solve_chains on a straight chain (linear constraints: one solve is
    exact): edges longer than (1 + limit) L end at exactly that length (the others are
    free: they move with their ends), repeated solves end with no edge over the trigger
    (1 + 1.1 limit) L; the mass-weighted centre of a free chain stays put, a pin does not
    move; a chain whose edges stay within the slack above the limit is not touched; the
    multipliers are not used."""
    rng = np.random.default_rng(4)
    m, limit = 10, 0.03
    rest = rng.uniform(0.05, 0.1, m)
    factor = np.where(np.arange(m) % 3 == 0, 1.10, rng.uniform(0.9, 1.02, m))
    for inv_mass in (np.r_[0.0, rng.uniform(0.5, 2.0, m)], rng.uniform(0.5, 2.0, m + 1)):
        p = np.zeros((m + 1, 3))
        p[1:, 2] = -np.cumsum(rest * factor)
        x = p.copy()
        ptr, verts, _, alpha, scale, lam, work = _vertical_chain(rest, inv_mass, np.zeros(m))
        lam[:] = 7.0
        solved = solve_chains(p, inv_mass, ptr, verts, rest, alpha, scale, lam, work, limit)
        assert solved == 1
        over = factor > 1 + limit
        np.testing.assert_allclose(-np.diff(p[:, 2])[over], rest[over] * (1 + limit), rtol=1e-12)
        for _ in range(20):  # the solver's limit passes, until no chain is solved
            if solve_chains(p, inv_mass, ptr, verts, rest, alpha, scale, lam, work, limit) == 0:
                break
        assert np.all(-np.diff(p[:, 2]) <= rest * (1 + 1.1 * limit) * (1 + 1e-12))
        np.testing.assert_array_equal(lam, 7.0)
        np.testing.assert_array_equal(p[:, :2], 0.0)
        if inv_mass[0] == 0.0:
            assert p[0, 2] == 0.0
        if inv_mass[0] > 0.0:
            mass = 1.0 / inv_mass
            assert mass @ p[:, 2] == pytest.approx(mass @ x[:, 2], rel=1e-12)
    p = np.zeros((m + 1, 3))
    p[1:, 2] = -np.cumsum(rest * (1 + 1.05 * limit))  # over the limit, within the slack
    before = p.copy()
    assert solve_chains(p, inv_mass, ptr, verts, rest, alpha, scale, lam, work, limit) == 0
    np.testing.assert_array_equal(p, before)


def test_chain_of_springs_hangs_at_the_static_elongation():
    """Implicit Euler by substeps (predict, one exact chain solve, v = dx/h) comes to rest
    where each spring carries the weight below it: elongation_k = g sum_(i>k) m_i / k_k."""
    rng = np.random.default_rng(2)
    m, g, h = 10, 9.81, 0.01
    rest = rng.uniform(0.05, 0.1, m)
    k = rng.uniform(200.0, 2000.0, m)  # N/m
    mass = rng.uniform(0.005, 0.02, m + 1)
    inv_mass = np.r_[0.0, 1.0 / mass[1:]]  # vertex 0 pinned
    args = _vertical_chain(rest, inv_mass, 1.0 / k / h**2)  # alpha~ = alpha / h^2
    lam = args[5]
    x = np.zeros((m + 1, 3))
    x[1:, 2] = -np.cumsum(rest)
    v = np.zeros_like(x)
    for _ in range(1000):
        v[1:, 2] -= h * g
        p = x + h * v
        lam[:] = 0.0
        solve_chains(p, inv_mass, *args)
        v, x = (p - x) / h, p
    weight_below = g * np.cumsum(mass[::-1])[::-1][1:]
    np.testing.assert_allclose(-np.diff(x[:, 2]), rest + weight_below / k, rtol=1e-9)
    assert np.abs(v).max() < 1e-9


def test_hinge_projection_follows_the_angle_gradient():
    rng = np.random.default_rng(3)
    x = np.array([[0, 0, 0], [0, 1, 0], [-1, 0.3, 0.1], [0.9, 0.6, 0.4]], float)
    x += 0.05 * rng.normal(size=x.shape)
    hinge = np.array([[0, 1, 2, 3]])
    theta = dihedral_angles(x, hinge)[0]
    eps = 1e-7
    grad = np.zeros((4, 3))
    for q in range(4):
        for k in range(3):
            y = x.copy()
            y[q, k] += eps
            grad[q, k] = (dihedral_angles(y, hinge)[0] - theta) / eps
    inv_mass = np.array([1.0, 2.0, 0.5, 1.5])
    rest = theta - 1e-3  # a small violation
    p = x.copy()
    project_hinge(p, inv_mass, 0, 1, 2, 3, rest, 0.0)
    step = p - x
    c = theta - rest
    expected = -c * inv_mass[:, None] * grad / np.sum(inv_mass[:, None] * grad**2)
    np.testing.assert_allclose(step, expected, rtol=1e-4, atol=1e-12)
    assert abs(dihedral_angles(p, hinge)[0] - rest) < 1e-3 * c  # fixed to first order


def test_fast_atan2_matches_libm():
    rng = np.random.default_rng(0)
    y, x = rng.normal(size=(2, 2000))
    got = np.array([fast_atan2(a, b) for a, b in zip(y, x, strict=True)])
    np.testing.assert_allclose(got, np.arctan2(y, x), atol=3e-8)
    assert fast_atan2(0.0, -1.0) == pytest.approx(np.pi) and fast_atan2(0.0, 0.0) == 0.0


def test_tethers_pull_only_the_vertices_beyond_their_rest_distance():
    """|p_i - p_anchor| <= L_i: a vertex outside the sphere lands on it along the same ray,
    one inside, a pinned one and one without an anchor stay put."""
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -3.0], [0.5, 0.0, 0.0], [4.0, 4.0, 4.0], [9.0, 0, 0]])
    inv_mass = np.array([0.0, 1.0, 1.0, 0.0, 1.0])
    anchor = np.array([-1, 0, 0, 0, -1])
    length = np.array([0.0, 2.0, 1.0, 1.0, 1.0])
    before = p.copy()
    project_tethers(p, inv_mass, anchor, length)
    np.testing.assert_array_equal(p[1], [0.0, 0.0, -2.0])
    np.testing.assert_array_equal(p[[0, 2, 3, 4]], before[[0, 2, 3, 4]])


def test_a_rigid_shear_edge_gets_its_length_and_keeps_its_centre_of_mass():
    """alpha~ = 0: one projection makes |p_i - p_j| = L exactly, moves the two ends along
    their line in inverse proportion to their masses; edges before ``first`` and edges of
    scale 0 are left alone."""
    p = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [7.0, 7.0, 7.0], [8.0, 7.0, 7.0]])
    inv_mass = np.array([1.0, 3.0, 1.0, 1.0])
    edges = np.array([[2, 3], [0, 1], [2, 3]])
    rest, alpha = np.array([5.0, 4.0, 2.0]), np.zeros(3)
    scale = np.array([0.25, 0.25, 0.0])
    lam = np.zeros(3)
    x = p.copy()
    project_shear_edges(p, inv_mass, edges, rest, alpha, scale, lam, 1)
    assert np.linalg.norm(p[1] - p[0]) == pytest.approx(4.0, rel=1e-14)
    mass = 1.0 / inv_mass[:2]
    np.testing.assert_allclose(mass @ p[:2], mass @ x[:2], rtol=1e-14)
    np.testing.assert_allclose(np.cross(p[1] - p[0], x[1] - x[0]), 0.0, atol=1e-14)
    np.testing.assert_array_equal(p[2:], x[2:])
    assert (
        lam[0] == 0.0 and lam[2] == 0.0 and lam[1] == pytest.approx(-0.25)
    )  # (L - l) / (w_i + w_j)


def test_edge_strain_limit_moves_only_the_edges_over_the_trigger():
    """An edge 20 % long is brought to exactly (1 + limit) L along its line, its centre of
    mass kept; one 3.2 % long (under the trigger 1 + 1.1 x 3 %) and one between two pins are
    left alone; only the moved edge's vertices are flagged."""
    p = np.array([[0, 0, 0], [0, 0, 1.2], [5, 0, 0], [5, 0, 1.032], [9, 0, 0], [9, 0, 2]], float)
    inv_mass = np.array([1.0, 3.0, 1.0, 1.0, 0.0, 0.0])
    edges = np.array([[0, 1], [2, 3], [4, 5]])
    rest = np.ones(3)
    x, moved = p.copy(), np.zeros(6, bool)
    assert limit_edges(p, inv_mass, edges, rest, 0, 3, 0.03, moved, _stamps(6, 3)) == 1
    assert p[1, 2] - p[0, 2] == pytest.approx(1.03, rel=1e-14)
    np.testing.assert_allclose(p[:2, :2], 0.0, atol=0)
    mass = 1.0 / inv_mass[:2]
    np.testing.assert_allclose(mass @ p[:2], mass @ x[:2], rtol=1e-14)
    np.testing.assert_array_equal(p[2:], x[2:])
    np.testing.assert_array_equal(moved, [True, True, False, False, False, False])


def test_edge_stretch_gives_the_largest_elongation_and_the_edges_beyond_a_limit():
    x = np.array([[0.0, 0, 0], [1.1, 0, 0], [1.1, 2.02, 0], [0, 0, 0.5]])
    edges = np.array([[0, 1], [1, 2], [0, 3]])
    rest = np.array([1.0, 2.0, 0.5])  # stretched by 10 %, 1 %, 0
    top, over = edge_stretch(x, edges, rest, 0.03)
    assert top == pytest.approx(0.1, rel=1e-12) and over == 1
    assert edge_stretch(x, edges, rest, 0.005)[1] == 2


def _stamps(n, e):
    return np.full(n, -1, np.int64), np.full(e, -1, np.int64), np.zeros(1, np.int64)


def test_edge_strain_limit_skipping_untouched_edges_gives_the_same_bits():
    """Passes that skip the edges whose vertices did not move since their last test end
    where passes that test every edge end, bit for bit."""
    rng = np.random.default_rng(3)
    rest_x = rng.uniform(0, 1, (40, 3))
    edges = np.array([(i, j) for i in range(40) for j in range(i + 1, 40) if rng.random() < 0.1])
    rest = np.linalg.norm(rest_x[edges[:, 0]] - rest_x[edges[:, 1]], axis=1)
    inv_mass = rng.uniform(0.5, 2.0, 40)
    start = rest_x * rng.uniform(1.0, 1.3, (40, 1))  # stretched
    kept, fresh = start.copy(), start.copy()
    stamps = _stamps(40, len(edges))
    moved = np.zeros(40, bool)
    for _ in range(20):
        a = limit_edges(kept, inv_mass, edges, rest, 0, len(edges), 0.03, moved, stamps)
        b = limit_edges(
            fresh, inv_mass, edges, rest, 0, len(edges), 0.03, moved, _stamps(40, len(edges))
        )
        assert a == b
    assert np.array_equal(kept, fresh) and not np.array_equal(kept, start)
