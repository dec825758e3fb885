"""The character of Fig. 6 and its shirt, as meshes the project makes itself.

    python -m windbench.geometry.character [--out conf/mesh]

writes ``character.ply`` (the body, a closed surface) and ``shirt.obj`` (the garment, one
piece) in the character's own frame: feet on z = 0, centred on x = y = 0, facing -x (the
scenes place both with ``offset``). Both come from signed-distance fields built of capsules
(points within r of a segment), joined by the polynomial smooth minimum

    smin(a, b) = mix(b, a, s) - k s (1 - s),   s = clamp(1/2 + (b - a) / (2 k), 0, 1),

which rounds every joint over a width k (Quilez), so the head sits on a neck that grows out
of the shoulders and nothing floats. The body is the zero level set of that field, meshed
by marching cubes (scikit-image) on a BODY_SPACING lattice. The shirt is the level set
``EASE`` outside the field of the torso, shoulders, neck and upper arms (the cloth hangs that
far off the skin), meshed the same way and then cut open: the hem (z = HEM), the collar
(z = COLLAR) and a cuff across each arm, SLEEVE metres from the shoulder joint. One quarter
(x <= 0, y <= 0) is cut out, its vertices evened out by tangential Laplacian smoothing
(each vertex moves halfway to the mean of its neighbours within the surface, then back onto
the level set along the field's gradient; vertices on a cut stay on it), and it is mirrored
twice, so the shirt is exactly symmetric front to back and left to right. The result is one
manifold piece of about GARMENT_SPACING edge length with four boundary loops: collar, hem
and two cuffs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ALPHA = np.radians(30.0)  # the arms' angle from the vertical
SHOULDER = np.array([0.0, 0.21, 1.40])  # the right shoulder joint (y > 0); the left mirrored
ARM = np.array([0.0, np.sin(ALPHA), -np.cos(ALPHA)])  # down the right arm
EASE = 0.025  # m between the shirt and the skin
HEM, COLLAR, SLEEVE = 0.9, 1.53, 0.25  # m: hem and collar heights, cuff from the shoulder joint
BODY_SPACING, GARMENT_SPACING = 0.01, 0.018  # m: marching-cubes lattices
SMOOTHING_PASSES = 40
CUFF_REACH = 0.085  # m from the arm axis: the cuff cuts the sleeve, not the torso

# (a, b, radius, blend k) in metres; parts off y = 0 are mirrored to -y (union_field)
TORSO = (
    ((0.0, 0.08, 0.95), (0.0, -0.08, 0.95), 0.11, 0.04),  # hips
    ((0.0, 0.05, 0.95), (0.0, 0.05, 1.28), 0.105, 0.04),  # flanks
    ((0.0, 0.06, 1.28), (0.0, -0.06, 1.28), 0.12, 0.04),  # chest
    ((0.0, 0.16, 1.40), (0.0, -0.16, 1.40), 0.065, 0.05),  # shoulders
    ((0.0, 0.0, 1.36), (0.0, 0.0, 1.58), 0.05, 0.04),  # neck
)
UPPER_ARM = (tuple(SHOULDER), tuple(SHOULDER + 0.28 * ARM), 0.045, 0.03)
# the shirt falls straight from the chest to the hem, loose over waist and hips
DRAPE = (((0.0, 0.07, 0.9), (0.0, 0.07, 1.28), 0.13, 0.04),)
LIMBS = (
    (tuple(SHOULDER + 0.28 * ARM), tuple(SHOULDER + 0.53 * ARM), 0.038, 0.02),  # forearm
    (tuple(SHOULDER + 0.55 * ARM), tuple(SHOULDER + 0.65 * ARM), 0.035, 0.02),  # hand
    ((0.0, 0.0, 1.66), (0.0, 0.0, 1.72), 0.095, 0.04),  # head
    ((0.0, 0.09, 0.92), (0.0, 0.095, 0.5), 0.07, 0.03),  # thigh
    ((0.0, 0.095, 0.5), (0.0, 0.1, 0.09), 0.05, 0.02),  # shin
    ((-0.02, 0.1, 0.045), (-0.15, 0.1, 0.035), 0.04, 0.02),  # foot (pointing forward, -x)
)


def capsule(p: np.ndarray, a, b, r: float) -> np.ndarray:
    """Signed distance from points p (..., 3) to the capsule of radius r on segment a-b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    e = b - a
    t = np.clip(((p - a) @ e) / (e @ e), 0.0, 1.0)
    return np.linalg.norm(p - a - t[..., None] * e, axis=-1) - r


def smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum of two distances over a blend width k (module docstring)."""
    s = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + s * (a - b) - k * s * (1.0 - s)


def union_field(p: np.ndarray, parts) -> np.ndarray:
    """Smooth union of the capsules ``parts`` and of the mirror image (y -> -y) of each part
    off the plane y = 0. A part is first joined with its image (smin is symmetric in its
    arguments), so the field is exactly symmetric left to right."""
    d = None
    for a, b, r, k in parts:
        c = capsule(p, a, b, r)
        if a[1] != -b[1]:  # not its own mirror image
            c = smin(c, capsule(p, (a[0], -a[1], a[2]), (b[0], -b[1], b[2]), r), k)
        d = c if d is None else smin(d, c, k)
    return d


def body_field(p: np.ndarray) -> np.ndarray:
    return union_field(p, (*TORSO, UPPER_ARM, *LIMBS))


def garment_field(p: np.ndarray) -> np.ndarray:
    """The shirt's level set is garment_field = 0: EASE outside the torso, neck and upper arms
    and a straight drape from chest to hem."""
    return union_field(p, (*TORSO, *DRAPE, UPPER_ARM)) - EASE


def level_set(field, lower, upper, spacing: float):
    """(vertices, triangles) of field = 0 by marching cubes, wound outward (field < 0 inside)."""
    from skimage.measure import marching_cubes

    axes = [np.arange(lo, hi + spacing / 2, spacing) for lo, hi in zip(lower, upper, strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    verts, faces, _, _ = marching_cubes(
        field(grid), 0.0, spacing=(spacing,) * 3, allow_degenerate=False
    )
    verts = verts + np.array([ax[0] for ax in axes])
    x0, x1, x2 = (verts[faces[:, k]] for k in range(3))
    if np.einsum("ij,ij->", x0, np.cross(x1, x2)) < 0:  # volume < 0: inside out
        faces = faces[:, ::-1]
    return verts, np.ascontiguousarray(faces, dtype=np.int64)


def body_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The character's closed body surface (module docstring)."""
    pad = 3 * BODY_SPACING
    verts, tris = level_set(body_field, (-0.25, -0.7, -0.02), (0.25, 0.7, 1.84 + pad), BODY_SPACING)
    return smooth(body_field, verts, tris), tris


def _cuff_plane():
    """(origin, normal) of the right cuff's plane, normal pointing back up the sleeve."""
    return SHOULDER + SLEEVE * ARM, -ARM


def quarter_cuts():
    """The planes that cut the shirt's quarter x <= 0, y <= 0 out of its closed level set:
    (origin, normal keeping the side it points to, name)."""
    origin, normal = _cuff_plane()
    mirror = np.array([1.0, -1.0, 1.0])
    return (
        (np.zeros(3), np.array([-1.0, 0.0, 0.0]), "front"),
        (np.zeros(3), np.array([0.0, -1.0, 0.0]), "side"),
        (np.array([0.0, 0.0, HEM]), np.array([0.0, 0.0, 1.0]), "hem"),
        (np.array([0.0, 0.0, COLLAR]), np.array([0.0, 0.0, -1.0]), "collar"),
        (origin * mirror, normal * mirror, "cuff"),
    )


def clip(vertices: np.ndarray, triangles: np.ndarray, plane, select: np.ndarray):
    """Cut the ``select``-ed triangles by a plane (origin, normal), keeping the side the
    normal points to (Sutherland-Hodgman on each triangle, new vertices shared along edges);
    the other triangles are kept whole."""
    origin, normal = plane
    d = (vertices - origin) @ normal
    d[np.abs(d) < 1e-12] = 0.0  # on the plane (snapped): no crossing of zero length
    verts, cut, out = list(vertices), {}, []

    def crossing(i: int, j: int) -> int:
        key = (min(i, j), max(i, j))
        if key not in cut:
            t = d[key[0]] / (d[key[0]] - d[key[1]])
            verts.append(vertices[key[0]] + t * (vertices[key[1]] - vertices[key[0]]))
            cut[key] = len(verts) - 1
        return cut[key]

    for tri, chosen in zip(triangles.tolist(), select.tolist(), strict=True):
        s = d[tri]
        if not chosen or np.all(s >= 0) and np.any(s > 0):
            out.append(tri)
            continue
        if np.all(s <= 0):
            continue
        poly = []
        for k in range(3):
            i, j = tri[k], tri[(k + 1) % 3]
            if d[i] >= 0:
                poly.append(i)
            if d[i] * d[j] < 0:
                poly.append(crossing(i, j))
        out += [[poly[0], poly[m], poly[m + 1]] for m in range(1, len(poly) - 1)]
    return np.asarray(verts), np.asarray(out, dtype=np.int64)


def near_arm(points: np.ndarray, radius: float) -> np.ndarray:
    """Points within ``radius`` of the left arm's axis (the arm of the quarter y <= 0)."""
    mirror = np.array([1.0, -1.0, 1.0])
    return capsule(points, SHOULDER * mirror, (SHOULDER + 0.6 * ARM) * mirror, radius) < 0


def compact(vertices: np.ndarray, triangles: np.ndarray):
    """Drop the vertices no triangle uses, and every component but the largest."""
    from windbench.geometry.triangle_mesh import components

    label = components(vertices.shape[0], triangles)
    keep = np.bincount(label[triangles[:, 0]]).argmax()
    triangles = triangles[label[triangles[:, 0]] == keep]
    used = np.unique(triangles)
    index = np.full(vertices.shape[0], -1)
    index[used] = np.arange(used.size)
    return vertices[used], index[triangles]


def garment_quarter():
    """The quarter x <= 0, y <= 0 of the open shirt, before smoothing, and the cut planes."""
    lower = (-0.25, -0.5, HEM - 0.05)
    verts, tris = level_set(garment_field, lower, (0.25, 0.5, COLLAR + 0.05), GARMENT_SPACING)
    cuts = quarter_cuts()
    for origin, normal, name in cuts:
        d = (verts - origin) @ normal
        near = np.abs(d) < GARMENT_SPACING / 5  # snap: no sliver next to the cut
        if name == "cuff":
            near &= near_arm(verts, CUFF_REACH)
        verts[near] -= d[near, None] * normal
        centre = verts[tris].mean(axis=1)
        select = near_arm(centre, CUFF_REACH) if name == "cuff" else np.ones(len(tris), bool)
        verts, tris = clip(verts, tris, (origin, normal), select)
    return (*compact(verts, tris), cuts)


def _gradient(field, x: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    """Central-difference gradient of a field at points x (n, 3)."""
    g = np.empty_like(x)
    for a in range(3):
        step = np.zeros(3)
        step[a] = eps
        g[:, a] = (field(x + step) - field(x - step)) / (2 * eps)
    return g


def _neighbour_means(triangles: np.ndarray, n: int, x: np.ndarray):
    """(mean of all neighbours, mean of boundary neighbours, boundary degree) per vertex."""
    from scipy.sparse import coo_matrix

    a = triangles.reshape(-1)
    b = triangles[:, [1, 2, 0]].reshape(-1)
    adjacency = coo_matrix((np.ones(a.size), (a, b)), shape=(n, n)).tocsr()
    adjacency = ((adjacency + adjacency.T) > 0).astype(float)
    directed = coo_matrix((np.ones(a.size), (a, b)), shape=(n, n)).tocsr()
    boundary = ((directed - directed.T) != 0).astype(float)  # edges of one triangle
    deg, bdeg = np.asarray(adjacency.sum(1)).ravel(), np.asarray(boundary.sum(1)).ravel()
    mean = adjacency @ x / deg[:, None]
    bmean = boundary @ x / np.maximum(bdeg, 1)[:, None]
    return mean, bmean, bdeg


def smooth(field, vertices: np.ndarray, triangles: np.ndarray, cuts=(), passes=SMOOTHING_PASSES):
    """Tangential Laplacian smoothing on the level set field = 0, cut vertices kept on their
    cuts ((origin, normal, name) planes)."""
    x = vertices.copy()
    bdeg = _neighbour_means(triangles, x.shape[0], x)[2]
    on = np.stack([np.abs((x - o) @ nrm) < 1e-9 for o, nrm, _ in cuts] or [bdeg < 0], axis=1)
    on &= (bdeg > 0)[:, None]  # the boundary vertices lying on a cut
    fixed = on.sum(axis=1) >= 2  # corners where two cuts meet: projected only
    for _ in range(passes):
        mean, bmean, _ = _neighbour_means(triangles, x.shape[0], x)
        target = np.where(on.any(axis=1)[:, None], bmean, mean)
        n = _gradient(field, x)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        step = 0.5 * (target - x)
        step -= np.einsum("ij,ij->i", step, n)[:, None] * n
        x[~fixed] += step[~fixed]
        for _ in range(3):  # back onto the level set, and onto the cuts (corners: both)
            g = _gradient(field, x)
            x -= (field(x) / np.einsum("ij,ij->i", g, g))[:, None] * g
            for c, (o, nrm, _) in enumerate(cuts):
                x[on[:, c]] -= ((x[on[:, c]] - o) @ nrm)[:, None] * nrm
    return x


def mirror(vertices: np.ndarray, triangles: np.ndarray, axis: int):
    """The mesh and its mirror image across the plane x_axis = 0, joined along that plane."""
    from windbench.geometry.triangle_mesh import merge_coincident

    image = vertices.copy()
    image[:, axis] = -image[:, axis]
    both = np.concatenate([vertices, image]) + 0.0  # +0.0: no -0.0 on the plane
    tris = np.concatenate([triangles, triangles[:, ::-1] + vertices.shape[0]])
    return merge_coincident(both, tris)


def garment_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The one-piece shirt (module docstring)."""
    verts, tris, cuts = garment_quarter()
    verts = smooth(garment_field, verts, tris, cuts)
    return mirror(*mirror(verts, tris, 1), 0)


def main(argv=None) -> None:
    import trimesh

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[2] / "conf" / "mesh"
    parser.add_argument("--out", type=Path, default=default)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    body = trimesh.Trimesh(*body_mesh(), process=False)
    body.export(args.out / "character.ply", encoding="binary")
    shirt = trimesh.Trimesh(*garment_mesh(), process=False)
    shirt.export(args.out / "shirt.obj", digits=6, include_normals=False, include_texture=False)
    print(
        f"wrote {args.out}: body {len(body.faces)} triangles, shirt {len(shirt.vertices)} vertices"
    )


if __name__ == "__main__":
    main()
