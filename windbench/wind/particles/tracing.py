"""Gust-particle tracing kernels (paper §4.2.2): Euler paths cut at cell faces, lee by
collision, and the cell field u = sum of the reached sources' w_i.

A particle of source i moves only in w_i (never the superposed field) by the paper's
explicit Euler step ``p_{t+dt} = p_t + w_i(p_t) dt``. Its path is walked cell by cell
(Amanatides & Woo's voxel traversal), so each piece lies inside one cell ("subdivided
into parts not exceeding the size of a grid cell") and no cell on the way is skipped.

Each piece is tested only against what is registered in its cell: the rigid bodies whose
surface may reach into the cell (:func:`register_bodies`) and the cloth triangles that
overlap it (:func:`windbench.geometry.raster.register_triangles`), so the cost is
O(particles x cells crossed), not O(particles x triangles). At the first hit the particle
stops on the surface (``delta`` outside it) and its velocity loses the normal component,
``w <- w - (n . w) n``; it spends the rest of the step sliding along the object. A head-on
hit (nothing left of w) ends the particle: its gust has stagnated at the wall.

Rigid bodies are convex (box, capsule, cylinder, plane), so their signed distance d is a
convex function along a piece; :func:`convex_first_hit` finds the first root of d exactly
(to round-off) without marching, also for thin poles (``resolve: false`` bodies are
obstacles like any other; their lee is thinner than a cell and mostly invisible on the grid).

Cell state per (cell, source): ``marked[c, s]``, the time the source's particles last
reached the cell (-inf: never), and ``values[c, s]``, the value that mark left (with one
source, ``values`` is u itself: u is that value while it counts). Choice (documented in
:mod:`windbench.wind.particles`): a free particle leaves w_i at the cell centre, so with
no obstacles the field equals the ``global`` backend's exactly. After a hit,
``mark_mode`` says which contact normals the particle's later marks in this step remove
from w_i(centre) (the paper's u(p_col) . n_obj = 0): those of every hit (``all``), of
rigid bodies only (``bodies``) or none. Within one step a deflected mark beats a free one
(the no-penetration condition wins at the surface); otherwise the later mark wins. The
kernels run serially over the particles in their stored order, so a run is bit-for-bit
reproducible.

Cost per step, none of it a pass over the grid: u is refreshed in a cell when a mark
there changes (in :func:`trace_gusts`) and when its last marks lapse ``memory`` later
(:func:`expire_cells`, over the cells first marked that many steps before); a per-cell
byte of flags (SOLID, BODIES, TRIANGLES) says where there is anything to test, and the
cloth's cells are flagged and unflagged in O(overlaps) (:func:`register_cloth`). On
large grids the cell state does not fit in the caches and a crossing would wait for
memory: the kernel evaluates w_i a few particles ahead and prefetches the cells their
paths will mark (``prefetch``; no effect on the numbers).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from windbench.geometry.bodies import body_distance, union_distance_point
from windbench.geometry.raster import segment_triangle
from windbench.wind.primitives import primitive_velocity

SOLID, BODIES, TRIANGLES = 1, 2, 4  # bits of the per-cell flags
MARK_NONE, MARK_BODIES, MARK_ALL = 0, 1, 2  # which hits make the marks "deflected"
MARK_MODES = {"none": MARK_NONE, "bodies": MARK_BODIES, "all": MARK_ALL}
ROOT_ITERATIONS = 60
AHEAD = 8  # particles between a particle's prefetch and its tracing
RADIX_BITS = 11  # bits of the cell id sorted per pass of sort_by_cell
RADIX = 1 << RADIX_BITS


@njit(cache=True)
def register_bodies(kinds, params, lower, h, shape):
    """CSR (start, items) of the bodies whose surface may reach into each cell.

    Body b is registered in cell c when d_b(centre_c) <= half the cell diagonal, i.e. the
    body meets the ball around the cell (cell id c = (i * ny + j) * nz + k).
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    n_cells = nx * ny * nz
    reach = 0.5 * np.sqrt(3.0) * h * (1.0 + 1e-9)
    normal = np.empty(3)
    start = np.zeros(n_cells + 1, dtype=np.int64)
    for fill in range(2):
        if fill == 1:
            for c in range(n_cells):
                start[c + 1] += start[c]
            items = np.empty(start[n_cells], dtype=np.int64)
            counts = np.zeros(n_cells, dtype=np.int64)
        else:
            items = np.empty(0, dtype=np.int64)
            counts = np.zeros(0, dtype=np.int64)
        for i in range(nx):
            for j in range(ny):
                for k in range(nz):
                    c = (i * ny + j) * nz + k
                    px = lower[0] + (i + 0.5) * h
                    py = lower[1] + (j + 0.5) * h
                    pz = lower[2] + (k + 0.5) * h
                    for b in range(kinds.shape[0]):
                        if body_distance(kinds[b], params[b], px, py, pz, normal) <= reach:
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
def convex_first_hit(kind, prm, ax, ay, az, ex, ey, ez, scratch, normal):
    """First s in [0, 1] with d(a + s e) <= 0 for one convex body, or -1; outward normal.

    f(s) = d(a + s e) is convex (d of a convex set), with slope f'(s) = n(s) . e. No root
    when f(1) > 0 and either |e| <= f(0) + f(1) (1-Lipschitz), f'(0) >= 0 or f'(1) <= 0
    (monotone), or the tangent lines at a bracket of the minimum meet above zero; else the
    root is bracketed and bisected. A particle touching the surface (f(0) <= 0) hits at
    s = 0 only if it moves inward. ``scratch`` is a (2, 3) work array.
    """
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
def _push(touched, n_touched, cell):
    """Append cell to the touched list (doubling it when full)."""
    if n_touched == touched.shape[0]:
        grown = np.empty(2 * touched.shape[0] + 16, dtype=np.int64)
        grown[:n_touched] = touched[:n_touched]
        touched = grown
    touched[n_touched] = cell
    return touched


@njit(cache=True, inline="always")
def _reached(t_cell, t_now, memory):
    """A reach at t_cell counts at t_now while t_now - t_cell <= memory (round-off slack)."""
    return t_now - t_cell <= memory * (1.0 + 1e-12) + 1e-12


@njit(cache=True, inline="always")
def _assemble_cell(c, marked, values, t_now, memory, u):
    """u[c] = sum of the values of the sources that reached cell c within memory."""
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
def _look_ahead(px, py, pz, w, tau, lower, h, shape, s, flags, marked, u):
    """Prefetch the cell state at the start, middle and end of the path p -> p + w tau of
    a particle traced a few places later (the cells it will most likely mark)."""
    inv_h = 1.0 / h
    for f in (0.0, 0.5 * tau, tau):
        i = int(np.floor((px + f * w[0] - lower[0]) * inv_h))
        j = int(np.floor((py + f * w[1] - lower[1]) * inv_h))
        k = int(np.floor((pz + f * w[2] - lower[2]) * inv_h))
        if 0 <= i < shape[0] and 0 <= j < shape[1] and 0 <= k < shape[2]:
            c = (i * shape[1] + j) * shape[2] + k
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


@njit(cache=True)
def trace_gusts(
    n,
    n_old,
    dt,
    new_durations,
    max_age,
    kinds,
    prims,
    lower,
    h,
    shape,
    flags,
    body_kinds,
    body_params,
    body_start,
    body_items,
    cloth_positions,
    cloth_triangles,
    tri_bounds,
    tri_slot,
    tri_start,
    tri_items,
    t_now,
    memory,
    delta,
    max_hits,
    mark_mode,
    prefetch,
    positions,
    sources,
    ages,
    marked,
    values,
    u,
    touched,
):
    """Advance particles 0..n-1 in their own w_i (p += w_i(p) tau), mark cells, refresh u.

    Particle q moves for tau = dt (q < n_old) or ``new_durations[q - n_old]`` (emitted
    within the step). ``positions``, ``sources``, ``ages`` are updated in place and
    compacted: the particles that stay alive (inside the grid, not stagnated, age <=
    ``max_age``) keep their order at the front. ``flags`` (uint8 per cell: SOLID, BODIES,
    TRIANGLES) say which cells hold obstacles, so a piece reads the registries only where
    there is something to test; the triangles of a flagged cell are
    ``tri_items[tri_start[tri_slot[cell]] : tri_start[tri_slot[cell] + 1]]``.
    ``tri_bounds`` (m, 2, 3) are the triangles' bounding boxes (min, max): a cheap test
    before Möller-Trumbore. ``marked`` (n_cells, n_sources: time of the last mark),
    ``values`` (n_cells, n_sources, 3: the value it left) and ``u`` are updated in place in
    the cells marked only; ``values`` may be ``u`` itself (one source: u is the value
    while reached). ``touched`` collects the cells first marked this step (grown when
    full). Returns (touched, n_touched, crossings, n_alive).
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    x0, y0, z0 = lower[0], lower[1], lower[2]
    n_touched = 0
    crossings = 0
    n_alive = 0
    wc = np.empty(3)
    hit_n = np.empty(3)
    tmp_n = np.empty(3)
    scratch = np.empty((2, 3))
    normals = np.empty((max_hits, 3))
    a = np.empty(3)  # the piece a -> b in one cell, for the collision tests
    b = np.empty(3)
    ahead = np.empty((AHEAD, 3))  # w_i(p) of the next AHEAD particles, slot q % AHEAD
    for q in range(-AHEAD, n):
        qa = q + AHEAD
        if q >= 0:
            s = sources[q]
            px, py, pz = positions[q, 0], positions[q, 1], positions[q, 2]
            vx, vy, vz = ahead[q % AHEAD, 0], ahead[q % AHEAD, 1], ahead[q % AHEAD, 2]
        if qa < n:
            # Euler: w_i(p_t), evaluated AHEAD particles early, and its cells prefetched
            sa = sources[qa]
            w = ahead[qa % AHEAD]
            primitive_velocity(
                kinds[sa], prims[sa], positions[qa, 0], positions[qa, 1], positions[qa, 2], w
            )
            if prefetch:
                _look_ahead(
                    positions[qa, 0],
                    positions[qa, 1],
                    positions[qa, 2],
                    w,
                    dt,
                    lower,
                    h,
                    shape,
                    sa,
                    flags,
                    marked,
                    u,
                )
        if q < 0:
            continue
        kind = kinds[s]
        prm = prims[s]
        duration = dt if q < n_old else new_durations[q - n_old]
        w2 = vx * vx + vy * vy + vz * vz  # velocity v: w_i, deflected after hits
        remaining = duration
        n_hits = 0
        n_marks = 0  # hits whose normal the cell marks remove (see mark_mode)
        alive = True
        stagnant = False
        moving = True
        while moving:
            # one straight path p -> p + e, e = v * remaining, walked cell by cell
            # (Amanatides-Woo): cell (i, j, k), next face at path fraction t_next*
            moving = False
            ex, ey, ez = vx * remaining, vy * remaining, vz * remaining
            in_x, i, si, t_next_x, t_cell_x = _walk_axis(px, ex, x0, h, nx)
            in_y, j, sj, t_next_y, t_cell_y = _walk_axis(py, ey, y0, h, ny)
            in_z, k, sk, t_next_z, t_cell_z = _walk_axis(pz, ez, z0, h, nz)
            if not (in_x and in_y and in_z):
                alive = False
                break
            t = 0.0
            while True:
                t_exit = max(t, min(t_next_x, t_next_y, t_next_z, 1.0))
                cell = (i * ny + j) * nz + k
                best = 2.0
                body_hit = False
                obstacles = flags[cell] & (BODIES | TRIANGLES)
                if obstacles:
                    # the piece a -> b lies in this cell: test what is registered here
                    a[0], a[1], a[2] = px + t * ex, py + t * ey, pz + t * ez
                    b[0], b[1], b[2] = px + t_exit * ex, py + t_exit * ey, pz + t_exit * ez
                if obstacles & BODIES:
                    for m in range(body_start[cell], body_start[cell + 1]):
                        bi = body_items[m]
                        sh = convex_first_hit(
                            body_kinds[bi],
                            body_params[bi],
                            a[0],
                            a[1],
                            a[2],
                            b[0] - a[0],
                            b[1] - a[1],
                            b[2] - a[2],
                            scratch,
                            tmp_n,
                        )
                        if 0.0 <= sh < best:
                            best = sh
                            body_hit = True
                            hit_n[:] = tmp_n
                if obstacles & TRIANGLES:
                    slot = tri_slot[cell]
                    for m in range(tri_start[slot], tri_start[slot + 1]):
                        tri = tri_items[m]
                        # bounding boxes apart: the piece cannot meet this triangle
                        apart = False
                        for ax in range(3):
                            lo_ab = min(a[ax], b[ax])
                            hi_ab = max(a[ax], b[ax])
                            if lo_ab > tri_bounds[tri, 1, ax] or hi_ab < tri_bounds[tri, 0, ax]:
                                apart = True
                        if apart:
                            continue
                        va = cloth_positions[cloth_triangles[tri, 0]]
                        vb = cloth_positions[cloth_triangles[tri, 1]]
                        vc = cloth_positions[cloth_triangles[tri, 2]]
                        sh = segment_triangle(a, b, va, vb, vc)
                        if 0.0 <= sh < best:
                            best = sh
                            body_hit = False
                            # the triangle's unit normal, turned to face the particle
                            tri_n = np.cross(vb - va, vc - va)
                            tri_n /= np.sqrt((tri_n * tri_n).sum())
                            if tri_n[0] * ex + tri_n[1] * ey + tri_n[2] * ez > 0.0:
                                tri_n = -tri_n
                            hit_n[:] = tri_n
                if best <= 1.0:
                    n_hits += 1
                    if mark_mode == MARK_ALL or (mark_mode == MARK_BODIES and body_hit):
                        normals[n_marks] = hit_n
                        n_marks += 1
                if marked[cell, s] != t_now or n_marks > 0:
                    # mark the cell for source s with w_i(centre), the contact normals of
                    # the marking hits removed, and refresh u there (air cells only: a
                    # solid cell keeps u = 0 and stores no value). A free mark repeated
                    # within the step changes nothing; a deflected one beats a free one.
                    first = marked[cell, s] != t_now
                    cx = x0 + (i + 0.5) * h
                    cy = y0 + (j + 0.5) * h
                    cz = z0 + (k + 0.5) * h
                    primitive_velocity(kind, prm, cx, cy, cz, wc)
                    for m in range(n_marks):
                        # w <- w - (n . w) n for each marking hit so far in this step
                        dn = wc[0] * normals[m, 0] + wc[1] * normals[m, 1] + wc[2] * normals[m, 2]
                        wc[0] -= dn * normals[m, 0]
                        wc[1] -= dn * normals[m, 1]
                        wc[2] -= dn * normals[m, 2]
                    marked[cell, s] = t_now
                    if not flags[cell] & SOLID:
                        values[cell, s, 0] = wc[0]
                        values[cell, s, 1] = wc[1]
                        values[cell, s, 2] = wc[2]
                        _assemble_cell(cell, marked, values, t_now, memory, u)
                    if first:  # its marks lapse memory later: on the touched list
                        touched = _push(touched, n_touched, cell)
                        n_touched += 1
                crossings += 1
                if best <= 1.0:
                    # stop on the surface, lose the normal component: w - (n . w) n
                    th = t + best * (t_exit - t)
                    px += th * ex + delta * hit_n[0]
                    py += th * ey + delta * hit_n[1]
                    pz += th * ez + delta * hit_n[2]
                    remaining *= 1.0 - th
                    dn = vx * hit_n[0] + vy * hit_n[1] + vz * hit_n[2]
                    vx -= dn * hit_n[0]
                    vy -= dn * hit_n[1]
                    vz -= dn * hit_n[2]
                    if vx * vx + vy * vy + vz * vz <= 1e-24 * w2:
                        stagnant = True  # head-on: the gust stagnates at the wall
                        remaining = 0.0
                    elif n_hits >= max_hits:
                        remaining = 0.0
                    # slide on along the surface; a path of length 0 still marks the cell
                    # the particle rests in (across the face the hit may have lain on)
                    moving = True
                    break
                if t_exit >= 1.0:
                    px += ex
                    py += ey
                    pz += ez
                    break
                # into the next cell across the nearest face
                if t_next_y < t_next_x:
                    axis = 2 if t_next_z < t_next_y else 1
                else:
                    axis = 2 if t_next_z < t_next_x else 0
                if axis == 0:
                    i += si
                    t = t_next_x
                    t_next_x += t_cell_x
                    inside = 0 <= i < nx
                elif axis == 1:
                    j += sj
                    t = t_next_y
                    t_next_y += t_cell_y
                    inside = 0 <= j < ny
                else:
                    k += sk
                    t = t_next_z
                    t_next_z += t_cell_z
                    inside = 0 <= k < nz
                if not inside:
                    alive = False
                    break
        age = ages[q] + duration
        if alive and not stagnant and age <= max_age:
            positions[n_alive, 0] = px
            positions[n_alive, 1] = py
            positions[n_alive, 2] = pz
            sources[n_alive] = s
            ages[n_alive] = age
            n_alive += 1
    return touched, n_touched, crossings, n_alive


@njit(cache=True)
def expire_cells(cells, t_mark, marked, values, flags, t_now, memory, u):
    """Refresh u in the cells marked at t_mark whose mark has just expired.

    A cell of the list whose marks of t_mark have all been renewed since keeps its u
    (nothing about it changed); the others get u = sum of the still-reached sources.
    """
    for m in range(cells.shape[0]):
        if m + AHEAD < cells.shape[0]:
            _prefetch(marked, (cells[m + AHEAD], 0))
            _prefetch(u, (cells[m + AHEAD], 0))
        c = cells[m]
        if flags[c] & SOLID:
            continue
        for s in range(marked.shape[1]):
            if marked[c, s] == t_mark:
                _assemble_cell(c, marked, values, t_now, memory, u)
                break


@njit(cache=True)
def sort_by_cell(n, lower, h, shape, positions, sources, ages):
    """Reorder particles 0..n-1 in place by cell id c = (i * ny + j) * nz + k, stably.

    LSD radix sort, 11 bits of c a pass (two passes up to 4 M cells): O(n) per pass, no
    pass over the grid.
    """
    keys = np.empty(n, dtype=np.int64)
    for q in range(n):
        c = 0
        for ax in range(3):
            i = int(np.floor((positions[q, ax] - lower[ax]) / h))
            c = c * shape[ax] + min(max(i, 0), shape[ax] - 1)
        keys[q] = c
    order = np.arange(n)
    order_tmp = np.empty(n, dtype=np.int64)
    keys_tmp = np.empty(n, dtype=np.int64)
    count = np.empty(RADIX + 1, dtype=np.int64)
    top = shape[0] * shape[1] * shape[2] - 1
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
def admit_particles(
    candidates,
    candidate_sources,
    candidate_durations,
    lower,
    upper,
    kinds,
    params,
    room,
    n,
    positions,
    sources,
    ages,
    durations,
):
    """Append the candidates that lie in the grid's half-open box [lower, upper) and outside
    every body, in order, at most ``room`` of them, after particle n - 1 (age 0; their
    durations compacted into ``durations``). Returns how many were admitted."""
    normal = np.empty(3)
    m = 0
    for p in range(candidates.shape[0]):
        if m == room:
            break
        x, y, z = candidates[p, 0], candidates[p, 1], candidates[p, 2]
        if not (lower[0] <= x < upper[0] and lower[1] <= y < upper[1] and lower[2] <= z < upper[2]):
            continue
        if kinds.shape[0] and union_distance_point(kinds, params, x, y, z, normal) < 0.0:
            continue
        positions[n + m, 0], positions[n + m, 1], positions[n + m, 2] = x, y, z
        sources[n + m] = candidate_sources[p]
        ages[n + m] = 0.0
        durations[m] = candidate_durations[p]
        m += 1
    return m
