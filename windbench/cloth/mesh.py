"""Cloth meshes: the rectangular flag of the paper's Figs. 3-5.

A mesh is the model part of a cloth (rest geometry, triangles, pinned vertices); the
solver's state (positions, velocities) lives elsewhere.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from windbench.errors import ConfigError


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


MESH_BUILDERS = {"flag": flag_mesh}


def mesh_from_config(spec: Mapping, key: str) -> ClothMesh:
    kind = spec.get("type", "flag")
    if kind not in MESH_BUILDERS:
        raise ConfigError(f"{key}.type", f"must be one of {sorted(MESH_BUILDERS)}, got {kind!r}")
    return MESH_BUILDERS[kind](spec, key)
