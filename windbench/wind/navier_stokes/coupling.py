"""Cloth-to-air coupling of the Navier-Stokes wind (paper §4.1.2), ``wind.coupling``.

- ``paper``: every cloth triangle is registered in the cells it cuts
  (:func:`windbench.geometry.raster.triangle_cells`); per marked cell the triangle normals
  are averaged (area-weighted) together with the cloth velocity; on every face next to a
  marked cell the normal component of the air velocity relative to the cloth is removed,
  u <- u - ((u - v_cloth) . n) n, "prior to any other operation" of the solver step.
  The cloth's own velocity is kept (the paper's Neumann condition u . n = 0 for a cloth
  at rest, generalised to a moving one).
- ``projection``: in addition, every grid face whose centre-to-centre segment crosses a
  cloth triangle (:func:`windbench.geometry.raster.segment_triangle`) is closed in the
  pressure projection, its normal velocity prescribed to the cloth's normal velocity
  ((v . n) n_a): a moving, impermeable wall, so that air cannot pass through the flag.
- ``none``: the cloth does not act on the air (one-way coupling).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from windbench.geometry.raster import segment_triangle
from windbench.wind.navier_stokes.advection import at_face
from windbench.wind.navier_stokes.boundaries import cells_beside


@njit(cache=True)
def cell_normals(positions, velocities, triangles, start, items, index, normals, velocity):
    """Per marked cell m (index[c] = m): area-weighted mean unit normal and cloth velocity.

    n_c = normalise(sum_t (b - a) x (c - a)),  v_c = sum_t A_t v_t / sum_t A_t,
    v_t the mean of the triangle's vertex velocities.
    """
    for c in range(start.shape[0] - 1):
        m = index.flat[c]
        if m < 0:
            continue
        nsum = np.zeros(3)
        vsum = np.zeros(3)
        asum = 0.0
        for e in range(start[c], start[c + 1]):
            t = items[e]
            a = positions[triangles[t, 0]]
            b = positions[triangles[t, 1]]
            cc = positions[triangles[t, 2]]
            n = np.cross(b - a, cc - a)
            area = 0.5 * np.sqrt((n * n).sum())
            nsum += n
            vt = (
                velocities[triangles[t, 0]]
                + velocities[triangles[t, 1]]
                + velocities[triangles[t, 2]]
            ) / 3.0
            vsum += area * vt
            asum += area
        norm = np.sqrt((nsum * nsum).sum())
        if norm > 0.0:
            normals[m] = nsum / norm
        else:
            normals[m] = 0.0
        if asum > 0.0:
            velocity[m] = vsum / asum
        else:
            velocity[m] = 0.0


@njit(cache=True)
def remove_normal_component(q, a, u, v, w, index, normals, velocity, out):
    """out = q - ((u_air - v_cloth) . n) n_a on faces of component a next to marked cells.

    ``n`` and ``v_cloth`` are the normalised sum / mean of those of the (one or two)
    marked cells beside the face; elsewhere out = q.
    """
    nx, ny, nz = index.shape
    P0, P1, P2 = q.shape
    for I in prange(1, P0 - 1):
        for J in range(1, P1 - 1):
            for K in range(1, P2 - 1):
                out[I, J, K] = q[I, J, K]
                ip, jp, kp, im, jm, km = cells_beside(I, J, K, a)
                n = np.zeros(3)
                vc = np.zeros(3)
                cnt = 0
                for side in range(2):
                    ci, cj, ck = (ip, jp, kp) if side == 1 else (im, jm, km)
                    if ci < 0 or cj < 0 or ck < 0 or ci >= nx or cj >= ny or ck >= nz:
                        continue
                    m = index[ci, cj, ck]
                    if m >= 0:
                        n += normals[m]
                        vc += velocity[m]
                        cnt += 1
                if cnt == 0:
                    continue
                norm = np.sqrt((n * n).sum())
                if norm == 0.0:
                    continue
                n /= norm
                vc /= cnt
                air = np.zeros(3)
                air[0] = at_face(u, 0, a, I, J, K)
                air[1] = at_face(v, 1, a, I, J, K)
                air[2] = at_face(w, 2, a, I, J, K)
                rel = (air[0] - vc[0]) * n[0] + (air[1] - vc[1]) * n[1] + (air[2] - vc[2]) * n[2]
                out[I, J, K] = q[I, J, K] - rel * n[a]  # u <- u - ((u - v) . n) n


@njit(cache=True)
def blocked_faces(positions, velocities, triangles, start, items, lower, h, shape):
    """Faces crossed by cloth: rows (component, I, J, K) of padded indices and their
    prescribed normal velocity (v . n) n_a of the first triangle that crosses the segment
    between the two cell centres beside the face."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    n_cells = nx * ny * nz
    rows = np.zeros((6 * (start[n_cells] + 1), 4), dtype=np.int64)
    vals = np.zeros(6 * (start[n_cells] + 1))
    count = 0
    p0 = np.empty(3)
    p1 = np.empty(3)
    for c in range(n_cells):
        if start[c + 1] == start[c]:
            continue
        i = c // (ny * nz)
        j = (c // nz) % ny
        k = c % nz
        for a in range(3):
            for side in range(2):
                off = np.zeros(3, dtype=np.int64)
                off[a] = 1 if side == 1 else -1
                i2, j2, k2 = i + off[0], j + off[1], k + off[2]
                if i2 < 0 or j2 < 0 or k2 < 0 or i2 >= nx or j2 >= ny or k2 >= nz:
                    continue
                c2 = (i2 * ny + j2) * nz + k2
                if start[c2 + 1] > start[c2] and c2 < c:
                    continue  # the other marked cell tests this segment
                p0[0] = lower[0] + (i + 0.5) * h
                p0[1] = lower[1] + (j + 0.5) * h
                p0[2] = lower[2] + (k + 0.5) * h
                p1[0] = p0[0] + off[0] * h
                p1[1] = p0[1] + off[1] * h
                p1[2] = p0[2] + off[2] * h
                hit = -1
                for cell in (c, c2):
                    for e in range(start[cell], start[cell + 1]):
                        t = items[e]
                        s = segment_triangle(
                            p0,
                            p1,
                            positions[triangles[t, 0]],
                            positions[triangles[t, 1]],
                            positions[triangles[t, 2]],
                        )
                        if s >= 0.0:
                            hit = t
                            break
                    if hit >= 0:
                        break
                if hit < 0:
                    continue
                ta = positions[triangles[hit, 0]]
                tb = positions[triangles[hit, 1]]
                tc = positions[triangles[hit, 2]]
                n = np.cross(tb - ta, tc - ta)
                n /= np.sqrt((n * n).sum())
                vt = (
                    velocities[triangles[hit, 0]]
                    + velocities[triangles[hit, 1]]
                    + velocities[triangles[hit, 2]]
                ) / 3.0
                vn = vt[0] * n[0] + vt[1] * n[1] + vt[2] * n[2]
                rows[count, 0] = a
                rows[count, 1] = max(i, i2) + 1 if a == 0 else i + 1
                rows[count, 2] = max(j, j2) + 1 if a == 1 else j + 1
                rows[count, 3] = max(k, k2) + 1 if a == 2 else k + 1
                vals[count] = vn * n[a]
                count += 1
    return rows[:count], vals[:count]


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
