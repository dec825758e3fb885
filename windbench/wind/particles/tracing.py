"""Gust-particle tracing kernels (paper §4.2.2): Euler paths cut at cell faces, lee by
collision, and the cell field u = sum of the reached sources' w_i.

A particle of source i moves only in w_i (never the superposed field) by the paper's
explicit Euler step ``p_{t+dt} = p_t + w_i(p_t) dt`` (:func:`euler_velocities` evaluates
w_i(p_t)). Its path is walked cell by cell (Amanatides & Woo's voxel traversal), so each
piece lies inside one cell ("subdivided into parts not exceeding the size of a grid
cell") and no cell on the way is skipped.

Each piece is tested only against what is registered in its cell: the rigid bodies whose
surface may reach into the cell (:func:`register_bodies`) and the cloth triangles that
overlap it (:func:`register_cloth`), so the cost is O(particles x cells crossed). At the
first hit the particle stops on the surface (``delta`` outside it) and its velocity loses
the normal component, the paper's ``w_i <- w_i - (n_obj . w_i) n_obj``; it spends the
rest of the step sliding along the object. A head-on hit (nothing left of w) ends the
particle: its gust has stagnated at the wall. The analytic bodies are convex, so their signed
distance is convex along a piece and :func:`convex_first_hit` finds its first root exactly;
mesh bodies are sphere-traced (:func:`windbench.geometry.sdf.lattice_first_hit`).

Cell state per (cell, source): ``marked[c, s]``, the time the source's particles last
reached the cell (-inf: never), and ``values[c, s]``, the value that mark left. A free
particle leaves w_i at the cell centre, so with no obstacles u equals the ``global``
backend's field; after a hit, ``mark_mode`` says which contact normals its later marks
remove from w_i(centre) (the paper's ``u(p_col) . n_obj = 0``): every hit's (``all``),
rigid bodies' (``bodies``) or none. Within one step a deflected mark beats a free one;
otherwise the later mark wins. A cell holds the paper's ``u = sum_i w_i`` over the
sources that reached it within ``memory``; u is refreshed only where marks change and
where they lapse (:func:`expire_cells`), never by a pass over the grid. The kernels run
serially over the particles in their stored order, so a run is bit-for-bit reproducible.

The kernels take a few structured arguments (named tuples of arrays and scalars): the
fixed :class:`GustModel`, the cloth registered this step (:class:`ClothCells`), the
changing :class:`CellState` and :class:`Particles`, the :class:`TraceStep` being taken
and the :class:`TraceWork` scratch. On large grids the cell state does not fit in the
caches: the tracing then prefetches the cells of the particle AHEAD places on.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from windbench.arrays import copy_head, cross
from windbench.geometry.bodies import (
    MESH,
    POSE,
    PREVIOUS,
    BodyTable,
    body_distance,
    is_moving,
    set_poses,
    table_distance,
    to_rest,
    turn_forward,
    union_distance_point,
)
from windbench.geometry.raster import segment_triangle
from windbench.geometry.sdf import lattice_first_hit
from windbench.wind.primitives import primitive_velocity

SOLID, BODIES, TRIANGLES = 1, 2, 4  # bits of the per-cell flags
MARK_NONE, MARK_BODIES, MARK_ALL = 0, 1, 2  # which hits make the marks "deflected"
MARK_MODES = {"none": MARK_NONE, "bodies": MARK_BODIES, "all": MARK_ALL}
ROOT_ITERATIONS = 60
# a body hit as a run-time boolean (np.bool_), not a constant: a literal True or False is
# a type of its own, for which numba compiles :func:`first_triangle_hit` once more
BODY_HIT, NO_BODY_HIT = np.bool_(True), np.bool_(False)
AHEAD = 8  # particles between a particle's prefetch and its tracing
RADIX_BITS = 11  # bits of the cell id sorted per pass of sort_by_cell
RADIX = 1 << RADIX_BITS


class CellGrid(NamedTuple):
    """The wind grid as the kernels see it (scalars); cell id c = (i * ny + j) * nz + k."""

    lower: tuple[float, float, float]  # lower corner, m
    upper: tuple[float, float, float]  # upper corner, m
    h: float  # cell width, m
    shape: tuple[int, int, int]  # cells per axis


class BodyCells(NamedTuple):
    """Rigid bodies (:func:`~windbench.geometry.bodies.body_table`) and, as CSR, the bodies
    registered in each cell: those of cell c are ``items[start[c]:start[c + 1]]``."""

    table: BodyTable
    start: np.ndarray
    items: np.ndarray


class TraceRules(NamedTuple):
    """The backend's fixed parameters as the kernels read them."""

    max_age: float  # s; older particles die
    memory: float  # s; a mark counts this long
    delta: float  # m; particles rest this far outside a surface they hit
    max_hits: int  # hits per particle per step
    mark_mode: int  # MARK_NONE | MARK_BODIES | MARK_ALL


class GustModel(NamedTuple):
    """Everything fixed at construction: grid, sources' w_i table, bodies, rules."""

    grid: CellGrid
    source_kinds: np.ndarray  # (n_sources,) primitive kinds
    source_params: np.ndarray  # (n_sources, 11) primitive rows
    bodies: BodyCells
    rules: TraceRules


class ClothCells(NamedTuple):
    """The cloth triangles of this step and the cells they overlap (:func:`register_cloth`):
    the triangles of a TRIANGLES cell c are ``items[start[slot[c]]:start[slot[c] + 1]]``;
    ``bounds`` (m, 2, 3) their bounding boxes (min, max)."""

    positions: np.ndarray
    triangles: np.ndarray
    bounds: np.ndarray
    slot: np.ndarray
    start: np.ndarray
    items: np.ndarray


class CellState(NamedTuple):
    """Per-cell arrays that change: flags (SOLID, BODIES, TRIANGLES), ``marked`` (n_cells,
    n_sources) times of the last marks, ``values`` (n_cells, n_sources, 3) what they left
    (may be ``u`` itself with one source), and ``u`` (n_cells, 3)."""

    flags: np.ndarray
    marked: np.ndarray
    values: np.ndarray
    u: np.ndarray


class Particles(NamedTuple):
    """Particle buffers: position (N, 3), source id (N,), age (N,) (s)."""

    positions: np.ndarray
    sources: np.ndarray
    ages: np.ndarray


class TraceWork(NamedTuple):
    """Scratch of :func:`trace_gusts`, owned by the backend's workspace; ``velocities``
    (N, 3) holds w_i(p) of each particle (:func:`euler_velocities`) on entry."""

    velocities: np.ndarray
    value: np.ndarray  # (3,) the value a mark leaves
    normal: np.ndarray  # (3,) normal of the nearest hit
    body_normal: np.ndarray  # (3,)
    root: np.ndarray  # (2, 3) scratch of convex_first_hit
    piece: np.ndarray  # (2, 3) the piece a -> b for the triangle tests
    normals: np.ndarray  # (max_hits, 3) normals of the hits that make marks deflected


class TraceStep(NamedTuple):
    """One step: particles 0..n-1 move, those from n_old on were emitted within the step
    and move for ``new_durations[q - n_old]``; marks are stamped ``t_now``."""

    dt: float
    t_now: float
    n: int
    n_old: int
    new_durations: np.ndarray
    prefetch: bool  # prefetch the cells of particles AHEAD places on (no effect on numbers)


@njit(cache=True)
def register_bodies(table, grid):
    """CSR (start, items) of the bodies whose surface may reach into each cell.

    Body b is registered in cell c when d_b(centre_c) <= half the cell diagonal, i.e. the
    body meets the ball around the cell.
    """
    nx, ny, nz = grid.shape
    n_cells = nx * ny * nz
    reach = 0.5 * np.sqrt(3.0) * grid.h * (1.0 + 1e-9)
    normal = np.empty(3)
    start = np.zeros(n_cells + 1, dtype=np.int64)
    items = np.empty(0, dtype=np.int64)
    for fill in range(2):  # count, then fill
        if fill == 1:
            for c in range(n_cells):
                start[c + 1] += start[c]
            items = np.empty(start[n_cells], dtype=np.int64)
        counts = np.zeros(n_cells if fill else 0, dtype=np.int64)
        for c in range(n_cells):
            i, j, k = c // (ny * nz), (c // nz) % ny, c % nz
            px = grid.lower[0] + (i + 0.5) * grid.h
            py = grid.lower[1] + (j + 0.5) * grid.h
            pz = grid.lower[2] + (k + 0.5) * grid.h
            for b in range(table.kinds.shape[0]):
                if table_distance(table, b, px, py, pz, normal) <= reach:
                    if fill == 0:
                        start[c + 1] += 1
                    else:
                        items[start[c] + counts[c]] = b
                        counts[c] += 1
    return start, items


@njit(cache=True)
def register_cloth(keys, m, previous, flags, tri_slot):
    """Flag the cells the cloth triangles overlap, in O(overlaps) (no pass over the grid).

    ``keys`` are the sorted ``cell * m + t`` of :func:`windbench.geometry.raster.
    triangle_cell_pairs`; ``previous`` the cells flagged last step, whose TRIANGLES bit is
    cleared first. Sets the bit and ``tri_slot[cell]`` = the cell's row in the returned
    CSR; returns (cells, start, items): the triangles of ``cells[r]`` are
    ``items[start[r]:start[r + 1]]`` (ascending).
    """
    for c in previous:
        flags[c] &= ~np.uint8(TRIANGLES)
    n_rows = 0
    for q in range(keys.shape[0]):
        if q == 0 or keys[q] // m != keys[q - 1] // m:
            n_rows += 1
    cells = np.empty(n_rows, dtype=np.int64)
    start = np.empty(n_rows + 1, dtype=np.int64)
    r = -1
    for q in range(keys.shape[0]):
        c = keys[q] // m
        if r < 0 or c != cells[r]:
            r += 1
            cells[r] = c
            start[r] = q
            flags[c] |= np.uint8(TRIANGLES)
            tri_slot[c] = r
    start[n_rows] = keys.shape[0]
    return cells, start, keys % m


@njit(cache=True)
def convex_first_hit(kind, prm, a, e, scratch, normal):
    """First s in [0, 1] with d(a + s e) <= 0 for one convex body, or -1; outward normal.

    f(s) = d(a + s e) is convex (d of a convex set), with slope f'(s) = n(s) . e. No root
    when f(1) > 0 and either |e| <= f(0) + f(1) (1-Lipschitz), f'(0) >= 0 or f'(1) <= 0
    (monotone), or the tangent lines at a bracket of the minimum meet above zero; else the
    root is bracketed and bisected. A particle touching the surface (f(0) <= 0) hits at
    s = 0 only if it moves inward. ``a``, ``e`` are 3-tuples; ``scratch`` a (2, 3) array.
    """
    ax, ay, az = a
    ex, ey, ez = e
    n0 = scratch[0]
    nm = scratch[1]
    length = np.sqrt(ex * ex + ey * ey + ez * ez)
    f0 = body_distance(kind, prm, ax, ay, az, n0)
    g0 = n0[0] * ex + n0[1] * ey + n0[2] * ez
    if f0 <= 0.0:
        if g0 < -1e-12 * length:
            normal[0], normal[1], normal[2] = n0[0], n0[1], n0[2]
            return 0.0
        return -1.0
    if length == 0.0:
        return -1.0
    f1 = body_distance(kind, prm, ax + ex, ay + ey, az + ez, nm)
    lo = 0.0
    hi = 1.0
    if f1 > 0.0:
        if f0 + f1 >= length or g0 >= 0.0:
            return -1.0
        g1 = nm[0] * ex + nm[1] * ey + nm[2] * ez
        if g1 <= 0.0:
            return -1.0
        flo, glo, fhi, ghi = f0, g0, f1, g1
        found = False
        for _ in range(ROOT_ITERATIONS):
            # convex f lies above both tangents; they meet at ts with value lb
            ts = (fhi - flo + glo * lo - ghi * hi) / (glo - ghi)
            if flo + glo * (ts - lo) > 0.0:
                return -1.0
            mid = 0.5 * (lo + hi)
            fm = body_distance(kind, prm, ax + mid * ex, ay + mid * ey, az + mid * ez, nm)
            if fm <= 0.0:
                hi = mid
                found = True
                break
            gm = nm[0] * ex + nm[1] * ey + nm[2] * ez
            if gm < 0.0:
                lo, flo, glo = mid, fm, gm
            else:
                hi, fhi, ghi = mid, fm, gm
        if not found:
            return -1.0
    # f(lo) > 0 >= f(hi): bisect to round-off, keep the outside end
    for _ in range(ROOT_ITERATIONS):
        if (hi - lo) * length <= 1e-13 * (1.0 + length):
            break
        mid = 0.5 * (lo + hi)
        if body_distance(kind, prm, ax + mid * ex, ay + mid * ey, az + mid * ez, nm) <= 0.0:
            hi = mid
        else:
            lo = mid
    body_distance(kind, prm, ax + lo * ex, ay + lo * ey, az + lo * ez, normal)
    return lo


@njit(cache=True, inline="always")
def first_body_hit(table, b, a, e, scratch, normal):
    """First s in [0, 1] where a + s e meets body b of the table, or -1; normal there.

    A moving body is met at its current pose: the piece carried to its rest frame,
    a0 = R^T (a - T), e0 = R^T e (s is the same on both), the normal turned back, R n0.
    """
    if is_moving(table, b):
        return _posed_first_hit(table, b, a, e, scratch, normal)
    return _rest_first_hit(table, b, a, e, scratch, normal)


@njit(cache=True, inline="always")
def _rest_first_hit(table, b, a, e, scratch, normal):
    """:func:`first_body_hit` on body b where its config places it."""
    if table.kinds[b] == MESH:
        return lattice_first_hit(table.fields, table.params[b], a, e, normal)
    return convex_first_hit(table.kinds[b], table.params[b], a, e, scratch, normal)


@njit(cache=True)
def _posed_first_hit(table, b, a, e, scratch, normal):
    """:func:`first_body_hit` on moving body b at its current pose."""
    pose = table.params[b, POSE:PREVIOUS]
    a0 = to_rest(pose, a[0], a[1], a[2])
    ex, ey, ez = e[0], e[1], e[2]
    e0 = (
        pose[0] * ex + pose[3] * ey + pose[6] * ez,
        pose[1] * ex + pose[4] * ey + pose[7] * ez,
        pose[2] * ex + pose[5] * ey + pose[8] * ez,
    )
    s = _rest_first_hit(table, b, a0, e0, scratch, normal)
    turn_forward(pose, normal)
    return s


@njit(cache=True)
def push_out_particles(table, positions, n, delta):
    """Particles 0..n-1 that a moving body of the table has swept over are moved out along
    its normal to ``delta`` outside its surface: p += (delta - d) n (the body carries them,
    as a hit stops a particle there)."""
    normal = np.empty(3)
    for q in range(n):
        for b in range(table.kinds.shape[0]):
            if not is_moving(table, b):
                continue
            px, py, pz = positions[q, 0], positions[q, 1], positions[q, 2]
            d = table_distance(table, b, px, py, pz, normal)
            if d < 0.0:
                for k in range(3):
                    positions[q, k] += (delta - d) * normal[k]


def follow_bodies(model: GustModel, bodies, time: float, state, solid) -> GustModel:
    """Pose the moving ``bodies`` at ``time`` (s) and register them again
    (:func:`register_bodies`); the cells' SOLID and BODIES flags follow, a cell the bodies
    now cover (``solid``, (n_cells,) bool) holds no wind and the particles they swept over
    are pushed out (:func:`push_out_particles`). ``state`` = (cells, particles, n). Returns
    the model with the new registration (the table's poses change in place)."""
    cells, particles, n = state
    table = model.bodies.table
    set_poses(table, bodies, time)
    push_out_particles(table, particles.positions, n, model.rules.delta)
    start, items = register_bodies(table, model.grid)
    cells.flags[:] &= np.uint8(~(SOLID | BODIES) & 0xFF)
    cells.flags[solid] |= SOLID
    cells.flags[np.diff(start) > 0] |= BODIES
    cells.u[solid] = 0.0
    cells.values[solid] = 0.0
    return model._replace(bodies=BodyCells(table, start, items))


@njit(cache=True, inline="always")
def _push(touched, n_touched, cell):
    """Append cell to the touched list (doubling it when full)."""
    if n_touched == touched.shape[0]:
        grown = np.empty(2 * touched.shape[0] + 16, dtype=np.int64)
        copy_head(grown, touched, touched.shape[0])
        touched = grown
    touched[n_touched] = cell
    return touched


@njit(cache=True, inline="always")
def _reached(t_cell, t_now, memory):
    """A reach at t_cell counts at t_now while t_now - t_cell <= memory (round-off slack)."""
    return t_now - t_cell <= memory * (1.0 + 1e-12) + 1e-12


@njit(cache=True, inline="always")
def _assemble_cell(c, marked, values, t_now, memory, u):
    """The paper's u = sum_i w_i in cell c, over the sources that reached it within memory."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for s in range(marked.shape[1]):
        if _reached(marked[c, s], t_now, memory):
            ux += values[c, s, 0]
            uy += values[c, s, 1]
            uz += values[c, s, 2]
    u[c, 0] = ux
    u[c, 1] = uy
    u[c, 2] = uz


@njit(cache=True, inline="always")
def _centre(ijk, g):
    """Centre of cell (i, j, k) of the grid g."""
    return (
        g.lower[0] + (ijk[0] + 0.5) * g.h,
        g.lower[1] + (ijk[1] + 0.5) * g.h,
        g.lower[2] + (ijk[2] + 0.5) * g.h,
    )


@intrinsic
def _prefetch(typingctx, arr, index):
    """Hint the CPU to fetch the cache line of ``arr[index]`` (index: a tuple) for writing
    (llvm.prefetch): no effect on results, only on when memory is read."""
    sig = types.void(arr, index)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        indices = cgutils.unpack_tuple(builder, args[1])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, indices, wraparound=False)
        i8p = builder.bitcast(ptr, ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0i8")
        builder.call(fn, [i8p, i32(1), i32(3), i32(1)])  # write, keep in cache, data
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, inline="always")
def _look_ahead(p, w, tau, g, s, flags, marked, u):
    """Prefetch the cell state at the start, middle and end of the path p -> p + w tau of
    a particle traced a few places later (the cells it will most likely mark)."""
    inv_h = 1.0 / g.h
    for f in (0.0, 0.5 * tau, tau):
        i = int(np.floor((p[0] + f * w[0] - g.lower[0]) * inv_h))
        j = int(np.floor((p[1] + f * w[1] - g.lower[1]) * inv_h))
        k = int(np.floor((p[2] + f * w[2] - g.lower[2]) * inv_h))
        if 0 <= i < g.shape[0] and 0 <= j < g.shape[1] and 0 <= k < g.shape[2]:
            c = (i * g.shape[1] + j) * g.shape[2] + k
            _prefetch(flags, (c,))
            _prefetch(marked, (c, s))
            _prefetch(u, (c, 0))


@njit(cache=True, inline="always")
def _walk_axis(p, e, lower, h, n):
    """One axis of the cell walk along p -> p + e: (inside, cell, step, t of the next
    face, t per cell width), t being the fraction of the path."""
    f = (p - lower) / h
    inside = 0.0 <= f < n
    cell = int(f)
    step = 1 if e > 0 else -1
    if e != 0.0:
        face = (cell + (1 if e > 0 else 0)) * h + lower
        return inside, cell, step, (face - p) / e, h / abs(e)
    return inside, cell, step, np.inf, np.inf


@njit(cache=True, inline="always")
def _start_walk(p, e, g):
    """Amanatides & Woo's set-up for the path p -> p + e: (inside the grid, cell (i, j, k),
    steps, path fraction of the next face per axis, path fraction per cell width, t = 0)."""
    in_x, i, si, tx, cx = _walk_axis(p[0], e[0], g.lower[0], g.h, g.shape[0])
    in_y, j, sj, ty, cy = _walk_axis(p[1], e[1], g.lower[1], g.h, g.shape[1])
    in_z, k, sk, tz, cz = _walk_axis(p[2], e[2], g.lower[2], g.h, g.shape[2])
    return in_x and in_y and in_z, (i, j, k), (si, sj, sk), (tx, ty, tz), (cx, cy, cz), 0.0


@njit(cache=True, inline="always")
def _cross_face(ijk, t_next, steps, t_cell, shape):
    """Amanatides & Woo: into the next cell across the nearest face of the path.

    Returns (cell indices, path fraction at the face, next faces, still inside the grid).
    """
    i, j, k = ijk
    tx, ty, tz = t_next
    if ty < tx:
        axis = 2 if tz < ty else 1
    else:
        axis = 2 if tz < tx else 0
    if axis == 0:
        i += steps[0]
        t = tx
        tx += t_cell[0]
        inside = 0 <= i < shape[0]
    elif axis == 1:
        j += steps[1]
        t = ty
        ty += t_cell[1]
        inside = 0 <= j < shape[1]
    else:
        k += steps[2]
        t = tz
        tz += t_cell[2]
        inside = 0 <= k < shape[2]
    return (i, j, k), t, (tx, ty, tz), inside


@njit(cache=True)
def first_triangle_hit(cloth, cell, a, b, e, best, body_hit, normal):
    """Earliest hit s < best of the piece a -> b (arrays; path direction e) on the cloth
    triangles registered in ``cell``: bounding boxes first, then Möller-Trumbore. The
    triangle's unit normal, turned against e, goes to ``normal``. Returns (s, whether the
    nearest hit is a body): (best, body_hit) if no triangle is nearer."""
    positions, triangles, bounds, slot, start, items = cloth
    for m in range(start[slot[cell]], start[slot[cell] + 1]):
        tri = items[m]
        apart = False  # bounding boxes apart: the piece cannot meet this triangle
        for ax in range(3):
            lo, hi = min(a[ax], b[ax]), max(a[ax], b[ax])
            apart |= lo > bounds[tri, 1, ax] or hi < bounds[tri, 0, ax]
        if apart:
            continue
        va = positions[triangles[tri, 0]]
        vb = positions[triangles[tri, 1]]
        vc = positions[triangles[tri, 2]]
        sh = segment_triangle(a, b, va, vb, vc)
        if 0.0 <= sh < best:
            best = sh
            body_hit = False
            tri_n = cross(vb - va, vc - va)
            tri_n /= np.sqrt((tri_n * tri_n).sum())
            if tri_n[0] * e[0] + tri_n[1] * e[1] + tri_n[2] * e[2] > 0.0:
                tri_n = -tri_n
            copy_head(normal, tri_n, tri_n.shape[0])
    return best, body_hit


@njit(cache=True, inline="always")
def _record_hit(mark_mode, body_hit, normal, normals, n_marks):
    """Keep the hit's normal when ``mark_mode`` makes the later marks deflected; the count."""
    if mark_mode == MARK_ALL or (mark_mode == MARK_BODIES and body_hit):
        for k in range(3):
            normals[n_marks, k] = normal[k]
        n_marks += 1
    return n_marks


@njit(cache=True)
def _remove_normals(w, normals, n_marks):
    """w <- w - (n . w) n for the normals of the marking hits (u(p_col) . n_obj = 0)."""
    for m in range(n_marks):
        dn = w[0] * normals[m, 0] + w[1] * normals[m, 1] + w[2] * normals[m, 2]
        w[0] -= dn * normals[m, 0]
        w[1] -= dn * normals[m, 1]
        w[2] -= dn * normals[m, 2]


@njit(cache=True, inline="always")
def _slide(p, v, e, th, delta, n):
    """Stop on the surface at path fraction th (``delta`` outside along the normal n) and
    keep the tangential velocity, the paper's w - (n . w) n. Returns (p, v)."""
    px = p[0] + (th * e[0] + delta * n[0])
    py = p[1] + (th * e[1] + delta * n[1])
    pz = p[2] + (th * e[2] + delta * n[2])
    dn = v[0] * n[0] + v[1] * n[1] + v[2] * n[2]
    return (px, py, pz), (v[0] - dn * n[0], v[1] - dn * n[1], v[2] - dn * n[2])


@njit(cache=True, inline="always")
def _after_hit(p, v, e, th, delta, n, remaining, w2):
    """:func:`_slide`, and what is left of the step. Returns (p, v, the time left, whether
    the particle stagnated: a head-on hit leaves nothing of w)."""
    p, v = _slide(p, v, e, th, delta, n)
    stagnant = v[0] * v[0] + v[1] * v[1] + v[2] * v[2] <= 1e-24 * w2
    return p, v, remaining * (1.0 - th), stagnant


@njit(cache=True)
def euler_velocities(model, particles, n, out):
    """out[q] = w_i(p_q) for particles 0..n-1, each in its own source's field: the velocity
    of the paper's Euler step p_{t+dt} = p_t + w_i(p_t) dt (§4.2.2)."""
    kinds, prims = model.source_kinds, model.source_params
    positions, sources, _ = particles
    for q in range(n):
        s = sources[q]
        primitive_velocity(
            kinds[s], prims[s], positions[q, 0], positions[q, 1], positions[q, 2], out[q]
        )


@njit(cache=True, inline="always")
def _piece_hit(bodies, cloth, flags, cell, p, e, span, work):
    """Earliest hit along the piece p + [t, t_exit] e (``span``) on the bodies and cloth
    triangles ``cell`` registers (its ``flags``): (fraction of the piece or 2.0, whether a
    body was hit); the normal at the hit goes to ``work`` 's hit normal."""
    b_table, b_start, b_items = bodies
    hit_n, tmp_n, scratch, ab = work[2], work[3], work[4], work[5]
    a, b = ab[0], ab[1]
    t, t_exit = span
    best = 2.0
    body_hit = NO_BODY_HIT
    obstacles = flags & (BODIES | TRIANGLES)
    if obstacles:  # the piece a -> b lies in this cell: test what it registers
        a[0], a[1], a[2] = p[0] + t * e[0], p[1] + t * e[1], p[2] + t * e[2]
        b[0], b[1], b[2] = p[0] + t_exit * e[0], p[1] + t_exit * e[1], p[2] + t_exit * e[2]
    if obstacles & BODIES:
        for m in range(b_start[cell], b_start[cell + 1]):
            e_ab = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
            sh = first_body_hit(b_table, b_items[m], (a[0], a[1], a[2]), e_ab, scratch, tmp_n)
            if 0.0 <= sh < best:
                best = sh
                body_hit = True
                copy_head(hit_n, tmp_n, tmp_n.shape[0])
    if obstacles & TRIANGLES:
        best, body_hit = first_triangle_hit(cloth, cell, a, b, e, best, body_hit, hit_n)
    return best, body_hit


@njit(cache=True, inline="always")
def _mark_cell(model, cells, t_now, ijk, s, marks, wc):
    """Mark cell ``ijk`` for source s at t_now with w_s(centre), less the normals of the
    marking hits (``marks`` = (normals, count)), and assemble its wind (§4.2.2); a solid
    cell keeps u = 0."""
    flags, marked, values, u = cells
    g = model.grid
    cell = (ijk[0] * g.shape[1] + ijk[1]) * g.shape[2] + ijk[2]
    cx, cy, cz = _centre(ijk, g)
    primitive_velocity(model.source_kinds[s], model.source_params[s], cx, cy, cz, wc)
    if marks[1]:
        _remove_normals(wc, marks[0], marks[1])
    marked[cell, s] = t_now
    if not flags[cell] & SOLID:
        values[cell, s, 0], values[cell, s, 1], values[cell, s, 2] = wc
        _assemble_cell(cell, marked, values, t_now, model.rules.memory, u)


@njit(cache=True)
def trace_gusts(model, cloth, cells, particles, step, work, touched):
    """Move particles 0..n-1 by the Euler step p += w_i(p) tau (§4.2.2, ``work.velocities``),
    mark the cells their paths cross, slide them along what they hit, compact the survivors.
    Returns (touched, n_touched, crossings, n_alive) (module docstring)."""
    rules, g = model.rules, model.grid
    flags, marked, u = cells[0], cells[1], cells[3]
    positions, sources, ages = particles
    velocities, wc, hit_n, normals = work[0], work[1], work[2], work[6]
    ny, nz = g.shape[1], g.shape[2]
    n_touched, crossings, n_alive = 0, 0, 0
    for q in range(step.n):
        qa = q + AHEAD
        if step.prefetch and qa < step.n:  # the cells a later particle will mark
            pa = (positions[qa, 0], positions[qa, 1], positions[qa, 2])
            wa = (velocities[qa, 0], velocities[qa, 1], velocities[qa, 2])
            _look_ahead(pa, wa, step.dt, g, sources[qa], flags, marked, u)
        s = sources[q]
        px, py, pz = positions[q, 0], positions[q, 1], positions[q, 2]
        vx, vy, vz = velocities[q, 0], velocities[q, 1], velocities[q, 2]
        tau = step.dt if q < step.n_old else step.new_durations[q - step.n_old]
        w2 = vx * vx + vy * vy + vz * vz
        remaining = tau
        n_hits = 0
        n_marks = 0  # hits whose normal the marks remove (rules.mark_mode)
        stagnant = False
        while True:  # one straight path p -> p + e, e = v * remaining, cell by cell
            ex, ey, ez = vx * remaining, vy * remaining, vz * remaining
            inside, (i, j, k), steps, (tx, ty, tz), t_cell, t = _start_walk(
                (px, py, pz), (ex, ey, ez), g
            )
            if not inside:
                break
            while True:
                t_exit = max(t, min(tx, ty, tz, 1.0))
                cell = (i * ny + j) * nz + k
                best, body_hit = _piece_hit(
                    model.bodies,
                    cloth,
                    flags[cell],
                    cell,
                    (px, py, pz),
                    (ex, ey, ez),
                    (t, t_exit),
                    work,
                )
                if best <= 1.0:
                    n_hits += 1
                    n_marks = _record_hit(rules.mark_mode, body_hit, hit_n, normals, n_marks)
                if marked[cell, s] != step.t_now or n_marks > 0:  # a free repeat changes nothing
                    first = marked[cell, s] != step.t_now
                    _mark_cell(model, cells, step.t_now, (i, j, k), s, (normals, n_marks), wc)
                    if first:  # its marks lapse memory later: on the touched list
                        touched = _push(touched, n_touched, cell)
                        n_touched += 1
                crossings += 1
                if best <= 1.0:  # slide on; a path of length 0 still marks its resting cell
                    th, n = t + best * (t_exit - t), (hit_n[0], hit_n[1], hit_n[2])
                    (px, py, pz), (vx, vy, vz), remaining, stagnant = _after_hit(
                        (px, py, pz), (vx, vy, vz), (ex, ey, ez), th, rules.delta, n, remaining, w2
                    )
                    if stagnant or n_hits >= rules.max_hits:
                        remaining = 0.0
                    break
                if t_exit >= 1.0:
                    px, py, pz = px + ex, py + ey, pz + ez
                    break
                (i, j, k), t, (tx, ty, tz), inside = _cross_face(
                    (i, j, k), (tx, ty, tz), steps, t_cell, g.shape
                )
                if not inside:
                    break
            if best > 1.0:  # the path ended without a hit: so does the particle's step
                break
        if inside and not stagnant and ages[q] + tau <= rules.max_age:
            positions[n_alive, 0], positions[n_alive, 1], positions[n_alive, 2] = px, py, pz
            sources[n_alive], ages[n_alive] = s, ages[q] + tau
            n_alive += 1
    return touched, n_touched, crossings, n_alive


@njit(cache=True)
def expire_cells(cell_list, t_mark, cells, t_now, memory):
    """Refresh u in the cells marked at t_mark whose mark has just expired.

    A cell of the list whose marks of t_mark have all been renewed since keeps its u
    (nothing about it changed); the others get u = sum of the still-reached sources.
    """
    marked, u = cells.marked, cells.u
    for m in range(cell_list.shape[0]):
        if m + AHEAD < cell_list.shape[0]:
            _prefetch(marked, (cell_list[m + AHEAD], 0))
            _prefetch(u, (cell_list[m + AHEAD], 0))
        c = cell_list[m]
        if cells.flags[c] & SOLID:
            continue
        for s in range(marked.shape[1]):
            if marked[c, s] == t_mark:
                _assemble_cell(c, marked, cells.values, t_now, memory, u)
                break


@njit(cache=True)
def cell_ids(grid, positions, n):
    """Cell id c = (i * ny + j) * nz + k of positions 0..n-1, clamped into the grid."""
    keys = np.empty(n, dtype=np.int64)
    for q in range(n):
        c = 0
        for ax in range(3):
            i = int(np.floor((positions[q, ax] - grid.lower[ax]) / grid.h))
            c = c * grid.shape[ax] + min(max(i, 0), grid.shape[ax] - 1)
        keys[q] = c
    return keys


@njit(cache=True)
def sort_by_cell(grid, n, particles):
    """Reorder particles 0..n-1 in place by cell id (:func:`cell_ids`), stably.

    LSD radix sort, RADIX_BITS of the id a pass: O(n) per pass, no pass over the grid.
    """
    keys = cell_ids(grid, particles.positions, n)
    order = np.arange(n)
    order_tmp = np.empty(n, dtype=np.int64)
    keys_tmp = np.empty(n, dtype=np.int64)
    count = np.empty(RADIX + 1, dtype=np.int64)
    top = grid.shape[0] * grid.shape[1] * grid.shape[2] - 1
    shift = 0
    while top >> shift > 0:
        count[:] = 0
        for q in range(n):
            count[((keys[q] >> shift) & (RADIX - 1)) + 1] += 1
        for d in range(RADIX):
            count[d + 1] += count[d]
        for q in range(n):
            d = (keys[q] >> shift) & (RADIX - 1)
            order_tmp[count[d]] = order[q]
            keys_tmp[count[d]] = keys[q]
            count[d] += 1
        order, order_tmp = order_tmp, order
        keys, keys_tmp = keys_tmp, keys
        shift += RADIX_BITS
    positions, sources, ages = particles
    old_positions = positions[:n].copy()
    old_sources = sources[:n].copy()
    old_ages = ages[:n].copy()
    for q in range(n):
        o = order[q]
        positions[q, 0] = old_positions[o, 0]
        positions[q, 1] = old_positions[o, 1]
        positions[q, 2] = old_positions[o, 2]
        sources[q] = old_sources[o]
        ages[q] = old_ages[o]


@njit(cache=True)
def reached_sources(marked, t_now, memory, out):
    """out[c, s] = whether source s reached cell c within the last ``memory`` seconds."""
    for c in range(marked.shape[0]):
        for s in range(marked.shape[1]):
            out[c, s] = _reached(marked[c, s], t_now, memory)


@njit(cache=True)
def admit_particles(candidates, model, room, n, particles, durations):
    """Append the candidates that lie in the grid's half-open box [lower, upper) and outside
    every body, in order, at most ``room`` of them, after particle n - 1 (age 0).

    ``candidates`` = (positions, sources, durations in the step); the admitted ones'
    durations are compacted into ``durations``. Returns how many were admitted.
    """
    points, candidate_sources, candidate_durations = candidates
    lower, upper = model.grid.lower, model.grid.upper
    bodies = model.bodies.table
    normal = np.empty(3)
    m = 0
    for c in range(points.shape[0]):
        if m == room:
            break
        x, y, z = points[c, 0], points[c, 1], points[c, 2]
        if not (lower[0] <= x < upper[0] and lower[1] <= y < upper[1] and lower[2] <= z < upper[2]):
            continue
        if bodies.kinds.shape[0] and union_distance_point(bodies, x, y, z, normal) < 0.0:
            continue
        q = n + m
        particles.positions[q, 0], particles.positions[q, 1], particles.positions[q, 2] = x, y, z
        particles.sources[q] = candidate_sources[c]
        particles.ages[q] = 0.0
        durations[m] = candidate_durations[c]
        m += 1
    return m
