"""The parts of the cloth held near the bodies: a superset of what the full box test finds,
for as long as no vertex has moved more than the slack.

Reference answer: the box test over every vertex, edge and triangle at the moved positions
(the broad phase the held parts replace), on a random sheet jittered within the slack.
"""

import numpy as np

from windbench.cloth.near_bodies import NEAR_SLACK, hold_near, near_bodies

BOX = np.array([[0.4, -0.1, 0.3, 0.5, 0.1, 0.6]])  # one grown body box (lower, upper)
PINNED = 5 * 10 + 5  # the vertex at (5/11, 0, 0.8 * 5/9) m of the 12 x 10 sheet: in the box


def _meets(p, corners):
    lo, hi = p[corners].min(axis=0), p[corners].max(axis=0)
    return bool(np.all(hi >= BOX[0, :3]) and np.all(lo <= BOX[0, 3:]))


def _sheet(nu=12, nv=10):
    """A 1 m x 0.8 m sheet in the plane y = 0, through the box, two triangles per quad."""
    u, v = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 0.8, nv), indexing="ij")
    x = np.stack([u.ravel(), np.zeros(u.size), v.ravel()], axis=1)
    ids = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = (
        ids[:-1, :-1].ravel(),
        ids[1:, :-1].ravel(),
        ids[1:, 1:].ravel(),
        ids[:-1, 1:].ravel(),
    )
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    inv_mass = np.ones(len(x))
    inv_mass[PINNED] = 0.0  # inside the box: its vertex, edges and triangles are never held
    edges = np.unique(
        np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1), axis=0
    )
    return (
        np.ascontiguousarray(x, np.float64),
        tris.astype(np.int64),
        edges.astype(np.int64),
        inv_mass,
    )


def _held(near, k):
    return set(getattr(near, ("vertices", "edges", "triangles")[k])[: near.counts[k]].tolist())


def test_held_parts_cover_the_box_test_while_the_cloth_moves_less_than_the_slack():
    x, tris, edges, inv_mass = _sheet()
    rng = np.random.default_rng(3)
    near = near_bodies(len(x), len(edges), len(tris))
    hold_near(BOX, BOX, inv_mass, edges, tris, x, near)
    anchor = near.anchor.copy()
    for _ in range(20):
        move = rng.normal(size=x.shape)
        move *= rng.uniform(0, 0.999 * NEAR_SLACK) / np.linalg.norm(move, axis=1).max()
        p = np.ascontiguousarray(x + move)
        hold_near(BOX, BOX, inv_mass, edges, tris, p, near)
        np.testing.assert_array_equal(near.anchor, anchor)  # held, not gathered again
        free = inv_mass > 0
        assert {i for i in range(len(p)) if free[i] and _meets(p, [i])} <= _held(near, 0)
        for k, prims in ((1, edges), (2, tris)):
            found = {e for e, c in enumerate(prims) if free[c].all() and _meets(p, c)}
            assert found <= _held(near, k)
            assert found  # the sheet crosses the box: the test is not empty
    assert len(_held(near, 2)) < len(tris) // 2  # and the held parts are few


def test_a_move_beyond_the_slack_gathers_again_and_pinned_parts_are_never_held():
    x, tris, edges, inv_mass = _sheet()
    near = near_bodies(len(x), len(edges), len(tris))
    hold_near(BOX, BOX, inv_mass, edges, tris, x, near)
    p = x.copy()
    p[5, 2] += 1.5 * NEAR_SLACK
    hold_near(BOX, BOX, inv_mass, edges, tris, p, near)
    np.testing.assert_array_equal(near.anchor, p)
    assert _meets(p, [PINNED]) and PINNED not in _held(near, 0)
    assert not any(PINNED in edges[e] for e in _held(near, 1))
    assert not any(PINNED in tris[f] for f in _held(near, 2))
    assert any(PINNED + 1 in edges[e] for e in _held(near, 1))  # its free neighbour's are
