"""Rigid obstacles: box, capsule, cylinder and plane, as signed distance functions.

The paper treats walls and the character's body as rigid objects that shape the wind but
feel no force (§4.1.2); cloth collides with them ([MKE03]) and wind particles stop at them
(§4.2.2). Every body here is one row of a parameter table (``kind`` + 7 floats) read by the
numba kernel :func:`body_distance`, which returns the signed distance (negative inside)
and the outward unit normal at the nearest surface point.

======== ==================================== ==============================================
body     config keys                          solid region
======== ==================================== ==============================================
box      ``min``, ``max``                     the axis-aligned box
capsule  ``a``, ``b``, ``radius``             points within ``radius`` of the segment a-b
cylinder ``a``, ``b``, ``radius``             the finite, flat-capped cylinder on a-b
plane    ``point``, ``normal``                the half-space behind the plane, (x-p).n < 0
======== ==================================== ==============================================

Every body may set ``name`` and ``resolve`` (default true). ``resolve: false`` marks a
body thinner than any sensible wind cell (a flag pole): cloth collides with it, but the
run does not demand that the wind grid hold a cell inside it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from windbench.errors import ConfigError

BOX, CAPSULE, CYLINDER, PLANE = 0, 1, 2, 3
KINDS = {"box": BOX, "capsule": CAPSULE, "cylinder": CYLINDER, "plane": PLANE}
N_PARAMS = 7
_KEYS = {
    "box": ("min", "max"),
    "capsule": ("a", "b", "radius"),
    "cylinder": ("a", "b", "radius"),
    "plane": ("point", "normal"),
}


@dataclass(frozen=True)
class Body:
    """A rigid obstacle: kind, parameter row and an optional name."""

    kind: str
    params: tuple[float, ...]
    name: str = ""
    resolve: bool = True  # False: thinner than the wind grid (a pole); cloth still collides

    @property
    def kind_id(self) -> int:
        return KINDS[self.kind]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box (infinite for a plane)."""
        p = np.asarray(self.params)
        if self.kind == "box":
            return p[0:3], p[3:6]
        if self.kind == "plane":
            return np.full(3, -np.inf), np.full(3, np.inf)
        r = p[6]
        return np.minimum(p[0:3], p[3:6]) - r, np.maximum(p[0:3], p[3:6]) + r

    def distance(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance ``(n,)`` and outward normal ``(n, 3)`` at world points."""
        return distances([self], points)


def body_from_config(spec: Mapping, key: str) -> Body:
    kind = spec.get("type")
    if kind not in KINDS:
        raise ConfigError(f"{key}.type", f"must be one of {sorted(KINDS)}, got {kind!r}")
    allowed = set(_KEYS[kind]) | {"type", "name", "resolve"}
    unknown = set(spec) - allowed
    if unknown:
        raise ConfigError(
            key, f"unknown key(s) {sorted(unknown)} for a {kind}; allowed {sorted(allowed)}"
        )
    row = np.zeros(N_PARAMS)
    for n, name in enumerate(k for k in _KEYS[kind] if k != "radius"):
        if name not in spec:
            raise ConfigError(f"{key}.{name}", f"is required for a {kind}: 3 numbers")
        v = np.asarray(list(spec[name]), dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ConfigError(f"{key}.{name}", f"must be 3 finite numbers, got {list(spec[name])}")
        row[3 * n : 3 * n + 3] = v
    if kind == "box" and np.any(row[3:6] <= row[0:3]):
        raise ConfigError(f"{key}.max", f"must exceed {key}.min on every axis")
    if kind in ("capsule", "cylinder"):
        r = float(spec.get("radius", 0.0))
        if r <= 0:
            raise ConfigError(f"{key}.radius", f"must be > 0, got {r}")
        row[6] = r
    if kind == "plane":
        n = row[3:6]
        if np.linalg.norm(n) == 0:
            raise ConfigError(f"{key}.normal", "must be a non-zero vector")
        row[3:6] = n / np.linalg.norm(n)
    return Body(
        kind,
        tuple(float(v) for v in row),
        str(spec.get("name", Body.name)),
        bool(spec.get("resolve", Body.resolve)),
    )


def body_table(bodies: Sequence[Body]) -> tuple[np.ndarray, np.ndarray]:
    """(kinds ``(m,)`` int64, params ``(m, 7)`` float64) for the numba kernels."""
    kinds = np.array([b.kind_id for b in bodies], dtype=np.int64)
    params = np.array([b.params for b in bodies], dtype=np.float64).reshape(len(bodies), N_PARAMS)
    return kinds, params


def distances(bodies: Sequence[Body], points) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance to the union of ``bodies`` and the outward normal there."""
    pts = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
    dist = np.empty(pts.shape[0])
    normal = np.empty_like(pts)
    kinds, params = body_table(bodies)
    union_distance(kinds, params, pts, dist, normal)
    return dist, normal


def inside(bodies: Sequence[Body], points) -> np.ndarray:
    """Boolean mask: points strictly inside any body."""
    if not bodies:
        return np.zeros(np.atleast_2d(points).shape[0], dtype=bool)
    return distances(bodies, points)[0] < 0.0


@njit(cache=True, inline="always")
def _segment_closest(px, py, pz, prm):
    """Parameter t in [0, 1] of the point of segment a-b nearest to p, and |b - a|^2."""
    ex, ey, ez = prm[3] - prm[0], prm[4] - prm[1], prm[5] - prm[2]
    len2 = ex * ex + ey * ey + ez * ez
    if len2 == 0.0:
        return 0.0, len2
    t = ((px - prm[0]) * ex + (py - prm[1]) * ey + (pz - prm[2]) * ez) / len2
    return min(1.0, max(0.0, t)), len2


@njit(cache=True)
def body_distance(kind, prm, px, py, pz, normal):
    """Signed distance from p to one body (negative inside); outward unit normal in ``normal``."""
    if kind == PLANE:
        normal[0], normal[1], normal[2] = prm[3], prm[4], prm[5]
        return (px - prm[0]) * prm[3] + (py - prm[1]) * prm[4] + (pz - prm[2]) * prm[5]
    if kind == BOX:
        p = (px, py, pz)
        # distance outside: length of the positive part of the per-axis excess
        q = np.empty(3)
        for a in range(3):
            centre = 0.5 * (prm[a] + prm[a + 3])
            half = 0.5 * (prm[a + 3] - prm[a])
            q[a] = abs(p[a] - centre) - half
        outside = 0.0
        for a in range(3):
            outside += max(q[a], 0.0) ** 2
        if outside > 0.0:
            d = np.sqrt(outside)
            for a in range(3):
                centre = 0.5 * (prm[a] + prm[a + 3])
                sgn = 1.0 if p[a] >= centre else -1.0
                normal[a] = sgn * max(q[a], 0.0) / d
            return d
        best = 0
        for a in range(1, 3):
            if q[a] > q[best]:
                best = a
        for a in range(3):
            normal[a] = 0.0
        centre = 0.5 * (prm[best] + prm[best + 3])
        normal[best] = 1.0 if p[best] >= centre else -1.0
        return q[best]
    # capsule and cylinder share the axis segment a-b
    t, len2 = _segment_closest(px, py, pz, prm)
    r = prm[6]
    if kind == CAPSULE:
        cx = prm[0] + t * (prm[3] - prm[0]) - px
        cy = prm[1] + t * (prm[4] - prm[1]) - py
        cz = prm[2] + t * (prm[5] - prm[2]) - pz
        d = np.sqrt(cx * cx + cy * cy + cz * cz)
        if d == 0.0:
            normal[0], normal[1], normal[2] = 0.0, 0.0, 1.0
        else:
            normal[0], normal[1], normal[2] = -cx / d, -cy / d, -cz / d
        return d - r
    # CYLINDER: radial distance and axial distance beyond the caps
    length = np.sqrt(len2)
    ax, ay, az = (prm[3] - prm[0]) / length, (prm[4] - prm[1]) / length, (prm[5] - prm[2]) / length
    s = (px - prm[0]) * ax + (py - prm[1]) * ay + (pz - prm[2]) * az
    rx, ry, rz = px - prm[0] - s * ax, py - prm[1] - s * ay, pz - prm[2] - s * az
    rho = np.sqrt(rx * rx + ry * ry + rz * rz)
    dr = rho - r
    da = max(-s, s - length)
    asign = -1.0 if s < 0.5 * length else 1.0
    if rho > 0.0:
        ux, uy, uz = rx / rho, ry / rho, rz / rho
    else:
        ux, uy, uz = 0.0, 0.0, 0.0
    if dr > 0.0 and da > 0.0:
        d = np.sqrt(dr * dr + da * da)
        normal[0] = (dr * ux + da * asign * ax) / d
        normal[1] = (dr * uy + da * asign * ay) / d
        normal[2] = (dr * uz + da * asign * az) / d
        return d
    if dr >= da:
        normal[0], normal[1], normal[2] = ux, uy, uz
        return dr
    normal[0], normal[1], normal[2] = asign * ax, asign * ay, asign * az
    return da


@njit(cache=True)
def union_distance_point(kinds, params, px, py, pz, normal):
    """Signed distance to the nearest of several bodies, normal of that one."""
    best = np.inf
    tmp = np.empty(3)
    normal[0], normal[1], normal[2] = 0.0, 0.0, 1.0
    for b in range(kinds.shape[0]):
        d = body_distance(kinds[b], params[b], px, py, pz, tmp)
        if d < best:
            best = d
            normal[0], normal[1], normal[2] = tmp[0], tmp[1], tmp[2]
    return best


@njit(cache=True)
def union_distance(kinds, params, points, dist, normal):
    """dist[p], normal[p] = signed distance to the union of bodies at points[p]."""
    for p in range(points.shape[0]):
        dist[p] = union_distance_point(
            kinds, params, points[p, 0], points[p, 1], points[p, 2], normal[p]
        )
