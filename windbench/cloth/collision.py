"""Cloth against rigid bodies: vertex projection with friction, and the penetration figure.

The paper's cloth system detects cloth/body contacts with k-DOP hierarchies [MKE03]; here
the bodies are few analytic shapes or tabulated meshes, so each cloth vertex asks the signed
distance to their union (:func:`windbench.geometry.bodies.union_distance_point`) and a
vertex closer than the collision margin is moved out along the body's outward normal
(position-based contact, Mueller et al. 2007). A vertex outside every body's bounding box
grown by the margin is skipped (:func:`near_a_body`): it lies farther than the margin from
all bodies, so the result is the same, for a fraction of the cost. Coulomb friction limits
the tangential displacement of a contact in the same substep: it is cancelled if shorter
than ``mu x penetration depth`` (static), else shortened by that amount (kinetic).

The paper's walls and character are still (§4.1.2). A kinematic body
(:mod:`windbench.geometry.motion`) is met at its pose at the end of each substep
(:func:`follow_track`) and drags what it touches: the tangential displacement that friction
limits is the vertex's relative to the body's surface point under it over the substep,
``(p - x_prev) - (p - X_prev(p))`` with X_prev the point's place at the previous pose, so a
sticking contact moves with the body. A moving body's broad-phase box is all space and its
clearances are reset every substep (it may approach any vertex).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from windbench.geometry.bodies import (
    POSE,
    PREVIOUS,
    Body,
    is_moving,
    moving_body_at,
    surface_displacement,
    union_distance_point,
)
from windbench.geometry.motion import POSE_WIDTH


def body_boxes(bodies: tuple[Body, ...], margin: float) -> np.ndarray:
    """(m, 6) bounding boxes (lower, upper) of the bodies grown by ``margin`` (planes: all space).

    The broad phase of :func:`near_a_body`: a point outside body b's grown box lies farther
    than ``margin`` from b, so b cannot touch it.
    """
    boxes = np.empty((len(bodies), 6))
    for b, body in enumerate(bodies):
        lo, hi = body.bounds() if body.motion is None else (-np.inf, np.inf)  # moving: anywhere
        boxes[b, :3], boxes[b, 3:] = lo - margin, hi + margin
    return boxes


@njit(cache=True)
def follow_track(bodies, k, clearance):
    """Pose the moving bodies for substep k: the previous pose ``track[k]``, the current
    ``track[k + 1]`` (the table's ``track``, (substeps + 1, m, POSE_WIDTH)); every clearance
    is reset (a body may have come closer)."""
    for b in range(bodies.kinds.shape[0]):
        if is_moving(bodies, b):
            for j in range(POSE_WIDTH):
                bodies.params[b, PREVIOUS + j] = bodies.track[k, b, j]
                bodies.params[b, POSE + j] = bodies.track[k + 1, b, j]
    clearance[:] = 0.0


@njit(cache=True, inline="always")
def near_a_body(boxes, px, py, pz):
    """Whether p lies in any grown bounding box (:func:`body_boxes`); else no contact."""
    for b in range(boxes.shape[0]):
        if (
            boxes[b, 0] <= px <= boxes[b, 3]
            and boxes[b, 1] <= py <= boxes[b, 4]
            and boxes[b, 2] <= pz <= boxes[b, 5]
        ):
            return True
    return False


@njit(cache=True, inline="always")
def project_vertex(bodies, margin, friction, x_prev, p, normal):
    """Move ``p`` (in place) out to ``margin`` from the bodies; friction against ``x_prev``.

    d = sdf(p) - margin < 0  ->  p += -d n;  tangential move dt limited by mu |d|.
    Returns d (how far p lay outside the margin; negative: how deep it lay inside).
    """
    d = union_distance_point(bodies, p[0], p[1], p[2], normal) - margin
    if d >= 0.0:
        return d
    b = moving_body_at(bodies, p[0], p[1], p[2], d + margin)
    for k in range(3):
        p[k] -= d * normal[k]
    # tangential displacement over the substep, relative to a moving body's surface
    ox, oy, oz = x_prev[0], x_prev[1], x_prev[2]
    if b >= 0:
        carried = np.empty(3)
        surface_displacement(bodies, b, p[0], p[1], p[2], carried)
        ox, oy, oz = ox + carried[0], oy + carried[1], oz + carried[2]
    dn = (p[0] - ox) * normal[0] + (p[1] - oy) * normal[1] + (p[2] - oz) * normal[2]
    tx = p[0] - ox - dn * normal[0]
    ty = p[1] - oy - dn * normal[1]
    tz = p[2] - oz - dn * normal[2]
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    limit = -friction * d
    if tl <= limit:  # static friction: the contact sticks
        p[0] -= tx
        p[1] -= ty
        p[2] -= tz
    elif tl > 0.0:  # kinetic friction: slide, shortened by mu x depth
        s = limit / tl
        p[0] -= s * tx
        p[1] -= s * ty
        p[2] -= s * tz
    return d


# |grad sdf| of the union of the bodies is at most 1 for the analytic shapes and sqrt 3 for a
# tabulated mesh inside its lattice (windbench.geometry.sdf; outside, the distance is that to
# the lattice's box, PAD_CELLS spacings or more, beyond any contact); the clearance test
# uses this bound.
LIPSCHITZ = 2.0


@njit(cache=True, inline="always")
def contact_vertex(contacts, i, x_prev, p, normal, clear):
    """:func:`project_vertex` for vertex ``i`` unless it cannot touch a body.

    ``clear`` = (probe (n, 3), clearance (n,)): at ``probe[i]`` vertex i lay
    ``clearance[i]`` outside the margin. The signed distance changes by at most
    LIPSCHITZ |p - probe| between two points, so while ``LIPSCHITZ |p - probe[i]|`` is
    smaller than the clearance the vertex is still outside the margin and the query is
    skipped: the result is the same, without the distance query. A query records its
    point and clearance (0 after a contact).
    """
    bodies, boxes, margin, friction = contacts
    probe, clearance = clear
    if not near_a_body(boxes, p[0], p[1], p[2]):
        return
    dx, dy, dz = p[0] - probe[i, 0], p[1] - probe[i, 1], p[2] - probe[i, 2]
    if LIPSCHITZ * LIPSCHITZ * (dx * dx + dy * dy + dz * dz) < clearance[i] * clearance[i]:
        return
    d = project_vertex(bodies, margin, friction, x_prev, p, normal)
    probe[i, 0], probe[i, 1], probe[i, 2] = p[0], p[1], p[2]
    clearance[i] = max(d, 0.0)


@njit(cache=True)
def deepest_penetration(bodies, boxes, positions):
    """max_i max(0, -sdf(x_i)): how deep the deepest vertex lies inside the union of the bodies.

    Only vertices inside a body's bounding box (``boxes``, :func:`body_boxes`) can be inside it.
    """
    normal = np.empty(3)
    deepest = 0.0
    for i in range(positions.shape[0]):
        px, py, pz = positions[i, 0], positions[i, 1], positions[i, 2]
        if near_a_body(boxes, px, py, pz):
            deepest = max(deepest, -union_distance_point(bodies, px, py, pz, normal))
    return deepest


def max_penetration(bodies, boxes, positions) -> float:
    """Largest depth (m) of any vertex inside any body of the table ``bodies``
    (:class:`~windbench.geometry.bodies.BodyTable`); 0 with no bodies or no vertices."""
    if bodies.kinds.shape[0] == 0 or positions.shape[0] == 0:
        return 0.0
    x = np.ascontiguousarray(positions, dtype=np.float64)
    return float(deepest_penetration(bodies, boxes, x))
