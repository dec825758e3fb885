"""The coupled step loop: one config -> one run -> one dataset.

``prepare(cfg)`` checks every input and builds the model (scene, grid, parameters) before
any work; :class:`Simulation` owns the loop, the NaN check and the recorder; ``run`` writes
the dataset. Per step (paper §4.1.2's order): the wind advances with the current cloth as
obstacle, the wind is sampled at the cloth vertices, the §3 forces are computed and handed
to the cloth solver.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from windbench import metrics
from windbench.aero import AeroParams, aerodynamic_forces
from windbench.cloth import check_cloth_solver, make_cloth_solver
from windbench.cloth.model import ClothModel, ClothState
from windbench.dataset import annotate, git_commit, package_versions, runtime_info, write_atomic
from windbench.errors import ConfigError, SimulationDiverged
from windbench.geometry.bodies import inside
from windbench.grid import Grid
from windbench.scenes import Scene, build_scene
from windbench.wind import backend_class, make_wind
from windbench.wind.base import Obstacles

log = logging.getLogger("windbench")
PHASES = ("wind", "aero", "cloth", "total")
BYTES_PER_CELL = 40 * 8  # budget of the heaviest backend: 40 float64 values per cell
MEMORY_FRACTION = 0.8  # of physical memory a run may plan to use


@dataclass(frozen=True)
class RunSetup:
    """The checked model of one run: nothing here changes while it runs."""

    cfg: DictConfig
    scene: Scene
    grid: Grid
    aero: AeroParams
    cloth: ClothModel
    dt: float
    n_steps: int
    snapshot_steps: tuple[int, ...]
    probe_points: dict[str, np.ndarray]
    cfl: float  # fastest source speed x dt / h


def _require(cond: bool, key: str, message: str):
    if not cond:
        raise ConfigError(key, message)


def prepare(cfg: DictConfig) -> RunSetup:
    """Check the whole config and build the model; raise ConfigError on the first fault."""
    dt, duration = float(cfg.sim.dt), float(cfg.sim.duration)
    _require(np.isfinite(dt) and dt > 0, "sim.dt", f"must be > 0 seconds, got {dt}")
    _require(duration >= dt, "sim.duration", f"must be at least sim.dt = {dt} s, got {duration}")
    _require(
        cfg.output.snapshots >= 1, "output.snapshots", f"must be >= 1, got {cfg.output.snapshots}"
    )
    _require(cfg.output.probe_points >= 1, "output.probe_points", "must be >= 1")
    backend = backend_class(cfg.wind.name)  # unknown backend: error listing the allowed ones
    scene = build_scene(cfg.scene)
    grid = Grid.from_domain(scene.lower, scene.upper, int(cfg.grid.resolution))  # no arrays yet
    _check_memory(grid, int(cfg.grid.resolution))
    _check_bodies_resolved(scene, grid)
    for probe in ("lee", "free_stream"):
        _require(
            probe in scene.probes or not scene.probes,
            f"scene.probes.{probe}",
            "is required when a scene has probes (lee and free_stream go together)",
        )
    backend.check(scene, grid, cfg.wind)
    cfl = _check_cfl(scene, grid, dt, backend)
    n_steps = int(round(duration / dt))
    snaps = np.unique(np.round(np.linspace(0, n_steps, cfg.output.snapshots + 1)[1:]).astype(int))
    model = ClothModel.from_meshes(scene.cloths)
    check_cloth_solver(cfg.cloth, model)  # unknown solver, bad setting or material: fail now
    return RunSetup(
        cfg=cfg,
        scene=scene,
        grid=grid,
        aero=AeroParams(**OmegaConf.to_container(cfg.aero)),
        cloth=model,
        dt=dt,
        n_steps=n_steps,
        snapshot_steps=tuple(int(s) for s in snaps if s >= 1),
        probe_points={k: b.lattice(int(cfg.output.probe_points)) for k, b in scene.probes.items()},
        cfl=cfl,
    )


def memory_bytes() -> int:
    """Physical memory of this machine (bytes)."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def _check_memory(grid: Grid, resolution: int):
    """The grid must fit in memory at BYTES_PER_CELL; say how much it would need."""
    need = float(grid.n_cells) * BYTES_PER_CELL
    limit = MEMORY_FRACTION * memory_bytes()
    _require(
        need <= limit,
        "grid.resolution",
        f"{resolution} gives {grid.n_cells} cells needing about {need / 2**30:.1f} GiB "
        f"({BYTES_PER_CELL // 8} float64 per cell); this machine allows {limit / 2**30:.1f} GiB",
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
    """Collects per-step figures and snapshots; turns them into the run dataset."""

    def __init__(self, setup: RunSetup):
        self.setup = setup
        self.times: list[float] = []
        self.rows: dict[str, list] = {}
        self.phases: dict[str, list[float]] = {}
        self.snap_times: list[float] = []
        self.snap_wind: list[np.ndarray] = []
        self.snap_probe: list[np.ndarray] = []

    def add(self, name: str, value):
        self.rows.setdefault(name, []).append(value)

    def add_phase(self, phase: str, seconds: float):
        """A backend's sub-phase time (``stats()`` keys ending in ``_seconds``)."""
        self.phases.setdefault(phase, []).append(seconds)

    def snapshot(self, t: float, wind: np.ndarray, probe_wind: np.ndarray):
        self.snap_times.append(t)
        self.snap_wind.append(np.array(wind, dtype=np.float64))
        self.snap_probe.append(probe_wind)

    def dataset(self, status: str, failure: str = "") -> xr.Dataset:
        s = self.setup
        n = len(self.times)
        x, y, z = s.grid.axes()
        comp = ["x", "y", "z"]
        ds = xr.Dataset(
            coords={
                "time": (
                    "time",
                    np.asarray(self.times, dtype=float),
                    {"units": "s", "long_name": "simulated time"},
                ),
                "component": ("component", comp),
                "x": ("x", x, {"units": "m"}),
                "y": ("y", y, {"units": "m"}),
                "z": ("z", z, {"units": "m"}),
                "cloth": ("cloth", s.cloth.names),
                "snapshot_time": (
                    "snapshot",
                    np.asarray(self.snap_times, dtype=float),
                    {"units": "s"},
                ),
            }
        )
        shape_w = (len(self.snap_wind), *s.grid.shape, 3)
        ds["wind"] = (
            ("snapshot", "x", "y", "z", "component"),
            np.asarray(self.snap_wind).reshape(shape_w),
        )
        phases = list(PHASES) + sorted(self.phases)
        seconds = np.asarray(self.rows.get("step_seconds", []), dtype=float).reshape(n, len(PHASES))
        extra = [np.asarray(self.phases[p][:n], dtype=float) for p in sorted(self.phases)]
        ds = ds.assign_coords(phase=("phase", phases))
        ds["step_seconds"] = (
            ("time", "phase"),
            np.column_stack([seconds, *extra]) if extra else seconds,
        )
        ds["aero_force"] = (
            ("time", "cloth", "component"),
            np.asarray(self.rows.get("aero_force", []), dtype=float).reshape(
                n, s.cloth.n_cloths, 3
            ),
        )
        ds["cloth_position"] = (
            ("time", "vertex", "component"),
            np.asarray(self.rows.get("cloth_position", []), dtype=float).reshape(
                n, s.cloth.n_vertices, 3
            ),
        )
        ds["cloth_triangles"] = (("triangle", "corner"), s.cloth.triangles)
        ds["vertex_cloth"] = (("vertex",), s.cloth.vertex_cloth)
        for key, values in self.rows.items():
            if key not in ("step_seconds", "aero_force", "cloth_position"):
                ds[key] = (("time",), np.asarray(values, dtype=float))
        if s.probe_points:
            names = sorted(s.probe_points)
            pts = np.concatenate([s.probe_points[k] for k in names])
            box = np.concatenate([[k] * len(s.probe_points[k]) for k in names])
            ds = ds.assign_coords(probe_box=("probe_point", box))
            ds["probe_points"] = (("probe_point", "component"), pts)
            ds["probe_wind"] = (
                ("snapshot", "probe_point", "component"),
                np.asarray(self.snap_probe).reshape(len(self.snap_probe), len(pts), 3),
            )
        cfg = s.cfg
        ds.attrs.update(
            wind=str(cfg.wind.name),
            scene=s.scene.name,
            resolution=int(cfg.grid.resolution),
            dt=s.dt,
            duration=float(cfg.sim.duration),
            seed=int(cfg.seed),
            experiment=str(cfg.get("experiment") or ""),
            grid_shape=list(s.grid.shape),
            grid_spacing=s.grid.h,
            reference_speed=s.scene.reference_speed,
            cfl=s.cfl,
            config=OmegaConf.to_yaml(cfg, resolve=True),
            status=status,
            failure=failure,
            steps_completed=n,
            steps_planned=s.n_steps,
            git_commit=git_commit(),
            **package_versions(),
            **runtime_info(),
        )
        return annotate(ds)


class Simulation:
    """Owns the loop: wind, aerodynamics, cloth, figures, NaN checks."""

    def __init__(self, setup: RunSetup, recorder: Recorder | None = None):
        self.setup = setup
        self.recorder = recorder or Recorder(setup)
        self.wind = make_wind(setup.cfg.wind, setup.scene, setup.grid)
        self.cloth_solver = make_cloth_solver(setup.cfg.cloth, setup.cloth, setup.scene.bodies)
        self.state: ClothState = setup.cloth.initial_state()

    def obstacles(self) -> Obstacles:
        return Obstacles(
            self.setup.scene.bodies,
            self.state.positions,
            self.state.velocities,
            self.setup.cloth.triangles,
        )

    def step(self, n: int):
        s = self.setup
        if s.cfg.sim.fail_at_step is not None and n + 1 >= s.cfg.sim.fail_at_step:
            raise SimulationDiverged(n + 1, "fault injected by sim.fail_at_step (testing)")
        t0 = time.perf_counter()
        self.wind.step(s.dt, self.obstacles())
        t1 = time.perf_counter()
        vertex_wind = (
            self.wind.sample(self.state.positions) if s.cloth.n_vertices else np.zeros((0, 3))
        )
        tri_f, vert_f = aerodynamic_forces(
            self.state.positions, self.state.velocities, vertex_wind, s.cloth.triangles, s.aero
        )
        t2 = time.perf_counter()
        self.state = self.cloth_solver.step(self.state, vert_f, s.dt)
        t3 = time.perf_counter()
        self._record(n, tri_f, (t1 - t0, t2 - t1, t3 - t2, t3 - t0))

    def _record(self, n: int, tri_f, seconds):
        s, rec = self.setup, self.recorder
        u = self.wind.velocity()
        self._check_finite(n, u)
        rec.times.append((n + 1) * s.dt)
        rec.add("step_seconds", seconds)
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
        for key, value in {**self.wind.stats(), **self.cloth_solver.stats(self.state)}.items():
            if key.endswith("_seconds"):  # a backend's own phase, e.g. advect_seconds
                rec.add_phase(key.removesuffix("_seconds"), float(value))
            else:
                rec.add(key, float(value))
        if n + 1 in s.snapshot_steps:
            pts = sorted(probe_wind)
            rec.snapshot(
                (n + 1) * s.dt,
                u,
                np.concatenate([probe_wind[k] for k in pts]) if pts else np.zeros((0, 3)),
            )

    def _check_finite(self, n: int, u: np.ndarray):
        if not np.isfinite(u).all():
            raise SimulationDiverged(n + 1, "wind field is not finite (NaN or inf)")
        if not np.isfinite(self.state.positions).all():
            raise SimulationDiverged(n + 1, "cloth positions are not finite (NaN or inf)")

    def run(self, progress: bool = True) -> Recorder:
        bar = tqdm(
            range(self.setup.n_steps),
            desc=f"{self.setup.scene.name}/{self.wind.name}",
            unit="step",
            disable=not (progress and sys.stderr.isatty()),
            mininterval=1.0,
        )
        for n in bar:
            self.step(n)
        return self.recorder


@dataclass
class RunResult:
    path: Path
    status: str
    failure: str = ""


def run(cfg: DictConfig, out_dir: Path) -> RunResult:
    """Check, simulate and write ``out_dir/windbench.nc`` (status complete or failed).

    A ConfigError is raised before anything is written. A blow-up or any other exception
    during the loop writes what was recorded with ``status = failed`` and the reason.
    """
    setup = prepare(cfg)
    path = Path(out_dir) / cfg.output.filename
    recorder = Recorder(setup)
    try:
        Simulation(setup, recorder).run(progress=bool(cfg.sim.progress))
    except Exception as err:  # noqa: BLE001 - recorded, then reported by the caller
        reason = str(err) if isinstance(err, SimulationDiverged) else f"{type(err).__name__}: {err}"
        log.error("run failed: %s", reason)
        write_atomic(recorder.dataset("failed", reason), path)
        return RunResult(path, "failed", reason)
    write_atomic(recorder.dataset("complete"), path)
    return RunResult(path, "complete")
