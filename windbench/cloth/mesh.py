"""Cloth meshes: the rectangular flag of the paper's Figs. 3-5, a tube shirt, and any
garment read from a mesh file (``type: mesh``: the one-piece shirt of Fig. 6).

A mesh is the model part of a cloth (rest geometry, triangles, pinned vertices); the
solver's state (positions, velocities) lives elsewhere. The rest shape is the shape the
cloth is built in: a garment file gives it as worn (its edge lengths and fold angles are
those the cloth keeps).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from windbench.errors import ConfigError
from windbench.geometry.triangle_mesh import boundary_loops, check_manifold, read_mesh


@dataclass(frozen=True)
class ClothMesh:
    """Rest geometry of one cloth: vertices ``(n, 3)``, triangles ``(m, 3)``, pinned ids."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    pinned: np.ndarray
    material: Mapping = field(default_factory=dict)
    shape: tuple[int, int] | None = None  # (nu, nv) for rectangular meshes

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])


def rectangle_triangles(nu: int, nv: int) -> np.ndarray:
    """Triangles of an nu x nv vertex lattice (vertex id = i * nv + j), alternating diagonals."""
    tris = []
    for i in range(nu - 1):
        for j in range(nv - 1):
            a, b, c, d = i * nv + j, (i + 1) * nv + j, (i + 1) * nv + j + 1, i * nv + j + 1
            if (i + j) % 2 == 0:
                tris += [(a, b, c), (a, c, d)]
            else:
                tris += [(a, b, d), (b, c, d)]
    return np.array(tris, dtype=np.int64)


def _vec(spec, name, key, n=3):
    try:
        v = np.asarray(list(spec[name]), dtype=float)
    except KeyError:
        raise ConfigError(f"{key}.{name}", f"is required: {n} numbers") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{key}.{name}", f"must be {n} finite numbers, got {list(spec[name])}")
    return v


FLAG_KEYS = {"name", "type", "origin", "size", "resolution", "u_axis", "v_axis", "pin", "material"}


def flag_mesh(spec: Mapping, key: str) -> ClothMesh:
    """A rectangular flag: ``origin`` is the corner at the pole's foot, ``size`` [width, height]
    along ``u_axis`` (away from the pole) and ``v_axis`` (up the pole), ``resolution``
    [nu, nv] vertices. ``pin``: ``pole`` (the whole edge u = 0), ``corners`` (its two ends),
    ``top`` (the edge v = max), ``top_corners``, ``none``, or a list of vertex ids.
    """
    unknown = set(spec) - FLAG_KEYS
    if unknown:
        raise ConfigError(key, f"unknown key(s) {sorted(unknown)}; allowed {sorted(FLAG_KEYS)}")
    origin = _vec(spec, "origin", key)
    width, height = _vec(spec, "size", key, 2)
    nu, nv = (int(v) for v in _vec(spec, "resolution", key, 2))
    if width <= 0 or height <= 0:
        raise ConfigError(f"{key}.size", f"must be positive, got {[width, height]}")
    if nu < 2 or nv < 2:
        raise ConfigError(
            f"{key}.resolution", f"needs at least 2 vertices per side, got {[nu, nv]}"
        )
    u = _vec({"u": spec.get("u_axis", [1, 0, 0])}, "u", f"{key}.u_axis")
    v = _vec({"v": spec.get("v_axis", [0, 0, 1])}, "v", f"{key}.v_axis")
    if abs(np.dot(u, v)) > 1e-9 * np.linalg.norm(u) * np.linalg.norm(v) or not (
        np.linalg.norm(u) and np.linalg.norm(v)
    ):
        raise ConfigError(f"{key}.v_axis", "u_axis and v_axis must be non-zero and orthogonal")
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    s = np.linspace(0.0, width, nu)
    t = np.linspace(0.0, height, nv)
    verts = origin + s[:, None, None] * u + t[None, :, None] * v
    verts = verts.reshape(-1, 3)
    ids = np.arange(nu * nv).reshape(nu, nv)
    pin = spec.get("pin", "pole")
    named = {
        "pole": ids[0, :],
        "corners": ids[0, [0, -1]],
        "top": ids[:, -1],
        "top_corners": ids[[0, -1], -1],
        "none": ids[:0, 0],
    }
    if isinstance(pin, str):
        if pin not in named:
            raise ConfigError(
                f"{key}.pin", f"must be one of {sorted(named)} or a list of ids, got {pin!r}"
            )
        pinned = named[pin]
    else:
        pinned = np.asarray(list(pin), dtype=np.int64)
        if pinned.size and (pinned.min() < 0 or pinned.max() >= nu * nv):
            raise ConfigError(f"{key}.pin", f"vertex ids must lie in [0, {nu * nv - 1}]")
    return ClothMesh(
        name=str(spec.get("name", "flag")),
        vertices=verts,
        triangles=rectangle_triangles(nu, nv),
        pinned=np.asarray(pinned, dtype=np.int64),
        material=dict(spec.get("material", {}) or {}),
        shape=(nu, nv),
    )


def tube_lattice(a, b, radius: float, n_around: int, n_along: int):
    """Vertices and triangles of an open cylindrical tube of cloth from ring ``a`` to ring ``b``.

    Vertex ``i * n_along + j`` sits at angle ``2 pi i / n_around`` around the axis and at
    ``j / (n_along - 1)`` of the way from a to b; the lattice wraps around (the seam joins
    column n_around - 1 to column 0) with the alternating diagonals of
    :func:`rectangle_triangles`, so ``n_around`` must be even. Angle 0 points along +x
    projected off the axis (along +y for an axis near x).
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    axis = (b - a) / np.linalg.norm(b - a)
    ref = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - np.dot(ref, axis) * axis
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phi = 2 * np.pi * np.arange(n_around) / n_around
    t = np.linspace(0.0, 1.0, n_along)
    ring = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2  # (n_around, 3)
    verts = a + t[None, :, None] * (b - a) + radius * ring[:, None, :]
    flat = rectangle_triangles(n_around + 1, n_along)
    flat = np.where(flat >= n_around * n_along, flat - n_around * n_along, flat)  # wrap the seam
    return verts.reshape(-1, 3), flat


SHIRT_KEYS = {
    "name",
    "type",
    "collar",
    "radius",
    "length",
    "resolution",
    "shoulder_width",
    "sleeve_radius",
    "sleeve_length",
    "sleeve_angle",
    "pin",
    "material",
}


def shirt_mesh(spec: Mapping, key: str) -> ClothMesh:
    """The shirt of Fig. 6: a torso tube and two sleeve tubes, hung from the shoulders.

    ``collar`` is the centre of the shoulder line (top of the torso tube, metres); the torso
    tube of ``radius`` hangs ``length`` down along -z with ``resolution`` [around, along]
    vertices (around even). Each sleeve is a tube of ``sleeve_radius`` and ``sleeve_length``
    starting at ``collar +- (0, shoulder_width / 2, 0)`` and pointing down and outwards
    (+-y), ``sleeve_angle`` degrees from the vertical; its lattice spacing follows the
    torso's. The three tubes are separate pieces of cloth in one mesh (a simplification:
    no shoulder seams); ``pin: collar`` holds their top rings (shoulders and armholes),
    ``pin: none`` lets the shirt rest on the body alone. The character faces -x, into a
    wind along +x.
    """
    unknown = set(spec) - SHIRT_KEYS
    if unknown:
        raise ConfigError(key, f"unknown key(s) {sorted(unknown)}; allowed {sorted(SHIRT_KEYS)}")
    collar = _vec(spec, "collar", key)
    scalars = {}
    for name in ("radius", "length", "shoulder_width", "sleeve_radius", "sleeve_length"):
        if name not in spec:
            raise ConfigError(f"{key}.{name}", "is required: a length in metres")
        scalars[name] = float(spec[name])
        if not (np.isfinite(scalars[name]) and scalars[name] > 0):
            raise ConfigError(f"{key}.{name}", f"must be > 0 metres, got {spec[name]}")
    angle = float(spec.get("sleeve_angle", 20.0))
    if not 0.0 <= angle < 90.0:
        raise ConfigError(f"{key}.sleeve_angle", f"must lie in [0, 90) degrees, got {angle}")
    n_around, n_along = (int(v) for v in _vec(spec, "resolution", key, 2))
    if n_around < 4 or n_around % 2 or n_along < 2:
        raise ConfigError(
            f"{key}.resolution",
            f"needs an even number >= 4 around and >= 2 along, got {[n_around, n_along]}",
        )
    r, length = scalars["radius"], scalars["length"]
    step_along = length / (n_along - 1)
    step_around = 2 * np.pi * r / n_around
    pieces = [tube_lattice(collar, collar - [0.0, 0.0, length], r, n_around, n_along)]
    rs, ls = scalars["sleeve_radius"], scalars["sleeve_length"]
    s_around = max(4, 2 * int(round(np.pi * rs / step_around)))
    s_along = max(2, int(round(ls / step_along)) + 1)
    a = np.radians(angle)
    for side in (-1.0, 1.0):
        top = collar + [0.0, side * scalars["shoulder_width"] / 2, 0.0]
        end = top + ls * np.array([0.0, side * np.sin(a), -np.cos(a)])
        pieces.append(tube_lattice(top, end, rs, s_around, s_along))
    verts, tris, pins, offset = [], [], [], 0
    for (v, t), (na, nl) in zip(
        pieces, [(n_around, n_along), (s_around, s_along), (s_around, s_along)], strict=True
    ):
        verts.append(v)
        tris.append(t + offset)
        pins.append(offset + np.arange(na) * nl)  # the top ring (j = 0) of each tube
        offset += v.shape[0]
    pin = spec.get("pin", "collar")
    if pin not in ("collar", "none"):
        raise ConfigError(f"{key}.pin", f"must be 'collar' or 'none', got {pin!r}")
    return ClothMesh(
        name=str(spec.get("name", "shirt")),
        vertices=np.concatenate(verts),
        triangles=np.concatenate(tris).astype(np.int64),
        pinned=np.concatenate(pins).astype(np.int64) if pin == "collar" else np.zeros(0, np.int64),
        material=dict(spec.get("material", {}) or {}),
    )


FILE_KEYS = {"name", "type", "file", "scale", "offset", "pin", "material"}
FILE_PINS = ("none", "top_loop")


def file_mesh(spec: Mapping, key: str) -> ClothMesh:
    """A cloth read from an OBJ, PLY or STL ``file`` (placed by ``scale`` and ``offset``,
    :mod:`windbench.geometry.triangle_mesh`), e.g. the one-piece shirt of
    ``conf/mesh/shirt.obj``. It must be manifold (at most two triangles on an edge); its
    boundary loops are its openings. ``pin``: ``none`` (the default: the cloth rests on the
    bodies), ``top_loop`` (the boundary loop of highest mean height, a shirt's collar) or a
    list of vertex ids (the file's order, coincident vertices merged).
    """
    unknown = set(spec) - FILE_KEYS
    if unknown:
        raise ConfigError(key, f"unknown key(s) {sorted(unknown)}; allowed {sorted(FILE_KEYS)}")
    vertices, triangles = read_mesh(spec, key)
    check_manifold(triangles, f"{key}.file")
    unused = vertices.shape[0] - np.unique(triangles).size
    if unused:
        raise ConfigError(f"{key}.file", f"{unused} vertex(es) belong to no triangle: no mass")
    pin = spec.get("pin", "none")
    if isinstance(pin, str):
        if pin not in FILE_PINS:
            raise ConfigError(
                f"{key}.pin", f"must be one of {list(FILE_PINS)} or a list of ids, got {pin!r}"
            )
        loops = boundary_loops(triangles) if pin == "top_loop" else []
        if pin == "top_loop" and not loops:
            raise ConfigError(f"{key}.pin", "top_loop needs a mesh with a boundary")
        pinned = max(loops, key=lambda ids: vertices[ids, 2].mean()) if loops else []
    else:
        pinned = np.asarray(list(pin), dtype=np.int64)
        if pinned.size and (pinned.min() < 0 or pinned.max() >= len(vertices)):
            raise ConfigError(f"{key}.pin", f"vertex ids must lie in [0, {len(vertices) - 1}]")
    return ClothMesh(
        name=str(spec.get("name", "cloth")),
        vertices=vertices,
        triangles=triangles,
        pinned=np.sort(np.asarray(pinned, dtype=np.int64)),
        material=dict(spec.get("material", {}) or {}),
    )


MESH_BUILDERS = {"flag": flag_mesh, "shirt": shirt_mesh, "mesh": file_mesh}


def mesh_from_config(spec: Mapping, key: str) -> ClothMesh:
    kind = spec.get("type", "flag")
    if kind not in MESH_BUILDERS:
        raise ConfigError(f"{key}.type", f"must be one of {sorted(MESH_BUILDERS)}, got {kind!r}")
    return MESH_BUILDERS[kind](spec, key)
