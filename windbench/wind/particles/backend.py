"""Backend ``particles``: particle tracing on flow primitives, with lee (paper §4.2.2).

"In our model every wind source is also a particle source: these particles form an
uncoupled particle system which can be considered as a wind gust." Each step:

1. **Emission** (:mod:`.emission`): every source emits its own particles over its region,
   at its rate, during its gust intervals; a particle emitted at instant t_e within the
   step is advanced only by the rest of the step.
2. **Tracing** (:mod:`.tracing`): a particle of source i moves in w_i alone (explicit
   Euler, ``p_{t+dt} = p_t + w_i(p_t) dt``); its path is cut at every cell face, and every
   cell a piece crosses is marked as reached by source i at this time.
3. **Lee**: each piece is tested against the rigid bodies and the current cloth triangles
   registered in its cell; at a hit the particle stops on the surface and keeps only the
   tangential part ``w_i - (n_obj . w_i) n_obj`` of its velocity.
4. **Field**: ``u = sum w_i`` per cell over the sources whose particles reached it within
   the last ``wind.memory`` seconds; cells no particle reached, and cells whose centre
   lies inside a rigid body, hold zero. ``sample()`` interpolates u trilinearly.

Choices the paper leaves open: a free particle leaves w_i at the cell *centre*, so with
no obstacles u equals the ``global`` backend's field wherever every source has arrived;
``wind.deflected_cells`` says which hits make a particle's later marks carry the
tangential w_i (``bodies``, the default, keeps the paper's no-flow-through condition at
walls and lets a cloth feel the wind that arrives at it; ``all`` applies it at every
object, ``none`` nowhere); a head-on hit (no tangential part left) ends the particle;
particles leave through every domain face (boundary kinds do not steer them); cloth
triangles are obstacles at their current positions (the paper's static collision test).
That is ``wind.lee_model=paper``, the default; ``mixing`` (:mod:`.mixing`) replaces steps
2-4 by gusts that mix, keep their flux at bodies and fill the shadow back in.

:class:`ParticleWind` keeps the model (:class:`~.tracing.GustModel` tables, emitters,
fixed at construction) apart from the :class:`ParticleState` that :func:`advance` takes
and returns and from the :class:`Workspace` of scratch it reuses. Tracing runs serially
in the particles' stored order, so the "later mark wins" rule is deterministic; every
``SORT_EVERY`` steps the particles are reordered by cell so that the walk through the cell
arrays is sequential in memory. Config: ``conf/wind/particles.yaml``, schema
:class:`ParticleConfig`; per-source ``emit`` / ``gusts`` keys: :mod:`.emission`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from windbench.config import check_settings, setting
from windbench.geometry.bodies import body_table
from windbench.geometry.raster import triangle_cell_pairs
from windbench.wind.base import Obstacles, WindField
from windbench.wind.particles import mixing
from windbench.wind.particles.emission import Emitter, emission_specs, emitters_from_scene
from windbench.wind.particles.tracing import (
    BODIES,
    MARK_MODES,
    SOLID,
    BodyCells,
    CellGrid,
    CellState,
    ClothCells,
    GustModel,
    Particles,
    TraceRules,
    TraceStep,
    TraceWork,
    admit_particles,
    euler_velocities,
    expire_cells,
    follow_bodies,
    reached_sources,
    register_bodies,
    register_cloth,
    sort_by_cell,
    trace_gusts,
)
from windbench.wind.primitives import parameter_table
from windbench.wind.registry import WindConfig, register_backend
from windbench.wind.surface_layer import MIXING_LENGTH_LIMIT

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
LEE_MODELS = ("paper", "mixing")
MIXING = ("lee_model", "mixing")  # the keys only the mixing lee reads (config.setting's when)
PAPER_MAX_AGE = 10.0  # s: the paper lee's particles die this old unless wind.max_age says


@dataclass
class ParticleConfig(WindConfig):
    """``wind.*`` keys of the particle-tracing backend (paper §4.2.2; :mod:`.mixing`)."""

    name: str = "particles"
    particles_per_second: float | None = setting(
        None, "s-1", "emission rate per source; null: the particles_per_cell rule", ge=0
    )
    particles_per_cell: float = setting(
        2.0, "1", "automatic rate: new particles per emitter cell per memory window", gt=0
    )
    max_particles: int = setting(1_000_000, "1", "cap on live particles (all sources)", ge=1)
    max_age: float | None = setting(
        None, "s", "older particles die; null: 10 s (paper lee), no limit (mixing lee)", gt=0
    )
    memory: float = setting(
        0.1, "s", "a cell counts as reached this long after its last particle", gt=0
    )
    max_hits: int = setting(
        8, "1", "collisions per particle per step before it waits for the next step", ge=1
    )
    deflected_cells: str = setting(
        "bodies",
        "",
        "paper lee: which hits make a particle's later marks carry w - (n.w) n",
        choices=tuple(MARK_MODES),
    )
    lee_model: str = setting(
        "paper",
        "",
        "paper: reached cells carry w_i, the rest 0; mixing: gusts that mix and keep their flux",
        choices=LEE_MODELS,
    )
    averaging_time: float = setting(
        1.0,
        "s",
        "mixing lee: time constant of each cell's running mean of its wind",
        gt=0,
        when=MIXING,
    )
    mixing_length_limit: float = setting(
        MIXING_LENGTH_LIMIT,
        "m",
        "mixing lee: Blackadar's lambda of the eddy diffusivity",
        gt=0,
        when=MIXING,
    )
    recirculation_backflow: float = setting(
        0.4,
        "1",
        "mixing lee: the wake eddy's backflow at the floor over the wind at the box's top",
        ge=0,
        le=1,
        when=MIXING,
    )
    wake_mixing: float = setting(
        0.05,
        "1",
        "mixing lee: wake eddy diffusivity over (wind at the box's top x height)",
        ge=0,
        when=MIXING,
    )
    recirculation_exponent: float = setting(
        2.0,
        "1",
        "mixing lee: m of the wake eddy's profile (1 - (z/h)^m)^2; backflow below (2m+1)^(-1/m) h",
        ge=1,
        le=50,
        when=MIXING,
    )
    recirculation_height: float = setting(
        1.0,
        "1",
        "mixing lee: the wake cavity's height over the box's height",
        ge=0.5,
        le=3,
        when=MIXING,
    )
    seed: int = setting(0, "1", "random seed (conf/wind/particles.yaml sets ${seed})", ge=0)


def max_age(params) -> float:
    """``wind.max_age`` (s), or without one PAPER_MAX_AGE for the paper lee and no limit for
    the mixing lee, whose particles carry the flux they stand for until they leave."""
    if params.max_age is not None:
        return float(params.max_age)
    return PAPER_MAX_AGE if params.lee_model == "paper" else np.inf


def _check(params) -> None:
    """One ConfigError naming the first bad ``wind.*`` value."""
    check_settings(params, ParticleConfig, "wind.")


@dataclass(frozen=True)
class ParticleModel:
    """What a run fixes: the kernels' tables, the emitters and the limits."""

    tables: GustModel
    emitters: tuple[Emitter, ...]
    capacity: int  # live particles at most
    n_cells: int
    big_grid: bool  # prefetch the cells ahead while particles are sparse
    mixing: mixing.MixingLee | None = None  # wind.lee_model=mixing (None: the paper's lee)


def particle_model(scene, grid, params) -> ParticleModel:
    """Check the ``wind.*`` values and build the model of ``scene`` on ``grid``."""
    _check(params)
    source_kinds, source_params = parameter_table(scene.sources)
    bodies = body_table(scene.bodies)
    cells = CellGrid(
        tuple(float(x) for x in grid.lower),
        tuple(float(x) for x in grid.upper),
        float(grid.h),
        tuple(int(n) for n in grid.shape),
    )
    start, items = register_bodies(bodies, cells)
    rules = TraceRules(
        max_age=max_age(params),
        memory=float(params.memory),
        delta=CONTACT_OFFSET * float(grid.h),
        max_hits=int(params.max_hits),
        mark_mode=MARK_MODES[params.deflected_cells],
    )
    tables = GustModel(cells, source_kinds, source_params, BodyCells(bodies, start, items), rules)
    emitters = emitters_from_scene(scene, grid, params, int(params.seed))
    lee = mixing.mixing_lee(scene, grid, params, emitters) if params.lee_model == "mixing" else None
    return ParticleModel(
        tables=tables,
        emitters=emitters,
        capacity=int(params.max_particles),
        n_cells=grid.n_cells,
        big_grid=grid.n_cells >= PREFETCH_CELLS,
        mixing=lee,
    )


@dataclass(frozen=True)
class ParticleState:
    """What changes: the live particles 0..n-1 of buffers grown on demand, the per-cell
    marks, values and u (:class:`~.tracing.CellState`), the cells the cloth flagged last
    step, the emission counters and the cells marked in each of the last steps (their
    marks lapse ``memory`` later). The arrays are large and the kernels update them in
    place; :func:`advance` returns the state with the rest replaced."""

    time: float
    steps: int
    n: int
    particles: Particles
    cells: CellState
    cloth_cells: np.ndarray  # cells with the TRIANGLES flag
    carry: np.ndarray  # (n_sources,) fraction of a particle carried to the next step
    counter: np.ndarray  # (n_sources,) particles emitted so far
    history: tuple[tuple[float, np.ndarray], ...]
    deposits: np.ndarray  # mixing lee: (n_cells, n_sources, 3) dwell time x wind of the step


def initial_state(model: ParticleModel, solid: np.ndarray) -> ParticleState:
    """No particles, no marks; ``solid`` (n_cells,) the cells whose centre is in a body."""
    n_sources = model.tables.source_kinds.shape[0]
    marked = np.full((model.n_cells, max(n_sources, 1)), -np.inf)
    u = np.zeros((model.n_cells, 3))
    # with one source the values are u itself (u = the value while it is reached)
    values = u.reshape(model.n_cells, 1, 3) if n_sources == 1 else np.zeros((*marked.shape, 3))
    flags = np.zeros(model.n_cells, dtype=np.uint8)
    flags[solid] |= SOLID
    flags[np.diff(model.tables.bodies.start) > 0] |= BODIES
    empty = Particles(np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0))
    return ParticleState(
        time=0.0,
        steps=0,
        n=0,
        particles=empty,
        cells=CellState(flags, marked, values, u),
        cloth_cells=np.zeros(0, dtype=np.int64),
        carry=np.zeros(n_sources),
        counter=np.zeros(n_sources, dtype=np.int64),
        history=(),
        deposits=np.zeros((model.n_cells if model.mixing else 0, max(n_sources, 1), 3)),
    )


@dataclass
class Workspace:
    """Scratch reused from step to step; it carries nothing the numbers depend on."""

    trace: TraceWork  # the tracing kernel's scratch (velocities grown with the particles)
    touched: np.ndarray = field(default_factory=lambda: np.zeros(1024, dtype=np.int64))
    tri_slot: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    blocks: dict = field(default_factory=dict)  # each source's current random sample block

    @classmethod
    def for_model(cls, model: ParticleModel) -> Workspace:
        vectors = (np.empty(3) for _ in range(3))
        max_hits = model.tables.rules.max_hits
        pairs = (np.empty((2, 3)), np.empty((2, 3)), np.empty((max_hits, 3)))
        return cls(TraceWork(np.empty((0, 3)), *vectors, *pairs))

    def velocities(self, n: int) -> TraceWork:
        """The tracing scratch with room for the Euler velocities of n particles."""
        if len(self.trace.velocities) < n:
            size = max(n, 2 * len(self.trace.velocities), 1024)
            self.trace = self.trace._replace(velocities=np.empty((size, 3)))
        return self.trace


def reserve(particles: Particles, n: int, k: int) -> Particles:
    """Buffers (doubled when grown) that hold k more particles after the n live ones."""
    if n + k <= len(particles.positions):
        return particles
    size = max(n + k, 2 * len(particles.positions), 1024)
    grown = []
    for old in particles:
        new = np.zeros((size, *old.shape[1:]), dtype=old.dtype)
        new[:n] = old[:n]
        grown.append(new)
    return Particles(*grown)


def emit(model: ParticleModel, state: ParticleState, work: Workspace, t1: float):
    """Append every source's new particles of [state.time, t1) to the state.

    Returns (state, their durations in the step, candidates dropped): candidates outside
    the grid's half-open box or inside a rigid body are dropped, and so is what exceeds
    ``max_particles``.
    """
    t0 = state.time
    pos, src, dur = [], [], []
    for e in model.emitters:
        block = work.blocks.setdefault(e.source, {})
        first = int(state.counter[e.source])
        p, instants, state.carry[e.source], state.counter[e.source] = e.emit(
            t0, t1, state.carry[e.source], first, block
        )
        keep = model.mixing.kept(e.source, p, first) if model.mixing else None
        if keep is not None:  # the mixing lee's flux weighting of a profile
            p, instants = p[keep], instants[keep]
        pos.append(p)
        src.append(np.full(len(p), e.source, dtype=np.int64))
        dur.append(t1 - instants)
    if not pos:
        return state, np.zeros(0), 0
    if len(pos) > 1:
        pos, src, dur = np.concatenate(pos), np.concatenate(src), np.concatenate(dur)
    else:
        pos, src, dur = pos[0], src[0], dur[0]
    particles = reserve(state.particles, state.n, len(pos))
    durations = np.empty(len(pos))
    room = max(model.capacity - state.n, 0)
    m = admit_particles((pos, src, dur), model.tables, room, state.n, particles, durations)
    return replace(state, n=state.n + m, particles=particles), durations[:m], len(pos) - m


def register_cloth_cells(model, state, work, obstacles: Obstacles):
    """Flag the cells the cloth triangles overlap now; (state, :class:`ClothCells`)."""
    positions = np.ascontiguousarray(obstacles.cloth_positions, dtype=np.float64)
    triangles = np.ascontiguousarray(obstacles.cloth_triangles, dtype=np.int64)
    m = triangles.shape[0]
    if m == 0 and len(state.cloth_cells) == 0:
        empty = (np.zeros((0, 2, 3)), work.tri_slot, np.zeros(1, np.int64), np.zeros(0, np.int64))
        return state, ClothCells(positions, triangles, *empty)
    if len(work.tri_slot) == 0:
        work.tri_slot = np.zeros(model.n_cells, dtype=np.int64)
    g = model.tables.grid
    lower, shape = np.asarray(g.lower), np.asarray(g.shape, dtype=np.int64)
    keys = triangle_cell_pairs(positions, triangles, lower, g.h, shape)
    flagged, start, items = register_cloth(
        keys, max(m, 1), state.cloth_cells, state.cells.flags, work.tri_slot
    )
    corners = positions[triangles]  # (m, 3 corners, 3)
    bounds = np.stack([corners.min(axis=1), corners.max(axis=1)], axis=1)
    cloth = ClothCells(positions, triangles, bounds, work.tri_slot, start, items)
    return replace(state, cloth_cells=flagged), cloth


def expire(model: ParticleModel, state: ParticleState, touched: np.ndarray) -> ParticleState:
    """Keep this step's marked cells; refresh u where marks older than memory lapse."""
    memory = model.tables.rules.memory
    history = (*state.history, (state.time, touched))
    while history and state.time - history[0][0] > memory * (1 + 1e-12) + 1e-12:
        t_mark, cells = history[0]
        expire_cells(cells, t_mark, state.cells, state.time, memory)
        history = history[1:]
    return replace(state, history=history)


def trace_paper(model, state, work, cloth, step: TraceStep) -> tuple[int, int, int]:
    """Steps 2-3 of the paper's lee: (survivors, cell crossings, cells marked)."""
    trace_work = work.velocities(state.n)
    euler_velocities(model.tables, state.particles, state.n, trace_work.velocities)
    work.touched, n_touched, crossings, n_alive = trace_gusts(
        model.tables, cloth, state.cells, state.particles, step, trace_work, work.touched
    )
    return n_alive, crossings, n_touched


def trace_mixed(model, state, work, cloth, step: TraceStep) -> tuple[int, int, int]:
    """The mixing lee's walk (:func:`.mixing.trace_mixing`): (survivors, crossings, 0)."""
    walk = mixing.MixStep(step.dt, step.t_now, step.n, step.n_old, step.new_durations, state.steps)
    n_alive, crossings = mixing.trace_mixing(
        model.tables,
        model.mixing.tables,
        cloth,
        state.cells,
        state.deposits,
        state.particles,
        walk,
        work.trace,
    )
    return n_alive, crossings, 0


def settle(model, state, work, n_touched: int, dt: float) -> ParticleState:
    """Step 4: the paper's marks lapse (:func:`expire`), or the mixing lee's cells take the
    step's deposits into their running mean (:func:`.mixing.blend_cells`)."""
    if model.mixing is None:
        return expire(model, state, work.touched[:n_touched].copy())
    lee = model.mixing
    scale = lee.inverse_density / (model.tables.grid.h**3 * dt)
    factor = -np.expm1(-dt / lee.averaging_time)
    mixing.blend_cells(state.deposits, scale, factor, state.cells.flags, lee.eddy, state.cells.u)
    return state


def advance(model, state, work, dt: float, obstacles: Obstacles):
    """One step of length dt (module docstring, steps 1-4): (next state, figures)."""
    t0 = time.perf_counter()
    n_old, t_end = state.n, state.time + dt
    state, new_durations, dropped = emit(model, state, work, t_end)
    t1 = time.perf_counter()
    state, cloth = register_cloth_cells(model, state, work, obstacles)
    sparse = model.big_grid and state.n < PREFETCH_DENSITY * model.n_cells
    step = TraceStep(dt, t_end, state.n, n_old, new_durations, sparse)
    trace = trace_paper if model.mixing is None else trace_mixed
    n_alive, crossings, n_touched = trace(model, state, work, cloth, step)
    t2 = time.perf_counter()
    state = replace(state, n=n_alive, steps=state.steps + 1, time=t_end)
    if state.steps % SORT_EVERY == 0:
        sort_by_cell(model.tables.grid, state.n, state.particles)
    state = settle(model, state, work, n_touched, dt)
    t3 = time.perf_counter()
    figures = {
        "dropped_particles": float(dropped),
        "live_particles": float(state.n),
        "emitted_particles": float(len(new_durations)),
        "cell_crossings": float(crossings),
        "particle_steps_per_second": step.n / (t2 - t1) if t2 > t1 else 0.0,
        "emit_seconds": t1 - t0,
        "trace_seconds": t2 - t1,
        "assemble_seconds": t3 - t2,
    }
    return state, figures


@register_backend("particles", config=ParticleConfig)
class ParticleWind(WindField):
    """Gust particles per source; u = sum of the reached sources' w_i (module docstring)."""

    compiles_kernels = True
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
        specs = emission_specs(scene)
        if params.lee_model == "mixing":
            mixing.check_sources(scene, specs)

    @classmethod
    def memory(cls, scene, grid, params, dt) -> dict[str, tuple[float, str]]:
        """Live particles (at most ``max_particles``, at most rate x ``max_age``), one step's
        emission candidates, and the per-source cell marks of a multi-source scene."""
        rate = sum(e.rate for e in emitters_from_scene(scene, grid, params, int(params.seed)))
        live = min(float(params.max_particles), rate * max_age(params))
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
        self.model = particle_model(scene, grid, params)
        self.state = initial_state(self.model, self.solid_mask().reshape(-1))
        self.workspace = Workspace.for_model(self.model)
        self._stats: dict[str, float] = {}

    @property
    def time(self) -> float:
        return self.state.time

    def step(self, dt: float, obstacles: Obstacles) -> None:
        if self.moving:  # the particles meet the bodies at the step's end
            t = self.state.time + dt
            self.pose_solid(t)
            solid = self.solid_mask().reshape(-1)
            st = self.state
            tables = follow_bodies(
                self.model.tables, self.scene.bodies, t, (st.cells, st.particles, st.n), solid
            )
            self.model = replace(self.model, tables=tables)
        self.state, self._stats = advance(self.model, self.state, self.workspace, dt, obstacles)

    def add_particles(self, positions, sources):
        """Insert particles (tests, benchmarks); the next step traces them for its full dt."""
        positions = np.atleast_2d(np.asarray(positions, dtype=np.float64))
        n, k = self.state.n, len(positions)
        particles = reserve(self.state.particles, n, k)
        particles.positions[n : n + k] = positions
        particles.sources[n : n + k] = np.asarray(sources, dtype=np.int64)
        particles.ages[n : n + k] = 0.0
        self.state = replace(self.state, n=n + k, particles=particles)

    # ---------------------------------------------------------------- queries
    def velocity(self) -> np.ndarray:
        """u on the cells (read-only view of the backend's state)."""
        u = self.state.cells.u.reshape(*self.grid.shape, 3)
        u.flags.writeable = False
        return u

    def stats(self) -> dict[str, float]:
        return dict(self._stats)

    def reached(self) -> np.ndarray:
        """``(n_sources, nx, ny, nz)`` bool: cells each source reached within ``memory``."""
        marked = self.state.cells.marked
        out = np.zeros(marked.shape, dtype=np.bool_)
        reached_sources(marked, self.state.time, self.model.tables.rules.memory, out)
        return out.T.reshape(marked.shape[1], *self.grid.shape)[: len(self.scene.sources)]

    def ever_reached(self) -> np.ndarray:
        """``(nx, ny, nz)`` bool: cells any particle has marked since the start."""
        return np.isfinite(self.state.cells.marked).any(axis=1).reshape(self.grid.shape)

    @property
    def particles(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Live particles: positions ``(n, 3)``, source ids ``(n,)``, ages ``(n,)`` (copies)."""
        n = self.state.n
        return tuple(buffer[:n].copy() for buffer in self.state.particles)
