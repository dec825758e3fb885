"""Cloth edges and triangles against bodies, self-collision and the intersection figure.

Reference answers: the distance from a segment to a line (closed form), a pole's radius as
the depth of an edge laid through its axis, two triangles known to cross or not, and the
geometry of sheets falling onto a plane (a fold, a stack) that must not interpenetrate.
"""

import numpy as np
import pytest

from windbench.cloth.collision import max_penetration
from windbench.cloth.edge_contact import edge_minimum, surface_penetration
from windbench.cloth.mesh import flag_mesh
from windbench.cloth.model import ClothModel, ClothState
from windbench.cloth.self_contact import (
    _BRIDGE,
    _COS_CONTACT,
    _NEVER_FLAT,
    _ROOT,
    LEAF,
    TASKS_PER_THREAD,
    _adjacent,
    _edges_close,
    _vertex_near_triangle,
    close_pairs,
    contact_pairs,
    descend,
    grow_by_moves,
    leaf_pairs,
    live_patches,
    pair_reach,
    pass_due,
    patch_tree,
    push_edges,
    refit,
    self_contact_model,
    self_contact_substep,
    self_contacts,
    self_intersections,
    tree_fit,
    triangles_cross,
    untangle,
    vertex_moves,
    vertex_rings,
)
from windbench.cloth.solver import XPBDCloth
from windbench.config import ClothConfig
from windbench.errors import ConfigError
from windbench.geometry.bodies import body_from_config, body_table

pytestmark = pytest.mark.heavy  # compiles the frame kernel with self-collision

DT = 1.0 / 60.0
POLE = {"type": "capsule", "a": [0.0, -1.0, 0.0], "b": [0.0, 1.0, 0.0], "radius": 0.01}


def _sheet(origin, size, n, u=(1, 0, 0), v=(0, 1, 0), name="c"):
    spec = {"origin": list(origin), "size": [size, size], "resolution": [n, n], "pin": "none"}
    spec.update(u_axis=list(u), v_axis=list(v))
    return flag_mesh(spec, name)


def _frames(solver, state, frames, force=None):
    """The states of ``frames`` frames under gravity (and a constant ``force`` per vertex)."""
    f = (
        np.zeros_like(state.positions)
        if force is None
        else np.tile(force, (state.positions.shape[0], 1))
    )
    out = []
    for _ in range(frames):
        state = solver.step(state, f, DT)
        out.append(state)
    return out


def test_edge_minimum_finds_the_point_of_a_segment_nearest_to_a_pole():
    """Segment (x, y0 + k x, z0) against the capsule on the y axis: the distance from the
    point at x is sqrt(x^2 + z0^2) - r, smallest at x = 0 (t where the segment crosses x = 0)."""
    body = body_from_config(POLE, "pole")
    table = body_table((body,))
    pa, pb = np.array([-0.13, 0.1, 0.02]), np.array([0.27, 0.3, 0.02])
    t, phi = edge_minimum(table, 0, pa, pb, np.empty(3))
    assert t == pytest.approx(0.13 / 0.4, abs=1e-4)
    assert phi == pytest.approx(0.02 - 0.01, abs=1e-7)


def test_penetration_figure_catches_an_edge_through_a_pole_that_vertices_miss():
    """A square (2 x 2 vertices) laid across the pole's axis: every vertex lies 0.15 m and
    more from the pole, but its edges and triangles pass through the axis: depth = radius."""
    model = ClothModel.from_meshes([_sheet((-0.15, -0.17, 0.0), 0.3, 2)])
    body = body_from_config(POLE, "pole")
    solver = XPBDCloth(model, (body,), ClothConfig())
    bodies, boxes, _, _ = solver.tables.contacts
    x = model.rest_positions
    assert max_penetration(bodies, boxes, x) == 0.0
    edges = solver.tables.constraints.edges
    tris = solver.tables.self_contact.triangles
    w = solver.tables.constraints.inv_mass
    assert surface_penetration(bodies, boxes, x, edges, tris, w) == pytest.approx(0.01, abs=1e-5)
    assert solver.stats(model.initial_state())["max_penetration"] == pytest.approx(0.01, abs=1e-5)


def test_an_edge_sliding_over_a_thin_pole_never_enters_it():
    """A square of 2 x 2 vertices (its edges 0.3 m long) falls across a 0.01 m pole and is
    pushed along x: it first rests on the pole at the margin (vertex contacts alone let it
    fall straight through: 0.09 m lower by frame 8), then slides over it and falls off the
    far side; no vertex ever comes near the pole, yet no edge or triangle ever enters it."""
    model = ClothModel.from_meshes([_sheet((-0.15, -0.15, 0.05), 0.3, 2)])
    body = body_from_config(POLE, "pole")
    cfg = ClothConfig()
    solver = XPBDCloth(model, (body,), cfg)
    mass = solver.tables.constraints.mass[0]
    states = _frames(solver, model.initial_state(), 60, force=(0.05 * 9.81 * mass, 0.0, 0.0))
    for state in states:
        assert solver.stats(state)["max_penetration"] == 0.0
    for state in states[4:10]:  # resting across the pole, at its radius plus the margin
        np.testing.assert_allclose(state.positions[:, 2], 0.01 + cfg.collision_margin, atol=0.01)
    x = states[-1].positions
    assert x[:, 0].min() > 0.0 and x[:, 2].max() < -0.5  # slid over it and fell off


def test_intersection_counter_counts_a_known_crossing():
    """Two triangles piercing each other: 1 pair; moved apart: 0; sharing a vertex: 0."""
    x = np.array(
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.2, 0.2, -0.5],
            [0.2, 0.2, 0.5],
            [0.8, 0.9, 0.0],
        ]
    )
    crossing = self_contact_model(x, np.array([[0, 1, 2], [3, 4, 5]]), 0.01)
    assert self_intersections(crossing, x) == 1
    apart = x.copy()
    apart[3:, 0] += 3.0
    assert self_intersections(crossing, apart) == 0
    fan = self_contact_model(x, np.array([[0, 1, 2], [0, 4, 3]]), 0.01)
    assert self_intersections(fan, x) == 0  # adjacent (a common vertex): not counted


def _fold_run(self_collision, frames=150):
    """A 0.6 m square sheet standing on its edge, tilted, dropped onto the floor: it buckles
    and folds over onto itself."""
    mesh = _sheet((0.0, 0.0, 0.02), 0.6, 16, u=(1, 0, 0), v=(0, 0.3, 1.0))
    model = ClothModel.from_meshes([mesh])
    floor = body_from_config({"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}, "f")
    cfg = ClothConfig()
    cfg.self_collision = self_collision
    solver = XPBDCloth(model, (floor,), cfg)
    states = _frames(solver, model.initial_state(), frames)
    return solver, model, [solver.stats(s)["self_intersections"] for s in states], states


def test_a_sheet_folding_onto_itself_never_intersects():
    solver, model, counts, states = _fold_run(True)
    assert max(counts) == 0
    z = states[-1].positions[:, 2]
    assert z.max() < 0.15  # it did fold down onto the floor
    _, _, counts_off, _ = _fold_run(False)
    assert max(counts_off) > 0  # without self-collision the same fold passes through itself


def test_two_sheets_dropped_onto_each_other_do_not_interpenetrate():
    """Sheet A falls onto sheet B lying on the floor (turned 30 degrees against it, so no
    vertex lines up): no triangle pair intersects, and A ends above B by the thickness."""
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    lower = _sheet((-0.25, -0.25, 0.01), 0.5, 12, name="b")
    upper = _sheet(
        (-0.2 * c + 0.2 * s, -0.2 * s - 0.2 * c, 0.2), 0.4, 10, u=(c, s, 0), v=(-s, c, 0)
    )
    model = ClothModel.from_meshes([lower, upper])
    floor = body_from_config({"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}, "f")
    cfg = ClothConfig()
    cfg.self_collision = True
    solver = XPBDCloth(model, (floor,), cfg)
    states = _frames(solver, model.initial_state(), 60)
    assert max(solver.stats(state)["self_intersections"] for state in states) == 0
    x = states[-1].positions
    n_lower = lower.n_vertices
    centre = np.linalg.norm(x[n_lower:, :2], axis=1) < 0.1
    below = np.linalg.norm(x[:n_lower, :2], axis=1) < 0.1
    assert x[n_lower:][centre, 2].min() > x[:n_lower][below, 2].max() + 0.5 * cfg.thickness


@pytest.mark.parametrize(("key", "value"), [("thickness", 0.0), ("self_collision", "yes")])
def test_a_bad_self_contact_key_is_named(key, value):
    model = ClothModel.from_meshes([_sheet((0, 0, 0), 0.3, 3)])
    cfg = ClothConfig()
    setattr(cfg, key, value)
    with pytest.raises(ConfigError, match=f"cloth.{key}"):
        XPBDCloth.check(model, cfg)


def _crumpled(n=9, seed=3):
    """A sheet of n x n vertices crumpled by random smooth bumps and a fold: its triangles
    cross each other in places."""
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 1.0, n)])
    x = model.rest_positions.copy()
    rng = np.random.default_rng(seed)
    x += 0.15 * rng.standard_normal(x.shape)
    return model, x


def _brute_force_crossings(triangles, x):
    """Every pair of triangles without a common vertex, the exact segment test."""
    count = 0
    for f in range(len(triangles)):
        for g in range(f + 1, len(triangles)):
            if set(triangles[f]) & set(triangles[g]):
                continue
            count += bool(triangles_cross(x, triangles[f], triangles[g]))
    return count


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_patch_hierarchy_counts_the_crossings_a_brute_force_search_finds(seed):
    """Culling by boxes and 90-degree normal cones loses no crossing pair: the count equals
    the all-pairs search on randomly crumpled sheets (which cross themselves in many
    places), on one thread and split into tasks for two threads."""
    model, x = _crumpled(seed=seed)
    sc = self_contact_model(model.rest_positions, model.triangles, 0.005)
    expected = _brute_force_crossings(sc.triangles, x)
    assert expected > 5
    assert self_intersections(sc, x) == expected
    assert self_intersections(sc._replace(threads=2), x) == expected


def test_the_threads_find_the_serial_search_pairs_in_its_order():
    """The contacts' search split into tasks for numba's threads (:func:`contact_pairs` of a
    model with a task limit) returns the one-thread search's vertex-triangle and edge pairs
    in the same order, so the pushes and the bits are the same: a 46 x 46 sheet (4050
    triangles, above PARALLEL_TRIANGLES) folded onto itself 4 mm apart and jittered."""
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 1.0, 46)])
    x = model.rest_positions.copy()
    upper = x[:, 1] > 0.5
    x[upper, 1], x[upper, 2] = 1.0 - x[upper, 1], 0.004
    x += np.random.default_rng(3).normal(0.0, 0.002, x.shape)
    one = self_contact_model(model.rest_positions, model.triangles, 0.005)
    two = self_contact_model(model.rest_positions, model.triangles, 0.005, threads=2)
    assert one.threads == 1 and two.threads == 2
    fit = tree_fit(one, x.shape[0])
    refit(one.tree, one.triangles, x, fit)
    limit = np.int64(4050 // (2 * TASKS_PER_THREAD))
    bounds = (fit.box, fit.dop, fit.cone, fit.live)
    args = (bounds, _COS_CONTACT, 0.02, _BRIDGE, _ROOT, _ROOT, limit, fit.stack)
    assert descend(two.tree, *args)[1] > 20  # tasks
    vt, ee = contact_pairs(one, x, fit, 0.02, 0.02)
    assert len(vt) > 100 and len(ee) > 100
    vt_2, ee_2 = contact_pairs(two, x, fit, 0.02, 0.02)
    np.testing.assert_array_equal(vt_2, vt)
    np.testing.assert_array_equal(ee_2, ee)


def test_a_search_from_the_pushed_patches_finds_every_pair_with_a_pushed_vertex():
    """:func:`live_patches` marks exactly the patches that hold a pushed vertex, and the
    search from them (a pass's second sweep) finds every close pair of the whole search
    that has a pushed vertex, and fewer pairs in all: a sheet folded onto itself."""
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 1.0, 17)])
    x = model.rest_positions.copy()
    upper = x[:, 1] > 0.5
    x[upper, 1], x[upper, 2] = 1.0 - x[upper, 1], 0.004
    sc = self_contact_model(model.rest_positions, model.triangles, 0.005)
    fit = tree_fit(sc, x.shape[0])
    refit(sc.tree, sc.triangles, x, fit)
    vt, ee = contact_pairs(sc, x, fit, 0.02, 0.02)
    pushed = np.zeros(x.shape[0], np.bool_)
    pushed[np.random.default_rng(5).choice(x.shape[0], 12, replace=False)] = True
    live_patches(sc.tree, pushed, fit.live)
    tree, tri, edges = sc.tree, sc.triangles, sc.tree.leaf_edge
    for k in range(len(tree.first)):
        own = tri[tree.order[tree.first[k] : tree.first[k] + tree.count[k]]]
        assert fit.live[k] == pushed[own].any()
    vt_2, ee_2 = contact_pairs(sc, x, fit, 0.02, 0.02)
    want_vt = {(i, f) for i, f in vt.tolist() if pushed[i] or pushed[tri[f]].any()}
    want_ee = {(e, g) for e, g in ee.tolist() if pushed[edges[[e, g]]].any()}
    assert want_vt and want_ee
    assert want_vt <= set(map(tuple, vt_2.tolist()))
    assert want_ee <= set(map(tuple, ee_2.tolist()))
    assert len(vt_2) + len(ee_2) < len(vt) + len(ee)


def test_a_flat_sheet_needs_no_leaf_tests_and_a_folded_one_does():
    """A plane sheet is one flat patch: no leaf pair is tested. Folded in half onto itself
    (the upper half turned over, 2 mm above the lower), the halves' patches are tested
    against each other."""
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 1.0, 17)])
    sc = self_contact_model(model.rest_positions, model.triangles, 0.005)
    x = model.rest_positions.copy()
    fit = tree_fit(sc, x.shape[0])
    refit(sc.tree, sc.triangles, x, fit)
    assert leaf_pairs(sc.tree, fit, 0.5, 0.02, True)[1] == 0
    upper = x[:, 1] > 0.5
    x[upper, 1] = 1.0 - x[upper, 1]
    x[upper, 2] = 0.002 + 0.001 * (x[upper, 1] < 0.49)
    refit(sc.tree, sc.triangles, x, fit)
    pairs, found = leaf_pairs(sc.tree, fit, 0.5, 0.02, True)
    assert found > 0
    leaves = np.flatnonzero(sc.tree.left < 0)
    corners = {
        k: x[sc.triangles[sc.tree.order[sc.tree.first[k] : sc.tree.first[k] + sc.tree.count[k]]]]
        for k in leaves
    }
    far = {k for k in leaves if corners[k][..., 1].max() < 0.4}  # away from the crease
    lower = {k for k in far if corners[k][..., 2].max() == 0.0}
    upper = {k for k in far if corners[k][..., 2].min() > 0.0015}
    # a patch of the lower half against one of the turned-over half, away from the crease
    assert any((a in lower and b in upper) or (a in upper and b in lower) for a, b in pairs[:found])


def test_leaves_a_third_joins_into_one_flat_patch_are_not_tested_against_each_other():
    """A fine sheet (cells of 1.6 cm, under the 2 cm reach) rippled 2 cm deep every 10 cm:
    larger patches are not flat, leaves are, and leaves that share no vertex come within
    the reach. The contacts' bridging (a third leaf sharing a vertex with each, the three
    one flat connected patch) leaves fewer pairs to test. Folded flat onto itself, 1 cm
    apart, its two layers are tested against each other."""
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 0.5, 33)])
    sc = self_contact_model(model.rest_positions, model.triangles, 0.005)
    x = model.rest_positions.copy()
    x[:, 2] = 0.02 * np.sin(2 * np.pi * x[:, 0] / 0.1) * np.sin(2 * np.pi * x[:, 1] / 0.12)
    fit = tree_fit(sc, x.shape[0])
    refit(sc.tree, sc.triangles, x, fit)
    bridged = leaf_pairs(sc.tree, fit, 0.5, 0.02, True)[1]
    assert bridged < 0.7 * leaf_pairs(sc.tree, fit, 0.5, 0.02, False)[1]
    x = model.rest_positions.copy()
    arm = x[:, 1] > 0.25  # folded over: the far half turned back above the near one
    x[arm, 1], x[arm, 2] = 0.5 - x[arm, 1], 0.01
    refit(sc.tree, sc.triangles, x, fit)
    pairs, found = leaf_pairs(sc.tree, fit, 0.5, 0.02, True)
    z = {
        k: x[sc.triangles[sc.tree.order[sc.tree.first[k] : sc.tree.first[k] + sc.tree.count[k]]]][
            ..., 2
        ]
        for k in np.unique(pairs[:found])
    }
    assert any(
        z[a].max() == 0.0 and z[b].min() == 0.01 or z[b].max() == 0.0 and z[a].min() == 0.01
        for a, b in pairs[:found]
    )


def test_diagonal_bounds_drop_leaf_pairs_of_a_tilted_sheet():
    """A sheet whose normal is (1, 1, 1) / sqrt 3: the boxes of patches a leaf apart
    overlap more than the patches come near. The 18-DOP search tests a strict subset of
    the leaf pairs the boxes alone would (diagonal bounds left open). That it misses no
    close pair is the next test's business (an all-pairs search on crumpled sheets)."""
    u, v = (np.sqrt(0.5), -np.sqrt(0.5), 0.0), tuple(np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0))
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 1.0, 17, u=u, v=v)])
    sc = self_contact_model(model.rest_positions, model.triangles, 0.005)
    x = model.rest_positions.copy()
    fit = tree_fit(sc, x.shape[0])
    refit(sc.tree, sc.triangles, x, fit)
    pairs, found = leaf_pairs(sc.tree, fit, _NEVER_FLAT, 0.02, False)
    with_dop = {tuple(q) for q in pairs[:found]}
    fit.dop[:, :6], fit.dop[:, 6:] = -np.inf, np.inf  # the diagonal bounds left open
    pairs, found = leaf_pairs(sc.tree, fit, _NEVER_FLAT, 0.02, False)
    assert with_dop < {tuple(q) for q in pairs[:found]}


@pytest.mark.parametrize("seed", [1, 2])
def test_the_close_pair_search_meets_each_pair_once_as_an_all_pairs_search_does(seed):
    """Without the cone culling, the vertex-triangle and edge-edge pairs found through the
    leaf pairs are exactly those of an all-pairs search with the same tests, each once."""
    model, x = _crumpled(seed=seed)
    sc = self_contact_model(model.rest_positions, model.triangles, 0.005)
    reach = 0.05
    fit = tree_fit(sc, x.shape[0])
    refit(sc.tree, sc.triangles, x, fit)
    pairs, found = leaf_pairs(sc.tree, fit, _NEVER_FLAT, reach, False)
    vt, ee = close_pairs(sc, x, fit.box, pairs, found, reach)
    tris = [tuple(int(v) for v in t) for t in sc.triangles]
    expected_vt = {
        (i, f)
        for f, t in enumerate(tris)
        for i in range(x.shape[0])
        if i not in t and _vertex_near_triangle(x, i, t, reach)
    }
    edges = sorted({tuple(sorted((t[k], t[(k + 1) % 3]))) for t in tris for k in range(3)})
    expected_ee = {
        (e, g)
        for n, e in enumerate(edges)
        for g in edges[n + 1 :]
        if not set(e) & set(g) and _edges_close(x, *e, *g, reach)
    }
    found_ee = [
        tuple(sorted((tuple(sc.tree.leaf_edge[a]), tuple(sc.tree.leaf_edge[b])))) for a, b in ee
    ]
    assert len(expected_vt) > 20 and len(expected_ee) > 20
    assert sorted(map(tuple, vt.tolist())) == sorted(expected_vt)
    assert sorted(found_ee) == sorted(expected_ee)


def _grown_search(sc, x, moves, grow):
    """(vertex-triangle pairs, edge pairs as vertex pairs) of the contacts' search at the
    thickness over the bounds grown by ``moves`` (or not), cones left out, the narrow
    phase at the largest pair's reach."""
    fit = tree_fit(sc, x.shape[0])
    refit(sc.tree, sc.triangles, x, fit)
    if grow:
        grow_by_moves(sc.tree, moves, fit.box, fit.dop)
    pairs, found = leaf_pairs(sc.tree, fit, _NEVER_FLAT, sc.thickness, False)
    reach = sc.thickness + 2.0 * moves.max()
    vt, ee = close_pairs(sc, x, fit.box, pairs, found, reach)
    edge = sc.tree.leaf_edge
    rows = {tuple(sorted((tuple(edge[a]), tuple(edge[b])))) for a, b in ee}
    return set(map(tuple, vt.tolist())), rows


@pytest.mark.parametrize("seed", [1, 2])
def test_bounds_grown_by_the_moves_find_every_pair_within_its_thickness_and_moves(seed):
    """Each vertex of a crumpled sheet moved up to 30 mm since the last pass (at random):
    the leaf pairs whose bounds, grown by those moves, come within the thickness hold every
    vertex-triangle pair of an all-pairs search within thickness + d_i + d_f of the plane
    (d_f the largest move of the triangle's corners) and every edge pair within thickness +
    the largest moves of the two edges."""
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 1.0, 17)])
    rng = np.random.default_rng(seed)
    x = model.rest_positions + 0.03 * rng.standard_normal(model.rest_positions.shape)
    thickness = 0.005
    sc = self_contact_model(model.rest_positions, model.triangles, thickness)
    moves = 0.03 * rng.random(x.shape[0])
    tris = [tuple(int(v) for v in t) for t in sc.triangles]
    expected_vt = {
        (i, f)
        for f, t in enumerate(tris)
        for i in range(x.shape[0])
        if i not in t
        and _vertex_near_triangle(x, i, t, thickness + moves[i] + moves[list(t)].max())
    }
    edges = sorted({tuple(sorted((t[k], t[(k + 1) % 3]))) for t in tris for k in range(3)})
    expected_ee = {
        (e, g)
        for n, e in enumerate(edges)
        for g in edges[n + 1 :]
        if not set(e) & set(g)
        and _edges_close(x, *e, *g, thickness + moves[list(e)].max() + moves[list(g)].max())
    }
    vt, ee = _grown_search(sc, x, moves, True)
    assert len(expected_vt) > 20 and len(expected_ee) > 20
    assert expected_vt <= vt and expected_ee <= ee


def test_bounds_grown_by_the_moves_reach_a_sheet_that_moved_fast():
    """Two parallel sheets (apart at rest, so that no patch holds both) now 30 mm apart,
    thickness 5 mm; the upper one moved 30 mm since the last pass, the lower one not: every
    vertex lies within 5 + 30 mm, its pair's reach, of the other sheet's triangles. The
    grown bounds find such a pair for every vertex, the bounds not grown none."""
    lower, upper = (
        _sheet((0.0, 0.0, 0.0), 1.0, 9, name="a"),
        _sheet((0.0, 0.0, 1.0), 1.0, 9, name="b"),
    )
    model = ClothModel.from_meshes([lower, upper])
    sc = self_contact_model(model.rest_positions, model.triangles, 0.005)
    sheet = (model.rest_positions[:, 2] > 0.5).astype(int)  # 1: the upper one
    x = model.rest_positions.copy()
    x[sheet == 1, 2] = 0.03
    moves = 0.03 * sheet
    tri_sheet = sheet[sc.triangles[:, 0]]

    def across(pairs):
        return {i for i, f in pairs if sheet[i] != tri_sheet[f]}

    assert across(_grown_search(sc, x, moves, True)[0]) == set(range(x.shape[0]))
    assert across(_grown_search(sc, x, moves, False)[0]) == set()


def test_the_patch_hierarchy_partitions_the_triangles_and_knows_separate_pieces():
    """Every triangle lies in exactly one leaf, every vertex and edge is listed by exactly
    one leaf; two separate sheets are not one piece at the root, each sheet's own subtree
    is."""
    a = _sheet((0.0, 0.0, 0.0), 1.0, 6, name="a")
    b = _sheet((0.0, 0.0, 3.0), 1.0, 6, name="b")  # the root splits along z
    model = ClothModel.from_meshes([a, b])
    tree = patch_tree(model.rest_positions, model.triangles)
    leaves = np.flatnonzero(tree.left < 0)
    covered = np.concatenate(
        [tree.order[tree.first[k] : tree.first[k] + tree.count[k]] for k in leaves]
    )
    assert np.array_equal(np.sort(covered), np.arange(len(model.triangles)))
    assert np.array_equal(np.sort(tree.leaf_vert), np.arange(model.n_vertices))
    edges = {tuple(sorted((t[k], t[(k + 1) % 3]))) for t in model.triangles for k in range(3)}
    assert sorted(map(tuple, tree.leaf_edge.tolist())) == sorted(edges)
    assert tree.count[leaves].max() <= LEAF
    assert not tree.connected[0]
    assert tree.connected[tree.left[0]] and tree.connected[tree.right[0]]


def test_patches_share_a_vertex_exactly_when_their_rims_do():
    """The adjacency test compares the rims (vertices a patch shares with triangles outside
    it) of two disjoint patches: it agrees with the intersection of their vertex sets for
    every pair of disjoint nodes of a 9 x 9 sheet's hierarchy."""
    model = ClothModel.from_meshes([_sheet((0.0, 0.0, 0.0), 1.0, 9)])
    tree = patch_tree(model.rest_positions, model.triangles)
    tris = model.triangles
    verts = [
        set(tris[tree.order[tree.first[k] : tree.first[k] + tree.count[k]]].ravel())
        for k in range(len(tree.first))
    ]
    tested = 0
    for a in range(len(verts)):
        for b in range(len(verts)):
            ta = set(tree.order[tree.first[a] : tree.first[a] + tree.count[a]])
            tb = set(tree.order[tree.first[b] : tree.first[b] + tree.count[b]])
            if ta & tb:
                continue  # nested nodes: the search never pairs them
            expected = bool(verts[a] & verts[b])
            assert _adjacent(tree.rim_ptr, tree.rim, a, b) == expected
            tested += expected
    assert tested > 100


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_two_crossing_edges_are_pushed_to_the_thickness_with_momentum_kept(side):
    """Edge x = 0..1 at z = 0 and edge y = -0.5..0.5 at x = 0.3, z = 1 mm, which started on
    the given side (z = side x 1 cm): afterwards their closest points are ``thickness``
    apart on that side along n = e1 x e2 (the z axis), and sum_i m_i dx_i = 0 (equal
    masses: the weights 1 - s, s, -(1 - u), -u sum to 0)."""
    p = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.3, -0.5, 0.001], [0.3, 0.5, 0.001]])
    xp = p.copy()
    xp[2:, 2] = side * 0.01
    inv_mass = np.ones(4)
    before = p.copy()
    c = push_edges(p, xp, inv_mass, 0, 1, 2, 3, 0.005, vertex_moves(p, xp, np.empty(4)))
    assert c < 0.0
    gap = p[2:, 2].mean() - (0.7 * p[0, 2] + 0.3 * p[1, 2])  # closest points: s = 0.3, u = 0.5
    assert gap == pytest.approx(side * 0.005, abs=1e-12)
    np.testing.assert_allclose((p - before).sum(axis=0), 0.0, atol=1e-15)


def _triangle(radius, z):
    """An equilateral triangle of circumradius ``radius`` about the z axis at height z."""
    a = np.array([0.3, 0.3 + 2 * np.pi / 3, 0.3 + 4 * np.pi / 3])
    return np.c_[radius * np.cos(a), radius * np.sin(a), np.full(3, z)]


def test_a_layer_pushed_through_the_one_below_is_brought_back_in_the_same_substep():
    """Three stacked triangles, thickness 5 mm: a heavy small one (V) that crossed the
    light middle one (A, z = 0) to z = -19.5 mm since the last pass, over a pinned wide one
    (B, z = -21 mm). Pushing V up carries A down through B; the substep ends with A back at
    B's thickness, z = -16 mm, and no crossing left. The pair A-B is searched (V's 23.5 mm
    move widens the search to 52 mm) but judged at its own reach, 20 mm (its parts had not
    moved). Whether one pass finds it depends on the order of the pairs; a pass that pushed
    a pair is followed by a second, so that the result does not."""
    sizes, tris = (0.02, 0.1, 0.3), np.arange(9).reshape(3, 3)
    rest = np.vstack([_triangle(r, z) for r, z in zip(sizes, (0.04, 0.0, -0.04), strict=True)])
    start = np.vstack([_triangle(r, z) for r, z in zip(sizes, (0.004, 0.0, -0.021), strict=True)])
    p = np.vstack([_triangle(r, z) for r, z in zip(sizes, (-0.0195, 0.0, -0.021), strict=True)])
    inv_mass = np.r_[np.full(3, 0.01), np.ones(3), np.zeros(3)]
    sc = self_contact_model(rest, tris, 0.005)
    fit = tree_fit(sc, 9)
    fit.anchor[:] = start
    self_contact_substep(sc, inv_mass, p, start, fit, True)
    assert fit.passes[0] == 2 and self_intersections(sc, p) == 0
    np.testing.assert_allclose(p[3:6, 2], -0.021 + 0.005, atol=1e-12)


def test_a_triangle_that_passed_a_layer_faster_than_the_base_reach_is_brought_back():
    """Thickness 5 mm, base reach 20 mm: a small triangle 10 mm above a pinned wide one at
    the last pass is 30 mm below it now (a 40 mm move, a free edge whipping at 16 m/s for
    a substep of 2.5 ms). The pass searches the pair within 40 + 0 + 5 mm and puts it back
    on its side at the thickness, +5 mm; within the base reach it would stay below."""
    tris = np.arange(6).reshape(2, 3)
    rest = np.vstack([_triangle(0.02, 0.04), _triangle(0.3, 0.0)])
    start = np.vstack([_triangle(0.02, 0.01), _triangle(0.3, 0.0)])
    p = np.vstack([_triangle(0.02, -0.03), _triangle(0.3, 0.0)])
    inv_mass = np.r_[np.ones(3), np.zeros(3)]
    sc = self_contact_model(rest, tris, 0.005)
    assert pair_reach(0.04, 0.0, 0.005) == pytest.approx(0.045)
    fit = tree_fit(sc, 6)
    fit.anchor[:] = start
    self_contact_substep(sc, inv_mass, p, start, fit, True)
    np.testing.assert_allclose(p[:3, 2], 0.005, atol=1e-12)
    np.testing.assert_array_equal(p[3:], start[3:])


@pytest.mark.parametrize("height", [0.015, 0.03])
def test_a_triangle_turned_over_does_not_carry_the_vertices_near_it_through_itself(height):
    """A pinned triangle whose corner lies ``height`` above a triangle of which a corner
    moved 2 mm across the opposite edge since the last pass (the triangle turned over, its
    normal reversed), while a third triangle moved 100 mm: the corner lies on the same side
    in space, so nothing is pushed. Read with the reversed normal it would be 15 or 30 mm on
    the wrong side and be carried through to the thickness; the 30 mm case is also beyond
    the pair's own reach (its parts moved 2 mm), which one reach for the whole cloth
    (2 x 100 + 5 mm) did not keep it from."""
    flat = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.05, 0.001, 0]])
    turned = flat.copy()
    turned[2, 1] = -0.001
    pinned = np.array([[0.05, -0.0003, height], [0.05, 0.05, height], [0.0, 0.05, height]])
    runner = np.array([[1.0, 1.0, 1.0], [1.1, 1.0, 1.0], [1.0, 1.1, 1.0]])
    start = np.vstack([flat, pinned, runner])
    p = np.vstack([turned, pinned, runner + [0.0, 0.0, 0.1]])
    inv_mass = np.r_[np.ones(3), np.zeros(3), np.ones(3)]
    tris = np.arange(9).reshape(3, 3)
    sc = self_contact_model(start, tris, 0.005)
    fit = tree_fit(sc, 9)
    fit.anchor[:] = start
    before = p.copy()
    assert self_contacts(sc, inv_mass, p, start, fit) == 0
    np.testing.assert_array_equal(p, before)


def _poked(side):
    """A small triangle (vertices 0-2) whose corner 0 lies 2 mm on the ``-side`` side of a
    wide triangle (3-5) in the plane z = 0, its other corners 30 mm on the ``side`` side:
    its two edges from corner 0 cross the wide triangle."""
    small = np.array([[0.0, 0.0, -0.002], [0.05, 0.0, 0.03], [0.0, 0.05, 0.03]])
    small[:, 2] *= side
    rest = np.vstack([_triangle(0.02, 0.04), _triangle(0.3, 0.0)])
    return np.vstack([small, _triangle(0.3, 0.0)]), self_contact_model(
        rest, np.arange(6).reshape(2, 3), 0.005
    )


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_corner_poked_through_a_pinned_triangle_is_taken_back_at_its_shallow_end(side):
    """The pinned wide triangle stays; the shallow corner (2 mm through) is moved along the
    normal to the thickness on its triangle's side, z = side x 5 mm, the deep corners stay,
    and no pair crosses any more."""
    p, sc = _poked(side)
    before = p.copy()
    assert self_intersections(sc, p) == 1
    assert untangle(sc, np.r_[np.ones(3), np.zeros(3)], p, tree_fit(sc, 6)) == 1
    assert self_intersections(sc, p) == 0
    assert p[0, 2] == pytest.approx(side * 0.005, abs=1e-15)
    np.testing.assert_array_equal(p[0, :2], before[0, :2])
    np.testing.assert_array_equal(p[1:], before[1:])


def test_untangling_two_free_triangles_keeps_their_momentum():
    """Equal masses: the corner moves by g w n and the wide triangle's corners by -g beta_q
    w n with sum beta_q = 1, so sum m dx = 0; the corner ends at the thickness from the
    point of the wide triangle under it (fixed beta, the normal before the move), and
    nothing crosses."""
    p, sc = _poked(1.0)
    before = p.copy()
    assert untangle(sc, np.ones(6), p, tree_fit(sc, 6)) == 1
    np.testing.assert_allclose((p - before).sum(axis=0), 0.0, atol=1e-15)
    wide = before[3:]
    e = np.cross(wide[1] - wide[0], wide[2] - wide[0])
    area2 = np.linalg.norm(e)
    beta = [np.cross(wide[(k + 2) % 3] - wide[(k + 1) % 3], before[0] - wide[(k + 1) % 3]) @ e
            for k in range(3)] / area2**2  # fmt: skip
    assert (beta > 0).all()
    assert (p[0] - beta @ p[3:]) @ e / area2 == pytest.approx(0.005, abs=1e-12)
    assert self_intersections(sc, p) == 0


# A crumple from a shirt run (10 vertices, in units of 10 um, about their centroid; edges
# 2-19 mm, thickness 5 mm): triangles (4, 2, 3) and (0, 5, 1) cross, edge 4-2 through the
# second and edge 0-5 through the first, and vertices 4 and 5, the shallower ends, are
# neighbours whose fans are folded through each other.
CRUMPLE = 1e-5 * np.array([
    [-252, -869, -578], [261, -317, 535], [857, -1486, -409], [744, -125, -1187],
    [-309, -164, 175], [297, 158, -51], [-545, 517, 806], [69, 1010, 368],
    [-494, 609, -299], [-629, 668, 640],
])  # fmt: skip
CRUMPLE_TRIANGLES = np.array([
    [4, 2, 3], [5, 4, 6], [0, 4, 5], [0, 2, 4], [0, 5, 1], [5, 6, 7], [1, 5, 7],
    [9, 4, 8], [4, 3, 8], [4, 9, 6],
])  # fmt: skip


def test_a_crumple_whose_apexes_poke_through_each_other_is_opened():
    """No edge taken back alone or with the others leaves fewer crossings here (taking
    vertex 4 or 5 back pushes its neighbours through); pulling both into their rings
    does: no pair crosses after, a brute-force search agrees, momentum is kept (equal
    masses), and no vertex moved more than 13 mm."""
    p = CRUMPLE.copy()
    sc = self_contact_model(p, CRUMPLE_TRIANGLES, 0.005)
    assert _brute_force_crossings(CRUMPLE_TRIANGLES, p) == 1
    assert untangle(sc, np.ones(len(p)), p, tree_fit(sc, len(p))) == 1
    assert self_intersections(sc, p) == 0 == _brute_force_crossings(CRUMPLE_TRIANGLES, p)
    np.testing.assert_allclose((p - CRUMPLE).sum(axis=0), 0.0, atol=1e-15)
    assert np.linalg.norm(p - CRUMPLE, axis=1).max() < 0.013


def test_the_vertex_rings_are_the_ends_of_each_vertex_edges():
    ptr, ring = vertex_rings(CRUMPLE_TRIANGLES, len(CRUMPLE))
    for v in range(len(CRUMPLE)):
        edges = CRUMPLE_TRIANGLES[(CRUMPLE_TRIANGLES == v).any(axis=1)]
        assert ring[ptr[v] : ptr[v + 1]].tolist() == sorted(set(edges.ravel()) - {v})


def test_a_sheet_started_through_another_is_untangled_in_the_first_frame():
    """Sheet A lies 6 mm above sheet B (thickness 5 mm), with its vertices within 6 cm of
    the middle pushed 2 mm through B: a crossing the contacts cannot undo, since they keep
    each vertex on the side it started on. Both fall freely (the same acceleration: only
    the contacts and the repair move them apart). No pair crosses after any of 20 frames,
    and A's middle ends above B."""
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    lower = _sheet((-0.25, -0.25, 0.0), 0.5, 12, name="b")
    upper = _sheet(
        (-0.2 * c + 0.2 * s, -0.2 * s - 0.2 * c, 0.006), 0.4, 10, u=(c, s, 0), v=(-s, c, 0)
    )
    model = ClothModel.from_meshes([lower, upper])
    x = model.rest_positions.copy()
    n_lower = lower.n_vertices
    middle = n_lower + np.flatnonzero(np.linalg.norm(x[n_lower:, :2], axis=1) < 0.06)
    x[middle, 2] = -0.002
    state = ClothState(x, np.zeros_like(x))
    cfg = ClothConfig()
    cfg.self_collision = True
    solver = XPBDCloth(model, (), cfg)
    assert solver.stats(state)["self_intersections"] > 0
    states = _frames(solver, state, 20)
    assert max(solver.stats(s)["self_intersections"] for s in states) == 0
    end = states[-1].positions
    below = np.linalg.norm(end[:n_lower, :2] - end[middle, :2].mean(axis=0), axis=1) < 0.1
    assert end[middle, 2].min() > end[:n_lower][below, 2].max()


def test_a_scene_without_cloth_has_an_empty_patch_tree():
    """No triangles (a scene of bodies and wind only): one empty leaf, no intersections."""
    sc = self_contact_model(np.zeros((0, 3)), np.zeros((0, 3), int), 0.005)
    assert sc.tree.first.shape == (1,) and sc.tree.count[0] == 0
    assert self_intersections(sc, np.zeros((0, 3))) == 0


def test_the_self_contact_pass_runs_when_a_crossing_could_leave_its_reach():
    """Thickness 5 mm, REACH 4: the pass may wait while 2 (d + d_h) <= 3 thickness = 15 mm,
    d the largest move since the last pass, d_h this substep's; it always runs in a frame's
    last substep."""
    anchor = np.zeros((3, 3))
    xp = np.zeros((3, 3))
    p = np.zeros((3, 3))
    p[1, 2] = 0.003  # d = d_h = 3 mm: 12 mm
    assert not pass_due(p, xp, anchor, 0.005, False)
    assert pass_due(p, xp, anchor, 0.005, True)
    p[1, 2] = 0.004  # 16 mm
    assert pass_due(p, xp, anchor, 0.005, False)
    xp[1, 2] = 0.004  # no move in this substep: d = 4 mm, d_h = 0: 8 mm
    assert not pass_due(p, xp, anchor, 0.005, False)
