"""Rigid obstacles: box, capsule, cylinder, plane and triangle mesh, as signed distances.

The paper treats walls and the character's body as rigid objects that shape the wind but
feel no force (§4.1.2); cloth collides with them ([MKE03]) and wind particles stop at them
(§4.2.2). Every body is one row of a parameter table (``kind`` + 7 floats, :class:`BodyTable`)
read by the numba kernel :func:`table_distance`, which returns the signed distance (negative
inside) and the outward unit normal at the nearest surface point.

======== ====================================== ============================================
body     config keys                            solid region
======== ====================================== ============================================
box      ``min``, ``max``                       the axis-aligned box
capsule  ``a``, ``b``, ``radius``               points within ``radius`` of the segment a-b
cylinder ``a``, ``b``, ``radius``               the finite, flat-capped cylinder on a-b
plane    ``point``, ``normal``                  the half-space behind the plane, (x-p).n < 0
mesh     ``file``, ``scale``, ``offset``,       inside a closed triangle mesh (OBJ, PLY, STL;
         ``spacing``                            :mod:`windbench.geometry.triangle_mesh`)
======== ====================================== ============================================

A mesh body's distance is tabulated once, on a lattice of ``spacing`` metres (default
MESH_SPACING), and sampled trilinearly (:mod:`windbench.geometry.sdf`); its row holds the
lattice's place in the table's ``fields`` and the mesh's bounding box.

Every body may set ``name``, ``resolve`` (default true) and ``motion``. ``resolve: false``
marks a body thinner than any sensible wind cell (a flag pole): cloth collides with it, but
the run does not demand that the wind grid hold a cell inside it. ``motion`` makes the body
kinematic (:mod:`windbench.geometry.motion`): its config places it at rest and the table's
poses carry it: row b of the table's ``params`` holds after its 7 parameters a moving flag
and the current and the previous pose (:func:`set_poses`); a still body (flag 0) is read
at its rest place as before.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import njit

from windbench.errors import ConfigError
from windbench.geometry.motion import POSE_WIDTH, Motion, motion_from_config
from windbench.geometry.sdf import SDFLattice, lattice_distance, sdf_lattice
from windbench.geometry.triangle_mesh import (
    Placement,
    check_closed,
    find_file,
    read_mesh,
    signed_volume,
)

BOX, CAPSULE, CYLINDER, PLANE, MESH = 0, 1, 2, 3, 4
KINDS = {"box": BOX, "capsule": CAPSULE, "cylinder": CYLINDER, "plane": PLANE, "mesh": MESH}
N_PARAMS = 7
MOVING = N_PARAMS  # params column: 1 for a moving body, 0 for a still one
POSE = MOVING + 1  # params columns of the current pose row ...
PREVIOUS = POSE + POSE_WIDTH  # ... and of the previous one
ROW = PREVIOUS + POSE_WIDTH
FIRST = np.int64(0)  # body 0 as an int64 value: a literal 0 compiles the distances again
MESH_SPACING = 0.01  # m: the SDF lattice of a mesh body; error ~ h^2 / (4 r) on radius r
_KEYS = {
    "box": ("min", "max"),
    "capsule": ("a", "b", "radius"),
    "cylinder": ("a", "b", "radius"),
    "plane": ("point", "normal"),
    "mesh": ("file", "scale", "offset", "spacing"),
}


class BodyTable(NamedTuple):
    """The bodies as the kernels read them: ``kinds`` (m,), ``params`` (m, 7),
    ``fields``, the mesh bodies' distance lattices one after another (:meth:`SDFLattice.entry`),
    and ``track`` (k, m, POSE_WIDTH), the poses at the cloth's coming substeps
    (:func:`set_track`). A row of ``params`` (ROW wide) holds the body's N_PARAMS
    parameters, at MOVING 1 for a moving body, and the state of one: its current pose row
    at POSE, the previous one at PREVIOUS (:func:`set_poses`)."""

    kinds: np.ndarray
    params: np.ndarray
    fields: np.ndarray
    track: np.ndarray


@dataclass(frozen=True)
class Body:
    """A rigid obstacle: kind, parameter row and an optional name."""

    kind: str
    params: tuple[float, ...]
    name: str = ""
    resolve: bool = True  # False: thinner than the wind grid (a pole); cloth still collides
    lattice: SDFLattice | None = field(default=None, compare=False, repr=False)  # mesh only
    motion: Motion | None = None  # None: the body stays where the config places it

    @property
    def kind_id(self) -> int:
        return KINDS[self.kind]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box (infinite for a plane)."""
        p = np.asarray(self.params)
        if self.kind == "box":
            return p[0:3], p[3:6]
        if self.kind == "mesh":
            return p[1:4], p[4:7]
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
    allowed = set(_KEYS[kind]) | {"type", "name", "resolve", "motion"}
    unknown = set(spec) - allowed
    if unknown:
        raise ConfigError(
            key, f"unknown key(s) {sorted(unknown)} for a {kind}; allowed {sorted(allowed)}"
        )
    body = mesh_body(spec, key) if kind == "mesh" else _analytic_body(kind, spec, key)
    if spec.get("motion") is None:
        return body
    lo, hi = body.bounds()
    centre = 0.5 * (lo + hi) if np.all(np.isfinite(lo) & np.isfinite(hi)) else None
    return replace(body, motion=motion_from_config(spec["motion"], f"{key}.motion", centre))


def _analytic_body(kind: str, spec: Mapping, key: str) -> Body:
    """A box, capsule, cylinder or plane from its checked keys (module docstring)."""
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


def mesh_body(spec: Mapping, key: str) -> Body:
    """A body of ``type: mesh``: a closed mesh file, its distance tabulated (module docstring)."""
    spacing = spec.get("spacing", MESH_SPACING)
    if not isinstance(spacing, int | float) or not np.isfinite(spacing) or spacing <= 0:
        raise ConfigError(f"{key}.spacing", f"must be a length > 0 (m), got {spacing!r}")
    path = find_file(spec.get("file"), f"{key}.file")
    placement = Placement.from_config(spec, key)
    stamp = path.stat()
    vertices, triangles, lattice = _tabulated(
        str(path), stamp.st_mtime_ns, stamp.st_size, placement, float(spacing), key
    )
    row = (0.0, *vertices.min(axis=0), *vertices.max(axis=0))  # lattice offset: body_table
    name = str(spec.get("name", Body.name))
    return Body(
        "mesh", tuple(float(v) for v in row), name, bool(spec.get("resolve", Body.resolve)), lattice
    )


@lru_cache(maxsize=8)
def _tabulated(path: str, mtime: int, size: int, placement: Placement, spacing: float, key: str):
    """Read, check and tabulate a body mesh once per file version, placement and spacing."""
    spec = {"file": path, "scale": placement.scale, "offset": list(placement.offset)}
    vertices, triangles = read_mesh(spec, key)
    check_closed(triangles, f"{key}.file")
    if signed_volume(vertices, triangles) < 0:  # wound inside out: turn it the right way
        triangles = triangles[:, ::-1].copy()
    return vertices, triangles, sdf_lattice(vertices, triangles, spacing)


def body_table(bodies: Sequence[Body], time: float = 0.0, track: int = 1) -> BodyTable:
    """The :class:`BodyTable` of ``bodies`` for the numba kernels, posed at ``time`` (s),
    with room for ``track`` poses per body (:func:`set_track`)."""
    kinds = np.array([b.kind_id for b in bodies], dtype=np.int64)
    params = np.zeros((len(bodies), ROW))
    params[:, :N_PARAMS] = np.array([b.params for b in bodies]).reshape(len(bodies), N_PARAMS)
    params[:, MOVING] = [b.motion is not None for b in bodies]
    entries, offset = [], 0
    for b, body in enumerate(bodies):
        if body.lattice is not None:
            params[b, 0] = offset
            entries.append(body.lattice.entry())
            offset += entries[-1].size
    fields = np.concatenate(entries) if entries else np.zeros(0)
    table = BodyTable(kinds, params, fields, np.zeros((track, len(bodies), POSE_WIDTH)))
    set_poses(table, bodies, time)
    set_poses(table, bodies, time)  # previous = current: no motion yet
    return table


def set_poses(table: BodyTable, bodies: Sequence[Body], time: float) -> None:
    """Pose the moving bodies of ``table`` at ``time`` (s), in place: each current pose row
    becomes the previous one (a still body keeps its zero rows)."""
    for b, body in enumerate(bodies):
        if body.motion is not None:
            table.params[b, PREVIOUS:ROW] = table.params[b, POSE:PREVIOUS]
            table.params[b, POSE:PREVIOUS] = body.motion.pose(time).row()


def set_track(table: BodyTable, bodies: Sequence[Body], times) -> None:
    """``track[k]`` = the moving bodies' pose rows at ``times[k]`` (s), in place."""
    for b, body in enumerate(bodies):
        if body.motion is not None:
            for k, t in enumerate(times):
                table.track[k, b] = body.motion.pose(float(t)).row()


def distances(bodies: Sequence[Body], points, time: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance to the union of ``bodies`` (posed at ``time``, s) and the outward
    normal there."""
    pts = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
    dist = np.empty(pts.shape[0])
    normal = np.empty_like(pts)
    union_distance(body_table(bodies, time), pts, dist, normal)
    return dist, normal


def body_velocity(bodies: Sequence[Body], points, time: float) -> np.ndarray:
    """(n, 3) velocity at ``time`` (s) of the body nearest each point (the one it lies in):
    c' + omega x (x - c) of a moving body (:meth:`~windbench.geometry.motion.Pose.point_velocity`),
    0 of a still one."""
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    velocity = np.zeros(pts.shape)
    if not bodies or not pts.size:
        return velocity
    nearest = np.argmin([distances([b], pts, time)[0] for b in bodies], axis=0)
    for b, body in enumerate(bodies):
        here = nearest == b
        if body.motion is not None and here.any():
            velocity[here] = body.motion.pose(time).point_velocity(pts[here])
    return velocity


def inside(bodies: Sequence[Body], points, time: float = 0.0) -> np.ndarray:
    """Boolean mask: points strictly inside any body (posed at ``time``, s)."""
    if not bodies:
        return np.zeros(np.atleast_2d(points).shape[0], dtype=bool)
    return distances(bodies, points, time)[0] < 0.0


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
    """Signed distance from p to one analytic (convex) body, negative inside; outward unit
    normal in ``normal`` (mesh bodies: :func:`table_distance`)."""
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
def rest_distance(table, b, px, py, pz, normal):
    """Signed distance from p to body b of a :class:`BodyTable` where its config places it,
    outward normal in ``normal``: the mesh bodies' lattices
    (:func:`~windbench.geometry.sdf.lattice_distance`), else :func:`body_distance`."""
    if table.kinds[b] == MESH:
        return lattice_distance(table.fields, table.params[b], px, py, pz, normal)
    return body_distance(table.kinds[b], table.params[b], px, py, pz, normal)


@njit(cache=True, inline="always")
def is_moving(table, b):
    """Whether body b of a :class:`BodyTable` moves (its params' MOVING column)."""
    return table.params[b, MOVING] != 0.0


@njit(cache=True, inline="always")
def to_rest(pose, px, py, pz):
    """x0 = R^T (x - T) of a pose row (R row-major, T): a world point in the rest frame."""
    dx, dy, dz = px - pose[9], py - pose[10], pz - pose[11]
    return (
        pose[0] * dx + pose[3] * dy + pose[6] * dz,
        pose[1] * dx + pose[4] * dy + pose[7] * dz,
        pose[2] * dx + pose[5] * dy + pose[8] * dz,
    )


@njit(cache=True)
def table_distance(table, b, px, py, pz, normal):
    """Signed distance from p to body b of a :class:`BodyTable`, outward normal in ``normal``:
    a still body's :func:`rest_distance`; a moving one's :func:`posed_distance`."""
    if is_moving(table, b):
        return posed_distance(table, b, px, py, pz, normal)
    if table.kinds[b] == MESH:  # rest_distance written out: the still path stays inlinable
        return lattice_distance(table.fields, table.params[b], px, py, pz, normal)
    return body_distance(table.kinds[b], table.params[b], px, py, pz, normal)


@njit(cache=True)
def posed_distance(table, b, px, py, pz, normal):
    """:func:`rest_distance` of moving body b at its current pose: d0(R^T (x - T)), the
    normal turned forward, R n0 (a call of its own, so that the still bodies' path stays
    small enough to inline)."""
    pose = table.params[b, POSE:PREVIOUS]
    qx, qy, qz = to_rest(pose, px, py, pz)
    d = rest_distance(table, b, qx, qy, qz, normal)
    turn_forward(pose, normal)
    return d


@njit(cache=True, inline="always")
def turn_forward(pose, normal):
    """normal <- R normal (in place), R the pose's rotation (row-major in pose[:9]): a
    direction of the body's rest frame turned into the world."""
    nx, ny, nz = normal[0], normal[1], normal[2]
    normal[0] = pose[0] * nx + pose[1] * ny + pose[2] * nz
    normal[1] = pose[3] * nx + pose[4] * ny + pose[5] * nz
    normal[2] = pose[6] * nx + pose[7] * ny + pose[8] * nz


@njit(cache=True)
def surface_displacement(table, b, px, py, pz, out):
    """out = how far the point of moving body b now at p moved with the body since the
    previous pose: p - (R_prev R^T (p - T) + T_prev)."""
    qx, qy, qz = to_rest(table.params[b, POSE:PREVIOUS], px, py, pz)
    prev = table.params[b, PREVIOUS:ROW]
    out[0] = px - (prev[0] * qx + prev[1] * qy + prev[2] * qz + prev[9])
    out[1] = py - (prev[3] * qx + prev[4] * qy + prev[5] * qz + prev[10])
    out[2] = pz - (prev[6] * qx + prev[7] * qy + prev[8] * qz + prev[11])


@njit(cache=True)
def union_distance_point(table, px, py, pz, normal):
    """Signed distance to the nearest body of a :class:`BodyTable`, normal of that one."""
    normal[0], normal[1], normal[2] = 0.0, 0.0, 1.0
    if table.kinds.shape[0] == 1:  # one body: no scratch to allocate (a contact's hot path)
        return table_distance(table, FIRST, px, py, pz, normal)
    best = np.inf
    tmp = np.empty(3)
    for b in range(table.kinds.shape[0]):
        d = table_distance(table, b, px, py, pz, tmp)
        if d < best:
            best = d
            normal[0], normal[1], normal[2] = tmp[0], tmp[1], tmp[2]
    return best


@njit(cache=True)
def moving_body_at(table, px, py, pz, distance):
    """The moving body of a :class:`BodyTable` whose signed distance at p is ``distance``
    (the union's, :func:`union_distance_point`: p's nearest body), or -1 if it is still."""
    tmp = np.empty(3)
    for b in range(table.kinds.shape[0]):
        if is_moving(table, b) and table_distance(table, b, px, py, pz, tmp) == distance:
            return b
    return -1


@njit(cache=True)
def union_distance(table, points, dist, normal):
    """dist[p], normal[p] = signed distance to the union of a table's bodies at points[p]."""
    for p in range(points.shape[0]):
        dist[p] = union_distance_point(table, points[p, 0], points[p, 1], points[p, 2], normal[p])
