"""Constraint topology of a triangle mesh: edges, hinges, rest lengths and angles, masses.

Pure numpy, computed once per model (the immutable part of the cloth solver):

- every mesh edge is a distance constraint. A cloth is a *lattice* when each of its triangles
  is right-angled opposite its longest side (half a rectangular cell, see
  :func:`windbench.cloth.mesh.rectangle_triangles`); there an edge is a *shear* edge when it
  is the longest edge of every triangle it bounds (a cell's diagonal), the others are
  *stretch* edges (the warp and weft threads). Any other mesh (an irregular garment) has no
  threads: every edge of it is a stretch edge, since its edges carry the membrane in all
  directions;
- every interior edge (two triangles) is a *hinge*: a dihedral-angle bending constraint on
  its four vertices ``(edge0, edge1, opposite in triangle A, opposite in triangle B)``;
- a vertex carries a third of the mass of each triangle it belongs to (lumped mass).

Stiffnesses map the continuum constants (SI) to the discrete constraints so that on a
rectangular lattice with cells ``hu x hv`` the discrete energy equals the continuum one:

- stretch, membrane stiffness ``Y`` (N/m): uniaxial strain eps stores ``Y eps^2 / 2`` per
  unit area, so a lattice edge of length L bounding triangles of total area ``A_e`` is a
  spring of stiffness ``k = Y A_e / L^2`` (N/m);
- shear, in-plane shear stiffness ``G`` (N/m): simple shear gamma stores ``G gamma^2 / 2``
  per area and changes a cell diagonal by ``gamma hu hv / L``, so ``k = G L^2 / A_e``;
- bending, bending stiffness ``B`` (N m): curvature kappa stores ``B kappa^2 / 2`` per
  area; across a hinge of length L the dihedral angle is ``kappa A_e / L``, so the
  hinge energy is ``k_b theta^2 / 2`` with ``k_b = B L^2 / A_e`` (N m / rad^2), the
  discrete-shells weight of Grinspun et al. (2003).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Topology:
    """Edges and hinges of a mesh with their rest measures (global vertex ids)."""

    edges: np.ndarray  # (E, 2)
    edge_length: np.ndarray  # (E,) rest length, m
    edge_area: np.ndarray  # (E,) total rest area of the triangles sharing the edge, m^2
    edge_shear: np.ndarray  # (E,) bool: diagonal (shear) edge
    edge_lattice: np.ndarray  # (E,) bool: edge of a lattice cloth
    edge_triangle: np.ndarray  # (E,) one triangle of the edge (for per-cloth material)
    hinges: np.ndarray  # (H, 4) edge0, edge1, opposite A, opposite B
    hinge_angle: np.ndarray  # (H,) rest dihedral angle, rad
    hinge_length: np.ndarray  # (H,)
    hinge_area: np.ndarray  # (H,)
    hinge_triangle: np.ndarray  # (H,)
    vertex_area: np.ndarray  # (n,) a third of the area of the triangles around each vertex


def triangle_areas(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area of each triangle: |(x1 - x0) x (x2 - x0)| / 2."""
    x0, x1, x2 = (positions[triangles[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(x1 - x0, x2 - x0), axis=1)


def dihedral_angles(positions: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """Signed dihedral angle of each hinge, the same convention as the solver's kernel.

    With edge e = x1 - x0, normals nA = (x2 - x0) x e... written out as in
    :func:`windbench.cloth.solver.hinge_gradient`: theta = atan2((nA x nB) . e^, nA . nB).
    """
    x0, x1, x2, x3 = (positions[hinges[:, k]] for k in range(4))
    e = x1 - x0
    na = np.cross(x2 - x0, x2 - x1)
    nb = np.cross(x3 - x1, x3 - x0)
    el = np.linalg.norm(e, axis=1, keepdims=True)
    sin = np.einsum("ij,ij->i", np.cross(na, nb), e / np.where(el > 0, el, 1.0))
    cos = np.einsum("ij,ij->i", na, nb)
    return np.arctan2(sin, cos)


RIGHT_ANGLE_COS = 1e-6  # |cos| of a lattice triangle's angle opposite its longest side


def lattice_triangles(rest: np.ndarray, triangles: np.ndarray, cloth: np.ndarray) -> np.ndarray:
    """Whether each triangle belongs to a lattice cloth (``cloth``: its cloth's index): one
    whose every triangle has a right angle opposite its longest side c,
    ``|a^2 + b^2 - c^2| / (2 a b) <= RIGHT_ANGLE_COS`` (law of cosines)."""
    if triangles.shape[0] == 0:
        return np.zeros(0, bool)
    side2 = np.stack(
        [
            np.sum((rest[triangles[:, (k + 1) % 3]] - rest[triangles[:, k]]) ** 2, axis=1)
            for k in range(3)
        ],
        axis=1,
    )
    side2.sort(axis=1)
    a2, b2, c2 = side2[:, 0], side2[:, 1], side2[:, 2]
    right = np.abs(a2 + b2 - c2) <= RIGHT_ANGLE_COS * 2.0 * np.sqrt(a2 * b2)
    irregular = np.bincount(cloth, weights=~right, minlength=int(cloth.max()) + 1) > 0
    return ~irregular[cloth]


def build_topology(
    rest: np.ndarray, triangles: np.ndarray, cloth: np.ndarray | None = None
) -> Topology:
    """Edges, hinges and lumped vertex areas of a (possibly multi-component) mesh; ``cloth``
    gives each triangle's cloth (default: all one cloth), which is a lattice or not as a
    whole (:func:`lattice_triangles`)."""
    n = rest.shape[0]
    m = triangles.shape[0]
    cloth = np.zeros(m, np.int64) if cloth is None else np.asarray(cloth, np.int64)
    lattice = lattice_triangles(rest, triangles, cloth)
    areas = triangle_areas(rest, triangles)
    vertex_area = np.zeros(n)
    for k in range(3):
        np.add.at(vertex_area, triangles[:, k], areas / 3.0)
    # half-edges: (a, b) of triangle t with opposite vertex c, keyed by the sorted pair
    a = triangles[:, [0, 1, 2]].reshape(-1)
    b = triangles[:, [1, 2, 0]].reshape(-1)
    c = triangles[:, [2, 0, 1]].reshape(-1)
    tri = np.repeat(np.arange(m), 3)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo.astype(np.int64) * max(n, 1) + hi
    order = np.argsort(key, kind="stable")
    key_s = key[order]
    uniq, first, counts = np.unique(key_s, return_index=True, return_counts=True)
    if counts.size and counts.max() > 2:
        raise ValueError("non-manifold mesh: an edge is shared by more than two triangles")
    e_lo, e_hi = lo[order][first], hi[order][first]
    edges = np.stack([e_lo, e_hi], axis=1).astype(np.int64)
    length = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1)
    edge_area = np.zeros(len(uniq))
    np.add.at(edge_area, np.repeat(np.arange(len(uniq)), counts), areas[tri[order]])
    # shear edge: the longest edge of every triangle it bounds
    side = np.linalg.norm(rest[b] - rest[a], axis=1).reshape(m, 3)
    longest = (side >= side.max(axis=1, keepdims=True) * (1 - 1e-9)) & (
        side > np.sort(side, axis=1)[:, [1]] * (1 + 1e-6)
    )
    is_long = longest.reshape(-1)[order]
    shear = np.logical_and.reduceat(is_long, first) if len(first) else np.zeros(0, bool)
    edge_lattice = lattice[tri[order][first]]
    # hinges: edges with two triangles
    two = np.flatnonzero(counts == 2)
    h0 = order[first[two]]
    h1 = order[first[two] + 1]
    hinges = np.stack([a[h0], b[h0], c[h0], c[h1]], axis=1).astype(np.int64)
    return Topology(
        edges=edges,
        edge_length=length,
        edge_area=edge_area,
        edge_shear=shear.astype(bool) & edge_lattice,
        edge_lattice=edge_lattice,
        edge_triangle=tri[order][first],
        hinges=hinges,
        hinge_angle=dihedral_angles(rest, hinges),
        hinge_length=length[two],
        hinge_area=edge_area[two],
        hinge_triangle=tri[h0],
        vertex_area=vertex_area,
    )


def tethers(
    rest: np.ndarray, edges: np.ndarray, pinned: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Long-range attachments (Kim, Chentanez, Mueller 2012): each vertex's nearest pin.

    The pin nearest along the mesh (shortest edge path) is the anchor; the tether length is
    the straight rest distance to it, the length of the cloth between them when the mesh is
    flat (a flag) or the path runs along a ruling line (the collar-to-hem lines of a tube).
    Returns (anchor ``(n,)``, -1 where a vertex cannot reach a pin or is pinned, length ``(n,)``,
    path ``(n,)`` the edge-path distance to the anchor, inf where there is none).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    n = rest.shape[0]
    anchor = np.full(n, -1, dtype=np.int64)
    length = np.zeros(n)
    if pinned.size == 0 or edges.size == 0:
        return anchor, length, np.full(n, np.inf)
    w = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    graph = coo_matrix((w, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    dist, _, source = dijkstra(
        graph, directed=False, indices=np.unique(pinned), min_only=True, return_predecessors=True
    )
    ok = np.isfinite(dist) & (source >= 0)
    ok[pinned] = False
    anchor[ok] = source[ok]
    length[ok] = np.linalg.norm(rest[ok] - rest[source[ok]], axis=1)
    return anchor, length, dist


def colour_order(
    constraints: np.ndarray, priority: np.ndarray, group: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Order of the constraints (rows of vertex ids) grouped by a greedy colouring.

    Constraints are taken by ``group``, then increasing ``priority``; each gets the smallest
    colour not yet used in its group by a constraint sharing one of its vertices. The order
    lists the groups in turn, each as colour 0, 1, ..., each colour by priority.
    Consecutive constraints of one colour touch disjoint vertices, so a Gauss-Seidel sweep
    in this order does the same as any order of the colour, while the processor overlaps
    neighbours instead of waiting for each result.
    Returns (order, colour of each constraint in that order).
    """
    group = np.zeros(constraints.shape[0], np.int64) if group is None else group
    by_priority = np.lexsort((priority, group))
    n = int(constraints.max()) + 1 if constraints.size else 0
    used = [0] * n  # bit c set: colour c is taken at this vertex (in the current group)
    touched: list[int] = []
    colour = np.empty(constraints.shape[0], dtype=np.int64)
    rows, groups = constraints.tolist(), group.tolist()
    current = None
    for k in by_priority.tolist():
        if groups[k] != current:
            for i in touched:
                used[i] = 0
            touched, current = [], groups[k]
        taken = 0
        for i in rows[k]:
            taken |= used[i]
        c = (~taken & (taken + 1)).bit_length() - 1  # lowest clear bit
        colour[k] = c
        for i in rows[k]:
            used[i] |= 1 << c
            touched.append(i)
    order = by_priority[np.lexsort((colour[by_priority], group[by_priority]))]
    return order, colour[order]


def thread_chains(
    rest: np.ndarray, edges: np.ndarray, priority: np.ndarray, straight: float = 0.5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decompose ``edges`` (the stretch edges) into threads: simple paths, each edge in one.

    Greedy straightest continuation: seeds are taken by increasing ``priority`` (then
    index); a seed edge grows at both ends, each time by the unused edge at the end vertex
    whose rest direction continues the last one most closely, as long as the cosine of the
    turn exceeds ``straight`` (0.5: less than 60 degrees) and the new vertex is not yet on
    the path (a closed ring, e.g. a tube's hoop, becomes a path and a one-edge chain). On a
    rectangular lattice the chains are the warp and weft threads.
    Returns (order ``(E,)``: the edges chain by chain, ptr ``(C + 1,)``: chain c is
    ``order[ptr[c]:ptr[c + 1]]``, vertices ``(E + C,)``: chain c's path is
    ``vertices[ptr[c] + c : ptr[c + 1] + c + 1]``, its k-th edge joins the k-th and
    (k+1)-th of them).
    """
    n_e = edges.shape[0]
    d = rest[edges[:, 1]] - rest[edges[:, 0]]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    incident: dict[int, list[int]] = {}
    for e, (a, b) in enumerate(edges.tolist()):
        incident.setdefault(a, []).append(e)
        incident.setdefault(b, []).append(e)
    ends = edges.tolist()
    dirs = d.tolist()
    used = [False] * n_e

    def grow(v: int, t: list[float], on_path: set[int]) -> tuple[list[int], list[int]]:
        path_e, path_v = [], []
        while True:
            best, best_cos, nxt = -1, straight, -1
            for e in incident[v]:
                if used[e]:
                    continue
                a, b = ends[e]
                other, s = (b, 1.0) if a == v else (a, -1.0)
                if other in on_path:
                    continue
                c = s * (dirs[e][0] * t[0] + dirs[e][1] * t[1] + dirs[e][2] * t[2])
                if c > best_cos:
                    best, best_cos, nxt = e, c, other
            if best < 0:
                return path_e, path_v
            used[best] = True
            s = 1.0 if ends[best][0] == v else -1.0
            t = [s * x for x in dirs[best]]
            path_e.append(best)
            path_v.append(nxt)
            on_path.add(nxt)
            v = nxt

    order: list[int] = []
    vertices: list[int] = []
    ptr = [0]
    for seed in np.lexsort((np.arange(n_e), priority)).tolist():
        if used[seed]:
            continue
        used[seed] = True
        a, b = ends[seed]
        on_path = {a, b}
        fwd_e, fwd_v = grow(b, dirs[seed], on_path)
        bwd_e, bwd_v = grow(a, [-x for x in dirs[seed]], on_path)
        order += bwd_e[::-1] + [seed] + fwd_e
        vertices += bwd_v[::-1] + [a, b] + fwd_v
        ptr.append(len(order))
    return (
        np.asarray(order, dtype=np.int64),
        np.asarray(ptr, dtype=np.int64),
        np.asarray(vertices, dtype=np.int64),
    )
