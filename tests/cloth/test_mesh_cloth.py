"""Cloths of ``type: mesh`` (a garment file) and cloth against mesh bodies."""

import numpy as np
import pytest
import trimesh

from windbench.cli import compose_config
from windbench.cloth.mesh import file_mesh, flag_mesh, mesh_from_config
from windbench.cloth.model import ClothModel
from windbench.cloth.solver import XPBDCloth
from windbench.errors import ConfigError
from windbench.geometry import character
from windbench.geometry.bodies import body_from_config
from windbench.geometry.triangle_mesh import boundary_loops
from windbench.scenes import build_scene

R = 0.3


@pytest.fixture(scope="module")
def sphere_body(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "ball.ply"
    trimesh.creation.icosphere(subdivisions=4, radius=R).export(path)
    return body_from_config({"type": "mesh", "file": str(path), "offset": [0, 0, 1]}, "ball")


def test_a_cloth_draped_on_a_mesh_sphere_never_enters_it(sphere_body):
    """A square cloth dropped on a sphere mesh: at every frame each vertex stays outside the
    analytic sphere (the mesh lies within 0.35 mm of it and the lattice adds 0.1 mm, under
    the 5 mm margin), and the cloth comes to rest on the sphere's top, draped around it."""
    cfg = compose_config(["scene=empty"])
    spec = {"origin": [-0.4, -0.4, 1.35], "size": [0.8, 0.8], "resolution": [21, 21], "pin": "none"}
    spec.update(u_axis=[1, 0, 0], v_axis=[0, 1, 0])
    model = ClothModel.from_meshes([flag_mesh(spec, "cloth")])
    solver = XPBDCloth(model, (sphere_body,), cfg.cloth)
    state = model.initial_state()
    zero = np.zeros_like(state.positions)
    closest = np.inf
    for _ in range(120):
        state = solver.step(state, zero, 1 / 60)
        closest = min(closest, (np.linalg.norm(state.positions - [0, 0, 1], axis=1) - R).min())
    assert closest > 0.0
    top = state.positions[10 * 21 + 10]
    margin = cfg.cloth.collision_margin
    assert top[2] == pytest.approx(1 + R + margin, abs=1.5e-3)
    assert state.positions[:, 2].min() < 1 + R - 0.15  # the edges hang down its sides
    assert solver.stats(state)["max_penetration"] == 0.0


def test_the_shirt_cloth_is_the_garment_file_placed_on_the_character():
    scene = build_scene(compose_config(["scene=shirt"]).scene)
    (body,) = scene.bodies
    (shirt,) = scene.cloths
    assert body.kind == "mesh" and shirt.name == "shirt"
    loops = boundary_loops(shirt.triangles)
    assert len(loops) == 4  # collar, hem, two cuffs
    assert shirt.pinned.size == 0  # it hangs on the shoulders
    assert body.distance(shirt.vertices)[0].min() > 0.01
    centre = shirt.vertices[np.concatenate(loops)].mean(axis=0)
    np.testing.assert_allclose(centre[:2], [1.5, 1.5], atol=1e-6)  # offset: [1.5, 1.5, 0]


def test_top_loop_pins_the_collar():
    spec = {"type": "mesh", "file": "mesh/shirt.obj", "pin": "top_loop"}
    mesh = mesh_from_config(spec, "scene.cloths[0]")
    np.testing.assert_allclose(mesh.vertices[mesh.pinned, 2], character.COLLAR, atol=1e-6)
    collar = np.flatnonzero(np.isclose(mesh.vertices[:, 2], character.COLLAR, atol=1e-6))
    assert mesh.pinned.tolist() == collar.tolist()


def test_quads_are_split_and_ids_kept(tmp_path):
    """An OBJ of two quads: four triangles on the file's six vertices, in the file's order."""
    text = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nv 1 1 0\nv 2 1 0\nf 1 2 5 4\nf 2 3 6 5\n"
    (tmp_path / "strip.obj").write_text(text)
    mesh = file_mesh({"file": str(tmp_path / "strip.obj"), "pin": [3, 5]}, "c")
    assert mesh.triangles.shape == (4, 3)
    np.testing.assert_allclose(mesh.vertices[3], [0, 1, 0])
    assert mesh.pinned.tolist() == [3, 5]
    assert len(boundary_loops(mesh.triangles)) == 1


def test_a_vertex_of_no_triangle_is_refused(tmp_path):
    lone = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], [[0, 1, 2]], process=False)
    lone.export(tmp_path / "lone.ply")
    with pytest.raises(ConfigError) as err:
        file_mesh({"file": str(tmp_path / "lone.ply")}, "c")
    assert err.value.key == "c.file" and "no mass" in err.value.message


@pytest.mark.parametrize(
    ("text", "spec", "key", "words"),
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", {"pin": "collar"}, "c.pin", "top_loop"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", {"pin": [3]}, "c.pin", "[0, 2]"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", {"size": 1}, "c", "unknown key"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n",
            {},
            "c.file",
            "manifold",
        ),
    ],
)
def test_bad_garment_files_and_keys_name_the_key(tmp_path, text, spec, key, words):
    (tmp_path / "c.obj").write_text(text)
    with pytest.raises(ConfigError) as err:
        file_mesh({"type": "mesh", "file": str(tmp_path / "c.obj"), **spec}, "c")
    assert err.value.key == key and words in err.value.message
