"""The tabulated signed distance of a mesh against shapes whose distance is known: a sphere
(|p| - R, up to the polyhedron's own deviation), a box (exact: its faces are planes), and
first hits of straight pieces on them."""

import numpy as np
import pytest
import trimesh

from windbench.geometry.sdf import (
    BAND_CELLS,
    lattice_distance,
    lattice_first_hit,
    sdf_lattice,
)

R = 0.3


def sphere_mesh(subdivisions: int = 3, radius: float = R):
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)


def chord_error(vertices, triangles, radius: float = R) -> float:
    """How far the inscribed polyhedron's faces come inside the sphere: R - min face-plane
    distance from the centre (the polyhedron's distance differs from |p| - R by at most this)."""
    x0 = vertices[triangles[:, 0]]
    n = np.cross(vertices[triangles[:, 1]] - x0, vertices[triangles[:, 2]] - x0)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return radius - np.abs(np.einsum("ij,ij->i", x0, n)).min()


def table_row(lattice, vertices):
    """(fields, params row) of one mesh body, as body_table lays them out."""
    return lattice.entry(), np.array([0.0, *vertices.min(0), *vertices.max(0)])


def sample(lattice, vertices, points):
    fields, prm = table_row(lattice, vertices)
    normal = np.empty(3)
    d = np.empty(len(points))
    normals = np.empty((len(points), 3))
    for i, p in enumerate(points):
        d[i] = lattice_distance(fields, prm, p[0], p[1], p[2], normal)
        normals[i] = normal
    return d, normals


def lattice_points(lattice):
    axes = [
        lattice.origin[a] + lattice.spacing * np.arange(n)
        for a, n in enumerate(lattice.values.shape)
    ]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def shell_points(n, inner, outer, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.uniform(inner, outer, n)[:, None]


@pytest.mark.parametrize("h", [0.04, 0.02, 0.01])
def test_lattice_values_of_a_sphere_mesh(h):
    """Within the band the lattice holds the polyhedron's exact distance, so it is |p| - R
    to within the chord error; beyond it (closest-point sweeps) within one spacing more."""
    v, t = sphere_mesh()
    lattice = sdf_lattice(v, t, h)
    exact = np.linalg.norm(lattice_points(lattice), axis=-1) - R
    chord = chord_error(v, t)
    band = np.abs(lattice.values) < BAND_CELLS * h
    err = np.abs(lattice.values - exact)
    assert err[band].max() <= chord + 1e-12
    assert err.max() <= chord + h
    assert np.all(
        np.sign(lattice.values[np.abs(exact) > chord]) == np.sign(exact[np.abs(exact) > chord])
    )


@pytest.mark.parametrize("h", [0.04, 0.02])
def test_sampled_distance_of_a_sphere_mesh_is_second_order(h):
    """Near the surface the trilinear sample differs from |p| - R by at most the chord error
    plus the interpolation error h^2/8 (|f_xx| + |f_yy| + |f_zz|) = h^2 / (4 rho) of the
    sphere's distance at radius rho >= R - h; the normal is within a few degrees of p/|p|."""
    v, t = sphere_mesh(4)
    lattice = sdf_lattice(v, t, h)
    pts = shell_points(2000, R - 0.2 * h, R + 0.2 * h)  # corners all within the band
    d, n = sample(lattice, v, pts)
    exact = np.linalg.norm(pts, axis=1) - R
    bound = chord_error(v, t) + h * h / (4 * (R - h))
    assert np.abs(d - exact).max() <= bound
    radial = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", n, radial).min() > np.cos(np.radians(8))


def test_sampled_error_shrinks_with_the_spacing():
    v, t = sphere_mesh(5)  # chord error 0.09 mm: small against the interpolation error
    pts = shell_points(1000, R - 0.004, R + 0.004)
    exact = np.linalg.norm(pts, axis=1) - R
    errors = [np.abs(sample(sdf_lattice(v, t, h), v, pts)[0] - exact).max() for h in (0.04, 0.02)]
    assert errors[1] < 0.4 * errors[0]


def test_box_mesh_distance_and_inside():
    """A box's distance is exact at the lattice points in the band and its inside is the
    box: points more than a spacing from the surface are classified right."""
    lo, hi = np.array([-0.2, -0.1, -0.3]), np.array([0.2, 0.1, 0.3])
    box = trimesh.creation.box(bounds=[lo, hi])
    v, t = np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int64)
    h = 0.02
    lattice = sdf_lattice(v, t, h)
    p = lattice_points(lattice)
    q = np.abs(p - (lo + hi) / 2) - (hi - lo) / 2
    exact = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)
    band = np.abs(exact) < BAND_CELLS * h
    np.testing.assert_allclose(lattice.values[band], exact[band], atol=1e-12)
    rng = np.random.default_rng(1)
    pts = rng.uniform(lo - 0.1, hi + 0.1, (4000, 3))
    q = np.abs(pts - (lo + hi) / 2) - (hi - lo) / 2
    inside = np.all(q < 0, axis=1)
    clear = np.abs(np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)) > h
    d, _ = sample(lattice, v, pts)
    assert np.array_equal((d < 0)[clear], inside[clear])


def test_first_hit_on_a_sphere_mesh():
    v, t = sphere_mesh(4)
    h = 0.02
    fields, prm = table_row(sdf_lattice(v, t, h), v)
    normal = np.empty(3)
    a, e = (-0.5, 0.05, 0.02), (1.0, 0.0, 0.0)
    s = lattice_first_hit(fields, prm, a, e, normal)
    x_hit = a[0] + s * e[0]
    x_exact = -np.sqrt(R**2 - 0.05**2 - 0.02**2)
    assert abs(x_hit - x_exact) <= chord_error(v, t) + h * h / (4 * (R - h)) + 1e-9
    assert normal[0] < -0.95  # facing the incoming piece
    # a piece passing beside, one ending short, and one leaving from the surface: no hit
    assert lattice_first_hit(fields, prm, (-0.5, 0.35, 0.0), e, normal) == -1.0
    assert lattice_first_hit(fields, prm, (-0.5, 0.0, 0.0), (0.1, 0.0, 0.0), normal) == -1.0
    assert lattice_first_hit(fields, prm, (0.0, 0.0, 0.0), (0.5, 0.0, 0.0), normal) == -1.0


def test_first_hit_of_a_non_convex_mesh_is_the_nearest_surface():
    """Two spheres in one mesh: a piece through both stops at the first (a convex root search
    on the union's distance could return either)."""
    left = trimesh.creation.icosphere(subdivisions=3, radius=0.1).apply_translation([-0.2, 0, 0])
    right = trimesh.creation.icosphere(subdivisions=3, radius=0.1).apply_translation([0.2, 0, 0])
    both = trimesh.util.concatenate([left, right])
    v, t = np.asarray(both.vertices), np.asarray(both.faces, dtype=np.int64)
    fields, prm = table_row(sdf_lattice(v, t, 0.01), v)
    normal = np.empty(3)
    s = lattice_first_hit(fields, prm, (0.5, 0.0, 0.0), (-1.0, 0.0, 0.0), normal)
    assert 0.5 - s == pytest.approx(0.3, abs=2e-3)  # the right sphere's outer side
    s = lattice_first_hit(fields, prm, (0.0, 0.0, 0.0), (-0.5, 0.0, 0.0), normal)
    assert 0.5 * s == pytest.approx(0.1, abs=2e-3)  # from the gap: the left sphere's inner side
    assert normal[0] > 0.95
