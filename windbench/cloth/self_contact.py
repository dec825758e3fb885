"""Self-collision and cloth-cloth collision: vertices against triangles and edges against
edges, culled by a bounding-volume hierarchy with normal cones. The paper's cloth system
[MKE03] keeps cloth from passing through itself. All cloths are one mesh
(:class:`~windbench.cloth.model.ClothModel`): one pass handles a flag folding on itself and
two flags touching alike. Thickness-based, not continuous: a vertex i closer than
``cloth.thickness`` to a triangle (a, b, c) it does not belong to, with its projection
q = sum_k beta_k x_k inside the triangle, is pushed back to the thickness on the side it
lay on at the last pass (sign s of its distance to the triangle's plane then):

    C = s (x_i - q) . n - thickness < 0,   den = w_i + sum_k beta_k^2 w_k,
    dx_i = -C w_i s n / den,   dx_k = C beta_k w_k s n / den,

skipped for a triangle turned over since (normal reversed: its sides swapped). The search
finds every pair within d_1 + d_2 + thickness of each other, d_1 and d_2 the largest moves
since the last pass of the vertex and of the triangle's corners: a crossing since then lies within
d_1 + d_2 of the plane. A pair found is judged within max(REACH thickness, d_1 + d_2 +
thickness) (:func:`pair_reach`): that also brings back a vertex that a push earlier in the
pass carried behind a triangle, and a pair that moved little is not pushed far because
another part moved fast. Edges that cross without a vertex near a triangle (a sheet over
another's border) are kept apart the same way at their closest points (:func:`push_edges`).

Broad phase (:func:`leaf_pairs`): a fixed hierarchy of triangle patches
(:func:`patch_tree`: median splits of the rest-pose centroids, leaves of at most LEAF
triangles) whose bounds (boxes and diagonal bounds: 18-DOPs, as the k-DOP hierarchies of
[MKE03]) and normal cones are refitted every substep (:func:`refit`). A patch is tested
against itself only when it is not flat, two patches only when their bounds, grown by their
vertices' largest move since the last pass (:func:`grow_by_moves`: far only where the cloth
moved fast), come within the thickness and they are not one flat patch together. Flat: a
connected patch whose normals lie within a cone below 90 degrees is a height field over
the plane normal to the cone's axis and cannot meet itself (Volino and Magnenat-Thalmann
1994; Provot 1997 uses the same cones for cloth). Their second condition, that the patch's
contour does not overlap itself in that projection, is not tested, as in most cloth
solvers: the contacts miss a flat patch that overlaps itself (a twist, a spiral ramp) until
it stops being flat. They use a narrower cone, CONTACT_CONE: within it, two points of the
patch within the reach of each other lie within reach / cos(CONTACT_CONE) of each other
along the surface, neighbours that the thickness test would reject anyway. Threads search
a large cloth's subtree pairs at once, with the same result (:func:`contact_pairs`).

The figure :func:`self_intersections` counts intersecting triangle pairs (Moeller-Trumbore)
through the hierarchy by its bounds alone, as an all-pairs search (a crumple's cones miss some).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange
from numba.typed import List

from windbench.arrays import copy_rows, largest_move

LEAF = 4  # triangles per leaf patch at most
REACH = 4.0  # a vertex this many thicknesses behind a triangle is brought back
PASS_SWEEPS = 2  # passes of the self-contacts at most, while the last pushed a pair
UNTANGLE_ROUNDS = 4  # rounds of :func:`untangle` at most, while the last moved an edge
CONTACT_CONE = math.radians(60.0)  # a patch is flat for the contacts below this half-angle
_COS_CONTACT = math.cos(CONTACT_CONE)
_NEVER_FLAT = 2.0  # a cosine no cone reaches: boxes alone (the intersection figure)
_COS_UNTANGLE = 0.0  # cos 90 degrees: the cones below it cull the untangling's search
_WIDE = -2.0  # the cosine recorded for a cone of 90 degrees or more
_SQRT2 = math.sqrt(2.0)
# leaf_pairs' ``bridge`` as np.bool_, not a literal True or False: a literal would compile
# leaf_pairs once for each
_BRIDGE, _NO_BRIDGE = np.bool_(True), np.bool_(False)
_CROSSINGS, _CONTACTS = np.bool_(True), np.bool_(False)  # what :func:`_task_search` seeks
# the contacts' search runs on the run's threads from this many triangles (a 64 x 64 cloth
# has 7938), in tasks of at most 1 / TASKS_PER_THREAD of a thread's share (:func:`contact_pairs`)
PARALLEL_TRIANGLES = 4000
TASKS_PER_THREAD = 16
_ROOT = np.int64(0)
_LEAVES = np.int64(-1)  # :func:`descend`'s limit that lists leaf pairs
DOP_SLACK = 1e-9  # m added to the diagonal bounds' gap (:func:`_dops_meet`) against rounding


class PatchTree(NamedTuple):
    """The fixed hierarchy of triangle patches (:func:`patch_tree`), nodes in preorder
    (children after their parent): node k holds the triangles order[first[k]:first[k] +
    count[k]]; a leaf has left = right = -1 and lists the vertices
    leaf_vert[vert_ptr[k]:vert_ptr[k + 1]] and edges leaf_edge[edge_ptr[k]:edge_ptr[k + 1]]
    it owns (empty ranges for inner nodes). Each vertex and edge is owned by one leaf that
    holds it, so that the search meets each vertex-triangle and edge-edge pair in one leaf
    pair only: listed by every leaf that holds them, a border vertex of leaves of two quads
    would be tested up to four times, a border edge twice."""

    order: np.ndarray  # (m,) triangle ids, patch by patch
    first: np.ndarray  # (N,)
    count: np.ndarray  # (N,)
    left: np.ndarray  # (N,) child, -1: a leaf
    right: np.ndarray  # (N,)
    connected: np.ndarray  # (N,) bool: the patch's triangles are one piece (sufficient test)
    vert_ptr: np.ndarray  # (N + 1,)
    leaf_vert: np.ndarray
    edge_ptr: np.ndarray  # (N + 1,)
    leaf_edge: np.ndarray  # (.., 2)
    corner_ptr: np.ndarray  # (N + 1,) every vertex of leaf k's triangles, once:
    leaf_corner: np.ndarray  # leaf_corner[corner_ptr[k]:corner_ptr[k + 1]] (its bounds)
    rim_ptr: np.ndarray  # (N + 1,) the vertices node k shares with triangles outside it:
    rim: np.ndarray  # rim[rim_ptr[k]:rim_ptr[k + 1]] (the adjacency test)
    nbr_ptr: np.ndarray  # (N + 1,) the leaves that share a vertex with leaf k, ascending:
    nbr: np.ndarray  # nbr[nbr_ptr[k]:nbr_ptr[k + 1]] (:func:`_bridged`)
    depth: int  # levels below the root


class SelfContact(NamedTuple):
    """The fixed tables of the self-contact pass (built with or without
    ``cloth.self_collision``: the intersection figure reads them too)."""

    triangles: np.ndarray  # (m, 3) global vertex ids, every cloth
    thickness: float  # m
    tree: PatchTree
    ring_ptr: np.ndarray  # (n + 1,) vertex i's neighbours are ring[ring_ptr[i]:ring_ptr[i + 1]]
    ring: np.ndarray  # (2 E,) the other ends of each vertex's edges (:func:`vertex_rings`)
    threads: int  # threads of the contacts' search (:func:`search_threads`)


class TreeFit(NamedTuple):
    """What :func:`refit` computes for the current positions, the traversal's scratch, and
    what the pass keeps between substeps (the positions at its last run, its count)."""

    normals: np.ndarray  # (m, 3) area-weighted normals 2 A n of the triangles
    box: np.ndarray  # (N, 6) lower and upper corners of each patch's box
    dop: np.ndarray  # (N, 12) lower and upper bounds of x+y, x-y, x+z, x-z, y+z, y-z
    cone: np.ndarray  # (N, 5): area-weighted normal sum (3), cos and sin of the half-angle
    stack: np.ndarray  # (S, 2) node pairs still to visit
    anchor: np.ndarray  # (n, 3) positions at the last pass (:func:`self_contact_substep`)
    passes: np.ndarray  # (1,) passes in the current frame
    moves: np.ndarray  # (n,) each vertex's move since the last pass (:func:`vertex_moves`)
    live: np.ndarray  # (N,) bool: the patches a search starts from (:func:`descend`)
    pushed: np.ndarray  # (n,) bool: the vertices a pass moved (:func:`self_contact_substep`)


def _split(centroid, order, lo, hi, nodes, depth):
    """Append the node of order[lo:hi] and, recursively, its children (preorder); the
    triangles are split at the median of their centroids along the widest axis."""
    k = len(nodes)
    nodes.append([lo, hi - lo, -1, -1])
    if hi - lo <= LEAF:
        return depth
    c = centroid[order[lo:hi]]
    axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
    mid = (lo + hi) // 2
    order[lo:hi] = order[lo:hi][np.argsort(c[:, axis], kind="stable")]
    nodes[k][2] = len(nodes)
    d_left = _split(centroid, order, lo, mid, nodes, depth + 1)
    nodes[k][3] = len(nodes)
    return max(d_left, _split(centroid, order, mid, hi, nodes, depth + 1))


def _one_piece(tris: np.ndarray) -> bool:
    """Whether a few triangles form one piece through shared vertices."""
    piece = {int(v) for v in tris[0]}
    rest = [set(map(int, t)) for t in tris[1:]]
    grown = True
    while rest and grown:
        grown = False
        for t in list(rest):
            if piece & t:
                piece |= t
                rest.remove(t)
                grown = True
    return not rest


def _csr(lists):
    """(ptr, values) of a list of arrays."""
    ptr = np.zeros(len(lists) + 1, np.int64)
    ptr[1:] = np.cumsum([len(a) for a in lists])
    values = np.concatenate(lists) if lists else np.zeros(0, np.int64)
    return ptr, values


def _claim(items: np.ndarray, owned: set) -> np.ndarray:
    """The rows of ``items`` (vertex ids, or vertex pairs of edges) not yet in ``owned``,
    which then holds them too."""
    keys = [tuple(np.atleast_1d(item).tolist()) for item in items]
    keep = [k for k, key in enumerate(keys) if key not in owned]
    owned.update(keys[k] for k in keep)
    return items[keep]


def _leaf_neighbours(corner_ptr: np.ndarray, corners: np.ndarray) -> list[np.ndarray]:
    """Per node, the other leaves that hold one of its corners (ascending; none for an
    inner node, whose corner range is empty)."""
    nodes = np.repeat(np.arange(len(corner_ptr) - 1), np.diff(corner_ptr))
    holders: dict[int, list[int]] = {}
    for k, v in zip(nodes.tolist(), corners.tolist(), strict=True):
        holders.setdefault(v, []).append(k)
    out = []
    for k in range(len(corner_ptr) - 1):
        near = {h for v in corners[corner_ptr[k] : corner_ptr[k + 1]].tolist() for h in holders[v]}
        out.append(np.array(sorted(near - {k}), np.int64))
    return out


def patch_tree(rest, triangles) -> PatchTree:
    """The hierarchy of the module docstring over ``triangles`` at the rest positions.

    ``connected`` is a sufficient test: a leaf whose triangles share vertices in a chain,
    an inner node whose children are connected and share a vertex."""
    tri = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    m = tri.shape[0]
    order = np.arange(m, dtype=np.int64)
    nodes: list[list[int]] = []
    depth = _split(rest[tri].mean(axis=1), order, 0, m, nodes, 0) if m else 0
    nodes = nodes or [[0, 0, -1, -1]]  # no cloth: one empty leaf
    first, count, left, right = (np.array(col, np.int64) for col in zip(*nodes, strict=True))
    connected = np.zeros(len(nodes), np.bool_)
    verts, edges, corners, rims = [], [], [], []
    owned_vertices, owned_edges = set(), set()
    valence = np.bincount(tri.ravel(), minlength=int(tri.max(initial=-1)) + 1)
    for k in range(len(nodes) - 1, -1, -1):
        own = tri[order[first[k] : first[k] + count[k]]]
        ids, inside = np.unique(own, return_counts=True)
        rims.append(ids[inside < valence[ids]])
        if left[k] < 0:
            connected[k] = own.shape[0] == 0 or _one_piece(own)
            corners.append(np.unique(own))
            verts.append(_claim(np.unique(own), owned_vertices))
            pairs = np.sort(own[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
            edges.append(_claim(np.unique(pairs, axis=0), owned_edges).reshape(-1, 2))
        else:
            a, b = left[k], right[k]
            shared = np.intersect1d(
                tri[order[first[a] : first[a] + count[a]]],
                tri[order[first[b] : first[b] + count[b]]],
            )
            connected[k] = connected[a] and connected[b] and shared.size > 0
            corners.append(np.zeros(0, np.int64))
            verts.append(np.zeros(0, np.int64))
            edges.append(np.zeros((0, 2), np.int64))
    vert_ptr, leaf_vert = _csr(verts[::-1])
    edge_ptr, leaf_edge = _csr(edges[::-1])
    corner_ptr, leaf_corner = _csr(corners[::-1])
    rim_ptr, rim = _csr(rims[::-1])
    nbr_ptr, nbr = _csr(_leaf_neighbours(corner_ptr, leaf_corner))
    return PatchTree(
        order,
        first,
        count,
        left,
        right,
        connected,
        vert_ptr,
        leaf_vert.astype(np.int64),
        edge_ptr,
        np.ascontiguousarray(leaf_edge.reshape(-1, 2), np.int64),
        corner_ptr,
        leaf_corner.astype(np.int64),
        rim_ptr,
        rim.astype(np.int64),
        nbr_ptr,
        nbr.astype(np.int64),
        depth,
    )


def vertex_rings(triangles: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """(ptr, ring): each vertex's neighbours along the edges of ``triangles``, ascending."""
    pairs = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    both = np.unique(np.vstack([pairs, pairs[:, ::-1]]), axis=0)
    ptr = np.searchsorted(both[:, 0], np.arange(n_vertices + 1)).astype(np.int64)
    return ptr, np.ascontiguousarray(both[:, 1], np.int64)


def self_contact_model(rest, triangles, thickness: float, threads: int = 1) -> SelfContact:
    """:class:`SelfContact` with the patch hierarchy of the rest positions, its contacts
    searched on ``threads`` threads (:func:`search_threads`)."""
    tri = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    rest = np.asarray(rest, np.float64)
    ring_ptr, ring = vertex_rings(tri, rest.shape[0])
    workers = search_threads(tri.shape[0], threads)
    return SelfContact(tri, float(thickness), patch_tree(rest, tri), ring_ptr, ring, workers)


def search_threads(triangles: int, threads: int) -> int:
    """The threads of the contacts' search (:func:`contact_pairs`) of a cloth of
    ``triangles`` triangles run on ``threads``: one below PARALLEL_TRIANGLES, where waking
    the threads costs more than they gain."""
    return 1 if triangles < PARALLEL_TRIANGLES else max(1, int(threads))


@njit(cache=True)
def _task_limit(sc):
    """The most triangles in a task of the parallel search: 1 / TASKS_PER_THREAD of a
    thread's share."""
    return np.int64(sc.triangles.shape[0] // (TASKS_PER_THREAD * sc.threads))


def tree_fit(sc: SelfContact, n_vertices: int) -> TreeFit:
    """Scratch for :func:`refit` and :func:`leaf_pairs` of ``sc``."""
    nodes = sc.tree.first.shape[0]
    return TreeFit(
        np.zeros((sc.triangles.shape[0], 3)),
        np.zeros((nodes, 6)),
        np.zeros((nodes, 12)),
        np.zeros((nodes, 5)),
        np.zeros((8 * (sc.tree.depth + 2), 2), np.int64),
        np.zeros((n_vertices, 3)),
        np.zeros(1, np.int64),
        np.zeros(n_vertices),
        np.ones(nodes, np.bool_),
        np.zeros(n_vertices, np.bool_),
    )


@njit(cache=True)
def _widened(sx, sy, sz, cone, k):
    """(cos, sin) of phi + theta: the cone of patch k (its row of ``cone``) seen from the
    axis (sx, sy, sz) / |s|, phi the angle between the axes; _WIDE when it reaches 90
    degrees (both angles below 90 degrees: the sum is below 180 and the addition formulas
    hold)."""
    if cone[k, 3] <= _WIDE:
        return _WIDE, 0.0
    cx, cy, cz = cone[k, 0], cone[k, 1], cone[k, 2]
    norm = math.sqrt((sx * sx + sy * sy + sz * sz) * (cx * cx + cy * cy + cz * cz))
    if norm == 0.0:
        return _WIDE, 0.0
    c_phi = (sx * cx + sy * cy + sz * cz) / norm
    if c_phi <= 0.0:
        return _WIDE, 0.0
    s_phi = math.sqrt(max(0.0, 1.0 - c_phi * c_phi))
    c = c_phi * cone[k, 3] - s_phi * cone[k, 4]
    if c <= 0.0:
        return _WIDE, 0.0
    return c, s_phi * cone[k, 3] + c_phi * cone[k, 4]


@njit(cache=True)
def _union_cos(cone, a, b):
    """cos of the half-angle of one cone around the normals of patches a and b."""
    sx, sy, sz = cone[a, 0] + cone[b, 0], cone[a, 1] + cone[b, 1], cone[a, 2] + cone[b, 2]
    return min(_widened(sx, sy, sz, cone, a)[0], _widened(sx, sy, sz, cone, b)[0])


@njit(cache=True)
def refit(tree, triangles, p, fit):
    """Boxes and normal cones of every patch at positions ``p`` (module docstring), leaves
    from their triangles, inner nodes from their children (the nodes in reverse preorder).
    The loops see plain arrays only: a named tuple handed to a helper in a loop costs
    reference counts for each of its arrays on every pass."""
    normals, box, dop, cone = fit.normals, fit.box, fit.dop, fit.cone
    order, first, count, left, right = tree.order, tree.first, tree.count, tree.left, tree.right
    ptr, corners = tree.corner_ptr, tree.leaf_corner
    for f in range(triangles.shape[0]):
        a, b, c = triangles[f, 0], triangles[f, 1], triangles[f, 2]
        e1x, e1y, e1z = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
        e2x, e2y, e2z = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
        normals[f, 0] = e1y * e2z - e1z * e2y  # 2 A n
        normals[f, 1] = e1z * e2x - e1x * e2z
        normals[f, 2] = e1x * e2y - e1y * e2x
    for k in range(first.shape[0] - 1, -1, -1):
        if left[k] < 0:
            _refit_leaf(order, first[k], first[k] + count[k], normals, cone, k)
            _leaf_bounds(corners, ptr[k], ptr[k + 1], p, box, dop, k)
            continue
        l, r = left[k], right[k]
        _union_bounds(box, dop, k, l, r)
        for a in range(3):
            cone[k, a] = cone[l, a] + cone[r, a]
        cl, sl = _widened(cone[k, 0], cone[k, 1], cone[k, 2], cone, l)
        cr, sr = _widened(cone[k, 0], cone[k, 1], cone[k, 2], cone, r)
        cone[k, 3], cone[k, 4] = (cl, sl) if cl < cr else (cr, sr)


@njit(cache=True)
def _union_bounds(box, dop, k, l, r):
    """The box and diagonal bounds of node k: those of its children l and r joined."""
    for a in range(3):
        box[k, a] = min(box[l, a], box[r, a])
        box[k, 3 + a] = max(box[l, 3 + a], box[r, 3 + a])
    for a in range(6):
        dop[k, a] = min(dop[l, a], dop[r, a])
        dop[k, 6 + a] = max(dop[l, 6 + a], dop[r, 6 + a])


@njit(cache=True)
def grow_by_moves(tree, moves, box, dop):
    """The bounds of :func:`refit` grown by how far the patches' vertices moved since the
    last pass: each leaf's box by the largest ``moves`` M_k of its corners, its diagonal
    bounds by sqrt(2) M_k (a move d changes x + y by at most sqrt(2) d), the inner nodes
    the union of their children's. Two patches whose grown bounds come within the
    thickness then hold every vertex-triangle and edge pair that lies within thickness +
    d_1 + d_2 (d the largest move of each part's vertices; at most thickness + M_a + M_b):
    every pair that touches or crossed since the last pass (module docstring). The search
    of the contacts (:func:`self_contacts`) reaches far only where the cloth moved fast."""
    left, right, ptr, corners = tree.left, tree.right, tree.corner_ptr, tree.leaf_corner
    for k in range(left.shape[0] - 1, -1, -1):
        if left[k] >= 0:
            _union_bounds(box, dop, k, left[k], right[k])
            continue
        m = 0.0
        for j in range(ptr[k], ptr[k + 1]):
            m = max(m, moves[corners[j]])
        d = _SQRT2 * m
        for a in range(3):
            box[k, a] -= m
            box[k, 3 + a] += m
        for a in range(6):
            dop[k, a] -= d
            dop[k, 6 + a] += d


@njit(cache=True)
def _refit_leaf(order, start, stop, normals, cone, k):
    """The cone around the normals of leaf k's triangles order[start:stop] (scalars: it
    runs for every leaf in every substep)."""
    sx = sy = sz = 0.0
    for j in range(start, stop):
        f = order[j]
        sx, sy, sz = sx + normals[f, 0], sy + normals[f, 1], sz + normals[f, 2]
    cone[k, 0], cone[k, 1], cone[k, 2] = sx, sy, sz
    norm = math.sqrt(sx * sx + sy * sy + sz * sz)
    low = 1.0
    for j in range(start, stop):
        f = order[j]
        nx, ny, nz = normals[f, 0], normals[f, 1], normals[f, 2]
        nf = math.sqrt(nx * nx + ny * ny + nz * nz)
        if norm == 0.0 or nf == 0.0:
            low = _WIDE
            break
        low = min(low, (sx * nx + sy * ny + sz * nz) / (norm * nf))
    cone[k, 3], cone[k, 4] = (
        (low, math.sqrt(max(0.0, 1.0 - low * low))) if low > 0.0 else (_WIDE, 0.0)
    )


@njit(cache=True)
def _leaf_bounds(corners, start, stop, p, box, dop, k):
    """The box of leaf k's vertices corners[start:stop] and their bounds along the six
    diagonal axes of :func:`_dops_meet` (unnormalised: x + y, x - y, x + z, x - z, y + z,
    y - z), in scalars."""
    x0 = y0 = z0 = d0 = d1 = d2 = d3 = d4 = d5 = np.inf
    x1 = y1 = z1 = e0 = e1 = e2 = e3 = e4 = e5 = -np.inf
    for j in range(start, stop):
        i = corners[j]
        x, y, z = p[i, 0], p[i, 1], p[i, 2]
        x0, x1, y0, y1, z0, z1 = (
            min(x0, x),
            max(x1, x),
            min(y0, y),
            max(y1, y),
            min(z0, z),
            max(z1, z),
        )
        d0, e0, d1, e1 = min(d0, x + y), max(e0, x + y), min(d1, x - y), max(e1, x - y)
        d2, e2, d3, e3 = min(d2, x + z), max(e2, x + z), min(d3, x - z), max(e3, x - z)
        d4, e4, d5, e5 = min(d4, y + z), max(e4, y + z), min(d5, y - z), max(e5, y - z)
    box[k, 0], box[k, 1], box[k, 2], box[k, 3], box[k, 4], box[k, 5] = x0, y0, z0, x1, y1, z1
    dop[k, 0], dop[k, 1], dop[k, 2], dop[k, 3], dop[k, 4], dop[k, 5] = d0, d1, d2, d3, d4, d5
    dop[k, 6], dop[k, 7], dop[k, 8], dop[k, 9], dop[k, 10], dop[k, 11] = e0, e1, e2, e3, e4, e5


@njit(cache=True)
def _dops_meet(dop, a, b, gap):
    """Whether patches a and b may come within ``gap`` of each other along the six
    diagonal axes (1, +-1, 0)/sqrt 2, ... of an 18-DOP (the box's three axes are
    :func:`_boxes_meet`'s): two points within ``gap`` differ by less than ``gap`` along
    every unit axis, so by less than sqrt(2) ``gap`` in the unnormalised sums, widened by
    DOP_SLACK against rounding. A tilted sheet's boxes overlap those of patches two or
    three leaves away; its diagonal bounds separate about half of them (64 x 64 flag)."""
    g = _SQRT2 * gap + DOP_SLACK
    for k in range(6):
        if dop[a, 6 + k] + g < dop[b, k] or dop[b, 6 + k] + g < dop[a, k]:
            return False
    return True


@njit(cache=True)
def _boxes_meet(box_a, a, box_b, b, gap):
    """Whether box row a of ``box_a`` and row b of ``box_b`` (lower and upper corners) come
    within ``gap`` of each other."""
    for k in range(3):
        if box_a[a, 3 + k] + gap < box_b[b, k] or box_b[b, 3 + k] + gap < box_a[a, k]:
            return False
    return True


@njit(cache=True)
def _adjacent(rim_ptr, rim, a, b):
    """Whether the disjoint patches a and b share a vertex: a shared vertex lies on both rims,
    each patch holding a triangle of it outside the other, so the two rims (ascending) are
    merged. No scratch: the threads of :func:`contact_pairs` call it at once."""
    i, j = rim_ptr[a], rim_ptr[b]
    while i < rim_ptr[a + 1] and j < rim_ptr[b + 1]:
        u, v = rim[i], rim[j]
        if u == v:
            return True
        i += u < v
        j += v < u
    return False


@njit(cache=True)
def _bridged(tree, cone, a, b, cos_flat):
    """Whether the connected leaves a and b lie in one flat connected patch with a leaf c
    that shares a vertex with each (the sorted neighbour lists merged; the cone bounded
    about the axis of the three): the patch a + c + b cannot meet itself, as a flat leaf
    cannot (module docstring)."""
    ptr, nbr, connected = tree.nbr_ptr, tree.nbr, tree.connected
    if not (connected[a] and connected[b]):
        return False
    i, j = ptr[a], ptr[b]
    while i < ptr[a + 1] and j < ptr[b + 1]:
        c, d = nbr[i], nbr[j]
        if c == d and connected[c]:
            sx = cone[a, 0] + cone[b, 0] + cone[c, 0]
            sy = cone[a, 1] + cone[b, 1] + cone[c, 1]
            sz = cone[a, 2] + cone[b, 2] + cone[c, 2]
            low = min(_widened(sx, sy, sz, cone, a)[0], _widened(sx, sy, sz, cone, b)[0])
            if min(low, _widened(sx, sy, sz, cone, c)[0]) > cos_flat:
                return True
        i += c <= d
        j += d <= c
    return False


@njit(cache=True)
def leaf_pairs(tree, fit, cos_flat, gap, bridge):
    """(pairs (K, 2), K): the leaf patches to test, (a, a) against itself and (a, b) against
    each other (module docstring): a patch is skipped when it is connected and its cone's
    cosine exceeds ``cos_flat``; two patches when their bounds (:func:`_boxes_meet`,
    :func:`_dops_meet`) are more than ``gap`` apart, or when they are connected, share a
    vertex and fit in one such cone together, or, with ``bridge``, two leaves that a third
    joins into one (:func:`_bridged`: the contacts; not the search for crossings, where a
    crumple tighter than the thickness crosses itself within such a cone)."""
    bounds = _search_bounds(fit)
    return descend(tree, bounds, cos_flat, gap, bridge, _ROOT, _ROOT, _LEAVES, fit.stack)


@njit(cache=True)
def _search_bounds(fit):
    """The patches' (box, dop, cone, live) that :func:`descend` searches by."""
    return fit.box, fit.dop, fit.cone, fit.live


@njit(cache=True)
def descend(tree, bounds, cos_flat, gap, bridge, a0, b0, limit, stack):
    """The depth-first search of :func:`leaf_pairs` from the node pair (a0, b0), with its
    own ``stack``. A pair of nodes of at most ``limit`` triangles together is listed as it
    is popped, untested (``limit`` = _LEAVES: none, the leaf pairs are listed): the tasks
    of :func:`contact_pairs`, in the order in which the whole search would visit them, so
    that their leaf pairs, one task after the other, are the whole search's in its order.
    ``bounds``: the patches' (box, dop, cone, live) (:class:`TreeFit`): a pair of which
    no patch is live is skipped."""
    box, dop, cone, live = bounds
    count, left, right, connected = tree.count, tree.left, tree.right, tree.connected
    pairs = np.empty((64, 2), np.int64)
    found = np.int64(0)  # not the literal 0: :func:`_append` would be compiled for it too
    top = 1
    stack[0, 0], stack[0, 1] = a0, b0
    while top > 0:
        top -= 1
        a, b = stack[top, 0], stack[top, 1]
        if not (live[a] or live[b]):
            continue
        if count[a] + count[b] <= limit:
            pairs, found = _append(pairs, found, a, b)
            continue
        if a == b:
            if connected[a] and cone[a, 3] > cos_flat:
                continue
            if left[a] >= 0:
                l, r = left[a], right[a]
                stack[top, 0], stack[top, 1] = l, l
                stack[top + 1, 0], stack[top + 1, 1] = r, r
                stack[top + 2, 0], stack[top + 2, 1] = l, r
                top += 3
                continue
        else:
            if not _boxes_meet(box, a, box, b, gap) or not _dops_meet(dop, a, b, gap):
                continue
            if (
                connected[a]
                and connected[b]
                and _union_cos(cone, a, b) > cos_flat
                and _adjacent(tree.rim_ptr, tree.rim, a, b)
            ):
                continue
            if bridge and left[a] < 0 and left[b] < 0 and _bridged(tree, cone, a, b, cos_flat):
                continue
            split_a = left[a] >= 0 and (left[b] < 0 or count[a] >= count[b])
            if split_a or left[b] >= 0:
                big, other = (a, b) if split_a else (b, a)
                stack[top, 0], stack[top, 1] = left[big], other
                stack[top + 1, 0], stack[top + 1, 1] = right[big], other
                top += 2
                continue
        pairs, found = _append(pairs, found, a, b)
    return pairs, found


@njit(cache=True)
def contact_pairs(sc, p, fit, gap, reach):
    """:func:`close_pairs` within ``reach`` of the contacts' :func:`leaf_pairs` within
    ``gap`` (of the bounds in ``fit``, grown or not: :func:`grow_by_moves`): on one
    thread, or, for a model searched on threads (:func:`search_threads`), split into the tasks
    of :func:`descend` searched by numba's threads one task at a time
    (:func:`_task_search`) and joined in the task order: the same pairs in the same order
    either way, so the same pushes and the same bits."""
    if sc.threads < 2:
        pairs, found = leaf_pairs(sc.tree, fit, _COS_CONTACT, gap, _BRIDGE)
        return close_pairs(sc, p, fit.box, pairs, found, reach)
    bounds, limit = _search_bounds(fit), _task_limit(sc)
    tasks, n = descend(sc.tree, bounds, _COS_CONTACT, gap, _BRIDGE, _ROOT, _ROOT, limit, fit.stack)
    vt, ee, _ = _task_search(sc, p, fit, tasks, n, gap, reach, _CONTACTS)
    return vt, ee


@njit(cache=True, parallel=True)
def _task_search(sc, p, fit, tasks, n, gap, reach, crossings):
    """(vertex-triangle pairs, edge pairs, crossings) of the tasks tasks[:n] of
    :func:`descend` (leaf pairs within ``gap``), searched in a parallel loop over the
    model's threads, thread w of T taking tasks w, w + T, w + 2 T, ... with its own stack:
    with ``crossings``, the intersecting triangle pairs of
    :func:`_threaded_crossing_count` (boxes alone, gap 0), summed; else the close pairs
    within ``reach`` of :func:`contact_pairs`, joined in the task order. Dealt out so,
    neighbouring tasks, which cost alike (a fold is one patch of the cloth), go to
    different threads: in contiguous halves one thread would hold most of a flapping
    flag's leaf pairs."""
    vt_parts, ee_parts = List(), List()
    for _ in range(n):
        vt_parts.append(np.empty((0, 2), np.int64))
        ee_parts.append(np.empty((0, 2), np.int64))
    box, dop, cone, live, stack = fit.box, fit.dop, fit.cone, fit.live, fit.stack
    triangles, workers, edges = sc.triangles, sc.threads, sc.tree.leaf_edge
    cos_flat, bridge = (_NEVER_FLAT, _NO_BRIDGE) if crossings else (_COS_CONTACT, _BRIDGE)
    eb = _edge_boxes(p, edges[:0] if crossings else edges)
    counts = np.zeros(workers, np.int64)
    # a parallel loop takes arrays and scalars, no tuples: the tree is packed again in it
    t0, t1, t2, t3, t4, t5, t6, t7, t8, t9, t10, t11, t12, t13, t14, t15, t16 = sc.tree
    for w in prange(workers):
        tree = PatchTree(t0, t1, t2, t3, t4, t5, t6, t7, t8, t9, t10, t11, t12, t13, t14, t15, t16)
        own, bounds = np.empty_like(stack), (box, dop, cone, live)
        for t in range(w, n, workers):
            a, b = tasks[t, 0], tasks[t, 1]
            pairs, found = descend(tree, bounds, cos_flat, gap, bridge, a, b, _LEAVES, own)
            if crossings:
                counts[w] += _crossings(tree, triangles, p, pairs, found)
            else:
                vt_parts[t] = _close_vertices(tree, triangles, p, box, pairs, found, reach)
                ee_parts[t] = _close_edges(tree, p, box, eb, pairs, found, reach)
    return _joined(vt_parts), _joined(ee_parts), counts.sum()


@njit(cache=True)
def _joined(parts):
    """The (K_i, 2) arrays of the list ``parts`` stacked in order."""
    total = 0
    for part in parts:
        total += part.shape[0]
    out = np.empty((total, 2), np.int64)
    n = 0
    for part in parts:
        out[n : n + part.shape[0]] = part
        n += part.shape[0]
    return out


@njit(cache=True)
def _grown(rows):
    """``rows`` (K, w) copied into an array of twice the rows."""
    out = np.empty((2 * rows.shape[0], rows.shape[1]), rows.dtype)
    copy_rows(out, rows, rows.shape[0])
    return out


@njit(cache=True)
def _append(rows, n, a, b):
    """(rows, n + 1) with the pair (a, b) written at row n (``rows`` grown when full)."""
    if n == rows.shape[0]:
        rows = _grown(rows)
    rows[n, 0], rows[n, 1] = a, b
    return rows, n + 1


@njit(cache=True)
def _plane(p, tri):
    """(nx, ny, nz, 2 A): unit normal of triangle ``tri`` at ``p`` and twice its area."""
    a, b, c = tri[0], tri[1], tri[2]
    e1x, e1y, e1z = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
    e2x, e2y, e2z = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    area2 = np.sqrt(nx * nx + ny * ny + nz * nz)
    if area2 > 0.0:
        nx, ny, nz = nx / area2, ny / area2, nz / area2
    return nx, ny, nz, area2


@njit(cache=True)
def _height(p, tri, i, nx, ny, nz):
    """(x_i - x_tri[0]) . n."""
    a = tri[0]
    return (p[i, 0] - p[a, 0]) * nx + (p[i, 1] - p[a, 1]) * ny + (p[i, 2] - p[a, 2]) * nz


@njit(cache=True)
def _barycentric(p, tri, i, nx, ny, nz, area2, k):
    """Barycentric coordinate k of the projection of vertex i on the plane of ``tri``:
    beta_k = ((x_b - x_a) x (x_i - x_a)) . n / 2A over the edge a-b opposite corner k."""
    a, b = tri[(k + 1) % 3], tri[(k + 2) % 3]
    ux, uy, uz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
    wx, wy, wz = p[i, 0] - p[a, 0], p[i, 1] - p[a, 1], p[i, 2] - p[a, 2]
    cx, cy, cz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    return (cx * nx + cy * ny + cz * nz) / area2


@njit(cache=True)
def push_vertex(p, xp, inv_mass, i, tri, thickness, moves):
    """The vertex-triangle contact of vertex i and triangle ``tri`` (module docstring),
    for a vertex within the pair's reach (:func:`pair_reach` of the vertices' ``moves``
    since ``xp``) of the triangle's plane. Returns C (0 when they do not touch)."""
    nx, ny, nz, area2 = _plane(p, tri)
    if area2 == 0.0:
        return 0.0
    dist = _height(p, tri, i, nx, ny, nz)
    corners = max(moves[tri[0]], moves[tri[1]], moves[tri[2]])
    if abs(dist) >= pair_reach(moves[i], corners, thickness):
        return 0.0
    beta = (
        _barycentric(p, tri, i, nx, ny, nz, area2, 0),
        _barycentric(p, tri, i, nx, ny, nz, area2, 1),
        _barycentric(p, tri, i, nx, ny, nz, area2, 2),
    )
    if beta[0] < 0.0 or beta[1] < 0.0 or beta[2] < 0.0:
        return 0.0
    mx, my, mz, a0 = _plane(xp, tri)
    if mx * nx + my * ny + mz * nz < 0.0:
        return 0.0  # turned over since the last pass: its sides have swapped, not the vertex
    side = _height(xp, tri, i, mx, my, mz) if a0 > 0.0 else dist
    s = 1.0 if (side if side != 0.0 else dist) >= 0.0 else -1.0
    c = s * dist - thickness
    if c >= 0.0:
        return 0.0
    den = inv_mass[i]
    for k in range(3):
        den += beta[k] * beta[k] * inv_mass[tri[k]]
    if den <= 0.0:
        return 0.0
    g = -c * s / den
    n = (nx, ny, nz)
    for a in range(3):
        p[i, a] += g * inv_mass[i] * n[a]
        for k in range(3):
            p[tri[k], a] -= g * beta[k] * inv_mass[tri[k]] * n[a]
    return c


@njit(cache=True)
def _outside_box(p, tri, i, gap):
    """Whether vertex i lies outside the box of triangle ``tri`` grown by ``gap``."""
    for k in range(3):
        x = p[i, k]
        if x + gap < min(p[tri[0], k], p[tri[1], k], p[tri[2], k]):
            return True
        if x - gap > max(p[tri[0], k], p[tri[1], k], p[tri[2], k]):
            return True
    return False


@njit(cache=True)
def _segment_parameters(p, i, j, k, l):
    """(s, u, |gap|^2) of the closest points p_i + s (p_j - p_i), p_k + u (p_l - p_k) of two
    edges (clamped to [0, 1]; parallel edges: s = 0), in scalars: it runs for every
    candidate pair."""
    d1x, d1y, d1z = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
    d2x, d2y, d2z = p[l, 0] - p[k, 0], p[l, 1] - p[k, 1], p[l, 2] - p[k, 2]
    rx, ry, rz = p[i, 0] - p[k, 0], p[i, 1] - p[k, 1], p[i, 2] - p[k, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    b = d1x * d2x + d1y * d2y + d1z * d2z
    c = d1x * rx + d1y * ry + d1z * rz
    f = d2x * rx + d2y * ry + d2z * rz
    den = a * e - b * b
    s = min(1.0, max(0.0, (b * f - c * e) / den)) if den > 1e-12 * a * e else 0.0
    u = (b * s + f) / e if e > 0.0 else 0.0
    if u < 0.0:
        u, s = 0.0, (min(1.0, max(0.0, -c / a)) if a > 0.0 else 0.0)
    elif u > 1.0:
        u, s = 1.0, (min(1.0, max(0.0, (b - c) / a)) if a > 0.0 else 0.0)
    gx, gy, gz = rx + s * d1x - u * d2x, ry + s * d1y - u * d2y, rz + s * d1z - u * d2z
    return s, u, gx * gx + gy * gy + gz * gz


@njit(cache=True)
def push_edges(p, xp, inv_mass, i, j, k, l, thickness, moves):
    """The edge-edge contact of edges i-j and k-l closer than their reach
    (:func:`pair_reach` of the vertices' ``moves`` since ``xp``): their closest points q1,
    q2 (both inside the edges) kept ``thickness`` apart along n = e1 x e2 on the side they
    lay on at ``xp``: C = s (q1 - q2) . n - thickness, the four vertices moved with their
    barycentric weights w = (1 - s, s, -(1 - u), -u) and inverse masses. Returns C (0 when
    they do not touch). Scalars only: it runs for every close pair."""
    reach = pair_reach(max(moves[i], moves[j]), max(moves[k], moves[l]), thickness)
    s, u, gap2 = _segment_parameters(p, i, j, k, l)
    if s <= 0.0 or s >= 1.0 or u <= 0.0 or u >= 1.0 or gap2 >= reach * reach:
        return 0.0  # apart, or nearest at an end point: the vertex-triangle contacts' business
    ax, ay, az = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
    bx, by, bz = p[l, 0] - p[k, 0], p[l, 1] - p[k, 1], p[l, 2] - p[k, 2]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if norm == 0.0:
        return 0.0
    nx, ny, nz = nx / norm, ny / norm, nz / norm
    w0, w1, w2, w3 = 1.0 - s, s, -(1.0 - u), -u
    dist = before = 0.0
    for x, y in ((nx, 0), (ny, 1), (nz, 2)):
        dist += x * (w0 * p[i, y] + w1 * p[j, y] + w2 * p[k, y] + w3 * p[l, y])
        before += x * (w0 * xp[i, y] + w1 * xp[j, y] + w2 * xp[k, y] + w3 * xp[l, y])
    if abs(dist) >= reach:
        return 0.0
    sgn = 1.0 if (before if before != 0.0 else dist) >= 0.0 else -1.0
    c = sgn * dist - thickness
    den = w0 * w0 * inv_mass[i] + w1 * w1 * inv_mass[j] + w2 * w2 * inv_mass[k]
    den += w3 * w3 * inv_mass[l]
    if c >= 0.0 or den <= 0.0:
        return 0.0
    g = -c * sgn / den
    for y, n in ((0, nx), (1, ny), (2, nz)):
        p[i, y] += g * w0 * inv_mass[i] * n
        p[j, y] += g * w1 * inv_mass[j] * n
        p[k, y] += g * w2 * inv_mass[k] * n
        p[l, y] += g * w3 * inv_mass[l] * n
    return c


@njit(cache=True)
def _incident(tri, i):
    return tri[0] == i or tri[1] == i or tri[2] == i


@njit(cache=True)
def _outside_patch(p, box, k, i, gap):
    """Whether vertex i lies outside the box of patch k grown by ``gap``."""
    for a in range(3):
        if p[i, a] + gap < box[k, a] or p[i, a] - gap > box[k, 3 + a]:
            return True
    return False


@njit(cache=True)
def _vertex_near_triangle(p, i, tri, reach):
    """Whether vertex i lies within ``reach`` of the plane of ``tri`` and projects inside
    it: the part of :func:`push_vertex`'s test that does not need the start positions."""
    nx, ny, nz, area2 = _plane(p, tri)
    if area2 == 0.0 or abs(_height(p, tri, i, nx, ny, nz)) >= reach:
        return False
    for k in range(3):
        if _barycentric(p, tri, i, nx, ny, nz, area2, k) < 0.0:
            return False
    return True


@njit(cache=True)
def _edges_close(p, i, j, k, l, reach):
    """Whether edges i-j and k-l come within ``reach`` at points inside both (the first
    test of :func:`push_edges`)."""
    s, u, gap2 = _segment_parameters(p, i, j, k, l)
    return 0.0 < s < 1.0 and 0.0 < u < 1.0 and gap2 < reach * reach


@njit(cache=True)
def _edge_boxes(p, edges):
    """(E, 6) the boxes of the edges (rows i, j) at ``p``: lower and upper corners."""
    out = np.empty((edges.shape[0], 6))
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        for a in range(3):
            out[e, a], out[e, 3 + a] = min(p[i, a], p[j, a]), max(p[i, a], p[j, a])
    return out


@njit(cache=True)
def close_pairs(sc, p, box, pairs, found, reach):
    """(vertex-triangle pairs (K, 2): vertex, triangle; edge pairs (L, 2): rows of
    ``leaf_edge``) that may touch at ``p`` within the leaf pairs ``pairs[:found]``:
    vertices within ``reach`` of a triangle's plane and projecting inside it, edges within
    ``reach`` at inner points. Found in loops of plain arrays and scalar tests, and pushed
    apart after them (:func:`self_contacts`): a call inside a search loop would cost
    reference counts on every pass."""
    eb = _edge_boxes(p, sc.tree.leaf_edge)
    return (
        _close_vertices(sc.tree, sc.triangles, p, box, pairs, found, reach),
        _close_edges(sc.tree, p, box, eb, pairs, found, reach),
    )


@njit(cache=True)
def _close_vertices(tree, triangles, p, box, pairs, found, reach):
    """The vertex-triangle pairs of :func:`close_pairs`."""
    order, first, count = tree.order, tree.first, tree.count
    vert_ptr, leaf_vert = tree.vert_ptr, tree.leaf_vert
    vt = np.empty((64, 2), np.int64)
    n_vt = np.int64(0)  # not the literal 0: :func:`_append` would be compiled for it
    for q in range(found):
        a, b = pairs[q, 0], pairs[q, 1]
        for side in range(1 if a == b else 2):
            va, tb = (a, b) if side == 0 else (b, a)
            for w in range(vert_ptr[va], vert_ptr[va + 1]):
                i = leaf_vert[w]
                if _outside_patch(p, box, tb, i, reach):
                    continue
                for j in range(first[tb], first[tb] + count[tb]):
                    f = order[j]
                    tri = (triangles[f, 0], triangles[f, 1], triangles[f, 2])  # no array view
                    if _incident(tri, i) or _outside_box(p, tri, i, reach):
                        continue
                    if _vertex_near_triangle(p, i, tri, reach):
                        vt, n_vt = _append(vt, n_vt, i, f)
    return vt[:n_vt]


@njit(cache=True)
def _close_edges(tree, p, box, eb, pairs, found, reach):
    """The edge pairs of :func:`close_pairs`, with the edges' boxes ``eb`` computed once
    (:func:`_edge_boxes`): an edge's box against the other patch's, then against each of
    its edges', then the closest points."""
    edge_ptr, edges = tree.edge_ptr, tree.leaf_edge
    ee = np.empty((64, 2), np.int64)
    n_ee = np.int64(0)  # as in :func:`_close_vertices`
    for q in range(found):
        a, b = pairs[q, 0], pairs[q, 1]
        for e in range(edge_ptr[a], edge_ptr[a + 1]):
            if not _boxes_meet(eb, e, box, b, reach):
                continue
            i, j = edges[e, 0], edges[e, 1]
            for g in range(e + 1 if a == b else edge_ptr[b], edge_ptr[b + 1]):
                k, l = edges[g, 0], edges[g, 1]
                if i == k or i == l or j == k or j == l or not _boxes_meet(eb, e, eb, g, reach):
                    continue
                if _edges_close(p, i, j, k, l, reach):
                    ee, n_ee = _append(ee, n_ee, e, g)
    return ee[:n_ee]


@njit(cache=True)
def self_contacts(sc, inv_mass, p, x0, fit):
    """One pass of the contacts of the module docstring, each vertex and edge kept on the
    side it lay on at ``x0`` (the last pass's positions) and searched within its pair's
    reach (:func:`pair_reach` of the moves since ``x0``): over the leaf patches whose
    bounds grown by those moves come within the thickness (:func:`leaf_pairs` after
    :func:`refit` and :func:`grow_by_moves`), the pairs within the largest pair reach
    (:func:`close_pairs`), vertices against triangles, then edges against edges. Returns
    the number of pairs it pushed apart."""
    triangles, thickness, edges = sc.triangles, sc.thickness, sc.tree.leaf_edge
    if triangles.shape[0] == 0:
        return 0
    moves = vertex_moves(p, x0, fit.moves)
    largest = moves.max()  # there are triangles, so vertices
    reach = pair_reach(largest, largest, thickness)
    refit(sc.tree, triangles, p, fit)
    grow_by_moves(sc.tree, moves, fit.box, fit.dop)
    vt, ee = contact_pairs(sc, p, fit, thickness, reach)
    pushed = 0
    for q in range(vt.shape[0]):
        f = vt[q, 1]
        tri = (triangles[f, 0], triangles[f, 1], triangles[f, 2])
        if push_vertex(p, x0, inv_mass, vt[q, 0], tri, thickness, moves) < 0.0:
            pushed += 1
            _mark(fit.pushed, vt[q, 0], tri[0], tri[1], tri[2])
    for q in range(ee.shape[0]):
        e, g = ee[q, 0], ee[q, 1]
        i, j, k, l = edges[e, 0], edges[e, 1], edges[g, 0], edges[g, 1]
        if push_edges(p, x0, inv_mass, i, j, k, l, thickness, moves) < 0.0:
            pushed += 1
            _mark(fit.pushed, i, j, k, l)
    return pushed


@njit(cache=True)
def _mark(flags, i, j, k, l):
    """flags[i], flags[j], flags[k], flags[l] = True."""
    flags[i] = flags[j] = flags[k] = flags[l] = True


@njit(cache=True)
def live_patches(tree, pushed, live):
    """``live`` set for the patches that hold a ``pushed`` vertex (leaves by their corners,
    inner nodes by their children), and cleared for the others."""
    left, right, ptr, corners = tree.left, tree.right, tree.corner_ptr, tree.leaf_corner
    for k in range(left.shape[0] - 1, -1, -1):
        if left[k] >= 0:
            live[k] = live[left[k]] or live[right[k]]
            continue
        live[k] = False
        for j in range(ptr[k], ptr[k + 1]):
            if pushed[corners[j]]:
                live[k] = True
                break


@njit(cache=True)
def vertex_moves(p, q, out):
    """``out`` filled with |p_i - q_i| (m), and returned."""
    for i in range(p.shape[0]):
        dx, dy, dz = p[i, 0] - q[i, 0], p[i, 1] - q[i, 1], p[i, 2] - q[i, 2]
        out[i] = math.sqrt(dx * dx + dy * dy + dz * dz)
    return out


@njit(cache=True)
def pair_reach(moved_1, moved_2, thickness):
    """The search distance of a pair (a vertex and a triangle, or two edges) whose parts
    moved at most ``moved_1`` and ``moved_2`` since the last pass: REACH thickness, and at
    least moved_1 + moved_2 + thickness, so that a pair that crossed since then is found
    (module docstring). The closest point of a triangle or an edge, at fixed barycentric
    weights, moves at most as far as its farthest corner."""
    return max(REACH * thickness, moved_1 + moved_2 + thickness)


@njit(cache=True)
def pass_due(p, xp, anchor, thickness, last):
    """Whether :func:`self_contact_substep` must run the pass now: in the frame's ``last``
    substep, or when the cloth may have moved so far since the pass at ``anchor`` that a
    crossing would leave the base reach (REACH thickness) before the next substep: a later
    pass still finds it (:func:`pair_reach`), but the sooner a crossing is undone, the
    smaller the push. Two points moving at most d each since the pass are at most 2 d
    closer; the pass runs when 2 (d + d_h) would exceed (REACH - 1) thickness,
    d = max_i |p_i - anchor_i|, d_h = max_i |p_i - xp_i| (this substep's move, the
    estimate of the next one's)."""
    if last:
        return True
    moved = largest_move(p, anchor) + largest_move(p, xp)
    return 2.0 * moved > (REACH - 1.0) * thickness


@njit(cache=True)
def self_contact_substep(sc, inv_mass, p, xp, fit, last):
    """The self-contacts of one substep: :func:`self_contacts` with the sides of the last
    pass (``fit.anchor``, the frame's start for the first), when :func:`pass_due`. A slow
    cloth (a shirt, a sheltered flag) runs it once or twice a frame, a flapping flag in
    every substep.

    A pass that pushed a pair apart is followed by another, up to PASS_SWEEPS, with the
    same sides: a push can carry a vertex or an edge through a layer that was beyond the
    reach when the pass searched (a layer pushed off the one above it, into the one
    below), and only a new search finds that. Without it, a quad of two_flags_wall's
    sheltered flag folded flat about its diagonal left its layers crossed for the rest of
    the run. The new search starts from the patches that hold a pushed vertex
    (:func:`live_patches`): a pair none of whose vertices the pushes moved is where the
    first search left it."""
    if pass_due(p, xp, fit.anchor, sc.thickness, last):
        fit.pushed[:] = False
        for sweep in range(PASS_SWEEPS):
            fit.passes[0] += 1
            if self_contacts(sc, inv_mass, p, fit.anchor, fit) == 0 or sweep == PASS_SWEEPS - 1:
                break
            live_patches(sc.tree, fit.pushed, fit.live)
            fit.pushed[:] = False
        fit.live[:] = True
        copy_rows(fit.anchor, p, p.shape[0])


@njit(cache=True)
def segment_crosses(p, i, j, a, b, c):
    """Whether the segment x_i-x_j meets the triangle x_a x_b x_c (Moeller-Trumbore, in
    scalars: it runs for every candidate pair)."""
    dx, dy, dz = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
    e1x, e1y, e1z = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
    e2x, e2y, e2z = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
    hx, hy, hz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * hx + e1y * hy + e1z * hz
    if abs(det) < 1e-300:
        return False
    sx, sy, sz = p[i, 0] - p[a, 0], p[i, 1] - p[a, 1], p[i, 2] - p[a, 2]
    u = (sx * hx + sy * hy + sz * hz) / det
    if u < 0.0 or u > 1.0:
        return False
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) / det
    if v < 0.0 or u + v > 1.0:
        return False
    t = (e2x * qx + e2y * qy + e2z * qz) / det
    return 0.0 <= t <= 1.0


@njit(cache=True)
def _share_vertex(a, b):
    for u in range(3):
        for v in range(3):
            if a[u] == b[v]:
                return True
    return False


@njit(cache=True)
def triangles_cross(p, a, b):
    """Whether an edge of triangle ``a`` crosses triangle ``b`` or one of b's crosses a."""
    for k in range(3):
        if segment_crosses(p, a[k], a[(k + 1) % 3], b[0], b[1], b[2]):
            return True
        if segment_crosses(p, b[k], b[(k + 1) % 3], a[0], a[1], a[2]):
            return True
    return False


@njit(cache=True)
def _boxes_apart(p, a, b):
    """Whether the boxes of triangles ``a`` and ``b`` do not meet."""
    for k in range(3):
        if max(p[a[0], k], p[a[1], k], p[a[2], k]) < min(p[b[0], k], p[b[1], k], p[b[2], k]):
            return True
        if min(p[a[0], k], p[a[1], k], p[a[2], k]) > max(p[b[0], k], p[b[1], k], p[b[2], k]):
            return True
    return False


@njit(cache=True)
def _one_side(p, f, g):
    """Whether the corners of triangle ``g`` (a 3-tuple) all lie strictly on one side of
    the plane of triangle ``f``: then the two cannot cross (exact, no tolerance)."""
    a, b, c = f
    e1x, e1y, e1z = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
    e2x, e2y, e2z = p[c, 0] - p[a, 0], p[c, 1] - p[a, 1], p[c, 2] - p[a, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    above = below = 0
    for k in g:
        d = (p[k, 0] - p[a, 0]) * nx + (p[k, 1] - p[a, 1]) * ny + (p[k, 2] - p[a, 2]) * nz
        above += d > 0.0
        below += d < 0.0
    return above == 3 or below == 3


@njit(cache=True)
def _crossing_candidates(tree, triangles, p, pairs, found):
    """(K, 2) triangle pairs of the leaf pairs ``pairs[:found]`` without a common vertex,
    whose boxes meet and neither of which lies on one side of the other's plane, in a loop
    of plain arrays and scalar tests (the segment tests come after it)."""
    out = np.empty((64, 2), np.int64)
    n = np.int64(0)  # as in :func:`_close_vertices`
    for q in range(found):
        a, b = pairs[q, 0], pairs[q, 1]
        for j in range(tree.first[a], tree.first[a] + tree.count[a]):
            f = tree.order[j]
            tf = (triangles[f, 0], triangles[f, 1], triangles[f, 2])
            start = j + 1 if a == b else tree.first[b]
            for jj in range(start, tree.first[b] + tree.count[b]):
                g = tree.order[jj]
                tg = (triangles[g, 0], triangles[g, 1], triangles[g, 2])
                if _share_vertex(tf, tg) or _boxes_apart(p, tf, tg):
                    continue
                if _one_side(p, tf, tg) or _one_side(p, tg, tf):
                    continue
                out, n = _append(out, n, f, g)
    return out[:n]


@njit(cache=True)
def _crossing_count(sc, p, fit):
    """The intersecting triangle pairs (module docstring) over the leaf pairs of
    :func:`leaf_pairs` by their boxes alone: each pair of triangles lies in one leaf pair,
    so each is counted once."""
    triangles = sc.triangles
    refit(sc.tree, triangles, p, fit)
    pairs, found = leaf_pairs(sc.tree, fit, _NEVER_FLAT, 0.0, _NO_BRIDGE)
    return _crossings(sc.tree, triangles, p, pairs, found)


@njit(cache=True)
def _threaded_crossing_count(sc, p, fit):
    """:func:`_crossing_count` split into the tasks of :func:`descend` (the model's task
    limit) that the threads count at once (:func:`_task_search`): the same sum. A
    separate entry point, so that a run that never takes it never compiles it."""
    refit(sc.tree, sc.triangles, p, fit)
    bounds, limit = _search_bounds(fit), _task_limit(sc)
    tasks, n = descend(
        sc.tree, bounds, _NEVER_FLAT, 0.0, _NO_BRIDGE, _ROOT, _ROOT, limit, fit.stack
    )
    return _task_search(sc, p, fit, tasks, n, 0.0, 0.0, _CROSSINGS)[2]


@njit(cache=True)
def _crossings(tree, triangles, p, pairs, found):
    """The intersecting triangle pairs within the leaf pairs ``pairs[:found]``."""
    candidates = _crossing_candidates(tree, triangles, p, pairs, found)
    count = 0
    for q in range(candidates.shape[0]):
        f, g = candidates[q, 0], candidates[q, 1]
        count += triangles_cross(p, triangles[f], triangles[g])
    return count


@njit(cache=True)
def _shallow_end(p, a, i, j):
    """(k, depth, s) for an edge i-j crossing triangle ``a``: its end k nearer to a's plane,
    |height| of k, and the side s (+-1) of the other end."""
    nx, ny, nz, _ = _plane(p, a)
    hi, hj = _height(p, a, i, nx, ny, nz), _height(p, a, j, nx, ny, nz)
    if abs(hi) < abs(hj):
        return i, abs(hi), (1.0 if hj >= 0.0 else -1.0)
    return j, abs(hj), (1.0 if hi >= 0.0 else -1.0)


@njit(cache=True)
def _uncross_edge(p, inv_mass, a, i, j, thickness):
    """Edge i-j, if it crosses triangle ``a``, taken back through a's plane at its shallower
    end k (:func:`_shallow_end`): k moved along a's unit normal n to ``thickness`` on the
    side s of the other end, C = s h_k - thickness, h_k = (x_k - x_a0) . n, against a's
    corners with the barycentric weights beta of k's projection (clamped into the
    triangle) as in :func:`push_vertex`. Returns whether it moved."""
    if not segment_crosses(p, i, j, a[0], a[1], a[2]):
        return False
    nx, ny, nz, area2 = _plane(p, a)
    if area2 == 0.0:
        return False
    k, _, s = _shallow_end(p, a, i, j)
    c = s * _height(p, a, k, nx, ny, nz) - thickness
    beta = _clamped_barycentric(p, a, k, nx, ny, nz, area2)
    den = inv_mass[k]
    for q in range(3):
        den += beta[q] * beta[q] * inv_mass[a[q]]
    if c >= 0.0 or den <= 0.0:
        return False
    g = -c * s / den
    for d, n in ((0, nx), (1, ny), (2, nz)):
        p[k, d] += g * inv_mass[k] * n
        for q in range(3):
            p[a[q], d] -= g * beta[q] * inv_mass[a[q]] * n
    return True


@njit(cache=True)
def _clamped_barycentric(p, tri, i, nx, ny, nz, area2):
    """The barycentric coordinates of vertex i's projection on triangle ``tri``, negative
    ones set to 0 and the rest rescaled to sum 1 (a point of the triangle)."""
    b0 = max(0.0, _barycentric(p, tri, i, nx, ny, nz, area2, 0))
    b1 = max(0.0, _barycentric(p, tri, i, nx, ny, nz, area2, 1))
    b2 = max(0.0, _barycentric(p, tri, i, nx, ny, nz, area2, 2))
    total = b0 + b1 + b2
    if total == 0.0:
        return (1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)
    return (b0 / total, b1 / total, b2 / total)


@njit(cache=True)
def untangle(sc, inv_mass, p, fit):
    """Undo the crossings of the cloth with itself at positions ``p`` (in place). Every
    edge that crosses a triangle (of the intersecting pairs :func:`self_intersections`
    counts) is taken back through the triangle's plane at its shallower end, to the
    thickness on the other end's side (:func:`_uncross_edge`). A vertex poked through a
    sheet is the shallower end of all its crossing edges, while each edge of the sheet
    that crosses the vertex's fan, judged against a steep fan triangle, names an end of
    its own: the edges go in the order of how many crossing edges their shallower end
    holds, most first (then the shallowest), so that the vertex goes back and the fan's
    crossings with it. Rounds repeat, UNTANGLE_ROUNDS at most, while each leaves fewer
    crossing edges than the one before (a region poked through comes back ring by ring
    from its border); a round that does not is undone and the edges are tried one at a
    time instead (:func:`_one_edge`: in a crease folded tighter than the thickness the
    push of one edge crosses a neighbour), and when none helps, the shallower ends are
    pulled into their rings (:func:`_unfold`: a crumple of a few triangles); when that
    does not help either, the crossing is left to the next frame. The contacts keep a
    vertex on the side it lay on at their last pass, so a crossing deeper than the
    thickness would otherwise stay. A pairwise form of the intersection-contour
    minimisation of Volino and Magnenat-Thalmann (2006). Returns the number of moves
    kept (an edge, or one unfolding); 0, and ``p`` unchanged, without a crossing."""
    moved = 0
    if sc.triangles.shape[0] < 2:
        return moved
    rows = _crossing_edges(sc, p, fit)
    for _ in range(UNTANGLE_ROUNDS):
        if rows.shape[0] == 0:
            break
        before = p.copy()
        now = 0
        for r in range(rows.shape[0]):
            now += _take_back(sc, inv_mass, p, rows, r, 1.0)
        after = _crossing_edges(sc, p, fit)
        if after.shape[0] >= rows.shape[0]:
            copy_rows(p, before, p.shape[0])
            now, after = _one_edge(sc, inv_mass, p, fit, rows)
            if now == 0:
                now, after = _kept_if_fewer(sc, p, fit, rows, _unfold(sc, inv_mass, p, rows))
            if now == 0:
                break
        moved += now
        rows = after
    return moved


@njit(cache=True)
def _one_edge(sc, inv_mass, p, fit, rows):
    """(1, crossing edges after) for the first of the crossing edges ``rows`` (in their
    order) whose move alone, to the thickness or to a tenth of it, leaves fewer crossing
    edges; (0, rows) and ``p`` unchanged when none does (:func:`_kept_if_fewer`)."""
    for r in range(rows.shape[0]):
        for clearance in (1.0, 0.1):
            q = p.copy()
            if _take_back(sc, inv_mass, q, rows, r, clearance):
                kept, after = _kept_if_fewer(sc, p, fit, rows, q)
                if kept:
                    return kept, after
    return 0, rows


@njit(cache=True)
def _unfold(sc, inv_mass, p, rows):
    """A copy of ``p`` in which each distinct shallower end k of the crossing edges
    ``rows`` is pulled to the centroid of its ring of neighbours j (the umbrella operator;
    Taubin 1995): C = x_k - (1/n) sum_j x_j = 0, projected with the inverse masses w as a
    position constraint, lam = -C / (w_k + sum_j w_j / n^2), dx_k = w_k lam, dx_j =
    -(w_j / n) lam (momentum kept). It opens a crumple of a few triangles folded tighter
    than the thickness, whose apexes poke through each other's fans so that taking one
    apex back pushes its neighbours through."""
    q = p.copy()
    done = np.zeros(p.shape[0], np.bool_)
    for r in range(rows.shape[0]):
        k = rows[r, 3]
        start, stop = sc.ring_ptr[k], sc.ring_ptr[k + 1]
        if done[k] or stop == start:
            continue
        done[k] = True
        n = stop - start
        centroid = np.zeros(3)
        w_ring = 0.0
        for m in range(start, stop):
            centroid += q[sc.ring[m]] / n
            w_ring += inv_mass[sc.ring[m]]
        den = inv_mass[k] + w_ring / (n * n)
        if den <= 0.0:
            continue
        lam = (centroid - q[k]) / den
        q[k] += inv_mass[k] * lam
        for m in range(start, stop):
            q[sc.ring[m]] -= inv_mass[sc.ring[m]] / n * lam
    return q


@njit(cache=True)
def _kept_if_fewer(sc, p, fit, rows, q):
    """(1, crossing edges at q) with ``p`` set to ``q`` if q leaves fewer crossing edges
    than ``rows``; else (0, rows), p unchanged."""
    after = _crossing_edges(sc, q, fit)
    if after.shape[0] >= rows.shape[0]:
        return 0, rows
    copy_rows(p, q, p.shape[0])
    return 1, after


@njit(cache=True)
def _crossing_edges(sc, p, fit):
    """(E, 4) rows (i, j, f, k): edge i-j of an intersecting pair crossing triangle f, k its
    shallower end, for the pairs at ``p``, in the order :func:`untangle` takes them back:
    by how many crossing edges their shallower end holds, most first, then by its depth.
    The search culls by the boxes and by the normal cones at 90 degrees (Volino and
    Magnenat-Thalmann 1994: a connected patch whose normals lie within such a cone cannot
    cross itself unless its contour overlaps itself in projection, module docstring):
    searched by boxes alone, as the figure is, it would cost a flapping flag's frame
    several times what it costs with the cones (``bench_cloth.py``)."""
    triangles = sc.triangles
    refit(sc.tree, triangles, p, fit)
    pairs, found = leaf_pairs(sc.tree, fit, _COS_UNTANGLE, 0.0, _NO_BRIDGE)
    candidates = _crossing_candidates(sc.tree, triangles, p, pairs, found)
    rows = np.empty((max(1, 6 * candidates.shape[0]), 4), np.int64)
    depth = np.empty(rows.shape[0])
    n = 0
    for q in range(candidates.shape[0]):
        for side in range(2):
            f, g = candidates[q, side], candidates[q, 1 - side]
            a = (triangles[f, 0], triangles[f, 1], triangles[f, 2])
            for e in range(3):
                i, j = triangles[g, e], triangles[g, (e + 1) % 3]
                if segment_crosses(p, i, j, a[0], a[1], a[2]):
                    rows[n, 0], rows[n, 1], rows[n, 2] = i, j, f
                    rows[n, 3], depth[n] = _shallow_end(p, a, i, j)[:2]
                    n += 1
    votes = np.zeros(p.shape[0], np.int64)
    for r in range(n):
        votes[rows[r, 3]] += 1
    key = np.empty(n)
    for r in range(n):
        key[r] = -votes[rows[r, 3]] + min(depth[r], 1.0) / 2.0  # a vote outweighs any depth
    return rows[:n][np.argsort(key, kind="mergesort")]


@njit(cache=True)
def _take_back(sc, inv_mass, p, rows, r, clearance):
    """Crossing edge ``rows[r]`` taken back if it still crosses, to ``clearance``
    thicknesses past the plane (:func:`_uncross_edge`). Returns whether it moved."""
    f = rows[r, 2]
    a = (sc.triangles[f, 0], sc.triangles[f, 1], sc.triangles[f, 2])
    return _uncross_edge(p, inv_mass, a, rows[r, 0], rows[r, 1], clearance * sc.thickness)


def self_intersections(sc: SelfContact, positions) -> int:
    """The number of intersecting pairs of triangles without a common vertex (module
    docstring), all cloths together; on the model's threads (:func:`search_threads`)."""
    if sc.triangles.shape[0] < 2:
        return 0
    x = np.ascontiguousarray(positions, dtype=np.float64)
    count = _crossing_count if sc.threads < 2 else _threaded_crossing_count
    return int(count(sc, x, tree_fit(sc, x.shape[0])))
