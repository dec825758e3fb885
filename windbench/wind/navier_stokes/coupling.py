"""Cloth-to-air coupling of the Navier-Stokes wind (paper §4.1.2), ``wind.coupling``.

- ``paper``: every cloth triangle is registered in the cells it cuts
  (:func:`windbench.geometry.raster.triangle_cells`); per marked cell the triangle normals
  are averaged (area-weighted) together with the cloth velocity; on every face next to a
  marked cell the normal component of the air velocity relative to the cloth is removed,
  u <- u - ((u - v_cloth) . n) n, "prior to any other operation" of the solver step.
  The cloth's own velocity is kept (the paper's Neumann condition u . n = 0 for a cloth
  at rest, generalised to a moving one).
- ``projection``: instead, every grid face whose centre-to-centre segment crosses a cloth
  triangle (:func:`windbench.geometry.raster.segment_triangle`) is a face of the cloth in
  the pressure projection: its velocity starts at the cloth's normal velocity ((v . n)
  n_a) and yields to the pressure jump as the cloth's mass per area lets it
  (:func:`move_membranes`; pinned or static cloth is an impermeable wall), so that air
  cannot pass through the flag and the solve holds the air's reaction to the cloth's
  motion within the step. The air acts back on the cloth through the projection's own
  pressure: each triangle carries the jump ``(p_- - p_+) A n`` across it, each side's
  pressure extrapolated to the sheet (:func:`triangle_pressure_loads`). Air enclosed by
  walls of cloth (a pocket: :func:`pockets`) keeps its volume only if their velocities add
  up to zero around it, which faceted motion does not guarantee: the projection's
  right-hand side loses its mean over each pocket (:func:`balance_pockets`), so that the
  Poisson problem stays solvable. The paper's removal is not applied as well: it stops
  the air on every face next to a cut cell, a cell's width around the cloth, whose set
  changes as the cloth moves, and the projection would turn each change into a pressure
  impulse on the cloth. ``experiments/projection_coupling.py`` measures the couplings
  side by side (``experiments/results/projection_coupling*.csv``).
- ``none``: the cloth does not act on the air (one-way coupling).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from windbench.geometry.raster import segment_triangle_xyz
from windbench.wind.navier_stokes.advection import at_face
from windbench.wind.navier_stokes.boundaries import cells_beside
from windbench.wind.navier_stokes.projection import psi_difference


@njit(cache=True)
def cell_normals(positions, velocities, triangles, start, items, index, normals, velocity):
    """Per marked cell m (index[c] = m): area-weighted mean unit normal and cloth velocity.

    n_c = normalise(sum_t (b - a) x (c - a)),  v_c = sum_t A_t v_t / sum_t A_t,
    v_t the mean of the triangle's vertex velocities. In scalars, as
    :func:`remove_normal_component`.
    """
    for c in range(start.shape[0] - 1):
        m = index.flat[c]
        if m < 0:
            continue
        n0 = n1 = n2 = s0 = s1 = s2 = asum = 0.0
        for e in range(start[c], start[c + 1]):
            x, y, z = _triangle_normal(positions, triangles, items[e])
            vx, vy, vz = _mean_velocity(velocities, triangles, items[e])
            area = 0.5 * np.sqrt(x * x + y * y + z * z)
            n0, n1, n2 = n0 + x, n1 + y, n2 + z
            s0 += area * vx
            s1 += area * vy
            s2 += area * vz
            asum += area
        norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        for k, (nk, sk) in enumerate(((n0, s0), (n1, s1), (n2, s2))):
            normals[m, k] = nk / norm if norm > 0.0 else 0.0
            velocity[m, k] = sk / asum if asum > 0.0 else 0.0


@njit(cache=True)
def remove_normal_component(q, a, u, v, w, index, normals, velocity, out):
    """out = q - ((u_air - v_cloth) . n) n_a on faces of component a next to marked cells.

    ``n`` and ``v_cloth`` are the normalised sum / mean of those of the (one or two)
    marked cells beside the face; elsewhere out = q. In scalars: a small array made per
    face costs an allocation on every face of the grid.
    """
    nx, ny, nz = index.shape
    P0, P1, P2 = q.shape
    for I in range(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                out[I, J, K] = q[I, J, K]
                ip, jp, kp, im, jm, km = cells_beside(I, J, K, a)
                n0 = n1 = n2 = v0 = v1 = v2 = 0.0
                cnt = 0
                for side in range(2):
                    ci, cj, ck = (ip, jp, kp) if side == 1 else (im, jm, km)
                    if ci < 0 or cj < 0 or ck < 0 or ci >= nx or cj >= ny or ck >= nz:
                        continue
                    m = index[ci, cj, ck]
                    if m >= 0:
                        n0, n1, n2 = n0 + normals[m, 0], n1 + normals[m, 1], n2 + normals[m, 2]
                        v0 += velocity[m, 0]
                        v1 += velocity[m, 1]
                        v2 += velocity[m, 2]
                        cnt += 1
                if cnt == 0:
                    continue
                norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
                if norm == 0.0:
                    continue
                n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
                v0, v1, v2 = v0 / cnt, v1 / cnt, v2 / cnt
                rel = (
                    (at_face(u, 0, a, I, J, K) - v0) * n0
                    + (at_face(v, 1, a, I, J, K) - v1) * n1
                    + (at_face(w, 2, a, I, J, K) - v2) * n2
                )
                na = n0 if a == 0 else (n1 if a == 1 else n2)
                out[I, J, K] = q[I, J, K] - rel * na  # u <- u - ((u - v) . n) n


@njit(cache=True)
def blocked_faces(positions, velocities, mobility, triangles, start, items, lower, h, shape):
    """Faces crossed by cloth: rows (component, I, J, K) of padded indices, their normal
    velocity (v . n) n_a and their Poisson weight h x the mean ``mobility`` of the corners
    (:func:`move_membranes`) of the first triangle that crosses the segment between the
    two cell centres beside the face (:func:`_first_crossing`). In scalars: the segment
    test runs for each face beside a marked cell and each triangle registered there."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    n_cells = nx * ny * nz
    rows = np.zeros((6 * (start[n_cells] + 1), 4), dtype=np.int64)
    vals = np.zeros(6 * (start[n_cells] + 1))
    weight = np.zeros(6 * (start[n_cells] + 1))
    count = 0
    for c in range(n_cells):
        if start[c + 1] == start[c]:
            continue
        i, j, k = c // (ny * nz), (c // nz) % ny, c % nz
        for a in range(3):
            for side in range(2):
                step = 1 if side == 1 else -1
                di, dj, dk = step * (a == 0), step * (a == 1), step * (a == 2)
                i2, j2, k2 = i + di, j + dj, k + dk
                if i2 < 0 or j2 < 0 or k2 < 0 or i2 >= nx or j2 >= ny or k2 >= nz:
                    continue
                c2 = (i2 * ny + j2) * nz + k2
                if start[c2 + 1] > start[c2] and c2 < c:
                    continue  # the other marked cell tests this segment
                x0 = lower[0] + (i + 0.5) * h
                y0 = lower[1] + (j + 0.5) * h
                z0 = lower[2] + (k + 0.5) * h
                segment = ((x0, y0, z0), (x0 + di * h, y0 + dj * h, z0 + dk * h))
                hit = _first_crossing(positions, triangles, start, items, c, segment)
                if hit < 0:
                    hit = _first_crossing(positions, triangles, start, items, c2, segment)
                if hit < 0:
                    continue
                rows[count, 0] = a
                rows[count, 1] = max(i, i2) + 1 if a == 0 else i + 1
                rows[count, 2] = max(j, j2) + 1 if a == 1 else j + 1
                rows[count, 3] = max(k, k2) + 1 if a == 2 else k + 1
                vals[count] = _normal_velocity(positions, velocities, triangles, hit, a)
                t0, t1, t2 = triangles[hit, 0], triangles[hit, 1], triangles[hit, 2]
                weight[count] = h * (mobility[t0] + mobility[t1] + mobility[t2]) / 3
                count += 1
    return rows[:count], vals[:count], weight[:count]


@njit(cache=True)
def _first_crossing(positions, triangles, start, items, cell, segment):
    """The first triangle registered in ``cell`` that the ``segment`` ((x0, y0, z0), (x1,
    y1, z1)) crosses (:func:`~windbench.geometry.raster.segment_triangle_xyz`), or -1."""
    p0, p1 = segment
    for e in range(start[cell], start[cell + 1]):
        t = items[e]
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        s = segment_triangle_xyz(
            p0, p1,
            (positions[a, 0], positions[a, 1], positions[a, 2]),
            (positions[b, 0], positions[b, 1], positions[b, 2]),
            (positions[c, 0], positions[c, 1], positions[c, 2]),
        )  # fmt: skip
        if s >= 0.0:
            return t
    return -1


@njit(cache=True)
def _triangle_normal(positions, triangles, t):
    """(b - a) x (c - a) of triangle t = (a, b, c): its normal, of length twice its area."""
    a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
    e1x, e1y = positions[b, 0] - positions[a, 0], positions[b, 1] - positions[a, 1]
    e1z = positions[b, 2] - positions[a, 2]
    e2x, e2y = positions[c, 0] - positions[a, 0], positions[c, 1] - positions[a, 1]
    e2z = positions[c, 2] - positions[a, 2]
    return e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x


@njit(cache=True)
def _mean_velocity(velocities, triangles, t):
    """The mean of triangle t's corner velocities."""
    a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
    return (
        (velocities[a, 0] + velocities[b, 0] + velocities[c, 0]) / 3.0,
        (velocities[a, 1] + velocities[b, 1] + velocities[c, 1]) / 3.0,
        (velocities[a, 2] + velocities[b, 2] + velocities[c, 2]) / 3.0,
    )


@njit(cache=True)
def _normal_velocity(positions, velocities, triangles, t, axis):
    """(v . n) n_axis: the normal velocity of triangle t (v the mean of its corners', n its
    unit normal), component ``axis``."""
    nx, ny, nz = _triangle_normal(positions, triangles, t)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx / norm, ny / norm, nz / norm
    vx, vy, vz = _mean_velocity(velocities, triangles, t)
    vn = vx * nx + vy * ny + vz * nz
    return vn * (nx if axis == 0 else (ny if axis == 1 else nz))


@njit(cache=True)
def apply_blocked(rows, vals, u, v, w, fu, fv, fw):
    """Set the blocked faces' velocity and mark them prescribed (free = 0)."""
    for r in range(rows.shape[0]):
        a, I, J, K = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        if a == 0:
            u[I, J, K] = vals[r]
            fu[I, J, K] = 0
        elif a == 1:
            v[I, J, K] = vals[r]
            fv[I, J, K] = 0
        else:
            w[I, J, K] = vals[r]
            fw[I, J, K] = 0


@njit(cache=True)
def _root(parent, c):
    """Root of cell c in the union-find forest ``parent`` (path halving)."""
    while parent[c] != c:
        parent[c] = parent[parent[c]]
        c = parent[c]
    return c


@njit(cache=True)
def pockets(free_u, free_v, free_w, solid, periodic):
    """(label per cell, count): cells joined by open faces (free = 1) into regions; a region
    with an open domain face (outflow or opening: pressure 0 there) or a solid cell is not
    a pocket (-1), the others are numbered 0 .. count - 1 (union-find over the faces; a
    face of a ``periodic`` axis joins the cells across the wrap)."""
    nx, ny, nz = solid.shape
    n = nx * ny * nz
    parent = np.arange(n)
    vented = np.zeros(n, dtype=np.bool_)
    free = (free_u, free_v, free_w)
    for a in range(3):
        f = free[a]
        for I in range(1, f.shape[0] - 1):
            for J in range(1, f.shape[1] - 1):
                for K in range(1, f.shape[2] - 1):
                    if f[I, J, K] == 0:
                        continue
                    ip, jp, kp, im, jm, km = cells_beside(I, J, K, a)
                    if periodic[a]:
                        ip, jp, kp = ip % nx, jp % ny, kp % nz
                        im, jm, km = im % nx, jm % ny, km % nz
                    inside_p = ip < nx and jp < ny and kp < nz
                    inside_m = im >= 0 and jm >= 0 and km >= 0
                    if inside_p and inside_m:
                        ra = _root(parent, (ip * ny + jp) * nz + kp)
                        rb = _root(parent, (im * ny + jm) * nz + km)
                        parent[ra] = rb
                        vented[rb] |= vented[ra]
                    elif inside_p:
                        vented[_root(parent, (ip * ny + jp) * nz + kp)] = True
                    elif inside_m:
                        vented[_root(parent, (im * ny + jm) * nz + km)] = True
    label = np.full(n, -1, dtype=np.int64)
    number = np.full(n, -1, dtype=np.int64)
    count = 0
    for c in range(n):
        r = _root(parent, c)
        if vented[r] or solid.flat[c]:
            continue
        if number[r] < 0:
            number[r] = count
            count += 1
        label[c] = number[r]
    return label.reshape(solid.shape), count


@njit(cache=True)
def balance_pockets(rhs, label, count):
    """rhs -= its mean over each pocket (:func:`pockets`), in place: the pocket's Poisson
    problem (no pressure fixed on it) is solvable only when its right-hand side sums to 0."""
    total = np.zeros(count)
    cells = np.zeros(count)
    for c in range(rhs.size):
        k = label.flat[c]
        if k >= 0:
            total[k] += rhs.flat[c]
            cells[k] += 1.0
    for c in range(rhs.size):
        k = label.flat[c]
        if k >= 0:
            rhs.flat[c] -= total[k] / cells[k]


@njit(cache=True)
def _straddling_cell(x, y, z, a, lower, h):
    """(index, theta): the cell (a tuple) whose centre and the next one's along axis a
    straddle the point (x, y, z) (the cells of the point on the other axes), and where the
    point lies between the two centres (0 at the lower, 1 at the upper)."""
    fx = (x - lower[0]) / h - (0.5 if a == 0 else 0.0)
    fy = (y - lower[1]) / h - (0.5 if a == 1 else 0.0)
    fz = (z - lower[2]) / h - (0.5 if a == 2 else 0.0)
    index = (int(np.floor(fx)), int(np.floor(fy)), int(np.floor(fz)))
    f = fx if a == 0 else (fy if a == 1 else fz)
    return index, f - index[a]


@njit(cache=True)
def _air_psi(psi, solid, index, a, offset):
    """(whether it is air, psi) of the cell ``offset`` cells from ``index`` along axis a:
    not air outside the grid or in a solid cell."""
    i, j, k = index[0], index[1], index[2]
    if a == 0:
        i += offset
    elif a == 1:
        j += offset
    else:
        k += offset
    n0, n1, n2 = psi.shape
    if i < 0 or j < 0 or k < 0 or i >= n0 or j >= n1 or k >= n2 or solid[i, j, k]:
        return False, 0.0
    return True, psi[i, j, k]


@njit(cache=True)
def _face_open(free, index, a, offset):
    """Whether the face between the cells ``offset`` and ``offset + 1`` from ``index`` along
    axis a is open (its padded index along a is that of the upper cell plus one)."""
    I, J, K = index[0] + 1, index[1] + 1, index[2] + 1
    if a == 0:
        return free[0][I + offset + 1, J, K] != 0
    if a == 1:
        return free[1][I, J + offset + 1, K] != 0
    return free[2][I, J, K + offset + 1] != 0


@njit(cache=True)
def _side_pressure(psi, solid, free, index, a, near, far, reach):
    """psi on one side of a sheet, at the sheet: the ``near`` cell's, extrapolated linearly
    over ``reach`` cells toward the sheet from the ``far`` cell beyond it, where that is air
    behind an open face (else the near cell's alone); NaN if the near cell is not air."""
    inside, p = _air_psi(psi, solid, index, a, near)
    if not inside:
        return np.nan
    there, q = _air_psi(psi, solid, index, a, far)
    if there and _face_open(free, index, a, min(near, far)):
        return p + reach * (p - q)
    return p


@njit(cache=True)
def triangle_pressure_loads(positions, triangles, psi, solid, free, lower, h, scale):
    """Pressure force over rho on each triangle, ``(p_- - p_+) / rho A n``: n its unit
    normal, A its area, p_-, p_+ the pressures behind and before it, along the axis a where
    |n_a| is largest, at its centroid: each side's from the two cells on that side, the
    nearer extrapolated linearly to the centroid from the farther (second order: a pressure
    gradient that runs through the sheet, e.g. across a wake or a hydrostatic one, puts no
    force on a sheet of no thickness, where the two cells next to it alone would give it
    that gradient times their distance h). A side whose farther cell is not air or lies
    behind a closed face (a wall, a body, the cloth again) keeps its nearer cell's value;
    a side outside the grid or in a solid cell counts as the other side (no jump).
    p / rho = ``scale`` psi; ``free``: the padded open-face masks of the three axes."""
    out = np.zeros((triangles.shape[0], 3))
    for t in range(triangles.shape[0]):
        nx, ny, nz = _triangle_normal(positions, triangles, t)  # |n| = 2 A
        if nx * nx + ny * ny + nz * nz == 0.0:
            continue
        axis = 1 if abs(ny) > abs(nx) else 0  # the first largest |n_a|, as np.argmax
        axis = 2 if abs(nz) > max(abs(nx), abs(ny)) else axis
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        index, theta = _straddling_cell(
            (positions[a, 0] + positions[b, 0] + positions[c, 0]) / 3.0,
            (positions[a, 1] + positions[b, 1] + positions[c, 1]) / 3.0,
            (positions[a, 2] + positions[b, 2] + positions[c, 2]) / 3.0,
            axis,
            lower,
            h,
        )
        low = _side_pressure(psi, solid, free, index, axis, 0, -1, theta)
        high = _side_pressure(psi, solid, free, index, axis, 1, 2, 1.0 - theta)
        if np.isnan(low) or np.isnan(high):
            continue  # a side outside the grid or in a body: no jump
        n_axis = nx if axis == 0 else (ny if axis == 1 else nz)
        behind, before = (low, high) if n_axis > 0.0 else (high, low)
        jump = 0.5 * scale * (behind - before)  # n has length 2 A
        out[t, 0], out[t, 1], out[t, 2] = jump * nx, jump * ny, jump * nz
    return out


@njit(cache=True)
def membrane_weights(rows, weight, wx, wy, wz):
    """Install the blocked faces' Poisson weights in the (unpadded) face weights, in place."""
    for r in range(rows.shape[0]):
        a, i, j, k = rows[r, 0], rows[r, 1] - 1, rows[r, 2] - 1, rows[r, 3] - 1
        if a == 0:
            wx[i, j, k] = weight[r]
        elif a == 1:
            wy[i, j, k] = weight[r]
        else:
            wz[i, j, k] = weight[r]


@njit(cache=True)
def move_membranes(rows, weight, psi, periodic, u, v, w):
    """q_f -= weight_f (psi_+ - psi_-) on the blocked faces: the cloth over a face yields to
    the pressure jump as its own mass lets it.

    A fluid face moves by dt/rho grad p = psi_+ - psi_- (psi = dt p / (rho h)); the cloth
    of mass mu per area over it by dt (p_- - p_+) / mu, i.e. by rho h / mu times that: a
    face of weight h x mobility in the Poisson problem. The solve then holds the air's
    reaction to the cloth's acceleration (its added mass) within the step, which an
    explicit exchange of force and velocity cannot for a cloth lighter than its air;
    pinned or static cloth (mobility 0) is a wall."""
    for r in range(rows.shape[0]):
        if weight[r] == 0.0:
            continue
        a, I, J, K = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        d = weight[r] * psi_difference(psi, a, I, J, K, periodic)
        if a == 0:
            u[I, J, K] -= d
        elif a == 1:
            v[I, J, K] -= d
        else:
            w[I, J, K] -= d


@njit(cache=True)
def open_membranes(rows, weight, fu, fv, fw):
    """Mark the blocked faces with a weight as free (1), in place: the air beside a cloth
    that moves is no pocket (:func:`pockets`)."""
    for r in range(rows.shape[0]):
        if weight[r] > 0.0:
            a, I, J, K = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
            if a == 0:
                fu[I, J, K] = 1
            elif a == 1:
                fv[I, J, K] = 1
            else:
                fw[I, J, K] = 1
