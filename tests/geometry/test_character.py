"""The character and shirt the project ships (conf/mesh/): one closed body with no floating
part, one manifold shirt with collar, hem and two cuffs, both from the fields they were
made of (windbench/geometry/character.py)."""

import numpy as np
import pytest

from windbench.geometry import character
from windbench.geometry.bodies import body_from_config
from windbench.geometry.triangle_mesh import (
    boundary_loops,
    components,
    edge_counts,
    read_mesh,
    signed_volume,
)

BODY = {"file": "mesh/character.ply"}
SHIRT = {"file": "mesh/shirt.obj"}


@pytest.fixture(scope="module")
def body():
    return read_mesh(BODY, "body")


@pytest.fixture(scope="module")
def shirt():
    return read_mesh(SHIRT, "shirt")


def test_the_body_is_one_closed_surface(body):
    v, t = body
    _, counts, repeated = edge_counts(t)
    assert np.all(counts == 2) and repeated == 0  # closed, consistently oriented
    assert components(len(v), t).max() == 0  # one piece: head on a neck, no floating part
    assert 0.06 < signed_volume(v, t) < 0.09  # m^3: a person of 60-90 kg
    assert v[:, 2].min() == pytest.approx(0.0, abs=0.01)  # standing on z = 0
    assert v[:, 2].max() == pytest.approx(1.72 + 0.095, abs=0.01)  # the head's top


def test_the_body_mesh_lies_on_its_field(body):
    """Every vertex on the smooth-union level set (marching cubes + projection)."""
    v, _ = body
    assert np.abs(character.body_field(v)).max() < 1e-4


def test_the_shirt_is_one_manifold_piece_with_collar_hem_and_cuffs(shirt):
    v, t = shirt
    edges, counts, repeated = edge_counts(t)
    assert counts.max() == 2 and repeated == 0  # manifold, consistently oriented
    assert components(len(v), t).max() == 0  # torso and sleeves stitched: one piece
    assert len(v) - len(edges) + len(t) == 2 - 4  # Euler: a sphere with four holes
    loops = sorted(boundary_loops(t), key=lambda ids: v[ids, 2].mean())
    assert len(loops) == 4
    hem, cuff_a, cuff_b, collar = (v[ids] for ids in loops)
    np.testing.assert_allclose(hem[:, 2], character.HEM, atol=1e-6)
    np.testing.assert_allclose(collar[:, 2], character.COLLAR, atol=1e-6)
    assert np.abs(collar[:, :2]).max() < 0.12  # around the neck
    for cuff in (cuff_a, cuff_b):  # across an arm, SLEEVE from its shoulder joint
        side = np.sign(cuff[:, 1].mean())
        joint = character.SHOULDER * [1, side, 1]
        arm = character.ARM * [1, side, 1]
        np.testing.assert_allclose((cuff - joint) @ arm, character.SLEEVE, atol=1e-6)
    assert {round(cuff_a[:, 1].mean(), 6), round(cuff_b[:, 1].mean(), 6)} == {
        round(-cuff_b[:, 1].mean(), 6),
        round(cuff_b[:, 1].mean(), 6),
    }


def test_the_shirt_is_mirror_symmetric(shirt):
    v, _ = shirt
    key = {tuple(p) for p in np.round(v, 6)}
    for axis in (0, 1):
        image = v.copy()
        image[:, axis] *= -1
        assert {tuple(p) for p in np.round(image, 6) + 0.0} == key


def test_the_shirt_starts_off_the_skin(shirt):
    """Every shirt vertex lies outside the body mesh by more than the cloth's margin."""
    v, _ = shirt
    body = body_from_config({"type": "mesh", **BODY}, "body")
    assert body.distance(v)[0].min() > 0.01
    assert np.abs(character.garment_field(v)).max() < 1e-5  # on its level set


def test_triangles_are_fit_for_a_cloth_solver(shirt):
    v, t = shirt
    x = v[t]
    angles = []
    for k in range(3):
        a, b = x[:, (k + 1) % 3] - x[:, k], x[:, (k + 2) % 3] - x[:, k]
        cos = np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        angles.append(np.degrees(np.arccos(cos)))
    smallest = np.min(angles, axis=0)
    assert smallest.min() > 10 and np.median(smallest) > 40
    assert 3500 < len(v) < 4700  # about a 64 x 64 cloth


@pytest.mark.slow
def test_the_shipped_meshes_are_what_the_generator_makes(tmp_path, body, shirt):
    character.main(["--out", str(tmp_path)])
    for name, shipped in (("character.ply", body), ("shirt.obj", shirt)):
        v, t = read_mesh({"file": str(tmp_path / name)}, name)
        assert t.shape == shipped[1].shape
        np.testing.assert_allclose(v, shipped[0], atol=2e-6)
