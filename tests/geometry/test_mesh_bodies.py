"""Bodies of ``type: mesh`` read from files: placement, the table the kernels read, the
dispatch in the cloth contacts and the particle hits, and the one-line errors."""

import numpy as np
import pytest
import trimesh

from windbench.errors import ConfigError
from windbench.geometry.bodies import (
    CAPSULE,
    body_from_config,
    body_table,
    distances,
    inside,
)
from windbench.geometry.triangle_mesh import boundary_loops, read_mesh
from windbench.wind.particles.tracing import first_body_hit

R = 0.3


@pytest.fixture(scope="module")
def sphere_file(tmp_path_factory):
    """An icosphere of radius 0.3 about the origin as an unmerged STL (corners stored apart)."""
    path = tmp_path_factory.mktemp("mesh") / "sphere.stl"
    trimesh.creation.icosphere(subdivisions=4, radius=R).export(path)
    return path


def test_stl_corners_are_merged_and_placed(sphere_file):
    v, t = read_mesh({"file": str(sphere_file), "scale": 2.0, "offset": [1, 2, 3]}, "k")
    assert len(v) == 2562 and len(t) == 5120  # the icosphere's own counts, not 3 x 5120
    np.testing.assert_allclose(np.linalg.norm(v - [1, 2, 3], axis=1), 2 * R, rtol=1e-6)
    assert boundary_loops(t) == []


def test_a_mesh_body_is_the_sphere_it_was_made_of(sphere_file):
    """Distance and normal of a mesh body against the analytic sphere, placed by offset."""
    spec = {"type": "mesh", "file": str(sphere_file), "offset": [1.0, 1.0, 1.0], "spacing": 0.01}
    body = body_from_config(spec, "scene.bodies[0]")
    lo, hi = body.bounds()
    np.testing.assert_allclose(lo, 1 - R, atol=1e-6)
    np.testing.assert_allclose(hi, 1 + R, atol=1e-6)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = 1.0 + d * rng.uniform(R - 0.02, R + 0.02, 500)[:, None]
    dist, normal = body.distance(pts)
    exact = np.linalg.norm(pts - 1.0, axis=1) - R
    assert np.abs(dist - exact).max() < 1e-3  # chord 0.35 mm + h^2/(4 R) 0.09 mm
    assert np.einsum("ij,ij->i", normal, d).min() > 0.99
    # far outside the lattice: the distance to the mesh's bounding box, a lower bound
    far, _ = body.distance([[3.0, 1.0, 1.0]])
    assert far[0] == pytest.approx(2.0 - R, abs=1e-6)


def test_the_table_holds_mesh_lattices_after_analytic_rows(sphere_file):
    box = body_from_config({"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]}, "b")
    mesh = {"type": "mesh", "file": str(sphere_file), "offset": [3, 0, 0], "spacing": 0.02}
    bodies = [
        box,
        body_from_config(mesh, "m"),
        body_from_config({**mesh, "offset": [0, 3, 0]}, "m"),
    ]
    table = body_table(bodies)
    assert table.kinds.tolist() == [0, 4, 4]
    assert table.params[1, 0] == 0 and table.params[2, 0] == table.fields.size // 2
    p = np.array([[0.5, 0.5, 0.5], [3.0, 0.0, 0.0], [0.0, 3.0, 0.29], [3.0, 3.0, 3.0]])
    assert inside(bodies, p).tolist() == [True, True, True, False]


def test_particles_hit_a_mesh_sphere_where_they_hit_the_analytic_one(sphere_file):
    """The tracing's hit dispatch: a mesh sphere and a capsule of zero length (a sphere)."""
    mesh = body_from_config({"type": "mesh", "file": str(sphere_file), "spacing": 0.01}, "m")
    ball = body_from_config({"type": "capsule", "a": [0, 0, 0], "b": [0, 0, 0], "radius": R}, "c")
    table = body_table([mesh, ball])
    assert table.kinds[1] == CAPSULE
    rng = np.random.default_rng(2)
    scratch, n_mesh, n_ball = np.empty((2, 3)), np.empty(3), np.empty(3)
    hits = 0
    for _ in range(200):
        a = tuple(rng.uniform(-0.5, 0.5, 3))
        e = tuple(-rng.uniform(0.2, 1.0) * np.asarray(a) + rng.normal(0.0, 0.1, 3))
        if np.linalg.norm(a) < R:
            continue
        s_mesh = first_body_hit(table, 0, a, e, scratch, n_mesh)
        s_ball = first_body_hit(table, 1, a, e, scratch, n_ball)
        length = np.linalg.norm(e)
        if s_ball >= 0 and s_mesh >= 0:
            hits += 1
            assert abs(s_mesh - s_ball) * length < 2e-3
            assert n_mesh @ n_ball > 0.98
        else:  # only a graze within the mesh's 0.4 mm of the sphere may differ
            s = max(s_ball, s_mesh)
            if s >= 0:
                p = np.asarray(a) + s * np.asarray(e)
                assert abs(np.linalg.norm(p) - R) < 1e-3
    assert hits > 50


def test_an_inside_out_mesh_is_turned_the_right_way(tmp_path):
    s = trimesh.creation.icosphere(subdivisions=2, radius=R)
    s.invert()
    s.export(tmp_path / "inverted.ply")
    body = body_from_config({"type": "mesh", "file": str(tmp_path / "inverted.ply")}, "b")
    assert body.distance([[0.0, 0.0, 0.0]])[0][0] < -0.25


@pytest.mark.parametrize(
    ("spec", "key", "words"),
    [
        ({"file": "nowhere.stl"}, "scene.bodies[0].file", "no such file"),
        ({"file": "body.xyz"}, "scene.bodies[0].file", "OBJ, PLY or STL"),
        ({"file": "open.stl"}, "scene.bodies[0].file", "boundary edge"),
        ({"file": "garbage.obj"}, "scene.bodies[0].file", "no triangles"),
        ({"file": "sphere.stl", "spacing": 0}, "scene.bodies[0].spacing", "> 0"),
        ({"file": "sphere.stl", "scale": -1}, "scene.bodies[0].scale", "> 0"),
        ({"file": "sphere.stl", "offset": [1, 2]}, "scene.bodies[0].offset", "3 finite"),
        ({"file": "sphere.stl", "radius": 1}, "scene.bodies[0]", "unknown key"),
    ],
)
def test_bad_mesh_bodies_name_the_key(tmp_path, monkeypatch, spec, key, words):
    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / "sphere.stl")
    half = trimesh.creation.icosphere(subdivisions=1)
    half.update_faces(half.triangles_center[:, 2] > 0)
    half.export(tmp_path / "open.stl")
    (tmp_path / "garbage.obj").write_text("this is not a mesh\n")
    monkeypatch.chdir(tmp_path)  # relative names: the current folder first
    with pytest.raises(ConfigError) as err:
        body_from_config({"type": "mesh", **spec}, "scene.bodies[0]")
    assert err.value.key == key and words in err.value.message


def test_distances_of_mixed_bodies_take_the_nearest(sphere_file):
    mesh = body_from_config({"type": "mesh", "file": str(sphere_file)}, "m")
    plane = body_from_config({"type": "plane", "point": [0, 0, -1], "normal": [0, 0, 1]}, "p")
    d, n = distances([mesh, plane], [[0.0, 0.0, -0.9], [0.0, 0.0, 0.4]])
    assert d[0] == pytest.approx(0.1) and n[0].tolist() == [0.0, 0.0, 1.0]
    assert d[1] == pytest.approx(0.1, abs=1e-3) and n[1][2] > 0.99
