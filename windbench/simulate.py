"""The coupled step loop: one config -> one run -> one dataset.

``prepare(cfg)`` checks every input and builds the model (scene, grid, parameters) before
any work; :class:`Simulation` owns the loop, the NaN check and the recorder; ``run`` writes
the dataset. Per step (paper §4.1.2's order): the wind advances with the current cloth as
obstacle, the wind is sampled at the cloth vertices, the §3 forces are computed and handed
to the cloth solver.
"""

from __future__ import annotations

import logging
import math
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from windbench import compile_ahead, metrics, runtime
from windbench.aero import AeroParams, cloth_forces
from windbench.cloth import check_cloth_solver, make_cloth_solver
from windbench.cloth.model import ClothModel, ClothState
from windbench.config import check_values
from windbench.dataset import git_commit, run_dataset, write_atomic
from windbench.errors import ConfigError, SimulationDiverged
from windbench.geometry.bodies import inside
from windbench.grid import Grid
from windbench.scenes import Scene, build_scene
from windbench.wind import backend_class, make_wind
from windbench.wind.base import Obstacles
from windbench.wind.primitives import superpose

log = logging.getLogger("windbench")
MEMORY_FRACTION = 0.8  # of physical memory a run may plan to use
# Memory budget per unit of what a user number scales (bytes; generous, not measured):
BYTES_PER_CELL = 40 * 8  # wind state of the heaviest backend: 40 float64 values per cell
BYTES_PER_VERTEX = 1024  # cloth solver: state, edges, hinges, tethers, orderings per vertex
RECORD_COPIES = 2  # recorded arrays exist twice while the dataset is assembled
RECORDED_SCALARS = 64  # per-step figures and phase times (a generous count), float64 each
FILENAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*\.nc")


@dataclass(frozen=True)
class FramePlan:
    """The steps that keep an animation frame (``output.frames``) and the wind slice's layer."""

    steps: frozenset[int]  # step numbers n + 1 (a frame at t = (n + 1) dt)
    layer: int  # z index of the horizontal wind slice
    height: float  # m, that layer's cell-centre height


@dataclass(frozen=True)
class RunSetup:
    """The checked model of one run: nothing here changes while it runs."""

    cfg: DictConfig
    scene: Scene
    grid: Grid
    aero: AeroParams
    cloth: ClothModel
    dt: float
    n_steps: int  # recorded steps
    spinup_steps: int  # steps before recording starts
    snapshot_steps: tuple[int, ...]
    probe_points: dict[str, np.ndarray]
    cfl: float  # fastest source speed x dt / h
    frames: FramePlan
    flow_through_time: float  # s: domain length along the wind / reference speed
    analysis_start: float  # s: start of the steady window the statistics are taken over
    wake: tuple | None  # (points, direction, u0) of the scene's wake probe

    @property
    def start_time(self) -> float:
        """Simulated time at which recording starts (the end of the spin-up)."""
        return self.spinup_steps * self.dt

    @property
    def end_time(self) -> float:
        """Simulated time of the last recorded step (the end of the steady window)."""
        return (self.spinup_steps + self.n_steps) * self.dt


def _require(cond: bool, key: str, message: str):
    if not cond:
        raise ConfigError(key, message)


def prepare(cfg: DictConfig) -> RunSetup:
    """Check the whole config and build the model; raise ConfigError on the first fault.

    Order: numbers (finite, in range), step count, file name, then every allocation that
    scales with a user number is estimated (:func:`memory_plan`) before it is made.
    """
    check_values(cfg)
    dt = float(cfg.sim.dt)
    # a bad number is refused before any mesh is built
    _seconds(cfg.sim.duration, "sim.duration", math.nan, positive=True)
    _seconds(cfg.sim.spinup, "sim.spinup", math.nan)
    check_filename(str(cfg.output.filename))
    runtime.thread_count(cfg.runtime.threads)  # a bad runtime.threads: refused now
    backend = backend_class(cfg.wind.name)  # unknown backend: error listing the allowed ones
    _check_cloth_specs(cfg.scene)  # before the meshes are built
    scene = build_scene(cfg.scene)
    n_steps = _recorded_steps(cfg.sim, scene)
    grid = Grid.from_domain(scene.lower, scene.upper, int(cfg.grid.resolution))  # no arrays yet
    spinup_steps = int(round(_seconds(cfg.sim.spinup, "sim.spinup", _auto_spinup(scene)) / dt))
    _require(
        spinup_steps + n_steps <= cfg.sim.max_steps,
        "sim.spinup",
        f"{spinup_steps} spin-up steps and {n_steps} recorded are more than sim.max_steps = "
        f"{cfg.sim.max_steps}; raise sim.max_steps to run that many",
    )
    flow_through, start = analysis_window(scene, spinup_steps * dt, (spinup_steps + n_steps) * dt)
    model = ClothModel.from_meshes(scene.cloths)
    plan = memory_plan(cfg, scene, grid, model, n_steps)
    _check_memory(plan)
    _check_bodies_resolved(scene, grid)
    for probe in ("lee", "free_stream"):
        _require(
            probe in scene.probes or not scene.probes,
            f"scene.probes.{probe}",
            "is required when a scene has probes (lee and free_stream go together)",
        )
    backend.check(scene, grid, cfg.wind)
    _check_memory({**plan, **backend.memory(scene, grid, cfg.wind, dt)})
    cfl = _check_cfl(scene, grid, dt, backend)
    snaps = np.unique(np.round(np.linspace(0, n_steps, cfg.output.snapshots + 1)[1:]).astype(int))
    check_cloth_solver(cfg.cloth, model)  # unknown solver, bad setting or material: fail now
    return RunSetup(
        cfg=cfg,
        scene=scene,
        grid=grid,
        aero=AeroParams(**OmegaConf.to_container(cfg.aero)),
        cloth=model,
        dt=dt,
        n_steps=n_steps,
        spinup_steps=spinup_steps,
        snapshot_steps=tuple(int(s) for s in snaps if s >= 1),
        probe_points={k: b.lattice(int(cfg.output.probe_points)) for k, b in scene.probes.items()},
        cfl=cfl,
        frames=plan_frames(cfg.output.frames, scene, grid, dt, n_steps),
        flow_through_time=flow_through,
        analysis_start=start,
        wake=_wake_reference(scene),
    )


FLOW_THROUGHS = 2.0  # the wind has crossed the domain this many times before statistics


def flow_through_time(scene: Scene) -> float:
    """T = L / U_ref: L the domain's extent along the fastest uniform source, U_ref the
    scene's reference speed; NaN for a scene without a uniform source (no flow through)."""
    uniform = [s for s in scene.sources if s.kind == "uniform" and s.speed_scale() > 0]
    if not uniform:
        return math.nan
    fastest = max(uniform, key=lambda s: s.speed_scale())
    direction = np.abs(np.asarray(fastest.velocity)) / fastest.speed_scale()
    return float(direction @ (scene.upper - scene.lower)) / scene.reference_speed


def analysis_window(scene: Scene, start: float, end: float) -> tuple[float, float]:
    """(flow-through time T, start of the steady window) of a run recording [start, end].

    Statistics are taken over t >= max(start, 2 T): by then the wind has crossed the
    domain twice (the particle front at least once, since particles move with the
    sources' own wind) and the start-up transient has left it. A scene whose air does not
    flow through keeps the second half of the recorded time.
    """
    flow_through = flow_through_time(scene)
    if not np.isfinite(flow_through):
        return flow_through, start + 0.5 * (end - start)
    return flow_through, max(start, FLOW_THROUGHS * flow_through)


def window_block(t: float, start: float, end: float, blocks: int) -> int:
    """Which of ``blocks`` equal blocks of the steady window (start, end] time t is in:
    ceil(blocks (t - start) / (end - start)) - 1, clipped to the blocks (t = start is in
    the first). The block means give the time mean's sampling error (batch means,
    :func:`windbench.report.lee.time_mean_error`)."""
    fraction = (t - start) / (end - start) if end > start else 1.0
    return min(blocks - 1, max(0, math.ceil(fraction * blocks - 1e-9) - 1))


MIN_WINDOW = 1.0  # s: sim.duration=auto records at least this long (without flow through: this)


def _auto_spinup(scene: Scene) -> float:
    """``sim.spinup=auto``: FLOW_THROUGHS flow-through times (0 for a scene without flow
    through), so that recording starts with a developed wind."""
    flow_through = flow_through_time(scene)
    return FLOW_THROUGHS * flow_through if np.isfinite(flow_through) else 0.0


def _auto_duration(scene: Scene, flow_throughs: float) -> float:
    """``sim.duration=auto``: the steady window spans ``flow_throughs``
    (``sim.window_flow_throughs``) flow-through times, at least MIN_WINDOW. A time mean
    over a separated wake needs several of its shedding periods (about H / (0.2 U) behind
    an obstacle of height H), which one flow-through time of a domain reaching several H
    behind the obstacle holds; its sampling noise (``lee_noise``) falls as
    1 / sqrt(window)."""
    flow_through = flow_through_time(scene)
    window = flow_throughs * flow_through if np.isfinite(flow_through) else 0.0
    return max(window, MIN_WINDOW)


def _seconds(value, key: str, auto: float, positive: bool = False) -> float:
    """``value`` of ``key`` in seconds: ``auto`` becomes ``auto``; anything else must be a
    finite number >= 0 (> 0 where ``positive``)."""
    if str(value) == "auto":
        return auto
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        seconds = math.nan
    _require(
        np.isfinite(seconds) and (seconds > 0 if positive else seconds >= 0),
        key,
        f"must be 'auto' or a number of seconds {'>' if positive else '>='} 0, got {value!r}",
    )
    return seconds


def _recorded_steps(sim, scene: Scene) -> int:
    """Steps recorded after the spin-up: ``sim.duration / sim.dt``, at most ``sim.max_steps``."""
    dt = float(sim.dt)
    auto = _auto_duration(scene, float(sim.window_flow_throughs))
    duration = _seconds(sim.duration, "sim.duration", auto, positive=True)
    _require(duration >= dt, "sim.duration", f"must be at least sim.dt = {dt} s, got {duration}")
    n_steps = int(round(duration / dt))
    _require(
        n_steps <= sim.max_steps,
        "sim.dt",
        f"{dt} s over sim.duration = {duration:.6g} s is {n_steps} steps, more than "
        f"sim.max_steps = {sim.max_steps}; raise sim.max_steps to run that many",
    )
    return n_steps


def _wake_reference(scene: Scene):
    """(points, direction, u0) of the scene's wake probe: u0 is the undisturbed wind of the
    sources along the probe's direction at each point (``None`` without a probe)."""
    if scene.wake is None:
        return None
    points = scene.wake.points()
    u0 = superpose(scene.sources, points.reshape(-1, 3)) @ scene.wake.direction
    if np.any(u0 <= 0):
        raise ConfigError("scene.wake", "the sources' wind must blow along its direction there")
    return points, scene.wake.direction, u0.reshape(points.shape[:-1])


def plan_frames(frames, scene: Scene, grid: Grid, dt: float, n_steps: int) -> FramePlan:
    """Every ``round(interval / dt)``-th step (at least every step) and the last one keep a
    frame; the slice is the cell layer nearest to ``height`` (default: the lee box's centre,
    else mid-domain)."""
    interval = float(frames.interval)
    _require(
        np.isfinite(interval) and interval >= 0,
        "output.frames.interval",
        f"must be >= 0 seconds (0: no frames), got {interval}",
    )
    lo, hi = float(scene.lower[2]), float(scene.upper[2])
    height = frames.height
    if height is None:
        lee = scene.probes.get("lee")
        height = 0.5 * (lee.lower[2] + lee.upper[2]) if lee is not None else 0.5 * (lo + hi)
    height = float(height)
    _require(
        lo <= height <= hi,
        "output.frames.height",
        f"must lie in the domain's z range [{lo:g}, {hi:g}] m, got {height}",
    )
    layer = int(np.clip(np.floor((height - lo) / grid.h), 0, grid.shape[2] - 1))
    steps: set[int] = set()
    if interval > 0:
        every = max(1, int(round(interval / dt)))
        steps = set(range(every, n_steps + 1, every)) | {n_steps}
    return FramePlan(frozenset(steps), layer, lo + (layer + 0.5) * grid.h)


def reached_box(cells: np.ndarray, grid: Grid) -> np.ndarray:
    """``(2, 3)``: the lowest and highest cell centre, per axis, of the cells that are True
    (nan where none is)."""
    box = np.full((2, 3), np.nan)
    for a in range(3):
        idx = np.flatnonzero(cells.any(axis=tuple(b for b in range(3) if b != a)))
        if idx.size:
            box[:, a] = grid.lower[a] + (idx[[0, -1]] + 0.5) * grid.h
    return box


def check_filename(name: str) -> None:
    """``output.filename`` must name a file inside the run folder: no folders, no hidden or
    temporary names (a leading dot is what :func:`windbench.dataset.temporary_name` uses)."""
    _require(
        FILENAME.fullmatch(name) is not None,
        "output.filename",
        f"must be a plain file name ending in .nc (letters, digits, '.', '_', '-'; no '/' "
        f"and no leading '.'), written inside the run folder; got {name!r}",
    )


def memory_bytes() -> int:
    """Physical memory of this machine (bytes)."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


Plan = dict[str, tuple[float, str]]  # config key -> (bytes, what it holds)


def memory_plan(cfg: DictConfig, scene: Scene, grid: Grid, cloth: ClothModel, n_steps: int) -> Plan:
    """Bytes a run holds at its peak, by the config key whose number each share scales with
    (a backend adds its own, :meth:`WindField.memory`)."""
    n_cells, n_vertices = float(grid.n_cells), float(cloth.n_vertices)
    n_snap = min(int(cfg.output.snapshots), n_steps)
    n_probes = float(len(scene.probes)) * float(cfg.output.probe_points) ** 3
    per_step = 8.0 * (3 * n_vertices + 3 * cloth.n_cloths + RECORDED_SCALARS)
    return {
        "grid.resolution": (
            n_cells * BYTES_PER_CELL,
            f"{cfg.grid.resolution} gives {grid.n_cells} cells",
        ),
        "output.snapshots": (
            n_snap * n_cells * 24.0 * RECORD_COPIES,
            f"{n_snap} wind snapshots of {grid.n_cells} cells",
        ),
        "output.probe_points": (  # lattice, samples of a step, one per snapshot
            n_probes * 24.0 * (2 + n_snap * RECORD_COPIES),
            f"{cfg.output.probe_points}^3 probe points in each of {len(scene.probes)} boxes",
        ),
        "scene.cloths": (n_vertices * BYTES_PER_VERTEX, f"{cloth.n_vertices} cloth vertices"),
        "sim.duration": (
            n_steps * per_step * RECORD_COPIES,
            f"{n_steps} steps x {per_step / 2**20:.3g} MiB recorded per step",
        ),
    }


def _check_cloth_specs(scene_cfg) -> None:
    """Refuse a cloth whose ``resolution`` alone (vertices at least) exceeds the memory
    allowed, before its mesh is built."""
    for i, spec in enumerate(scene_cfg.get("cloths") or ()):
        res = spec.get("resolution") if hasattr(spec, "get") else None
        if res is None or len(res) != 2:
            continue  # the mesh builder names what is missing
        vertices = float(np.prod([float(v) for v in res]))
        _check_memory(
            {f"scene.cloths[{i}].resolution": (vertices * BYTES_PER_VERTEX, f"{list(res)}")}
        )


def _check_memory(plan: Plan) -> None:
    """The planned shares must fit in MEMORY_FRACTION of this machine's memory; the error
    names the key of the largest share and lists the others."""
    total = sum(b for b, _ in plan.values())
    limit = MEMORY_FRACTION * memory_bytes()
    if total <= limit:
        return
    gib = 2.0**30
    shares = sorted(plan.items(), key=lambda kv: -kv[1][0])
    key, (_, what) = shares[0]
    others = ", ".join(f"{k} {b / gib:.3g}" for k, (b, _) in shares[1:] if b >= 0.01 * gib)
    raise ConfigError(
        key,
        f"{what}: the run would need about {total / gib:.3g} GiB"
        + (f" (other shares in GiB: {others})" if others else "")
        + f"; this machine allows {limit / gib:.3g} GiB",
    )


def _check_cfl(scene: Scene, grid: Grid, dt: float, backend) -> float:
    """CFL = U dt / h with U the fastest source (or wall) speed; warn or refuse.

    Above the backend's ``max_cfl`` a warning is logged (accuracy suffers); when the wind
    would cross the whole domain in one step the run is meaningless and refused.
    """
    speeds = [s.speed_scale() for s in scene.sources]
    speeds += [float(np.linalg.norm(v)) for v in scene.wall_velocity.values()]
    speed = max(speeds, default=0.0)
    cfl = speed * dt / grid.h
    longest = float((scene.upper - scene.lower).max())
    if speed * dt > longest:  # (speed > 0 here: a still scene passes)
        raise ConfigError(
            "sim.dt",
            f"{dt} s lets the wind ({speed:.3g} m/s) cross the whole domain ({longest} m) in "
            f"one step (CFL {cfl:.3g}); use sim.dt <= {longest / speed:.3g}",
        )
    if cfl > backend.max_cfl:
        log.warning(
            "CFL number %.3g exceeds %.3g, the stable range of backend %s",
            cfl,
            backend.max_cfl,
            backend.name,
        )
    else:
        log.info("CFL number %.3g", cfl)
    return cfl


def _check_bodies_resolved(scene: Scene, grid: Grid):
    """Each finite body must hold at least one cell centre, or the grid cannot see it."""
    centres = grid.cell_centres().reshape(-1, 3)
    for i, body in enumerate(scene.bodies):
        if body.kind == "plane" or not body.resolve:
            continue
        if not inside([body], centres).any():
            lo, hi = body.bounds()
            thinnest = float((hi - lo).min())
            need = int(np.ceil(2 * (scene.upper - scene.lower).max() / thinnest))
            raise ConfigError(
                "grid.resolution",
                f"{grid.shape} cells (h = {grid.h:.3g} m) cannot resolve scene.bodies[{i}] "
                f"({body.kind}, thinnest side {thinnest:.3g} m): use at least {need}",
            )


class Recorder:
    """Collects per-step figures and snapshots (:func:`windbench.dataset.run_dataset` turns
    them into the run dataset); ``units`` holds the long_name and units of the figures the
    backend and the cloth solver record (their ``stats_units``)."""

    def __init__(self, setup: RunSetup):
        self.setup = setup
        self.units: dict[str, tuple[str, str]] = {}
        self.times: list[float] = []
        self.rows: dict[str, list] = {}
        self.phases: dict[str, list[float]] = {}
        self.snap_times: list[float] = []
        self.snap_wind: list[np.ndarray] = []
        self.snap_probe: list[np.ndarray] = []
        self.probe_sum: np.ndarray | None = None  # probe wind summed over the steady window
        self.probe_count = 0
        self.block_sum: np.ndarray | None = None  # the same per block of the window
        self.block_count = np.zeros(int(setup.cfg.output.window_blocks), dtype=np.int64)
        self.frame_times: list[float] = []
        self.frame_data: dict[str, list[np.ndarray]] = {}
        self.load_average: dict[str, list[float]] = {}  # "start"/"end": 1, 5, 15 min

    def add(self, name: str, value):
        self.rows.setdefault(name, []).append(value)

    def add_phase(self, phase: str, seconds: float):
        """A backend's sub-phase time (``stats()`` keys ending in ``_seconds``)."""
        self.phases.setdefault(phase, []).append(seconds)

    def snapshot(self, t: float, wind: np.ndarray, probe_wind: np.ndarray):
        self.snap_times.append(t)
        self.snap_wind.append(np.array(wind, dtype=np.float64))
        self.snap_probe.append(probe_wind)

    def accumulate_probes(self, t: float, probe_wind: np.ndarray):
        """Add the probe wind of a step to the steady-window mean (t >= analysis_start) and
        to the mean of its block of the window (:func:`window_block`)."""
        if t < self.setup.analysis_start - 1e-9:
            return
        if self.probe_sum is None:
            self.probe_sum = np.zeros_like(probe_wind)
            self.block_sum = np.zeros((len(self.block_count), *probe_wind.shape))
        self.probe_sum += probe_wind
        self.probe_count += 1
        block = window_block(
            t, self.setup.analysis_start, self.setup.end_time, len(self.block_count)
        )
        self.block_sum[block] += probe_wind
        self.block_count[block] += 1

    def frame(self, t: float, arrays: dict[str, np.ndarray]):
        """One animation frame: arrays named in :data:`windbench.dataset.FRAME_VARIABLES`."""
        self.frame_times.append(t)
        for name, value in arrays.items():
            self.frame_data.setdefault(name, []).append(np.array(value))


class Simulation:
    """Owns the loop: wind, aerodynamics, cloth, figures, NaN checks."""

    def __init__(
        self,
        setup: RunSetup,
        recorder: Recorder | None = None,
        budget: runtime.ThreadBudget | None = None,
    ):
        self.setup = setup
        self.recorder = recorder or Recorder(setup)
        self.budget = budget or runtime.ThreadBudget.as_set()  # numba threads per step
        self.wind = make_wind(setup.cfg.wind, setup.scene, setup.grid)
        self.cloth_solver = make_cloth_solver(setup.cfg.cloth, setup.cloth, setup.scene.bodies)
        self.state: ClothState = setup.cloth.initial_state()
        self.mobility = self.cloth_solver.mobility()  # m^2/kg per vertex
        for producer in (self.wind, self.cloth_solver):
            self.recorder.units.update(getattr(producer, "stats_units", {}))

    def obstacles(self) -> Obstacles:
        return Obstacles(
            self.setup.scene.bodies,
            self.state.positions,
            self.state.velocities,
            self.setup.cloth.triangles,
            float(self.setup.aero.air_density) * self.mobility,
        )

    def step(self, n: int):
        s = self.setup
        if s.cfg.sim.fail_at_step is not None and n + 1 >= s.cfg.sim.fail_at_step:
            raise SimulationDiverged(n + 1, "fault injected by sim.fail_at_step (testing)")
        self.budget.update()
        c0, t0 = time.process_time(), time.perf_counter()
        self.wind.step(s.dt, self.obstacles())
        t1 = time.perf_counter()
        vertex_wind = (
            self.wind.sample(self.state.positions) if s.cloth.n_vertices else np.zeros((0, 3))
        )
        tri_f, vert_f = cloth_forces(
            self.state.positions,
            self.state.velocities,
            vertex_wind,
            s.cloth.triangles,
            self.wind.cloth_pressure_loads(),  # the air's own pressure (projection coupling)
            s.aero,
        )
        t2 = time.perf_counter()
        self.state = self.cloth_solver.step(self.state, vert_f, s.dt)
        t3, c3 = time.perf_counter(), time.process_time()
        if n < s.spinup_steps:  # spin-up: the wind develops, nothing is recorded
            self._check_finite(n, self.wind.velocity())
            return
        self._record(n, tri_f, (t1 - t0, t2 - t1, t3 - t2, t3 - t0), c3 - c0)

    def _record(self, n: int, tri_f, seconds, cpu_seconds: float):
        s, rec = self.setup, self.recorder
        u = self.wind.velocity()
        self._check_finite(n, u)
        rec.times.append((n + 1) * s.dt)
        rec.add("step_seconds", seconds)
        rec.add("step_cpu_seconds", cpu_seconds)
        rec.add("step_threads", self.budget.current)
        forces = s.cloth.per_cloth_sum(tri_f)
        rec.add("aero_force", forces)
        rec.add("cloth_position", self.state.positions.copy())
        div = self.wind.divergence()
        if div is None:
            div = metrics.central_divergence_field(u, self.wind.solid_mask(), s.grid.h)
        div_rms, div_max = metrics.divergence_figures(div, s.grid.h, s.scene.reference_speed)
        rec.add("divergence_rms", div_rms)
        rec.add("divergence_max", div_max)
        probe_wind = {k: self.wind.sample(p) for k, p in s.probe_points.items()}
        if probe_wind:
            rec.add(
                "lee_speed_ratio", metrics.speed_ratio(probe_wind["lee"], probe_wind["free_stream"])
            )
        if s.scene.lee_force:
            shel, expo = (s.scene.cloth_index(c) for c in s.scene.lee_force)
            rec.add("lee_force_ratio", metrics.force_ratio(forces[shel], forces[expo]))
        if s.wake is not None:
            points, direction, u0 = s.wake
            along = self.wind.sample(points.reshape(-1, 3)) @ direction
            rec.add("wake_speed_ratio", (along.reshape(u0.shape) / u0).mean(axis=-1))
        for key, value in {**self.wind.stats(), **self.cloth_solver.stats(self.state)}.items():
            if key.endswith("_seconds"):  # a backend's own phase, e.g. advect_seconds
                rec.add_phase(key.removesuffix("_seconds"), float(value))
            else:
                rec.add(key, float(value))
        pts = sorted(probe_wind)
        probes = np.concatenate([probe_wind[k] for k in pts]) if pts else np.zeros((0, 3))
        rec.accumulate_probes((n + 1) * s.dt, probes)
        recorded = n + 1 - s.spinup_steps  # steps since recording started
        if recorded in s.snapshot_steps:
            rec.snapshot((n + 1) * s.dt, u, probes)
        if recorded in s.frames.steps:
            rec.frame((n + 1) * s.dt, self._frame(u, tri_f))

    def _frame(self, u: np.ndarray, tri_f: np.ndarray) -> dict[str, np.ndarray]:
        """The wind slice, the force on each triangle and, where the backend tracks it
        (``ever_reached``), which cells of the slice the wind has reached."""
        k = self.setup.frames.layer
        out = {"slice_wind": u[:, :, k, :], "triangle_force": tri_f}
        reached = getattr(self.wind, "ever_reached", None)
        if reached is not None:
            cells = reached()
            out["slice_reached"] = cells[:, :, k].astype(np.int8)
            out["reached_box"] = reached_box(cells, self.setup.grid)
        return out

    def _check_finite(self, n: int, u: np.ndarray):
        if not np.isfinite(u).all():
            raise SimulationDiverged(n + 1, "wind field is not finite (NaN or inf)")
        if not np.isfinite(self.state.positions).all():
            raise SimulationDiverged(n + 1, "cloth positions are not finite (NaN or inf)")

    def run(self, progress: bool = True, first_step_done=None) -> Recorder:
        """All steps, spin-up included; ``progress``: a bar on a terminal, else a log
        line every tenth of the run (:class:`windbench.runtime.ProgressLog`), either
        saying when the run gave threads up (:meth:`windbench.runtime.ThreadBudget.note`);
        ``first_step_done()``, if given, is called once after the first step."""
        total = self.setup.spinup_steps + self.setup.n_steps
        label = f"{self.setup.scene.name}/{self.wind.name}"
        terminal = sys.stderr.isatty()
        bar = tqdm(
            range(total), desc=label, unit="step", disable=not (progress and terminal),
            mininterval=1.0,
        )  # fmt: skip
        lines = runtime.ProgressLog(label, total) if progress and not terminal else None
        shown = ""  # the bar's note
        for n in bar:
            self.step(n)
            if n == 0:  # every kernel compiled or loaded
                if first_step_done is not None:
                    first_step_done()
                self.budget.restart()
            note = self.budget.note()
            if lines is not None:
                lines.update(n + 1, note)
            elif note != shown and not bar.disable:
                bar.set_postfix_str(shown := note, refresh=False)
        return self.recorder


@dataclass
class RunResult:
    path: Path
    status: str
    failure: str = ""


def run(cfg: DictConfig, out_dir: Path, jobs: int = 1) -> RunResult:
    """Check, simulate and write ``out_dir/windbench.nc`` (status complete or failed).

    A ConfigError is raised before anything is written. The run's kernels use
    ``runtime.threads`` threads, ``auto`` sharing the cores with the ``jobs`` runs a
    launcher has in flight (:func:`windbench.runtime.thread_count`) and kept to the cores
    other processes leave free where that is faster (:class:`windbench.runtime.ThreadBudget`,
    which the dataset's ``numba_threads`` records as planned). A blow-up or any
    other exception during the loop writes what was recorded with ``status = failed`` and
    the reason.
    """
    budget = runtime.ThreadBudget.of(cfg.runtime.threads, jobs)  # before any kernel
    with compile_ahead.cloth_kernels(cfg, jobs) as helper:
        return _run(cfg, out_dir, helper, budget)


def _run(cfg: DictConfig, out_dir: Path, helper, budget: runtime.ThreadBudget) -> RunResult:
    """:func:`run` once its thread ``budget`` is set and the compile ``helper`` (or None)
    started, which is stopped once the first step is done: the run's kernels are all there
    then."""
    setup = prepare(cfg)
    path = Path(out_dir) / cfg.output.filename
    git_commit()  # the code as loaded now, before the loop (cached)
    recorder = Recorder(setup)
    recorder.load_average["start"] = runtime.load_average()
    status, reason = "complete", ""
    try:
        Simulation(setup, recorder, budget).run(
            progress=bool(cfg.sim.progress), first_step_done=lambda: compile_ahead.stop(helper)
        )
    except Exception as err:  # noqa: BLE001 - recorded, then reported by the caller
        reason = str(err) if isinstance(err, SimulationDiverged) else f"{type(err).__name__}: {err}"
        log.error("run failed: %s", reason)
        status = "failed"
    budget.restore()  # the dataset's numba_threads: the run's planned count
    recorder.load_average["end"] = runtime.load_average()
    write_atomic(run_dataset(setup, recorder, status, reason), path)
    return RunResult(path, status, reason)
