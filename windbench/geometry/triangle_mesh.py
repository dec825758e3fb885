"""Triangle meshes read from OBJ, PLY or STL files, and the facts about them the scenes check.

A body or cloth of ``type: mesh`` names a ``file``; :func:`read_mesh` loads it with
``trimesh`` (which also triangulates quads and polygons), merges coincident vertices (an STL
file stores each triangle's corners apart), applies the config's ``scale`` then ``offset``
(x' = scale x + offset, so a file in millimetres takes ``scale: 0.001``) and refuses a bad
file with one line naming the key. A relative path is looked up in the current folder, then
in the config folder (``conf/`` of a checkout, the configs of an installed wheel), where the
project's own meshes live (``conf/mesh/``).

Topology: an undirected edge with one triangle lies on the boundary, one with more than two
makes the mesh non-manifold. A body must be *closed* (no boundary edge, consistently
oriented: every directed edge once), the condition under which its inside is well defined;
a cloth must be manifold and may have boundary loops (a shirt's collar, hem and cuffs).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from windbench.config import config_dir
from windbench.errors import ConfigError

FORMATS = (".obj", ".ply", ".stl")


@dataclass(frozen=True)
class Placement:
    """Where a mesh file goes in the scene: x' = scale x + offset (metres)."""

    scale: float = 1.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_config(cls, spec: Mapping, key: str) -> Placement:
        scale = spec.get("scale", cls.scale)
        if not isinstance(scale, int | float) or not np.isfinite(scale) or scale <= 0:
            raise ConfigError(f"{key}.scale", f"must be a number > 0, got {scale!r}")
        offset = spec.get("offset", cls.offset)
        try:
            off = np.asarray(list(offset), dtype=float)
        except (TypeError, ValueError):
            off = np.zeros(0)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise ConfigError(f"{key}.offset", f"must be 3 finite numbers (m), got {offset!r}")
        return cls(float(scale), (float(off[0]), float(off[1]), float(off[2])))


def find_file(name, key: str) -> Path:
    """The mesh file a config names: absolute, else in the current folder, else in the
    config folder (ConfigError naming ``key`` when it is in neither)."""
    if not isinstance(name, str) or not name:
        raise ConfigError(key, f"must name an OBJ, PLY or STL file, got {name!r}")
    path = Path(name).expanduser()
    if path.suffix.lower() not in FORMATS:
        raise ConfigError(key, f"must be an OBJ, PLY or STL file, got {name!r}")
    places = [path] if path.is_absolute() else [Path.cwd() / path, config_dir() / path]
    for place in places:
        if place.is_file():
            return place
    raise ConfigError(key, f"no such file {name!r} (looked in {', '.join(map(str, places))})")


def merge_coincident(vertices: np.ndarray, triangles: np.ndarray):
    """Vertices at exactly the same point made one (kept in order of first appearance)."""
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # unique rows in the file's order
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return vertices[first[order]], rank[inverse.reshape(-1)][triangles]


def read_mesh(spec: Mapping, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices ``(n, 3)`` m, triangles ``(m, 3)``) of the ``file`` a body or cloth names,
    placed by its ``scale`` and ``offset``; degenerate triangles (a repeated vertex) dropped."""
    import trimesh

    path = find_file(spec.get("file"), f"{key}.file")
    placement = Placement.from_config(spec, key)
    try:
        mesh = trimesh.load(path, force="mesh", process=False, skip_materials=True)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        triangles = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    except Exception as err:  # any parser failure is the file's fault
        raise ConfigError(f"{key}.file", f"cannot read {path}: {err}") from None
    if triangles.shape[0] == 0:
        raise ConfigError(f"{key}.file", f"{path} holds no triangles")
    if not np.all(np.isfinite(vertices)):
        raise ConfigError(f"{key}.file", f"{path} has non-finite vertex coordinates")
    vertices, triangles = merge_coincident(vertices, triangles)
    distinct = (
        (triangles[:, 0] != triangles[:, 1])
        & (triangles[:, 1] != triangles[:, 2])
        & (triangles[:, 2] != triangles[:, 0])
    )
    vertices = placement.scale * vertices + np.asarray(placement.offset)
    return vertices, triangles[distinct]


def edge_counts(triangles: np.ndarray):
    """(undirected edges ``(E, 2)`` sorted, triangles per edge ``(E,)``, directed edges
    that occur more than once)."""
    a = triangles.reshape(-1)
    b = triangles[:, [1, 2, 0]].reshape(-1)
    directed = np.stack([a, b], axis=1)
    _, twice = np.unique(directed, axis=0, return_counts=True)
    edges, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    return edges, counts, int(np.sum(twice > 1))


def check_closed(triangles: np.ndarray, key: str) -> None:
    """ConfigError unless every edge has exactly two triangles, oppositely oriented."""
    _, counts, repeated = edge_counts(triangles)
    if np.any(counts != 2) or repeated:
        raise ConfigError(
            key,
            f"a body mesh must be closed and consistently oriented: {int(np.sum(counts == 1))} "
            f"boundary edge(s), {int(np.sum(counts > 2))} edge(s) with more than two "
            f"triangles, {repeated} edge(s) oriented alike in two triangles",
        )


def check_manifold(triangles: np.ndarray, key: str) -> None:
    """ConfigError when an edge has more than two triangles (a cloth must be a surface)."""
    _, counts, _ = edge_counts(triangles)
    if np.any(counts > 2):
        raise ConfigError(
            key,
            f"a cloth mesh must be manifold: {int(np.sum(counts > 2))} edge(s) with "
            "more than two triangles",
        )


def signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Enclosed volume, positive when the triangles wind counter-clockwise seen from outside:
    V = 1/6 sum_t x0 . (x1 x x2) (divergence theorem)."""
    x0, x1, x2 = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->", x0, np.cross(x1, x2)) / 6.0)


def components(n_vertices: int, triangles: np.ndarray) -> np.ndarray:
    """Connected component of each vertex (through shared edges), ``(n,)`` labels 0, 1, ..."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a = triangles.reshape(-1)
    b = triangles[:, [1, 2, 0]].reshape(-1)
    graph = coo_matrix((np.ones(a.size), (a, b)), shape=(n_vertices, n_vertices))
    return connected_components(graph, directed=False)[1]


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """The closed boundary loops (vertex ids in order) of a manifold triangle mesh.

    A boundary edge is a directed edge whose reverse is in no triangle; following them head
    to tail gives each loop (a vertex on two loops, a pinch, is walked once per loop).
    """
    a = triangles.reshape(-1)
    b = triangles[:, [1, 2, 0]].reshape(-1)
    pairs = set(zip(a.tolist(), b.tolist(), strict=True))
    nxt: dict[int, list[int]] = {}
    for u, v in pairs:
        if (v, u) not in pairs:
            nxt.setdefault(u, []).append(v)
    loops = []
    while nxt:
        start = min(nxt)
        loop, u = [start], start
        while True:
            v = nxt[u].pop()
            if not nxt[u]:
                del nxt[u]
            if v == start:
                break
            loop.append(v)
            u = v
        loops.append(np.asarray(loop, dtype=np.int64))
    return loops
