"""Boundary conditions of the MAC (staggered) velocity on the six domain faces and at bodies.

Storage (see :mod:`windbench.wind.navier_stokes`): component ``a`` of the velocity lives on
the faces normal to axis ``a`` in a *padded* array with one ghost layer on every side,
shape ``(nx + 2, ny + 2, nz + 2)`` plus one along axis ``a``. Padded index ``I`` sits at
``lower + (I - 1) h`` along axis ``a`` and at ``lower + (I - 1/2) h`` along the others, so
the interior faces are ``1 .. n_a + 1`` along ``a`` and the interior cells ``1 .. n``.

Per domain face (``scene.boundary``) the kinds act as follows on component ``a``:

========== ============================== ==============================================
kind       normal component (a = face axis) tangential components (ghost cell, h/2 out)
========== ============================== ==============================================
inflow     = inflow wind w_in . n          ghost = 2 w_in - interior (wall value w_in)
opening    = w_in before the projection,    as inflow
           then free (pressure p = 0)
outflow    free (pressure p = 0)           ghost = interior (zero normal gradient)
slip       = wall velocity . n (0)        ghost = interior (no shear stress)
no_slip    = wall velocity . n (0)        ghost = 2 U_wall - interior (the lid velocity)
rough      = 0 (the ground)                ghost = interior; the stress is the wall law's
                                           (:mod:`.wall_law`), not the ghost's
periodic   face n = face 0                 ghost = the opposite interior cell
========== ============================== ==============================================

The wall/inflow values are pre-evaluated on each face plane (``plane_values``). Faces with
a solid cell (a rigid body, paper §4.1.2 "the inside of (rigid) objects") on either side
carry zero velocity: no flux through a body, no wind inside it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

INFLOW, OUTFLOW, SLIP, NO_SLIP, PERIODIC, OPENING, ROUGH = 0, 1, 2, 3, 4, 5, 6
KIND_CODES = {
    "inflow": INFLOW,
    "outflow": OUTFLOW,
    "slip": SLIP,
    "no_slip": NO_SLIP,
    "periodic": PERIODIC,
    "rough": ROUGH,
}
FACE_NAMES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
# the padded low ghost layer and the first inner one, as int64 values: a literal index
# would compile :func:`_layer` once per value
GHOST, INNER = np.int64(0), np.int64(1)


def padded_shape(shape, a: int) -> tuple[int, int, int]:
    """Padded array shape of velocity component ``a`` on a grid of ``shape`` cells."""
    return tuple(int(n) + 2 + (1 if b == a else 0) for b, n in enumerate(shape))


def component_origin(lower, h: float, a: int) -> np.ndarray:
    """World position of padded element ``[0, 0, 0]`` of component ``a``."""
    lo = np.asarray(lower, dtype=np.float64)
    return lo - np.where(np.arange(3) == a, 1.0, 0.5) * h


def plane_points(lower, upper, h: float, shape, a: int, face: int) -> np.ndarray:
    """World points ``(P1, P2, 3)`` on domain face ``face`` at component ``a``'s padded
    transverse lattice (the two axes other than the face's, in increasing order)."""
    b = face // 2
    origin = component_origin(lower, h, a)
    pshape = padded_shape(shape, a)
    others = [c for c in range(3) if c != b]
    axes = [origin[c] + h * np.arange(pshape[c]) for c in others]
    g1, g2 = np.meshgrid(axes[0], axes[1], indexing="ij")
    pts = np.empty((*g1.shape, 3))
    pts[..., others[0]] = g1
    pts[..., others[1]] = g2
    pts[..., b] = lower[b] if face % 2 == 0 else upper[b]
    return pts


@njit(cache=True, inline="always")
def cells_beside(I, J, K, a):
    """Unpadded indices (i+, j+, k+, i-, j-, k-) of the cells on the + and - side of the
    padded face (I, J, K) of component a (they may lie outside the grid)."""
    return I - 1, J - 1, K - 1, I - 1 - int(a == 0), J - 1 - int(a == 1), K - 1 - int(a == 2)


@njit(cache=True)
def _layer(q, b, L):
    """The padded layer L of q along axis b: a plane over the other two axes in increasing
    order (a face plane's transverse lattice). Basic indexing: ``q.transpose(axes)``
    would compile numba's formatted-error path (:mod:`windbench.arrays`)."""
    if b == 0:
        return q[L, :, :]
    if b == 1:
        return q[:, L, :]
    return q[:, :, L]


@njit(cache=True)
def _copy_plane(dst, src):
    """dst[:, :] = src[:, :n1, :n2] for two planes (views): written out, one compiled loop
    for every copy of :func:`fill_boundary` (an array assignment per statement compiled a
    broadcasting loop of its own each)."""
    for c1 in range(dst.shape[0]):
        for c2 in range(dst.shape[1]):
            dst[c1, c2] = src[c1, c2]


@njit(cache=True)
def _mirror(ghost, inner, wall):
    """ghost = 2 wall - inner (planes of one axis, :func:`_layer`): the wall value halfway
    between the ghost and the inner cell."""
    for c1 in range(ghost.shape[0]):
        for c2 in range(ghost.shape[1]):
            ghost[c1, c2] = 2.0 * wall[c1, c2] - inner[c1, c2]


@njit(cache=True)
def zero_solid_faces(q, a, solid):
    """q = 0 on every interior face of component a that touches a solid cell."""
    nx, ny, nz = solid.shape
    P0, P1, P2 = q.shape
    for I in range(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                i, j, k = I - 1, J - 1, K - 1  # the cell on the + side of this face
                hit = False
                if i < nx and j < ny and k < nz and solid[i, j, k]:
                    hit = True
                if a == 0 and i >= 1 and solid[i - 1, j, k]:
                    hit = True
                if a == 1 and j >= 1 and solid[i, j - 1, k]:
                    hit = True
                if a == 2 and k >= 1 and solid[i, j, k - 1]:
                    hit = True
                if hit:
                    q[I, J, K] = 0.0


@njit(cache=True)
def fill_boundary(q, a, kinds, planes, set_normal):
    """Impose the face kinds on component a (table in the module docstring).

    ``planes[face]`` holds the wall/inflow velocity component a at the face's padded
    transverse lattice. ``set_normal``: also overwrite the normal boundary faces of
    inflow/opening/wall kinds (False leaves them, e.g. after the projection set them).
    Axes are filled in order x, y, z over the whole padded range, so edges and corners
    take consistent values.
    """
    P = q.shape
    for b in range(3):
        n_b = P[b] - 2 - (1 if b == a else 0)  # cells along b
        lo_kind = kinds[2 * b]
        hi_kind = kinds[2 * b + 1]
        if b == a:  # the normal component: boundary faces 1 and n_b + 1, ghosts beyond
            lo_face, hi_face = INNER, n_b + 1
            if lo_kind == PERIODIC:
                _copy_plane(_layer(q, b, hi_face), _layer(q, b, lo_face))
                _copy_plane(_layer(q, b, GHOST), _layer(q, b, hi_face - 1))
                _copy_plane(_layer(q, b, hi_face + 1), _layer(q, b, lo_face + 1))
                continue
            for side in range(2):
                kind = lo_kind if side == 0 else hi_kind
                face = lo_face if side == 0 else hi_face
                if set_normal and kind != OUTFLOW:
                    _copy_plane(_layer(q, b, face), planes[2 * b + side])
                _copy_plane(_layer(q, b, 0 if side == 0 else hi_face + 1), _layer(q, b, face))
        else:  # a tangential component: ghost cells h/2 beyond the face
            if lo_kind == PERIODIC:
                _copy_plane(_layer(q, b, GHOST), _layer(q, b, n_b))
                _copy_plane(_layer(q, b, n_b + 1), _layer(q, b, INNER))
                continue
            for side in range(2):
                kind = lo_kind if side == 0 else hi_kind
                ghost = _layer(q, b, 0 if side == 0 else n_b + 1)
                inner = _layer(q, b, 1 if side == 0 else n_b)
                if kind == SLIP or kind == OUTFLOW or kind == ROUGH:
                    _copy_plane(ghost, inner)
                else:  # inflow, opening, no_slip: the wall value at the face
                    _mirror(ghost, inner, planes[2 * b + side])


def boundary_planes(kinds, wall_values, inflow_fn, lower, upper, h, shape):
    """Per component a: ``(6, M, M)`` array of the wall/inflow value of component a on each
    face's padded transverse lattice (unused entries 0).

    ``wall_values[face]``: 3-vector wall velocity (no_slip lid; zero for slip);
    ``inflow_fn(points (m,3), face) -> (m,3)``: the inflow wind at points of a face.
    """
    m = max(int(n) for n in shape) + 3
    out = []
    for a in range(3):
        arr = np.zeros((6, m, m))
        for face in range(6):
            kind = kinds[face]
            if kind in (OUTFLOW, PERIODIC):
                continue
            pts = plane_points(lower, upper, h, shape, a, face)
            if kind in (INFLOW, OPENING):
                vals = inflow_fn(pts.reshape(-1, 3), face)[:, a].reshape(pts.shape[:2])
            else:
                vals = np.full(pts.shape[:2], float(wall_values[face][a]))
                if kind in (SLIP, ROUGH) and a == face // 2:
                    vals[:] = 0.0
            arr[face, : vals.shape[0], : vals.shape[1]] = vals
        out.append(arr)
    return out


@njit(cache=True)
def free_faces(a, kinds, solid, free):
    """free[I,J,K] = 1 where face (I,J,K) of component a is an unknown, else 0.

    Prescribed (0): ghosts; faces touching a solid cell; normal domain faces of inflow,
    slip and no_slip kind; the duplicate last face of a periodic axis. Outflow and
    opening faces are unknowns (the projection sets them against p = 0).
    """
    nx, ny, nz = solid.shape
    n = (nx, ny, nz)
    P0, P1, P2 = free.shape
    free[:] = 0
    for I in range(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                idx = (I - 1, J - 1, K - 1)
                along = idx[a]
                lo_kind, hi_kind = kinds[2 * a], kinds[2 * a + 1]
                # the cells on the - and + side of the face (wrapped on periodic axes)
                ip = min(idx[0], nx - 1)
                jp = min(idx[1], ny - 1)
                kp = min(idx[2], nz - 1)
                im, jm, km = idx[0], idx[1], idx[2]
                if a == 0:
                    im = idx[0] - 1
                elif a == 1:
                    jm = idx[1] - 1
                else:
                    km = idx[2] - 1
                if along == n[a]:
                    if hi_kind == PERIODIC or (hi_kind != OUTFLOW and hi_kind != OPENING):
                        continue
                    if solid[im, jm, km]:
                        continue
                    free[I, J, K] = 1
                    continue
                if along == 0:
                    if lo_kind == PERIODIC:
                        im, jm, km = im % nx, jm % ny, km % nz
                    elif lo_kind != OUTFLOW and lo_kind != OPENING:
                        continue
                    else:
                        if not solid[ip, jp, kp]:
                            free[I, J, K] = 1
                        continue
                if solid[ip, jp, kp] or solid[im, jm, km]:
                    continue
                free[I, J, K] = 1
