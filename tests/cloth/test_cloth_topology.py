"""Constraint topology and the continuum-to-discrete stiffness mapping (windbench.cloth.topology).

The energies are checked against the continuum membrane and plate energies of a uniform
deformation, known in closed form: uniaxial strain (Y eps^2 / 2 per area), simple shear
(G gamma^2 / 2) and cylindrical bending (B kappa^2 / 2).
"""

import numpy as np
import pytest

from windbench.cloth.mesh import flag_mesh, shirt_mesh
from windbench.cloth.model import ClothModel
from windbench.cloth.solver import XPBDCloth
from windbench.cloth.topology import (
    build_topology,
    colour_order,
    dihedral_angles,
    tethers,
    thread_chains,
    triangle_areas,
)
from windbench.config import ClothConfig

W, H, NU, NV = 1.2, 0.8, 7, 5


def _flag(pin="pole"):
    spec = {"origin": [0, 0, 0], "size": [W, H], "resolution": [NU, NV], "pin": pin}
    spec.update(u_axis=[1, 0, 0], v_axis=[0, 1, 0])
    return flag_mesh(spec, "c")


def _solver(mesh, **material):
    cfg = ClothConfig()
    for k, v in material.items():
        setattr(cfg.material, k, v)
    return XPBDCloth(ClothModel.from_meshes([mesh]), (), cfg)


def test_lattice_counts_and_areas():
    mesh = _flag()
    t = build_topology(mesh.vertices, mesh.triangles)
    n_edges = NU * (NV - 1) + NV * (NU - 1) + (NU - 1) * (NV - 1)
    assert len(t.edges) == n_edges
    assert t.edge_shear.sum() == (NU - 1) * (NV - 1)  # one diagonal per cell
    boundary = 2 * (NU - 1) + 2 * (NV - 1)
    assert len(t.hinges) == n_edges - boundary
    assert t.vertex_area.sum() == pytest.approx(W * H)
    assert t.edge_area.sum() == pytest.approx(3 * W * H)  # each triangle counted per edge
    np.testing.assert_allclose(t.hinge_angle, 0.0, atol=1e-12)  # flat rest shape


def test_dihedral_angle_of_a_fold():
    # two unit right triangles sharing the edge x0-x1 on the y axis, folded by 60 degrees
    fold = np.radians(60.0)
    x = np.array([[0, 0, 0], [0, 1, 0], [-1, 0, 0], [np.cos(fold), 0, np.sin(fold)]], float)
    angle = dihedral_angles(x, np.array([[0, 1, 2, 3]]))[0]
    assert abs(angle) == pytest.approx(fold)  # 0 when flat


def _spring_energy(solver, x, shear: bool) -> float:
    """Sum of k dL^2 / 2 over the shear (or the stretch) edges at positions x."""
    t = solver.topology
    sel = t.edge_shear if shear else ~t.edge_shear
    d = t.edges[sel]
    dl = np.linalg.norm(x[d[:, 0]] - x[d[:, 1]], axis=1) - t.edge_length[sel]
    return 0.5 * np.sum(dl**2 * solver.stiffness.edge_k[sel])


def test_uniaxial_stretch_energy_matches_membrane_stiffness():
    mesh = _flag()
    y_mod, eps = 3000.0, 1e-4
    x = mesh.vertices * [1 + eps, 1, 1]
    energy = _spring_energy(_solver(mesh, stretch_stiffness=y_mod), x, shear=False)
    assert energy == pytest.approx(0.5 * y_mod * eps**2 * W * H, rel=1e-3)


def test_simple_shear_energy_matches_shear_stiffness():
    mesh = _flag()
    g_mod, gamma = 40.0, 1e-5
    x = mesh.vertices + np.outer(mesh.vertices[:, 1] * gamma, [1, 0, 0])
    energy = _spring_energy(_solver(mesh, shear_stiffness=g_mod), x, shear=True)
    assert energy == pytest.approx(0.5 * g_mod * gamma**2 * W * H, rel=1e-3)


def test_cylindrical_bending_energy_matches_bending_stiffness():
    mesh = _flag()
    b_mod = 2e-4
    s = _solver(mesh, bend_stiffness=b_mod)
    kappa = 0.5  # 1/m: the flag rolled around a cylinder of radius 2 m along its u axis
    u, v = mesh.vertices[:, 0], mesh.vertices[:, 1]
    x = np.stack([np.sin(kappa * u) / kappa, v, (1 - np.cos(kappa * u)) / kappa], axis=1)
    theta = dihedral_angles(x, s.topology.hinges)
    energy = 0.5 * np.sum(theta**2 * s.stiffness.hinge_k)
    hu = W / (NU - 1)
    # only the hinges on the NU - 2 interior v-lines bend, each carrying a cell column
    assert energy == pytest.approx(0.5 * b_mod * kappa**2 * (W - hu) * H, rel=1e-9)


def test_tethers_of_a_flag_run_straight_to_the_pole():
    mesh = _flag(pin="pole")
    t = build_topology(mesh.vertices, mesh.triangles)
    anchor, length, path = tethers(mesh.vertices, t.edges, mesh.pinned)
    assert np.all(anchor[mesh.pinned] == -1)
    free = np.setdiff1d(np.arange(NU * NV), mesh.pinned)
    np.testing.assert_allclose(length[free], mesh.vertices[free, 0])  # distance to the pole
    np.testing.assert_allclose(mesh.vertices[anchor[free], 1], mesh.vertices[free, 1])
    np.testing.assert_allclose(path[free], length[free])  # lattice rows are straight paths


def _chains(vertices, triangles, priority=None):
    t = build_topology(vertices, triangles)
    stretch = t.edges[~t.edge_shear]
    priority = np.zeros(len(stretch)) if priority is None else priority
    order, ptr, verts = thread_chains(vertices, stretch, priority)
    paths = [verts[ptr[c] + c : ptr[c + 1] + c + 1] for c in range(len(ptr) - 1)]
    for c, path in enumerate(paths):  # chain c's k-th edge joins its k-th and (k+1)-th vertex
        np.testing.assert_array_equal(
            np.sort(stretch[order[ptr[c] : ptr[c + 1]]], axis=1),
            np.sort(np.stack([path[:-1], path[1:]], axis=1), axis=1),
        )
    assert sorted(order.tolist()) == list(range(len(stretch)))  # every edge in one chain
    return stretch, paths


def test_thread_chains_of_a_lattice_are_its_warp_and_weft_threads():
    mesh = _flag(pin="pole")
    _, paths = _chains(mesh.vertices, mesh.triangles)
    ids = np.arange(NU * NV).reshape(NU, NV)
    threads = {tuple(r) for r in ids} | {tuple(c) for c in ids.T}  # warp and weft
    assert len(paths) == NU + NV
    assert {tuple(p) if p[0] < p[-1] else tuple(p[::-1]) for p in paths} == threads


def _shirt_spec():
    return dict(
        collar=[0, 0, 1.5],
        radius=0.2,
        length=0.5,
        resolution=[24, 11],
        shoulder_width=0.6,
        sleeve_radius=0.08,
        sleeve_length=0.2,
        sleeve_angle=20.0,
    )


def test_thread_chains_of_the_shirt_are_straight_simple_paths():
    mesh = shirt_mesh(_shirt_spec(), "c")
    stretch, paths = _chains(mesh.vertices, mesh.triangles)
    x = mesh.vertices
    for path in paths:
        assert len(np.unique(path)) == len(path)  # a simple path: no vertex twice
        d = np.diff(x[path], axis=0)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        assert np.all(np.einsum("ij,ij->i", d[:-1], d[1:]) > 0.5)  # turns under 60 degrees
    # torso: 24 lines of 10 edges along, 11 hoops = a path of 23 edges + a closing edge;
    # each sleeve: 10 lines of 4 edges, 5 hoops of 9 + 1
    lengths = sorted(len(p) - 1 for p in paths)
    expected = [1] * (11 + 2 * 5) + [4] * 20 + [9] * 10 + [10] * 24 + [23] * 11
    assert lengths == expected


def test_shirt_tubes_are_closed_and_hang_from_their_top_rings():
    mesh = shirt_mesh(_shirt_spec(), "c")
    t = build_topology(mesh.vertices, mesh.triangles)
    # closed tubes: the lateral area is 2 pi r l (up to the polygon's chord factor)
    torso = 24 * 11
    area_torso = triangle_areas(mesh.vertices, mesh.triangles[: 2 * 24 * 10]).sum()
    chord = 24 * np.sin(np.pi / 24) / np.pi
    assert area_torso == pytest.approx(2 * np.pi * 0.2 * 0.5 * chord, rel=1e-9)
    # every interior hinge of a tube bends by the polygon's outer angle 2 pi / n_around
    ring = np.abs(t.hinge_angle[(t.hinges < torso).all(axis=1)])
    assert np.isclose(ring, 0.0).any() and np.isclose(ring.max(), 2 * np.pi / 24)
    assert np.allclose(mesh.vertices[mesh.pinned[:24], 2], 1.5)  # torso collar ring
    sleeve_pins = mesh.vertices[mesh.pinned[24:]]  # the armholes: rings of radius 0.08
    centre = np.where(sleeve_pins[:, 1:2] > 0, [0, 0.3, 1.5], [0, -0.3, 1.5])
    np.testing.assert_allclose(np.linalg.norm(sleeve_pins - centre, axis=1), 0.08)
    assert len(sleeve_pins) == 2 * 10  # 2 round(pi r_s / (2 pi r / 24)) = 10 around each


def test_colour_order_of_a_chain_alternates():
    chain = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    order, colour = colour_order(chain, np.arange(4.0))
    assert order.tolist() == [0, 2, 1, 3] and colour.tolist() == [0, 0, 1, 1]
    order, colour = colour_order(chain, np.arange(4.0), group=np.array([0, 0, 1, 1]))
    assert order.tolist() == [0, 1, 2, 3] and colour.tolist() == [0, 1, 0, 1]


def test_colour_order_is_a_greedy_colouring_of_the_hinges():
    mesh = _flag(pin="pole")
    t = build_topology(mesh.vertices, mesh.triangles)
    priority = np.random.default_rng(0).permutation(len(t.hinges)).astype(float)
    order, colour = colour_order(t.hinges, priority)
    assert sorted(order.tolist()) == list(range(len(t.hinges)))
    assert np.all(np.diff(colour) >= 0)
    for c in np.unique(colour):
        rows = order[colour == c]
        assert np.all(np.diff(priority[rows]) > 0)  # by priority within a colour
        assert len(np.unique(t.hinges[rows])) == 4 * len(rows)  # no shared vertex
        # greedy: every hinge of colour c > 0 meets an earlier hinge of each smaller colour
        for k in rows if c > 0 else []:
            for lower in range(c):
                earlier = order[(colour == lower) & (priority[order] < priority[k])]
                assert np.isin(t.hinges[earlier], t.hinges[k]).any()


def _jittered(mesh, seed=3, amount=0.2):
    """The flag with its interior vertices moved in its plane by up to ``amount`` of a cell:
    the same triangles, no longer halves of rectangles."""
    rng = np.random.default_rng(seed)
    x = mesh.vertices.copy()
    ids = np.arange(NU * NV).reshape(NU, NV)[1:-1, 1:-1].ravel()
    cell = np.array([W / (NU - 1), H / (NV - 1)])
    x[ids, :2] += amount * cell * rng.uniform(-1, 1, (ids.size, 2))
    return x


def test_only_lattices_have_shear_edges():
    """A flag and a tube shirt are lattices (right triangles): one shear diagonal per cell.
    Moving the flag's inner vertices makes it irregular: every edge is a stretch edge. In a
    model of both, each cloth keeps its own kind."""
    mesh = _flag()
    tube = shirt_mesh(
        {"collar": [0, 0, 1], "radius": 0.2, "length": 0.5, "resolution": [12, 6]}
        | {"shoulder_width": 0.5, "sleeve_radius": 0.08, "sleeve_length": 0.2},
        "s",
    )
    for m in (mesh, tube):
        t = build_topology(m.vertices, m.triangles)
        assert t.edge_lattice.all() and t.edge_shear.sum() == m.triangles.shape[0] // 2
    jitter = _jittered(mesh)
    t = build_topology(jitter, mesh.triangles)
    assert not t.edge_lattice.any() and not t.edge_shear.any()
    both = np.concatenate([mesh.vertices, jitter])
    tris = np.concatenate([mesh.triangles, mesh.triangles + NU * NV])
    cloth = np.repeat([0, 1], mesh.triangles.shape[0])
    t = build_topology(both, tris, cloth)
    first = t.edges[:, 0] < NU * NV
    assert t.edge_lattice[first].all() and not t.edge_lattice[~first].any()
    assert t.edge_shear.sum() == (NU - 1) * (NV - 1)


@pytest.mark.parametrize("limit", [0.0, 0.03])
def test_irregular_cloth_keeps_the_strain_limit_hanging_from_its_pins(limit):
    """The jittered flag of a soft membrane (Y = 5 N/m: its weight alone stretches it by
    some 25 %) hung by its two top corners in still air for 2 s: with the limit no edge is
    longer than the limit's trigger, (1 + 1.1 limit) L; without it they are."""
    from tests.cloth.test_cloth_solver import _run

    mesh = _flag(pin="top_corners")
    soft = {"stretch_stiffness": 5.0}
    cloth = ClothModel.from_meshes(
        [type(mesh)("c", _jittered(mesh), mesh.triangles, mesh.pinned, soft)]
    )
    cfg = ClothConfig()
    cfg.strain_limit = limit
    solver = XPBDCloth(cloth, (), cfg)
    c = solver.tables.constraints
    assert c.n_lattice == 0 and c.n_stretch == len(solver.topology.edges)
    state, _ = _run(solver, cloth, 120, air=True)
    assert state.positions[:, 2].min() < -0.5  # it hangs
    stretch = solver.max_stretch(state.positions)
    assert stretch <= 0.033 + 1e-9 if limit else stretch > 0.1
