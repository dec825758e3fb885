"""Backend ``particles``: particle tracing on flow primitives, with lee (paper §4.2.2).

"In our model every wind source is also a particle source: these particles form an
uncoupled particle system which can be considered as a wind gust." Each step:

1. **Emission** (:mod:`windbench.wind.particles.emission`): every source emits its own particles over
   its region, at its rate, during its gust intervals; a particle emitted at instant t_e
   within the step is advanced only by the rest of the step.
2. **Tracing** (:mod:`windbench.wind.particles.tracing`): a particle of source i moves in w_i alone
   (explicit Euler, p += w_i(p) dt); its path is cut at every cell face, and every cell a
   piece crosses is marked as reached by source i at this time.
3. **Lee**: each piece is tested against the rigid bodies and the current cloth triangles
   registered in its cell; at a hit the particle stops on the surface and keeps only the
   tangential part w - (n . w) n of its velocity, so it slides along and never crosses.
4. **Field**: u(cell) = sum of w_i(cell) over the sources whose particles reached the cell
   within the last ``wind.memory`` seconds; cells no particle reached hold zero, and so do
   cells whose centre lies inside a rigid body. ``sample()`` interpolates u trilinearly.

Choices the paper leaves open (written down here):

- *Value of a reached cell.* A free particle of source i leaves w_i evaluated at the cell
  centre (not at the particle), so with no obstacles u equals the ``global`` backend's
  field exactly wherever every source has arrived, and the result does not depend on
  which particle came last.
- *Cells after a hit* (``wind.deflected_cells``). A particle that has hit an object slides
  on with w - (n . w) n in every case; the marks it leaves afterwards in that step carry
  w_i(centre) with the contact normals projected out (a deflected mark, overriding free
  marks of the same step) for hits on rigid bodies (``bodies``, the default), on bodies
  and cloth (``all``: the paper's u(p_col) . n_obj = 0 at every object) or never
  (``none``). The default keeps the paper's no-flow-through condition at walls but lets
  a cloth feel the wind that arrives at it: with ``all``, the cells a cloth sits in hold
  only the tangential wind, and the §3 drag on an exposed cloth collapses (|F| on
  ``scene=flag`` with ``cloth.solver=static`` after 1.5 s: 3.8 N with ``all``, 22.3 N
  with ``bodies``, 22.7 N with ``none``, 24.6 N from the ``global`` backend). The lee
  behind the cloth is the same in all three modes: no particle crosses it.
- *Head-on hits.* A particle whose velocity has no tangential part left after a hit
  (w parallel to n) is removed: its gust has stagnated at the wall. It still marks the
  cell where it stopped (with zero where ``deflected_cells`` makes that hit count).
- *Sinks* emit on the whole domain boundary; their particles gather at the centre (where
  w_i vanishes inside the core) until ``max_age``.
- *Order and cost.* Tracing runs serially over the particles in their stored order (so
  the "later mark wins" rule is deterministic); every ``SORT_EVERY`` steps the particles
  are reordered by cell (stable O(n) radix sort) so that the walk through the cell
  arrays is sequential in memory. Cost per step: O(particles x cells crossed) for
  emission, tracing, collision tests (only what is registered in each crossed cell,
  found through per-cell flags; cloth triangles registered in O(overlaps)) and the field
  update (u is refreshed in the cells whose marks change and in those whose marks lapse
  ``memory`` later); nothing per step is O(cells). On grids of ``PREFETCH_CELLS`` cells
  and more, with fewer particles than half the cells, the tracing prefetches the cell
  state a few particles ahead. Measured
  figures: ``experiments/README.md`` (``scaling_particles``, ``bench_particles.py``).
- *Domain faces.* Particles leave through every face and die (the field outside the grid
  is not kept); boundary kinds (slip, periodic, ...) do not steer them.
- *Thin poles* (``resolve: false``) are obstacles like other bodies.
- *Obstacle motion.* Cloth triangles are registered at their current positions each step;
  a particle does not inherit their velocity (the paper's static collision test). With
  ``memory`` of a few steps the lee follows moving cloth.

Config (``conf/wind/particles.yaml``, schema :class:`ParticleConfig`):
``particles_per_second`` (per source; null: automatic, see emission), ``particles_per_cell``,
``max_particles`` (live particles are capped: emission beyond it is dropped),
``max_age`` (s), ``memory`` (s), ``max_hits`` (collisions per particle per step),
``deflected_cells`` (``all``, ``bodies`` or ``none``, see above),
``seed`` (``${seed}``). Per-source ``emit`` / ``gusts`` keys: see
:mod:`windbench.wind.particles.emission`.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from windbench.errors import ConfigError
from windbench.geometry.bodies import body_table
from windbench.geometry.raster import triangle_cell_pairs
from windbench.wind.base import Obstacles, WindField
from windbench.wind.particles.emission import emitters_from_scene
from windbench.wind.particles.tracing import (
    BODIES,
    MARK_MODES,
    SOLID,
    admit_particles,
    expire_cells,
    reached_sources,
    register_bodies,
    register_cloth,
    sort_by_cell,
    trace_gusts,
)
from windbench.wind.primitives import parameter_table
from windbench.wind.registry import WindConfig, register_backend

CONTACT_OFFSET = 1e-6  # particles rest this many cell widths outside a surface they hit
SORT_EVERY = 8  # steps between reorderings of the particles by cell (memory locality)
# Grids this large (cell state > 2 MB) prefetch the cells ahead of tracing while particles
# are sparse (fewer than one per two cells); denser particles find their cells in cache.
PREFETCH_CELLS = 1 << 16
PREFETCH_DENSITY = 0.5  # particles per cell
# memory budget (bytes): a live particle (position, source, age, doubling buffers, sort
# copies) and a candidate of one step's emission (position, source, instant, duration)
BYTES_PER_PARTICLE = 128
BYTES_PER_CANDIDATE = 128


@dataclass
class ParticleConfig(WindConfig):
    """``wind.*`` keys of the particle-tracing backend (paper §4.2.2)."""

    name: str = "particles"
    particles_per_second: float | None = None  # per source; null: particles_per_cell rule
    particles_per_cell: float = 2.0  # automatic rate: new particles per emitter cell per memory
    max_particles: int = 1_000_000  # cap on live particles (all sources)
    max_age: float = 10.0  # s; older particles die
    memory: float = 0.1  # s; a cell keeps a source's wind this long after its last particle
    max_hits: int = 8  # collisions per particle per step before it waits for the next step
    deflected_cells: str = "bodies"  # which hits make later marks w - (n.w) n: all|bodies|none
    seed: int = 0  # conf/wind/particles.yaml sets ${seed}


def _check(params) -> None:
    """One ConfigError naming the first bad ``wind.*`` value."""
    auto = params.particles_per_second is None
    checks = [
        ("max_particles", params.max_particles >= 1, ">= 1"),
        ("max_age", params.max_age > 0, "> 0 seconds"),
        ("memory", params.memory > 0, "> 0 seconds"),
        ("max_hits", params.max_hits >= 1, ">= 1"),
        ("particles_per_cell", params.particles_per_cell > 0, "> 0"),
        ("particles_per_second", auto or params.particles_per_second >= 0, ">= 0 or null"),
        ("deflected_cells", params.deflected_cells in MARK_MODES, f"one of {sorted(MARK_MODES)}"),
        ("seed", params.seed >= 0, ">= 0"),
    ]
    for key, ok, allowed in checks:
        if not ok:
            raise ConfigError(f"wind.{key}", f"must be {allowed}, got {getattr(params, key)}")


@register_backend("particles", config=ParticleConfig)
class ParticleWind(WindField):
    """Gust particles per source; u = sum of the reached sources' w_i (module docstring)."""

    stats_units = {
        "live_particles": ("particles alive after the step", "1"),
        "emitted_particles": ("particles emitted in the step", "1"),
        "dropped_particles": ("emitted particles dropped (outside, in a body, over the cap)", "1"),
        "cell_crossings": ("cell faces crossed by the particles in the step", "1"),
        "particle_steps_per_second": ("particles traced per second of tracing time", "s-1"),
    }

    @classmethod
    def check(cls, scene, grid, params) -> None:
        """Raise ConfigError for bad ``wind.*`` values or source ``emit``/``gusts`` keys."""
        _check(params)
        emitters_from_scene(scene, grid, params, int(params.seed))

    @classmethod
    def memory(cls, scene, grid, params, dt) -> dict[str, tuple[float, str]]:
        """Live particles (at most ``max_particles``, at most rate x ``max_age``), one step's
        emission candidates, and the per-source cell marks of a multi-source scene."""
        rate = sum(e.rate for e in emitters_from_scene(scene, grid, params, int(params.seed)))
        live = min(float(params.max_particles), rate * float(params.max_age))
        n_src = len(scene.sources)
        rate_key = (
            "particles_per_cell" if params.particles_per_second is None else "particles_per_second"
        )
        return {
            "wind.max_particles": (live * BYTES_PER_PARTICLE, f"up to {live:.3g} live particles"),
            f"wind.{rate_key}": (
                rate * dt * BYTES_PER_CANDIDATE,
                f"{rate * dt:.3g} particles emitted per step",
            ),
            "scene.sources": (
                grid.n_cells * n_src * 32.0 if n_src > 1 else 0.0,
                f"marks of {n_src} sources in {grid.n_cells} cells",
            ),
        }

    def __init__(self, scene, grid, params):
        super().__init__(scene, grid, params)
        _check(params)
        self.emitters = emitters_from_scene(scene, grid, params, int(params.seed))
        # model: fixed tables for the kernels, parameters read once
        self._kinds, self._prims = parameter_table(scene.sources)
        self._body_kinds, self._body_params = body_table(scene.bodies)
        self._lower = np.asarray(grid.lower, dtype=np.float64)
        self._upper = np.asarray(grid.upper, dtype=np.float64)
        self._shape = np.asarray(grid.shape, dtype=np.int64)
        self._h = float(grid.h)
        self._body_start, self._body_items = register_bodies(
            self._body_kinds, self._body_params, self._lower, self._h, self._shape
        )
        self._capacity = int(params.max_particles)
        self._memory = float(params.memory)
        self._max_age = float(params.max_age)
        self._max_hits = int(params.max_hits)
        self._mark_mode = MARK_MODES[params.deflected_cells]
        self._big_grid = grid.n_cells >= PREFETCH_CELLS  # and particles sparse: prefetch
        # state
        n_sources = len(scene.sources)
        self.time = 0.0
        self._steps = 0
        # particles 0.._n-1 of buffers grown on demand: position, source id, age
        self._n = 0
        self._pos = np.zeros((0, 3))
        self._src = np.zeros(0, dtype=np.int64)
        self._age = np.zeros(0)
        self._carry = np.zeros(n_sources)
        self._counter = np.zeros(n_sources, dtype=np.int64)
        self._blocks = [{} for _ in range(n_sources)]  # each source's current sample block
        # per (cell, source): time of the last mark (-inf: never) and the value it left;
        # with one source the values are u itself (u = the value while it is reached)
        self._marked = np.full((grid.n_cells, max(n_sources, 1)), -np.inf)
        self._u = np.zeros((grid.n_cells, 3))
        if n_sources == 1:
            self._values = self._u.reshape(grid.n_cells, 1, 3)
        else:
            self._values = np.zeros((grid.n_cells, max(n_sources, 1), 3))
        # per cell: SOLID (centre in a body), BODIES (bodies registered), TRIANGLES (cloth)
        self._flags = np.zeros(grid.n_cells, dtype=np.uint8)
        self._flags[self.solid_mask().reshape(-1)] |= SOLID
        self._flags[np.diff(self._body_start) > 0] |= BODIES
        self._tri_slot = np.zeros(0, dtype=np.int64)  # grown to n_cells with the first cloth
        self._tri_cells = np.zeros(0, dtype=np.int64)  # cells flagged TRIANGLES
        self._no_triangles = (np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros((0, 2, 3)))
        self._touched = np.zeros(1024, dtype=np.int64)
        self._history: deque[tuple[float, np.ndarray]] = deque()
        self._stats: dict[str, float] = {}

    # ---------------------------------------------------------------- emission
    def _emit(self, t0: float, t1: float) -> np.ndarray:
        """Append the new particles of all sources in [t0, t1); their durations in the step.

        Candidates outside the grid's half-open box or inside a rigid body are dropped, and
        so is what exceeds ``max_particles``.
        """
        pos, src, dur = [], [], []
        for e in self.emitters:
            p, instants, carry, counter = e.emit(
                t0, t1, self._carry[e.source], int(self._counter[e.source]), self._blocks[e.source]
            )
            self._carry[e.source], self._counter[e.source] = carry, counter
            pos.append(p)
            src.append(np.full(len(p), e.source, dtype=np.int64))
            dur.append(t1 - instants)
        if not pos:
            self._stats["dropped_particles"] = 0.0
            return np.zeros(0)
        if len(pos) > 1:
            pos, src, dur = np.concatenate(pos), np.concatenate(src), np.concatenate(dur)
        else:
            pos, src, dur = pos[0], src[0], dur[0]
        self._reserve(len(pos))
        durations = np.empty(len(pos))
        m = admit_particles(
            pos,
            src,
            dur,
            self._lower,
            self._upper,
            self._body_kinds,
            self._body_params,
            max(self._capacity - self._n, 0),
            self._n,
            self._pos,
            self._src,
            self._age,
            durations,
        )
        self._n += m
        self._stats["dropped_particles"] = float(len(pos) - m)
        return durations[:m]

    def _reserve(self, k: int) -> None:
        """Grow the particle buffers (doubling) so that k more fit after the live ones."""
        n = self._n
        if n + k > len(self._pos):
            size = max(n + k, 2 * len(self._pos), 1024)
            for name in ("_pos", "_src", "_age"):
                old = getattr(self, name)
                grown = np.zeros((size, *old.shape[1:]), dtype=old.dtype)
                grown[:n] = old[:n]
                setattr(self, name, grown)

    def add_particles(self, positions, sources):
        """Insert particles (tests, benchmarks); the next step traces them for its full dt."""
        positions = np.atleast_2d(np.asarray(positions, dtype=np.float64))
        n, k = self._n, len(positions)
        self._reserve(k)
        self._pos[n : n + k] = positions
        self._src[n : n + k] = np.asarray(sources, dtype=np.int64)
        self._age[n : n + k] = 0.0
        self._n = n + k

    # ---------------------------------------------------------------- step
    def step(self, dt: float, obstacles: Obstacles) -> None:
        t0 = time.perf_counter()
        t_start, t_end = self.time, self.time + dt
        n_old = self._n
        new_dur = self._emit(t_start, t_end)
        t1 = time.perf_counter()
        tri_slot, tri_start, tri_items, tri_bounds = self._register_cloth(obstacles)
        n_traced = self._n
        self._touched, n_touched, crossings, self._n = trace_gusts(
            n_traced,
            n_old,
            dt,
            new_dur,
            self._max_age,
            self._kinds,
            self._prims,
            self._lower,
            self._h,
            self._shape,
            self._flags,
            self._body_kinds,
            self._body_params,
            self._body_start,
            self._body_items,
            self._cloth_pos,
            self._cloth_tris,
            tri_bounds,
            tri_slot,
            tri_start,
            tri_items,
            t_end,
            self._memory,
            CONTACT_OFFSET * self._h,
            self._max_hits,
            self._mark_mode,
            self._big_grid and n_traced < PREFETCH_DENSITY * self.grid.n_cells,
            self._pos,
            self._src,
            self._age,
            self._marked,
            self._values,
            self._u,
            self._touched,
        )
        t2 = time.perf_counter()
        self._steps += 1
        if self._steps % SORT_EVERY == 0:
            self._sort_by_cell()
        self.time = t_end
        self._expire(self._touched[:n_touched].copy())
        t3 = time.perf_counter()
        trace = t2 - t1
        self._stats.update(
            live_particles=float(self._n),
            emitted_particles=float(len(new_dur)),
            cell_crossings=float(crossings),
            particle_steps_per_second=n_traced / trace if trace > 0 else 0.0,
            emit_seconds=t1 - t0,
            trace_seconds=trace,
            assemble_seconds=t3 - t2,
        )

    def _register_cloth(self, obstacles: Obstacles):
        """Flag the cells the cloth triangles overlap now: (slot, start, items, bounds)."""
        self._cloth_pos = np.ascontiguousarray(obstacles.cloth_positions, dtype=np.float64)
        self._cloth_tris = np.ascontiguousarray(obstacles.cloth_triangles, dtype=np.int64)
        m = self._cloth_tris.shape[0]
        if m == 0 and len(self._tri_cells) == 0:
            return self._tri_slot, *self._no_triangles
        if len(self._tri_slot) == 0:
            self._tri_slot = np.zeros(self.grid.n_cells, dtype=np.int64)
        keys = triangle_cell_pairs(
            self._cloth_pos, self._cloth_tris, self._lower, self._h, self._shape
        )
        self._tri_cells, start, items = register_cloth(
            keys, max(m, 1), self._tri_cells, self._flags, self._tri_slot
        )
        corners = self._cloth_pos[self._cloth_tris]  # (m, 3 corners, 3)
        bounds = np.stack([corners.min(axis=1), corners.max(axis=1)], axis=1)
        return self._tri_slot, start, items, bounds

    def _sort_by_cell(self) -> None:
        """Reorder the particles by cell id (stable), so that tracing walks memory in order."""
        sort_by_cell(self._n, self._lower, self._h, self._shape, self._pos, self._src, self._age)

    def _expire(self, touched: np.ndarray) -> None:
        """Keep this step's marked cells; refresh u where marks older than memory lapse."""
        self._history.append((self.time, touched))
        while (
            self._history and self.time - self._history[0][0] > self._memory * (1 + 1e-12) + 1e-12
        ):
            t_mark, cells = self._history.popleft()
            expire_cells(
                cells,
                t_mark,
                self._marked,
                self._values,
                self._flags,
                self.time,
                self._memory,
                self._u,
            )

    # ---------------------------------------------------------------- queries
    def velocity(self) -> np.ndarray:
        """u on the cells (read-only view of the backend's state)."""
        u = self._u.reshape(*self.grid.shape, 3)
        u.flags.writeable = False
        return u

    def stats(self) -> dict[str, float]:
        return dict(self._stats)

    def reached(self) -> np.ndarray:
        """``(n_sources, nx, ny, nz)`` bool: cells each source reached within ``memory``."""
        out = np.zeros(self._marked.shape, dtype=np.bool_)
        reached_sources(self._marked, self.time, self._memory, out)
        return out.T.reshape(self._marked.shape[1], *self.grid.shape)[: len(self.scene.sources)]

    def ever_reached(self) -> np.ndarray:
        """``(nx, ny, nz)`` bool: cells any particle has marked since the start."""
        return np.isfinite(self._marked).any(axis=1).reshape(self.grid.shape)

    @property
    def particles(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Live particles: positions ``(n, 3)``, source ids ``(n,)``, ages ``(n,)`` (copies)."""
        n = self._n
        return self._pos[:n].copy(), self._src[:n].copy(), self._age[:n].copy()
