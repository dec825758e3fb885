"""The ``mixing`` lee (``wind.lee_model=mixing``): gusts that mix, keep their flux and fill
the shadow back in, at particle-tracing cost.

The paper's particles stop where a body stops them: behind a fence u = 0 to the outlet
and the blocked air's flux is lost. Here a particle of source i marks the air it brings
and takes the Ito (Euler-Maruyama) step of dn/dt + div(n w_i) = div(K grad n),

    X_{n+1} = X_n + (w_i(X_n) + dK/dz e_z) tau + sqrt(2 K(z_n) tau) xi,

xi of zero mean and unit variance per axis (uniform on [-sqrt 3, sqrt 3]: bounded, so one
step never jumps a wall), so a uniform density in the divergence-free w_i stays uniform
(the well-mixed condition) and a point release spreads with variance 2 K t per axis.
K(z) = l(z)^2 |dU/dz| is the Navier-Stokes backend's surface-layer K of the sources'
profile (``surface_layer.sources_viscosity``: both models mix alike), plus I |U| L for inflow
``turbulence`` (Taylor); below the lowest sheared height K keeps its value there.

Flux kept: at a hit the carried wind a (if it points into the surface) turns along it
with its speed kept, a <- |a| t_hat, t_hat along a - (n.a) n or, head-on, toward the box
face's nearest edge that stands free of the domain faces (stagnation flow splits toward
the edges); the random part is mirrored. Walls and the faces a source blows in through
mirror, periodic faces wrap; beyond outflow faces particles fly on in a buffer of
BUFFER_CELLS and may diffuse back. Only ``wind.max_age`` (default: none) ends them else.

Cell wind: each piece of a path in cell c adds its time there times the carried wind,
d_{c,i} += dtau a, and u_c = sum_i d_{c,i} / (n_i h^3 dt) is w_i times the fraction of the
source's air that reached c (above a fence, where the deflected air crowds, more than 1:
the speed-up); n_i = R_i / (Q_i f_max), rate over the volume flux of the faces it enters
by, a profile's candidates kept with probability f(z) / f_max so that n_i is uniform.
Particles are conserved, so the volume flux through any plane is the inflow's, up to the
diffusive K dn/dx. Cells keep a running mean u <- u + (1 - e^(-dt/T)) (u_step - u),
T = ``wind.averaging_time``. Sources must be uniform winds entering through the faces.
Behind each box on the floor the near wake (:mod:`.wake`) adds a separation cavity the
particles go around, its recirculating eddy to the cells' wind and its shear layer's K.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from windbench.arrays import copy_head
from windbench.errors import ConfigError
from windbench.geometry.bodies import BOX
from windbench.wind.particles.emission import emission_specs
from windbench.wind.particles.tracing import (
    BODIES,
    BODY_HIT,
    SOLID,
    TRIANGLES,
    _cross_face,
    _start_walk,
    first_body_hit,
    first_triangle_hit,
)
from windbench.wind.particles.wake import (
    Eddy,
    eddy_field,
    leave_cavity,
    wake_diffusivity,
    wake_rows,
)
from windbench.wind.primitives import NO_PROFILE, primitive_velocity, profile_factor
from windbench.wind.surface_layer import sources_viscosity

LEAVE, MIRROR, WRAP = 0, 1, 2  # what a domain face does to a particle that reaches it
FACE_ACTIONS = {"inflow": LEAVE, "outflow": LEAVE, "slip": MIRROR, "no_slip": MIRROR}
FACE_ACTIONS["rough"] = MIRROR
FACE_ACTIONS["periodic"] = WRAP
TABLE_NODES = 256  # heights of the K(z) table over the domain
SHEAR_STEP = 1e-3  # central-difference step of the shear, in table spacings
SQRT3 = np.sqrt(3.0)
UNIT_21 = 1.0 / (1 << 21)  # three uniforms of 21 bits from one 64-bit hash
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
EDGE_SLACK = 1e-9  # m: a box edge this close to a domain face stands on it (closed)
BUFFER_CELLS = 2  # cells beyond an open face where particles fly on and may come back
THINNING_STREAM = 1 << 62  # random streams of the emission's flux weighting (walks: steps)


class MixingModel(NamedTuple):
    """The mixing lee's fixed tables as the kernels read them."""

    diffusivity: np.ndarray  # (M,) K (m^2/s) at heights z_first + k dz
    z_first: float  # m
    dz: float  # m
    faces: np.ndarray  # (n_sources, 3, 2) LEAVE | MIRROR | WRAP per source and face
    seed: int
    wakes: np.ndarray  # (n_wakes, N_WAKE) the obstacles' near wakes (:mod:`.wake`)
    floor: float  # m: the domain's lowest height


class MixStep(NamedTuple):
    """One step: as :class:`~.tracing.TraceStep`, and the step's number (random stream)."""

    dt: float
    t_now: float
    n: int
    n_old: int
    new_durations: np.ndarray
    index: int


# ---------------------------------------------------------------- model


def diffusivity_table(scene, grid, limit: float) -> tuple[np.ndarray, float, float]:
    """(K at TABLE_NODES heights, first height, spacing) (m^2/s, m, m): the sources'
    surface-layer K plus I |U| L of each inflow ``turbulence``, held at its lowest positive
    value below the lowest sheared height (module docstring)."""
    lower, upper = np.asarray(grid.lower, float), np.asarray(grid.upper, float)
    dz = (upper[2] - lower[2]) / TABLE_NODES
    heights = lower[2] + (np.arange(TABLE_NODES) + 0.5) * dz
    k = sources_viscosity(scene.sources, heights, lower, upper, limit, SHEAR_STEP * dz)
    for s in scene.sources:
        if s.turbulence is not None:
            intensity, length = s.turbulence
            k = k + intensity * float(np.linalg.norm(s.velocity)) * length
    positive = np.flatnonzero(k > 0)
    if positive.size:
        k[: positive[0]] = k[positive[0]]
    return np.ascontiguousarray(k), float(heights[0]), float(dz)


def face_actions(scene) -> np.ndarray:
    """(n_sources, 3, 2) LEAVE | MIRROR | WRAP of each domain face for each source's
    particles: walls (slip, no_slip, rough) and the faces the source blows in through mirror (the
    gusts enter with their whole flux, none diffuses back out), periodic faces wrap, the
    other inflow and outflow faces let them leave."""
    b = scene.boundary
    out = np.empty((len(scene.sources), 3, 2), dtype=np.int64)
    for i, prim in enumerate(scene.sources):
        for ax, name in enumerate("xyz"):
            for side, kind in enumerate((b[f"{name}_min"], b[f"{name}_max"])):
                blows_in = prim.velocity[ax] > 0 if side == 0 else prim.velocity[ax] < 0
                out[i, ax, side] = MIRROR if blows_in else FACE_ACTIONS[kind]
    return out


def free_density(prim, emitter, lower, upper) -> float:
    """n_i = R / (Q f_max) (particles per m^3): the undisturbed density of a uniform
    source's gusts, Q = sum |U . n| A over the faces it blows in through, f_max the
    profile's largest factor on them (the domain's top: f grows with height)."""
    velocity = np.asarray(prim.velocity, dtype=float)
    ext = np.asarray(upper, float) - np.asarray(lower, float)
    areas = np.array([ext[1] * ext[2], ext[0] * ext[2], ext[0] * ext[1]])
    flux = float(np.abs(velocity) @ areas)
    return emitter.rate / (flux * profile_ceiling(prim, upper))


def profile_ceiling(prim, upper) -> float:
    """f_max: the profile factor at the domain's top (1 without a profile)."""
    return float(profile_factor(prim.row(), float(upper[2])))


def check_sources(scene, specs) -> None:
    """ConfigError unless every source is a uniform wind emitted through the domain faces."""
    for i, (prim, spec) in enumerate(zip(scene.sources, specs, strict=True)):
        if prim.kind != "uniform" or spec.box is not None:
            what = f"a {prim.kind} source" if prim.kind != "uniform" else "emits from emit.box"
            raise ConfigError(
                "wind.lee_model",
                f"mixing needs uniform sources entering through the domain faces; "
                f"scene.sources[{i}] is {what} (use wind.lee_model=paper)",
            )


@dataclass(frozen=True)
class MixingLee:
    """What the mixing lee fixes for a run: the kernels' tables, the sources' undisturbed
    densities, the flux weighting of profiled emission and the averaging time."""

    tables: MixingModel
    inverse_density: np.ndarray  # (n_sources,) 1 / n_i, m^3 per particle
    rows: np.ndarray  # (n_sources, N_PARAMS) the sources' primitive rows
    ceilings: np.ndarray  # (n_sources,) f_max; 0 for a source without a profile
    averaging_time: float  # s
    eddy: np.ndarray  # (n_cells, 3) m/s: the wakes' recirculating eddies at the cells

    def kept(self, source: int, points: np.ndarray, first: int) -> np.ndarray | None:
        """Mask of a profiled source's candidates kept by the flux weighting (numbers
        first, first + 1, ...); None for a source without a profile (all kept)."""
        if self.ceilings[source] == 0.0:
            return None
        stream = THINNING_STREAM + source
        return keep_by_profile(
            points, self.rows[source], self.ceilings[source], self.tables.seed, stream, first
        )


def mixing_lee(scene, grid, params, emitters) -> MixingLee:
    """Check the scene's sources and build the mixing lee of ``scene`` on ``grid``."""
    check_sources(scene, emission_specs(scene))
    k, z_first, dz = diffusivity_table(scene, grid, float(params.mixing_length_limit))
    lower, upper = np.asarray(grid.lower, float), np.asarray(grid.upper, float)
    near_wake = Eddy(
        float(params.recirculation_backflow),
        float(params.wake_mixing),
        float(params.recirculation_exponent),
        float(params.recirculation_height),
    )
    wakes = wake_rows(scene, lower, near_wake)
    eddy = eddy_field(wakes, lower, float(grid.h), tuple(int(n) for n in grid.shape))
    tables = MixingModel(k, z_first, dz, face_actions(scene), int(params.seed), wakes, lower[2])
    density = np.array(
        [free_density(p, e, lower, upper) for p, e in zip(scene.sources, emitters, strict=True)]
    )
    return MixingLee(
        tables=tables,
        inverse_density=np.where(density > 0, 1.0 / np.maximum(density, 1e-300), 0.0),
        rows=np.array([p.row() for p in scene.sources]).reshape(len(scene.sources), -1),
        ceilings=np.array(
            [
                profile_ceiling(p, upper) if p.profile[0] != NO_PROFILE else 0.0
                for p in scene.sources
            ]
        ),
        averaging_time=float(params.averaging_time),
        eddy=eddy,
    )


# ---------------------------------------------------------------- random numbers


@njit(cache=True, inline="always")
def _hash(x):
    """splitmix64's finaliser: a well-mixed 64-bit function of x (uint64)."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@njit(cache=True, inline="always")
def unit_triple(seed, stream, q):
    """Three uniforms in (0, 1), a pure function of (seed, stream, q): counter-based, so a
    run draws the same numbers in any order and on any number of threads."""
    x = _hash(np.uint64(seed) * GOLDEN + np.uint64(stream))
    x = _hash(x ^ (np.uint64(q) * GOLDEN))
    mask = np.uint64((1 << 21) - 1)
    u0 = (float(x & mask) + 0.5) * UNIT_21
    u1 = (float((x >> np.uint64(21)) & mask) + 0.5) * UNIT_21
    u2 = (float((x >> np.uint64(42)) & mask) + 0.5) * UNIT_21
    return u0, u1, u2


@njit(cache=True)
def keep_by_profile(points, prm, ceiling, seed, stream, first):
    """Mask of the candidates kept by the flux weighting: candidate k (number first + k of
    its source) is kept with probability f(z_k) / f_max."""
    keep = np.empty(points.shape[0], dtype=np.bool_)
    for k in range(points.shape[0]):
        u, _, _ = unit_triple(seed, stream, first + k)
        keep[k] = u * ceiling < profile_factor(prm, points[k, 2])
    return keep


# ---------------------------------------------------------------- kernels


@njit(cache=True, inline="always")
def _diffusivity(table, z_first, dz, z):
    """(K, dK/dz) at height z: the table interpolated linearly, held beyond its ends."""
    f = (z - z_first) / dz
    if f <= 0.0:
        return table[0], 0.0
    last = table.shape[0] - 1
    if f >= last:
        return table[last], 0.0
    k = int(f)
    slope = table[k + 1] - table[k]
    return table[k] + (f - k) * slope, slope / dz


@njit(cache=True, inline="always")
def _random_part(mix, seed_stream, q, p, tau):
    """r = grad K + sqrt(2 K / tau) xi (m/s): the diffusive part of the path velocity, K
    the surface layer's K(z) plus the obstacles' wake K_w(p) (:mod:`.wake`)."""
    k, dk = _diffusivity(mix.diffusivity, mix.z_first, mix.dz, p[2])
    kw, gx, gy, gz = wake_diffusivity(mix.wakes, p, mix.floor)
    u0, u1, u2 = unit_triple(mix.seed, seed_stream, q)
    amp = SQRT3 * np.sqrt(2.0 * (k + kw) / tau) if tau > 0.0 else 0.0
    return (
        amp * (2.0 * u0 - 1.0) + gx,
        amp * (2.0 * u1 - 1.0) + gy,
        amp * (2.0 * u2 - 1.0) + dk + gz,
    )


@njit(cache=True, inline="always")
def _tangential(x, n):
    """(x - (n . x) n, its squared length)."""
    dn = x[0] * n[0] + x[1] * n[1] + x[2] * n[2]
    t = (x[0] - dn * n[0], x[1] - dn * n[1], x[2] - dn * n[2])
    return t, t[0] * t[0] + t[1] * t[1] + t[2] * t[2]


@njit(cache=True, inline="always")
def _bounce(a, r, n, escape):
    """(a, r) after a hit on a surface of unit normal n (into the air): the carried wind a,
    if it points into the surface, turned along it with its speed kept, |a| t_hat, t_hat
    the direction of its tangential part or, head-on, ``escape`` (a box face's nearest
    open edge) or r's tangential part (none: a stops); r mirrored if it points in."""
    rn = r[0] * n[0] + r[1] * n[1] + r[2] * n[2]
    if rn < 0.0:
        r = (r[0] - 2.0 * rn * n[0], r[1] - 2.0 * rn * n[1], r[2] - 2.0 * rn * n[2])
    if a[0] * n[0] + a[1] * n[1] + a[2] * n[2] >= 0.0:  # a leaves the surface: as it is
        return a, r
    aa = a[0] * a[0] + a[1] * a[1] + a[2] * a[2]
    t, tt = _tangential(a, n)
    if tt <= 1e-18 * aa:
        t, tt = escape, escape[0] * escape[0] + escape[1] * escape[1] + escape[2] * escape[2]
    if tt == 0.0:
        t, tt = _tangential(r, n)
    if tt == 0.0:
        return (0.0, 0.0, 0.0), r
    scale = np.sqrt(aa / tt)
    return (scale * t[0], scale * t[1], scale * t[2]), r


@njit(cache=True)
def escape_direction(table, b, p, n, lower, upper, faces):
    """Where the air that meets body b head-on at p (normal n) leaves its face: for a box,
    the direction along the face to its nearest open edge (stagnation flow on a plate
    splits toward its edges), (0, 0, 0) if none is open or for any other body. An edge is
    open if it stands free of the domain's faces or on a face the particle leaves by
    (``faces``: the source's (3, 2) LEAVE | MIRROR | WRAP, :func:`face_actions`): an edge
    on the ground or a side wall is closed, one on an outflow face open, so the air a wall
    across the whole domain stops leaves by the outflow instead of piling up."""
    if b < 0 or table.kinds[b] != BOX:
        return (0.0, 0.0, 0.0)
    prm = table.params[b]
    best, axis, sign = np.inf, -1, 0.0
    for ax in range(3):
        if abs(n[ax]) > 0.5:  # the face's own axis
            continue
        low_open = prm[ax] > lower[ax] + EDGE_SLACK or faces[ax, 0] == LEAVE
        high_open = prm[ax + 3] < upper[ax] - EDGE_SLACK or faces[ax, 1] == LEAVE
        if low_open and p[ax] - prm[ax] < best:
            best, axis, sign = p[ax] - prm[ax], ax, -1.0
        if high_open and prm[ax + 3] - p[ax] < best:
            best, axis, sign = prm[ax + 3] - p[ax], ax, 1.0
    if axis < 0:
        return (0.0, 0.0, 0.0)
    return (sign if axis == 0 else 0.0, sign if axis == 1 else 0.0, sign if axis == 2 else 0.0)


@njit(cache=True)
def nearest_hit(bodies, cloth, obstacles, cell, p, e, t0, t1, work):
    """Earliest hit on the bodies and cloth triangles ``cell`` registers (``obstacles``: its
    flag bits): (fraction of the piece p + [t0, t1] e or 2.0, the body hit or -1); the
    normal at the hit goes to ``work.normal``. Called only for cells that register some."""
    best, body = 2.0, -1
    a, b = work.piece[0], work.piece[1]
    for ax in range(3):
        a[ax] = p[ax] + t0 * e[ax]
        b[ax] = p[ax] + t1 * e[ax]
    if obstacles & BODIES:
        table, start, items = bodies
        ab = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
        for m in range(start[cell], start[cell + 1]):
            sh = first_body_hit(
                table, items[m], (a[0], a[1], a[2]), ab, work.root, work.body_normal
            )
            if 0.0 <= sh < best:
                best, body = sh, items[m]
                copy_head(work.normal, work.body_normal, work.body_normal.shape[0])
    if obstacles & TRIANGLES:
        best, on_body = first_triangle_hit(cloth, cell, a, b, e, best, BODY_HIT, work.normal)
        body = body if on_body else -1
    return best, body


@njit(cache=True, inline="always")
def _at_face(end, ijk, actions, s, a, r, g):
    """A path that left the grid at ``end``: (p, a, r, alive). The face's action for
    source s: LEAVE puts it just outside (:func:`_beyond` flies it on), MIRROR puts it back
    just inside and bounces it (:func:`_bounce`, the face's normal into the domain), WRAP
    moves it to the opposite face."""
    axis, side = 0, 0
    for ax in range(3):
        if ijk[ax] < 0 or ijk[ax] >= g.shape[ax]:
            axis, side = ax, int(ijk[ax] >= 0)
    action = actions[s, axis, side]
    inset = 1e-9 * g.h
    lo, hi = g.lower[axis] + inset, g.upper[axis] - inset
    if action == LEAVE:  # just outside: the particle flies on in the buffer beyond
        at = lo - 2.0 * inset if side == 0 else hi + 2.0 * inset
        return (
            (at if axis == 0 else end[0], at if axis == 1 else end[1], at if axis == 2 else end[2]),
            a,
            r,
            True,
        )
    at = (lo if side == 0 else hi) if action == MIRROR else (hi if side == 0 else lo)
    p = (at if axis == 0 else end[0], at if axis == 1 else end[1], at if axis == 2 else end[2])
    if action == MIRROR:
        sign = 1.0 if side == 0 else -1.0
        n = (sign if axis == 0 else 0.0, sign if axis == 1 else 0.0, sign if axis == 2 else 0.0)
        a, r = _bounce(a, r, n, (0.0, 0.0, 0.0))
    return p, a, r, True


@njit(cache=True, inline="always")
def _buffered(p, actions, s, g):
    """Whether p lies in the grid or in the buffer beyond its LEAVE faces (BUFFER_CELLS
    wide, across those faces only)."""
    reach = BUFFER_CELLS * g.h
    for ax in range(3):
        if p[ax] < g.lower[ax] and (actions[s, ax, 0] != LEAVE or p[ax] < g.lower[ax] - reach):
            return False
        if p[ax] >= g.upper[ax] and (actions[s, ax, 1] != LEAVE or p[ax] > g.upper[ax] + reach):
            return False
    return True


@njit(cache=True, inline="always")
def _beyond(p, e, actions, s, g):
    """A particle at p outside the grid with the path p -> p + e: (p, path fraction at which
    it comes back in or -1, alive). Beyond an outflow the air goes on as inside (no bodies
    there), so particles fly on in a buffer and may diffuse back: the outflow face does not
    absorb them, which would starve its last cells of air within a length K / U of it."""
    if not _buffered(p, actions, s, g):
        return p, -1.0, False
    t_in, t_out, axis = 0.0, 1.0, -1
    for ax in range(3):
        if e[ax] == 0.0:
            if not g.lower[ax] <= p[ax] < g.upper[ax]:
                t_in = 2.0
            continue
        t0, t1 = (g.lower[ax] - p[ax]) / e[ax], (g.upper[ax] - p[ax]) / e[ax]
        near, far = min(t0, t1), max(t0, t1)
        if near > t_in:
            t_in, axis = near, ax
        t_out = min(t_out, far)
    if axis >= 0 and t_in <= t_out:  # back in across the face of ``axis``
        inset = 1e-9 * g.h
        at = g.lower[axis] + inset if e[axis] > 0.0 else g.upper[axis] - inset
        q = (p[0] + t_in * e[0], p[1] + t_in * e[1], p[2] + t_in * e[2])
        return (
            (at if axis == 0 else q[0], at if axis == 1 else q[1], at if axis == 2 else q[2]),
            t_in,
            True,
        )
    q = (p[0] + e[0], p[1] + e[1], p[2] + e[2])
    return q, -1.0, _buffered(q, actions, s, g)


@njit(cache=True, inline="always")
def _deposit(deposits, marked, cell, s, dwell, a, t_now):
    """d_{c,s} += dwell time x carried wind; the cell counts as reached by s at t_now."""
    deposits[cell, s, 0] += dwell * a[0]
    deposits[cell, s, 1] += dwell * a[1]
    deposits[cell, s, 2] += dwell * a[2]
    marked[cell, s] = t_now


@njit(cache=True)
def trace_mixing(model, mix, cloth, cells, deposits, particles, step, work):
    """Move particles 0..n-1 by the mixing step (module docstring) cell by cell: deposit the
    wind they carry in every air cell, bounce at hits and wall faces, wrap at periodic ones;
    compact the survivors. Returns (n_alive, cells crossed)."""
    kinds, prims, rules, g = model.source_kinds, model.source_params, model.rules, model.grid
    flags, marked = cells.flags, cells.marked
    positions, sources, ages = particles
    actions, wc, normal = mix.faces, work.value, work.normal
    ny, nz = g.shape[1], g.shape[2]
    n_alive, crossings = 0, 0
    for q in range(step.n):
        s = sources[q]
        tau = step.dt if q < step.n_old else step.new_durations[q - step.n_old]
        p = (positions[q, 0], positions[q, 1], positions[q, 2])
        primitive_velocity(kinds[s], prims[s], p[0], p[1], p[2], wc)
        a, r = (wc[0], wc[1], wc[2]), _random_part(mix, step.index, q, p, tau)
        remaining, events, alive = tau, 0, True
        while alive and remaining > 0.0 and events < rules.max_hits:
            e = ((a[0] + r[0]) * remaining, (a[1] + r[1]) * remaining, (a[2] + r[2]) * remaining)
            inside, ijk, steps, t_next, t_cell, t = _start_walk(p, e, g)
            if not inside:  # beyond an open face: fly on, come back, or leave for good
                p, entry, alive = _beyond(p, e, actions, s, g)
                if entry < 0.0:
                    break
                remaining *= 1.0 - entry
                continue
            while True:  # the pieces of the path p -> p + e, one per cell
                t_exit = max(t, min(t_next[0], t_next[1], t_next[2], 1.0))
                cell = (ijk[0] * ny + ijk[1]) * nz + ijk[2]
                best, body = 2.0, -1
                if flags[cell] & (BODIES | TRIANGLES):
                    best, body = nearest_hit(
                        model.bodies, cloth, flags[cell], cell, p, e, t, t_exit, work
                    )
                t_end = t + best * (t_exit - t) if best <= 1.0 else t_exit
                if not flags[cell] & SOLID:
                    _deposit(deposits, marked, cell, s, (t_end - t) * remaining, a, step.t_now)
                crossings += 1
                if best <= 1.0 or t_exit >= 1.0:
                    break
                ijk, t, t_next, inside = _cross_face(ijk, t_next, steps, t_cell, g.shape)
                if not inside:
                    t_end = t
                    break
            end = (p[0] + t_end * e[0], p[1] + t_end * e[1], p[2] + t_end * e[2])
            if best <= 1.0:  # a hit: rest just outside the surface, go on deflected
                n = (normal[0], normal[1], normal[2])
                p = (
                    end[0] + rules.delta * n[0],
                    end[1] + rules.delta * n[1],
                    end[2] + rules.delta * n[2],
                )
                escape = escape_direction(
                    model.bodies.table, body, end, n, g.lower, g.upper, actions[s]
                )
                a, r = _bounce(a, r, n, escape)
            elif inside:  # the whole path walked
                p, remaining = end, 0.0
            else:  # a domain face: leave, or mirror or wrap and go on
                p, a, r, alive = _at_face(end, ijk, actions, s, a, r, g)
            remaining *= 1.0 - t_end
            events += 1
        if alive and ages[q] + tau <= rules.max_age:
            p = leave_cavity(mix.wakes, p, mix.floor)
            positions[n_alive, 0], positions[n_alive, 1], positions[n_alive, 2] = p
            sources[n_alive], ages[n_alive] = s, ages[q] + tau
            n_alive += 1
    return n_alive, crossings


@njit(cache=True)
def blend_cells(deposits, scale, factor, flags, eddy, u):
    """u <- u + factor (sum_s scale_s d_{c,s} + e_c - u) in every air cell (the running mean
    of the step's wind, scale_s = 1 / (n_s h^3 dt), plus the wakes' eddy e_c); the
    deposits are cleared."""
    for c in range(u.shape[0]):
        if flags[c] & SOLID:
            continue
        for ax in range(3):
            step_wind = eddy[c, ax]
            for s in range(scale.shape[0]):
                step_wind += deposits[c, s, ax] * scale[s]
                deposits[c, s, ax] = 0.0
            u[c, ax] += factor * (step_wind - u[c, ax])
