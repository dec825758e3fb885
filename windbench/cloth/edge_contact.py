"""Cloth edges and triangles against rigid bodies, and the penetration figure they enter.

A vertex contact (:mod:`windbench.cloth.collision`) keeps every vertex out of the bodies,
but a body thinner than an edge (a flag pole of radius 0.05 m against 0.06 m edges) can
still pass between two vertices. Here each cloth edge near a body (its box overlaps the
body's grown box, :func:`~windbench.cloth.collision.body_boxes`) finds the point
q(t) = (1 - t) x_a + t x_b where the body's signed distance phi is smallest
(:func:`edge_minimum`: EDGE_SAMPLES samples, then a golden-section search in the bracket
of the best; exact for the convex analytic bodies, whose phi is convex along a line). When
that point lies strictly inside the edge and closer than the margin,
C = phi(q) - margin < 0, both end vertices move along the body normal n with their
barycentric weights and inverse masses (position-based edge contact):

    s = -C / ((1 - t)^2 w_a + t^2 w_b),  dx_a = s (1 - t) w_a n,  dx_b = s t w_b n,

which moves q by exactly -C n to first order. A body thinner than a triangle is caught by
TRIANGLE_SAMPLES interior points (barycentric beta) in the same way:
dx_k = -C beta_k w_k n / sum_j beta_j^2 w_j. The end points themselves are the vertex
contacts' business, so a minimum at an end of the edge is left alone. Only bodies thinner
than twice the edge (a capsule's or cylinder's diameter, a box's shortest side) are
searched: through a thicker one no edge passes without a vertex entering it first; a
plane (phi linear along an edge) and a mesh body (the character) are left out.

Edges and triangles with a pinned corner are left alone: a pin attaches the cloth to a
body (a flag's hem wraps its pole), so the cloth next to it may lie inside it.

Which bodies: :func:`surface_boxes` keeps the grown boxes of the bodies thin enough for
an edge or triangle of the cloth stretched to STRETCH_SLACK times its longest rest side
and empties the others, so a cloth near thick bodies only (the character's mesh, a wall)
does no edge work at all and a flag does it only at its pole.

Skipping: phi changes by at most LIPSCHITZ per metre, so an edge whose end vertices are
known (from their last vertex query, the contacts' clearances) to lie farther from the
bodies than the margin plus LIPSCHITZ times half the edge's length cannot touch them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from windbench.cloth.collision import LIPSCHITZ
from windbench.cloth.near_bodies import box_within
from windbench.geometry.bodies import BOX, CAPSULE, CYLINDER, table_distance

STRETCH_SLACK = 1.5  # an edge longer than this times the longest rest side has blown up
EMPTY_BOX = (np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf)  # meets no point
EDGE_SAMPLES = 5  # phi sampled at t = k / (EDGE_SAMPLES - 1) ...
GOLDEN_STEPS = 16  # ... then this many golden-section steps in the best sample's bracket
END_GAP = 1e-3  # a minimum at t < END_GAP or t > 1 - END_GAP is the end vertex's contact
INV_PHI = 0.6180339887498949  # 1 / golden ratio
# interior points of a triangle (barycentric coordinates): its centroid and the midpoints
# between the centroid and each corner
TRIANGLE_SAMPLES = np.array(
    [
        [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0],
        [2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0],
        [1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0],
        [1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0],
    ]
)


@njit(cache=True, inline="always")
def _phi_on_edge(bodies, b, pa, pb, t, normal):
    """phi_b((1 - t) pa + t pb), normal there in ``normal``."""
    s = 1.0 - t
    return table_distance(
        bodies,
        b,
        s * pa[0] + t * pb[0],
        s * pa[1] + t * pb[1],
        s * pa[2] + t * pb[2],
        normal,
    )


@njit(cache=True)
def edge_minimum(bodies, b, pa, pb, normal):
    """(t, phi) at the point of segment pa-pb nearest to body b (smallest signed distance),
    the body's outward normal there in ``normal``.

    EDGE_SAMPLES equally spaced samples, then GOLDEN_STEPS golden-section steps in the
    bracket around the best sample (a unimodal phi: the analytic bodies are convex)."""
    step = 1.0 / (EDGE_SAMPLES - 1)
    best_k, best = 0, np.inf
    for k in range(EDGE_SAMPLES):
        d = _phi_on_edge(bodies, b, pa, pb, k * step, normal)
        if d < best:
            best_k, best = k, d
    lo, hi = max(0.0, (best_k - 1) * step), min(1.0, (best_k + 1) * step)
    t1, t2 = hi - INV_PHI * (hi - lo), lo + INV_PHI * (hi - lo)
    f1 = _phi_on_edge(bodies, b, pa, pb, t1, normal)
    f2 = _phi_on_edge(bodies, b, pa, pb, t2, normal)
    for _ in range(GOLDEN_STEPS):
        if f1 <= f2:
            hi, t2, f2 = t2, t1, f1
            t1 = hi - INV_PHI * (hi - lo)
            f1 = _phi_on_edge(bodies, b, pa, pb, t1, normal)
        else:
            lo, t1, f1 = t1, t2, f2
            t2 = lo + INV_PHI * (hi - lo)
            f2 = _phi_on_edge(bodies, b, pa, pb, t2, normal)
    t, f = (t1, f1) if f1 <= f2 else (t2, f2)
    if best < f:  # the best sample itself (an end point)
        t = best_k * step
    return t, _phi_on_edge(bodies, b, pa, pb, t, normal)


@njit(cache=True, inline="always")
def _thin(bodies, b, size):
    """Whether body b is thinner than twice ``size`` (the longest side of an edge or
    triangle): a capsule's or cylinder's diameter, a box's shortest side. Through a
    thicker body no edge passes without a vertex inside it (module docstring)."""
    kind, prm = bodies.kinds[b], bodies.params[b]
    if kind == CAPSULE or kind == CYLINDER:
        return 2.0 * prm[6] < 2.0 * size
    if kind == BOX:
        return min(prm[3] - prm[0], prm[4] - prm[1], prm[5] - prm[2]) < 2.0 * size
    return False


@njit(cache=True, inline="always")
def _box_overlaps(box, lo, hi):
    """Whether the axis-aligned box [lo, hi] meets the grown body box ``box`` (6,)."""
    for k in range(3):
        if hi[k] < box[k] or lo[k] > box[k + 3]:
            return False
    return True


@njit(cache=True, inline="always")
def _bounds(p, corners, lo, hi):
    """lo, hi = the bounding box of the vertices ``corners`` of ``p``."""
    for k in range(3):
        lo[k], hi[k] = np.inf, -np.inf
    for i in corners:
        for k in range(3):
            lo[k] = min(lo[k], p[i, k])
            hi[k] = max(hi[k], p[i, k])


@njit(cache=True, inline="always")
def _lower_bound(clear, p, i):
    """A lower bound of how far vertex i lies outside the margin (clearances, LIPSCHITZ)."""
    probe, clearance = clear
    dx, dy, dz = p[i, 0] - probe[i, 0], p[i, 1] - probe[i, 1], p[i, 2] - probe[i, 2]
    return clearance[i] - LIPSCHITZ * np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, inline="always")
def _clear_of_bodies(clear, p, corners, reach):
    """Whether every point within ``reach`` of one of the ``corners`` lies outside the margin."""
    bound = np.inf
    for i in corners:
        bound = min(bound, _lower_bound(clear, p, i))
    return bound > LIPSCHITZ * reach


@njit(cache=True, inline="always")
def _push(p, inv_mass, corners, beta, depth, normal):
    """Move the point sum_k beta_k p[corners[k]] by -depth along ``normal`` (depth < 0),
    each vertex by its share beta_k w_k / sum_j beta_j^2 w_j; False if none can move."""
    den = 0.0
    for k in range(corners.shape[0]):
        den += beta[k] * beta[k] * inv_mass[corners[k]]
    if den <= 0.0:
        return False
    s = -depth / den
    for k in range(corners.shape[0]):
        g = s * beta[k] * inv_mass[corners[k]]
        for a in range(3):
            p[corners[k], a] += g * normal[a]
    return True


@njit(cache=True, inline="always")
def _may_touch(bodies, boxes, b, p, corners, lo, hi):
    """Whether body b is thin for the edge or triangle ``corners`` and its grown box meets
    theirs (``lo``, ``hi``: scratch, set to their bounds)."""
    _bounds(p, corners, lo, hi)
    return _thin(bodies, b, _longest_side(p, corners)) and _box_overlaps(boxes[b], lo, hi)


@njit(cache=True)
def project_edge(contacts, inv_mass, p, corners, normal, beta):
    """The edge contact of edge ``corners`` (2,) against every body it may touch (module
    docstring); ``beta`` (2,) scratch. Returns the deepest C found (0 if none)."""
    bodies, boxes, margin, _ = contacts
    lo, hi = np.empty(3), np.empty(3)
    deepest = 0.0
    for b in range(boxes.shape[0]):
        if not _may_touch(bodies, boxes, b, p, corners, lo, hi):
            continue
        t, d = edge_minimum(bodies, b, p[corners[0]], p[corners[1]], normal)
        d -= margin
        if d < 0.0 and END_GAP < t < 1.0 - END_GAP:
            beta[0], beta[1] = 1.0 - t, t
            if _push(p, inv_mass, corners, beta, d, normal):
                deepest = min(deepest, d)
    return deepest


@njit(cache=True)
def project_triangle(contacts, inv_mass, p, corners, normal):
    """The triangle contact of triangle ``corners`` (3,) at TRIANGLE_SAMPLES (module
    docstring). Returns the deepest C found (0 if none)."""
    bodies, boxes, margin, _ = contacts
    lo, hi = np.empty(3), np.empty(3)
    deepest = 0.0
    for b in range(boxes.shape[0]):
        if not _may_touch(bodies, boxes, b, p, corners, lo, hi):
            continue
        for s in range(TRIANGLE_SAMPLES.shape[0]):
            beta = TRIANGLE_SAMPLES[s]
            q = np.zeros(3)
            for k in range(3):
                for a in range(3):
                    q[a] += beta[k] * p[corners[k], a]
            d = table_distance(bodies, b, q[0], q[1], q[2], normal) - margin
            if d < 0.0 and _push(p, inv_mass, corners, beta, d, normal):
                deepest = min(deepest, d)
    return deepest


@njit(cache=True, inline="always")
def _longest_side(p, corners):
    """The longest distance between two of the ``corners`` of ``p``."""
    top = 0.0
    for u in range(corners.shape[0]):
        for v in range(u + 1, corners.shape[0]):
            d2 = 0.0
            for a in range(3):
                d2 += (p[corners[u], a] - p[corners[v], a]) ** 2
            top = max(top, d2)
    return np.sqrt(top)


@njit(cache=True, inline="always")
def _attached(inv_mass, prims, e, corners):
    """Whether one of the ``corners`` of edge or triangle ``prims[e]`` is pinned: the cloth
    is attached to a body there (a flag's hem around its pole), so it may lie in it as the
    scene put it."""
    for c in range(corners):
        if inv_mass[prims[e, c]] == 0.0:
            return True
    return False


@njit(cache=True)
def surface_contacts(contacts, inv_mass, edges, triangles, p, clear, near):
    """Every edge, then every triangle, that may touch a body pushed out to the margin
    (:func:`project_edge`, :func:`project_triangle`), of those ``near`` holds
    (:mod:`~windbench.cloth.near_bodies`, held at ``p``); ``clear`` the vertex contacts'
    clearances (module docstring: skipping)."""
    normal, beta = np.empty(3), np.empty(2)
    for e in _near_ones(contacts.boxes, p, edges, near.edges, near.counts[1]):
        _near_edge(contacts, inv_mass, p, edges[e], clear, normal, beta)
    for f in _near_ones(contacts.boxes, p, triangles, near.triangles, near.counts[2]):
        _near_triangle(contacts, inv_mass, p, triangles[f], clear, normal)


@njit(cache=True)
def _near_ones(boxes, p, prims, held, n_held):
    """Of the edges or triangles (rows of 2 or 3 corners) ``held[:n_held]``, those whose box
    meets a body's grown box (:func:`~windbench.cloth.near_bodies.box_within`). A loop of
    its own: with the contact calls in the same loop numba keeps reference counts inside
    it, which cost far more than the box tests."""
    last = prims.shape[1] - 1
    out = np.empty(n_held, np.int64)
    found = 0
    for q in range(n_held):
        e = held[q]
        if box_within(boxes, p, prims[e, 0], prims[e, min(1, last)], prims[e, last], 0.0):
            out[found] = e
            found += 1
    return out[:found]


@njit(cache=True)
def _near_edge(contacts, inv_mass, p, corners, clear, normal, beta):
    """:func:`project_edge` for an edge near a body's box unless the clearances of its ends
    show it cannot touch one (a call apart from the broad-phase loop keeps that loop tight)."""
    if not _clear_of_bodies(clear, p, corners, 0.5 * _longest_side(p, corners)):
        project_edge(contacts, inv_mass, p, corners, normal, beta)


@njit(cache=True)
def _near_triangle(contacts, inv_mass, p, corners, clear, normal):
    """:func:`project_triangle` for a triangle near a body's box, as :func:`_near_edge`."""
    if not _clear_of_bodies(clear, p, corners, _longest_side(p, corners)):
        project_triangle(contacts, inv_mass, p, corners, normal)


@njit(cache=True)
def deepest_surface_penetration(bodies, boxes, positions, edges, triangles, inv_mass, parts):
    """max(0, -phi) over the points of the edges (:func:`edge_minimum`) and the triangles'
    TRIANGLE_SAMPLES: how deep the deepest edge or triangle point lies inside a body.
    Edges and triangles with a pinned corner are left out, as in the contacts; ``parts``
    (edge ids, triangle ids) are those that may meet a body's box."""
    normal, lo, hi = np.empty(3), np.empty(3), np.empty(3)
    deepest = 0.0
    for b in range(boxes.shape[0]):
        for e in parts[0]:
            if _attached(inv_mass, edges, e, 2):
                continue
            _bounds(positions, edges[e], lo, hi)
            if _thin(bodies, b, _longest_side(positions, edges[e])) and _box_overlaps(
                boxes[b], lo, hi
            ):
                pa, pb = positions[edges[e, 0]], positions[edges[e, 1]]
                deepest = max(deepest, -edge_minimum(bodies, b, pa, pb, normal)[1])
        for f in parts[1]:
            if _attached(inv_mass, triangles, f, 3):
                continue
            _bounds(positions, triangles[f], lo, hi)
            thin = _thin(bodies, b, _longest_side(positions, triangles[f]))
            if not thin or not _box_overlaps(boxes[b], lo, hi):
                continue
            for s in range(TRIANGLE_SAMPLES.shape[0]):
                q = np.zeros(3)
                for k in range(3):
                    for a in range(3):
                        q[a] += TRIANGLE_SAMPLES[s, k] * positions[triangles[f, k], a]
                deepest = max(deepest, -table_distance(bodies, b, q[0], q[1], q[2], normal))
    return deepest


def surface_penetration(bodies, boxes, positions, edges, triangles, inv_mass, parts=None) -> float:
    """Largest depth (m) of a point of a cloth edge or triangle inside a body of the table
    ``bodies`` (:func:`deepest_surface_penetration`); 0 with no bodies or no cloth.
    ``parts`` (edge ids, triangle ids): a superset of those whose box meets a body's box
    in ``boxes`` (the held parts of :mod:`~windbench.cloth.near_bodies`); default all."""
    if bodies.kinds.shape[0] == 0 or positions.shape[0] == 0:
        return 0.0
    x = np.ascontiguousarray(positions, dtype=np.float64)
    if parts is None:
        parts = (np.arange(edges.shape[0]), np.arange(triangles.shape[0]))
    return float(deepest_surface_penetration(bodies, boxes, x, edges, triangles, inv_mass, parts))


def surface_boxes(bodies, boxes, positions, triangles) -> np.ndarray:
    """``boxes`` (m, 6) with the box of every body too thick for any edge or triangle of
    the cloth (:func:`_thin` at STRETCH_SLACK times the longest side of a triangle at
    ``positions``, the rest shape) replaced by EMPTY_BOX: the surface contacts' bodies."""
    out = np.array(boxes, dtype=np.float64, copy=True)
    if triangles.shape[0] == 0:
        out[:] = EMPTY_BOX
        return out
    corners = positions[triangles]  # (T, 3, 3)
    sides = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    reach = STRETCH_SLACK * float(sides.max())
    for b in range(out.shape[0]):
        if not _thin(bodies, b, reach):
            out[b] = EMPTY_BOX
    return out
