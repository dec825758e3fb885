"""Backend ``navier_stokes``: stable fluids (paper §4.1.1, Stam 1999) with cloth coupling
(paper §4.1.2), on the scene's grid of cubic cells (physical sizes, SI units).

Equations (4.1)-(4.2): div u = 0, du/dt = -(u . grad) u - grad p / rho + nu lap u + f.
One step of ``dt``, each operator in its own module:

1. cloth coupling, "prior to any other operation" (:mod:`.coupling`, ``wind.coupling``);
2. forces (:mod:`.forcing`): ``wind.body_force`` and the interior flow primitives; a
   source or sink also emits its volume as a divergence target of the projection;
3. eddy viscosity, ``wind.turbulence`` (:mod:`.turbulence`): the surface layer's K of the
   sources' profile (default), Smagorinsky's, or none; a rough ground's stress (:mod:`.wall_law`);
4. advection (:mod:`.advection`) and viscosity (:mod:`.diffusion`), ``wind.advection``:
   ``semi_lagrangian`` (the paper's scheme: RK2 backtrace, trilinear interpolation) or
   limited ``maccormack``, each followed by implicit (backward Euler) viscosity — first
   order in time; or ``second_order``, the trapezoidal rule along the characteristics
   (:meth:`NavierStokesWind._advect_diffuse_second_order`), second order in space and time;
5. projection to the relative residual ``wind.pressure_tol`` (:mod:`.projection`; CG
   with a multigrid preconditioner, :mod:`.multigrid`, from an extrapolation, :mod:`.guess`).

MAC grid: component a on the faces normal to axis a, pressure at cell centres, so that
divergence and gradient are adjoint (the projection is an orthogonal projection free of
checkerboard modes) and walls, bodies and cloth-blocked faces are prescribed face
velocities. ``velocity()`` returns cell-centred values (the mean of two faces, zero in
solid cells), which ``sample()`` interpolates trilinearly like every other backend.

Boundaries (:mod:`.boundaries`): inflow faces take the superposed sources (a uniform
source only where it blows in, with its inflow ``turbulence`` if it has one and its
``gusts`` envelope: :mod:`windbench.wind.envelope`); a domain without an outflow face whose inflow carries
a net volume flux turns its inflow faces into openings (pressure zero). The initial
field is the superposed sources, zero at bodies, projected. Cells whose centre lies in a
rigid body are solid: every face touching one has zero velocity (the paper's interior
check), or a moving body's velocity there (:meth:`NavierStokesWind._move_bodies`).
``wind.precision=float32`` stores the velocity, its scratch and the pressure solve's
vectors, and interpolates the advection, in single precision; the pressure, the other
arithmetic, every sum and the viscous solve's iterate stay double, and the pressure
tolerance is at least TOLERANCE_FLOOR.

Figures per step (``stats()``): pressure iterations, residual and right-hand side, the
MAC divergence on air cells, diffusion sweeps, CFL, cells marked by cloth, the largest
eddy viscosity and its substeps, and the phases couple, advect, diffuse, project.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numba
import numpy as np

from windbench.errors import ConfigError
from windbench.geometry.bodies import body_velocity
from windbench.geometry.raster import triangle_cells
from windbench.wind import surface_layer
from windbench.wind.base import Obstacles, WindField
from windbench.wind.envelope import SourceTimes
from windbench.wind.navier_stokes import (
    advection,
    boundaries,
    coupling,
    diffusion,
    threads,
    trapezoid,
    turbulence,
    wall_law,
)
from windbench.wind.navier_stokes.boundaries import (
    INFLOW,
    KIND_CODES,
    OPENING,
    OUTFLOW,
    PERIODIC,
    ROUGH,
    component_origin,
    padded_shape,
)
from windbench.wind.navier_stokes.forcing import add_force, relax_to_primitives
from windbench.wind.navier_stokes.guess import GUESSES, PressureGuess
from windbench.wind.navier_stokes.multigrid import MultigridPoisson
from windbench.wind.navier_stokes.projection import (
    cell_centred,
    divergence_norms,
    face_flux,
    face_weights,
    largest_magnitude,
    subtract_gradient,
)
from windbench.wind.primitives import parameter_table, profile_scale, superpose
from windbench.wind.registry import WindConfig, register_backend
from windbench.wind.surface_layer import MIXING_LENGTH_LIMIT

ADVECTION = ("semi_lagrangian", "maccormack", "second_order")
PRECISION = ("float64", "float32")
# float32 holds about seven digits: a pressure solve asked for less than this relative
# residual would stop on rounding noise (or never), so its tolerance is at least this
TOLERANCE_FLOOR = {"float64": 0.0, "float32": 1e-6}
COUPLING = ("none", "paper", "projection")
TURBULENCE = ("none", "smagorinsky", "mixing_length")
DIFFUSION_MAX_SWEEPS = 500


def _face_viscosities(nu_t, faces) -> None:
    """faces[a] = nu_t at every face of component a (:func:`.turbulence.face_viscosity`),
    whenever nu_t changes: once for ``mixing_length`` (again if bodies move), every step
    for ``smagorinsky``."""
    for a in range(3):
        turbulence.face_viscosity(nu_t, a, faces[a])


@dataclass
class NavierStokesConfig(WindConfig):
    """``wind.*`` keys of the Navier-Stokes backend (paper §4.1)."""

    name: str = "navier_stokes"
    advection: str = "semi_lagrangian"  # semi_lagrangian | maccormack | second_order
    viscosity: float = 1.5e-5  # kinematic, m^2/s (air)
    pressure_tol: float = 1e-6  # relative residual of the projection
    pressure_max_iterations: int = 200
    pressure_guess: str = GUESSES[0]  # extrapolate | previous: the solve's start (.guess)
    # bound on the implicit solve's max error / velocity scale: 1e-7, under one float32
    # unit (1.19e-7); one sweep at air's viscosity up to 128^3 cells of the scaling scene,
    # where 1e-8 takes two (experiments/bench_ns.py)
    diffusion_tol: float = 1e-7
    source_relaxation: float = 10.0  # 1/s: interior primitives pull the air toward w_i
    coupling: str = "paper"  # none | paper | projection (paper §4.1.2)
    body_force: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # m/s^2
    turbulence: str = "mixing_length"  # none | smagorinsky | mixing_length (eddy viscosity)
    smagorinsky_constant: float = 0.17  # C_s of nu_t = (C_s h)^2 |S|
    mixing_length_limit: float = MIXING_LENGTH_LIMIT  # m, Blackadar's lambda
    seed: int = 0  # synthetic inflow turbulence (conf/wind/navier_stokes.yaml sets ${seed})
    # float64 | float32: storage of the velocity, its scratch and the pressure solve's
    # vectors (the pressure itself, the arithmetic and every sum stay float64)
    precision: str = "float64"


def _check(params):
    choices = (
        ("advection", ADVECTION),
        ("coupling", COUPLING),
        ("precision", PRECISION),
        ("pressure_guess", GUESSES),
        ("turbulence", TURBULENCE),
    )
    for key, allowed in choices:
        name = str(params.get(key))
        if name not in allowed:
            raise ConfigError(f"wind.{key}", f"must be one of {list(allowed)}, got {name!r}")
    if str(params.get("coupling")) == "projection" and str(params.get("advection")) == (
        "second_order"
    ):
        raise ConfigError(
            "wind.coupling",
            "projection works with wind.advection semi_lagrangian or maccormack, not "
            "second_order (its projection carries half the pressure to the next step)",
        )
    cs = float(params.get("smagorinsky_constant"))
    if not (np.isfinite(cs) and 0 < cs < 1):
        raise ConfigError("wind.smagorinsky_constant", f"must lie in (0, 1), got {cs}")
    limit = float(params.get("mixing_length_limit"))
    if not (np.isfinite(limit) and limit > 0):
        raise ConfigError("wind.mixing_length_limit", f"must be a length > 0 m, got {limit}")
    for key in ("viscosity", "source_relaxation"):
        val = float(params.get(key))
        if not (np.isfinite(val) and val >= 0):
            raise ConfigError(f"wind.{key}", f"must be a finite number >= 0, got {val}")
    for key in ("pressure_tol", "diffusion_tol"):
        val = float(params.get(key))
        if not (0 < val < 1):
            raise ConfigError(f"wind.{key}", f"must lie in (0, 1), got {val}")
    if int(params.get("pressure_max_iterations")) < 1:
        raise ConfigError("wind.pressure_max_iterations", "must be >= 1")
    force = list(params.get("body_force"))
    if len(force) != 3 or not np.all(np.isfinite(np.asarray(force, dtype=float))):
        raise ConfigError("wind.body_force", f"must be 3 finite numbers (m/s^2), got {force}")


@register_backend("navier_stokes", config=NavierStokesConfig)
class NavierStokesWind(WindField):
    """Stable-fluids wind on a MAC grid (see module docstring)."""

    # Semi-Lagrangian advection is stable at any CFL, but a backtrace longer than a few
    # cells jumps over thin walls and smears the flow: warn above 5 (Foster & Fedkiw 2001).
    max_cfl = 5.0
    compiles_kernels = True
    stats_units = {
        "pressure_iterations": (
            "iterations of the pressure solve (multigrid-preconditioned CG)",
            "1",
        ),
        "pressure_residual": ("relative residual of the pressure solve", "1"),
        "pressure_rhs_norm": ("||h div u*||_2 before the projection", "m s-1"),
        "mac_divergence_max": ("max of |div u| h / U_ref of the MAC divergence on air cells", "1"),
        "mac_divergence_rms": ("RMS of |div u| h / U_ref of the MAC divergence on air cells", "1"),
        "diffusion_sweeps": ("sweeps of the implicit diffusion solve", "1"),
        "cfl": ("CFL number max|u| dt / h of the step", "1"),
        "cloth_cells": ("cells marked by the cloth (coupling)", "1"),
        "eddy_viscosity_max": ("largest eddy viscosity of the step (wind.turbulence)", "m2 s-1"),
        "eddy_substeps": ("explicit stages of the eddy-viscosity term (Runge-Kutta-Legendre)", "1"),
    }

    @classmethod
    def check(cls, scene, grid, params) -> None:
        """ConfigError for bad ``wind.*`` values and a grid too fine for the rough ground's
        wall law (called by simulate.prepare)."""
        _check(params)
        if scene.boundary["z_min"] == "rough":
            wall_law.drag_coefficient(scene, float(grid.lower[2]), float(grid.h))

    def __init__(self, scene, grid, params):
        _check(params)
        super().__init__(scene, grid, params)
        self.advection = str(params.advection)
        self.coupling = str(params.coupling)
        self.viscosity = float(params.viscosity)
        self.dtype = np.dtype(str(params.precision))
        self.tol = max(float(params.pressure_tol), TOLERANCE_FLOOR[self.dtype.name])
        self.diffusion_tol = float(params.diffusion_tol)
        self.max_iterations = int(params.pressure_max_iterations)
        self.relaxation = float(params.source_relaxation)
        self.turbulence = str(params.turbulence)
        self.time = 0.0
        self.times = SourceTimes.build(scene, params.seed)  # gusts and fluctuations
        self.fluctuations = [
            (s, f) for s, f in zip(scene.sources, self.times.fluctuations, strict=True) if f
        ]
        self.body_force = np.asarray(list(params.body_force), dtype=float)
        shape = grid.shape
        self.h = float(grid.h)
        self.lower = np.asarray(grid.lower, dtype=float)
        self.cells = np.asarray(grid.shape, dtype=np.int64)
        self.solid = self._solid.astype(np.uint8)
        self.kinds = self._face_kinds(scene)
        self.wall_drag, self._floor_scratch = self._rough_ground(scene, shape)
        self.periodic = np.array([self.kinds[2 * a] == PERIODIC for a in range(3)])
        # axes that carry a derivative: not a one-cell periodic axis (2D problems)
        self.axes = np.array([not (self.periodic[a] and shape[a] == 1) for a in range(3)], np.int64)
        self.origins = np.stack([component_origin(self.lower, self.h, a) for a in range(3)])
        self.walls = [
            np.asarray(scene.wall_velocity.get(f, np.zeros(3)), dtype=float)
            for f in boundaries.FACE_NAMES
        ]
        self.planes = self._boundary_planes()
        interior = [s for s in scene.sources if s.kind != "uniform"]
        self.prim_kinds, self.prim_params = parameter_table(interior)
        self.prim_radii = np.array([max(p.core_radius, self.h) for p in interior])
        self.target = self._mass_sources(interior)
        # state: the three padded face arrays, pressure (warm start) and work arrays
        self.q = [np.zeros(padded_shape(shape, a), self.dtype) for a in range(3)]
        self.work = [np.zeros_like(x) for x in self.q]
        limited = self.advection in ("maccormack", "second_order")
        self.work2 = [np.zeros_like(x) for x in self.q] if limited else None
        single = self.dtype != np.float64  # the viscous solve's iterate: float64 scratch
        self.diffusion_iterate = [np.zeros(x.shape) for x in self.q] if single else None
        self.qmin = [np.zeros_like(x) for x in self.q] if limited else None
        self.qmax = [np.zeros_like(x) for x in self.q] if limited else None
        second = self.advection == "second_order"
        self.old = [np.zeros_like(x) for x in self.q] if second else None  # u^(n-1)
        self.rhs_w = [np.zeros_like(x) for x in self.q] if second else None
        self._pressure_scale = 0.0  # converts psi into (dt/2) grad p for the next step
        self._last_dt = 0.0
        self.free_static = [np.zeros(x.shape, np.uint8) for x in self.q]
        for a in range(3):
            boundaries.free_faces(a, self.kinds, self.solid, self.free_static[a])
        self.free = [f.copy() for f in self.free_static]
        self.solid_faces = [self._faces_touching_solid(a) for a in range(3)]
        self.solid_values = [0.0, 0.0, 0.0]  # still bodies; moving ones: _move_bodies
        dirichlet = any(k in (OUTFLOW, OPENING) for k in self.kinds)
        self.poisson = MultigridPoisson(
            shape, self.periodic, singular=not dirichlet, dtype=self.dtype
        )
        self.weights = [np.zeros(w.shape) for w in self.poisson.fine.w]
        self._set_weights()
        self.psi = np.zeros(shape)
        self.guess = PressureGuess(shape, str(params.pressure_guess))
        self.rhs = np.zeros(shape)
        self.smagorinsky_length2 = np.full(
            shape[2], (float(params.smagorinsky_constant) * self.h) ** 2
        )
        self.nu_t, self.nu_face, self.stage_work = self._eddy_fields(params)
        self._u_cell = np.zeros((*shape, 3))
        self._cell_valid = False
        self._stats: dict[str, float] = {}
        self._blocked = None  # (rows, velocities, weights) of the faces the cloth closes
        self._pockets = (np.full(shape, -1, np.int64), 0)  # air the cloth encloses
        self._loads = None  # pressure force / rho on each cloth triangle
        if self.moving:
            self._move_bodies()
        self._initial_condition(scene)

    # ------------------------------------------------------------ set-up helpers

    def _rough_ground(self, scene, shape) -> tuple[float, np.ndarray | None]:
        """(C_D of the rough ground, the wall law's scratch plane of the x faces)
        (:mod:`.wall_law`); (0, None) without one."""
        if self.kinds[4] != ROUGH:
            return 0.0, None
        plane = np.zeros(padded_shape(shape, 0)[:2], dtype=self.dtype)
        return wall_law.drag_coefficient(scene, self.lower[2], self.h), plane

    def _face_kinds(self, scene) -> np.ndarray:
        kinds = np.array([KIND_CODES[scene.boundary[f]] for f in boundaries.FACE_NAMES])
        if OUTFLOW not in kinds and INFLOW in kinds:
            net = 0.0
            for f in range(6):
                if kinds[f] != INFLOW:
                    continue
                b = f // 2
                pts = boundaries.plane_points(
                    self.grid.lower, self.grid.upper, self.grid.h, self.grid.shape, b, f
                )[1:-1, 1:-1].reshape(-1, 3)
                sign = 1.0 if f % 2 == 0 else -1.0  # inward normal . e_b
                net += sign * self._inflow(pts, f)[:, b].sum()
            if abs(net) > 1e-9 * max(1.0, abs(self.scene.reference_speed)) * self.grid.n_cells:
                kinds[kinds == INFLOW] = OPENING
        return kinds.astype(np.int64)

    def _inflow(self, points, face) -> np.ndarray:
        """Inflow wind at points of ``face`` at the backend's time: uniform sources only
        where they blow in, with their synthetic turbulence if they carry one."""
        b = face // 2
        n_out = -1.0 if face % 2 == 0 else 1.0
        chosen = [s for s in self.scene.sources if s.kind != "uniform" or s.velocity[b] * n_out < 0]
        if self.times.gusty:
            index = [i for i, s in enumerate(self.scene.sources) if s in chosen]
            return self.times.wind(points, self.time, index)  # gusts: e_i(t) (w_i + u'_i)
        wind = superpose(chosen, points)
        for source, fluctuation in self.fluctuations:
            if source in chosen:
                wind += fluctuation(points, self.time) * profile_scale(source, points)[:, None]
        return wind

    def _boundary_planes(self):
        return boundaries.boundary_planes(
            self.kinds, self.walls, self._inflow, self.lower, self.grid.upper, self.h,
            self.grid.shape,
        )  # fmt: skip

    def _mass_sources(self, interior) -> np.ndarray:
        """Target h div u per cell: each source (sink) emits (draws) m over its core."""
        target = np.zeros(self.grid.shape)
        centres = self.grid.cell_centres()
        for p, r in zip(interior, self.prim_radii, strict=True):
            if p.kind not in ("source", "sink"):
                continue
            d = np.linalg.norm(centres - np.asarray(p.center), axis=-1)
            weight = np.exp(-((d / r) ** 3)) * (self.solid == 0)
            if weight.sum() == 0:
                continue
            sign = 1.0 if p.kind == "source" else -1.0
            target += sign * p.strength / self.h**2 * weight / weight.sum()  # sum = m / h^2
        return target

    def _initial_condition(self, scene):
        for a in range(3):
            pts = self._face_points(a)
            self.q[a][...] = superpose(scene.sources, pts.reshape(-1, 3))[:, a].reshape(
                pts.shape[:3]
            )
        self._apply_boundaries(set_normal=True)
        self._project()

    def set_velocity(self, field) -> None:
        """Replace the state by ``field(points (n, 3)) -> (n, 3)`` sampled at the faces,
        then impose the boundaries and project (for validation problems and tests)."""
        for a in range(3):
            pts = self._face_points(a)
            self.q[a][...] = np.asarray(field(pts.reshape(-1, 3)))[:, a].reshape(pts.shape[:3])
        self._apply_boundaries(set_normal=True)
        self._project()
        self._pressure_scale, self._last_dt = 0.0, 0.0  # no earlier time level

    def _move_bodies(self) -> None:
        """Moving bodies (:mod:`windbench.geometry.motion`) as moving boundaries: the solid
        cells at the backend's time, re-rasterised (free faces, solid faces, Poisson
        weights, eddy viscosity) when they change, and on every face touching a solid cell
        the velocity of the body there, u_face = c' + omega x (x_face - c), which the
        projection keeps as a prescribed face value. A rigid motion is divergence free, so
        the prescribed fluxes of a closed domain still balance."""
        self.pose_solid(self.time)
        solid = self._solid.astype(np.uint8)
        if not np.array_equal(solid, self.solid):
            self.solid[...] = solid
            for a in range(3):
                boundaries.free_faces(a, self.kinds, self.solid, self.free_static[a])
                self.free[a][...] = self.free_static[a]
            self.solid_faces = [self._faces_touching_solid(a) for a in range(3)]
            self._set_weights()
            if self.turbulence == "mixing_length" and self.nu_t is not None:
                self.nu_t = self._eddy_viscosity_model(float(self.params.mixing_length_limit))
                _face_viscosities(self.nu_t, self.nu_face)
        self.solid_values = [
            body_velocity(
                self.scene.bodies,
                self._face_points(a).reshape(-1, 3)[self.solid_faces[a]],
                self.time,
            )[:, a].astype(self.dtype)
            for a in range(3)
        ]

    def _faces_touching_solid(self, a) -> np.ndarray:
        """Flat indices of the faces of component a next to a body."""
        probe = np.ones(self.q[a].shape)
        boundaries.zero_solid_faces(probe, a, self.solid)
        return np.flatnonzero(probe == 0.0)

    def _face_points(self, a) -> np.ndarray:
        shp = self.q[a].shape
        o = self.origins[a]
        axes = [o[b] + self.h * np.arange(shp[b]) for b in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def _set_weights(self):
        for a in range(3):
            face_weights(self.free[a], a, self.periodic, self.weights[a])
        self.poisson.set_weights(*self.weights)

    # ------------------------------------------------------------ operators

    def _apply_boundaries(self, set_normal: bool):
        for a in range(3):
            self.q[a].reshape(-1)[self.solid_faces[a]] = self.solid_values[a]
            boundaries.fill_boundary(self.q[a], a, self.kinds, self.planes[a], set_normal)
        if self._blocked is not None and len(self._blocked[0]):
            rows, vals, _ = self._blocked
            coupling.apply_blocked(rows, vals, *self.q, *self.free)

    def _fill(self, arrays):
        for a in range(3):
            boundaries.fill_boundary(arrays[a], a, self.kinds, self.planes[a], True)

    def _carry(self, dt_h, src, out, bounds=False, velocity=None):
        """out[a] = src[a](x - d) for the three components, d the backtrace of ``velocity``
        (default: the current one) over dt_h = dt / h; with ``bounds`` also the limiter's
        qmin/qmax."""
        qmin, qmax = (self.qmin, self.qmax) if bounds else (out, out)
        advection.advect(
            *(velocity or self.q), self.cells, self.periodic, dt_h, numba.get_num_threads(),
            tuple(src), tuple(out), tuple(qmin), tuple(qmax), bounds,
        )  # fmt: skip

    def _advect(self, dt):
        dt_h = dt / self.h
        if self.advection == "semi_lagrangian":
            self._carry(dt_h, self.q, self.work)
        else:
            self._carry(dt_h, self.q, self.work2, bounds=True)
            self._fill(self.work2)
            self._carry(-dt_h, self.work2, self.work)  # the same velocity, backwards
            for a in range(3):
                advection.maccormack_correct(
                    self.q[a], self.work2[a], self.work[a], self.qmin[a], self.qmax[a], self.work[a]
                )
        self.q, self.work = self.work, self.q
        self._apply_boundaries(set_normal=True)

    def _advect_diffuse_second_order(self, dt) -> int:
        """Advection and viscosity of the second-order step (``wind.advection=second_order``).

        The trapezoidal rule along the characteristic from (X, t^n) to (x, t^n+1),

            u^n+1(x) = u^n(X) - dt/2 [grad p^n(X) + grad p^n+1(x)]
                       + nu dt/2 [lap u^n(X) + lap u^n+1(x)],

        is second order in time (the semi-Lagrangian Crank-Nicolson projection scheme,
        e.g. Xiu & Karniadakis 2001): w = u^n - (dt/2) grad p^n + nu dt/2 lap u^n is carried
        by limited MacCormack along backtraces of the midpoint velocity u^n+1/2 = 3/2 u^n -
        1/2 u^n-1, the implicit half of the viscosity is solved (alpha = nu dt / (2 h^2)),
        and the projection supplies (dt/2) grad p^n+1 as the gradient of its psi, which the
        next step subtracts again. The first step has no previous pressure or velocity: its
        psi is a full step's dt grad p, halved for the second step."""
        dt_h = dt / self.h
        if self._last_dt == 0.0:  # first step: u^n-1 = u^n
            for a in range(3):
                self.old[a][...] = self.q[a]
        for a in range(3):
            trapezoid.midpoint_velocity(self.q[a], self.old[a])
        scale = self._pressure_scale * (dt / self._last_dt if self._last_dt else 0.0)
        beta = 0.5 * self.viscosity * dt / self.h**2
        w = self.rhs_w
        for a in range(3):
            trapezoid.carried_field(
                self.q[a], a, self.psi, scale, beta, self.axes, self.free[a], self.periodic,
                w[a],
            )  # fmt: skip
        self._fill(w)
        self._carry(dt_h, w, self.work2, bounds=True, velocity=self.old)
        self._fill(self.work2)
        self._carry(-dt_h, self.work2, self.work, velocity=self.old)
        for a in range(3):
            advection.maccormack_correct_smooth(
                w[a], self.work2[a], self.work[a], self.qmin[a], self.qmax[a], self.axes,
                self.work[a],
            )  # fmt: skip
        # u^n becomes u^n-1 of the next step; the midpoint field is scratch from here
        self.old, self.q, self.work = self.q, self.work, self.old
        self._apply_boundaries(set_normal=True)
        sweeps = self._diffuse(0.5 * dt)
        self._pressure_scale = 1.0 if self._last_dt else 0.5
        self._last_dt = dt
        return sweeps

    def _eddy_viscosity_model(self, limit: float) -> np.ndarray | None:
        """nu_t per cell: fixed for ``mixing_length`` (the undisturbed wind's shear at each
        layer, :func:`windbench.wind.surface_layer.surface_layer_viscosity`), updated every step for
        ``smagorinsky``, None without turbulence or where the wind has no shear."""
        if self.turbulence == "none":
            return None
        if self.turbulence == "smagorinsky":
            return np.zeros(self.grid.shape)
        layers = surface_layer.sources_viscosity(
            self.scene.sources,
            self.grid.axes()[2],
            self.lower,
            self.grid.upper,
            limit,
            1e-3 * self.h,
        )
        if not np.any(layers > 0):
            return None
        return np.where(self.solid.astype(bool), 0.0, layers[None, None, :])

    def _eddy_fields(self, params) -> tuple:
        """The eddy term's fields (:meth:`_eddy_diffusion`): nu_t per cell
        (:meth:`_eddy_viscosity_model`), each component's face viscosities (float64) and
        a buffer more for the Runge-Kutta-Legendre stages (velocity precision); all None
        without an eddy viscosity."""
        nu_t = self._eddy_viscosity_model(float(params.mixing_length_limit))
        if nu_t is None:
            return None, None, None
        faces = [np.zeros(x.shape) for x in self.q]
        _face_viscosities(nu_t, faces)
        return nu_t, faces, [np.zeros_like(x) for x in self.q]

    def _eddy_diffusion(self, dt) -> tuple[float, int]:
        """Eddy viscosity of the mean flow (:mod:`.turbulence`): one explicit
        Runge-Kutta-Legendre step of as many stages as its stability needs
        (:func:`.turbulence.legendre_stages`), each component's through three buffers,
        the ghost layer filled after each stage; returns (largest nu_t in m^2/s,
        stages)."""
        if self.nu_t is None:
            return 0.0, 0
        if self.turbulence == "smagorinsky":
            turbulence.eddy_viscosity(
                *self.q, self.solid, self.axes, self.h, self.smagorinsky_length2, self.nu_t
            )
            _face_viscosities(self.nu_t, self.nu_face)
        peak = float(self.nu_t.max())
        euler = turbulence.SUBSTEP_LIMIT / (2 * int(self.axes.sum()))  # nu dt / h^2
        stages = turbulence.legendre_stages(peak * dt / self.h**2 / euler)
        for a in range(3):
            self.q[a] = self._legendre_step(a, stages, dt / self.h**2)
        self._apply_boundaries(set_normal=True)
        return peak, stages

    def _legendre_step(self, a: int, stages: int, dt_h2: float) -> np.ndarray:
        """Component a after the RKL1 stages (:func:`.turbulence.legendre_stage`), in
        one of the three buffers q[a], work[a], stage_work[a]; the other two become the
        scratch ones."""
        older, current = self.q[a], self.q[a]
        spare = [self.work[a], self.stage_work[a]]
        for j in range(1, stages + 1):
            out = spare.pop()
            stage = np.array(turbulence.legendre_stage(j, stages))
            turbulence.eddy_diffusion(
                current, older, self.nu_face[a], self.axes, dt_h2, self.free[a], stage, out
            )
            boundaries.fill_boundary(out, a, self.kinds, self.planes[a], True)
            if older is not current:
                spare.append(older)
            older, current = current, out
        rest = [x for x in (self.q[a], self.work[a], self.stage_work[a]) if x is not current]
        self.work[a], self.stage_work[a] = rest
        return current

    def _ground_drag(self, dt) -> None:
        """The rough ground's stress on the first layer of cells (:mod:`.wall_law`)."""
        if not self.wall_drag:
            return
        rate = dt * self.wall_drag / self.h
        wall_law.floor_drag(
            self.q[0],
            self.q[1],
            self.free[0],
            self.free[1],
            rate,
            self._floor_scratch,
        )
        self._apply_boundaries(set_normal=True)

    def _forces(self, dt):
        forced = bool(np.any(self.body_force != 0.0))
        for a in range(3):
            if self.body_force[a] != 0.0:
                add_force(self.q[a], self.free[a], self.body_force[a] * dt)
        if self.prim_kinds.size and self.relaxation > 0:
            forced = True
            factor = 1.0 - np.exp(-self.relaxation * dt)
            for a in range(3):
                relax_to_primitives(
                    self.q[a],
                    a,
                    self.origins[a],
                    self.h,
                    self.prim_kinds,
                    self.prim_params,
                    self.prim_radii,
                    factor,
                    self.free[a],
                )
        if forced:  # ghosts and periodic copies must see the new values
            self._apply_boundaries(set_normal=True)

    def _diffuse(self, dt) -> int:
        """Implicit viscous diffusion of the three components (:mod:`.diffusion`): a first
        Jacobi sweep from the advected field into the iterate, while the advected field
        stays as the right-hand side, then red-black Gauss-Seidel sweeps until the
        contraction bound meets ``diffusion_tol``. In float64 the iterate is the work
        arrays, which then become the state; in float32 it is float64 scratch, copied into
        the state at the end (a float32 iterate would stall at its rounding, which the
        solve's condition, up to 1 + 4 alpha d, amplifies)."""
        alpha = self.viscosity * dt / self.h**2
        if alpha == 0.0:
            return 0
        n = max(x.shape[0] for x in self.q)
        changes, peaks = np.zeros(n), np.zeros(n)
        change = peak = 0.0
        iterate = self.work if self.diffusion_iterate is None else self.diffusion_iterate
        for a in range(3):
            diffusion.jacobi_first_sweep(
                self.q[a], iterate[a], alpha, self.axes, self.free[a], changes, peaks
            )
            boundaries.fill_boundary(iterate[a], a, self.kinds, self.planes[a], False)
            change, peak = max(change, changes.max()), max(peak, peaks.max())
        rhs = self.q
        if iterate is self.work:
            self.q, self.work = self.work, self.q  # work: the right-hand side q0 from here
        scale = max(peak, self.scene.reference_speed)
        bound = diffusion.error_bound_factor(alpha, int(self.axes.sum()))
        sweeps = 1
        while change * bound > self.diffusion_tol * scale and sweeps < DIFFUSION_MAX_SWEEPS:
            sweeps += 1
            change = 0.0
            for a in range(3):
                for colour in (0, 1):
                    changes[:] = 0.0
                    diffusion.gauss_seidel_half(
                        iterate[a], rhs[a], colour, alpha, self.axes, self.free[a], changes
                    )
                    change = max(change, changes.max())
                    boundaries.fill_boundary(iterate[a], a, self.kinds, self.planes[a], False)
        if iterate is not self.q:
            for a in range(3):
                np.copyto(self.q[a], iterate[a], casting="same_kind")
        return sweeps

    def _project(self, dt: float | None = None):
        """The projection (:mod:`.projection`) of a step ``dt`` (None: of a state that is
        no time step), its solve started from the last solutions extrapolated
        (:mod:`.guess`). Returns (iterations, relative residual, ||rhs||_2)."""
        face_flux(*self.q, self.target, self.rhs)
        np.negative(self.rhs, out=self.rhs)  # A psi = -(h div u - target)
        if self._pockets[1]:  # air enclosed by cloth: its right-hand side must sum to 0
            coupling.balance_pockets(self.rhs, *self._pockets)
        atol = 1e-14 * self.scene.reference_speed * np.sqrt(self.grid.n_cells)
        self.guess.start(self.psi, dt, lambda x: self.poisson.smooth_residual_norm(x, self.rhs))
        iters, res = self.poisson.solve(
            self.psi, self.rhs, self.tol, self.max_iterations, atol=atol
        )
        self.guess.solved_step(dt)
        rhs_norm = self.poisson.rhs_norm  # ||rhs||_2, computed by the solve
        for a in range(3):
            subtract_gradient(self.q[a], a, self.psi, self.free[a], self.periodic)
        if self._blocked is not None:  # the cloth yields to the pressure jump
            rows, _, weight = self._blocked
            coupling.move_membranes(rows, weight, self.psi, self.periodic, *self.q)
        for a in range(3):
            boundaries.fill_boundary(self.q[a], a, self.kinds, self.planes[a], False)
        self._cell_valid = False
        return iters, res, rhs_norm

    def _couple(self, obstacles: Obstacles):
        """Paper §4.1.2: act on the air where the cloth is (``wind.coupling``,
        :mod:`.coupling`). ``paper`` removes the air's velocity normal to the cloth,
        relative to it, next to every cell the cloth cuts; ``projection`` closes the faces
        the cloth crosses in the pressure solve instead. Returns the cells the cloth cuts."""
        self._blocked, self._loads = None, None
        self._pockets = (self._pockets[0], 0)
        tris = obstacles.cloth_triangles
        if self.coupling == "none" or tris is None or len(tris) == 0:
            return 0
        pos = np.ascontiguousarray(obstacles.cloth_positions, dtype=np.float64)
        vel = np.ascontiguousarray(obstacles.cloth_velocities, dtype=np.float64)
        tris = np.ascontiguousarray(tris, dtype=np.int64)
        start, items = triangle_cells(pos, tris, self.grid)
        if self.coupling == "paper":
            self._remove_normal_velocity(pos, vel, tris, start, items)
        else:
            self._close_cloth_faces(pos, vel, tris, start, items, obstacles.cloth_mobility)
        self._apply_boundaries(set_normal=True)
        if self.coupling == "projection":
            rows, _, weight = self._blocked
            self._set_membrane_weights(rows, weight)
        return int(np.count_nonzero(np.diff(start)))

    def _remove_normal_velocity(self, pos, vel, tris, start, items):
        """``paper``: u <- u - ((u - v_cloth) . n) n on the faces next to the cells the
        cloth cuts (:func:`.coupling.remove_normal_component`)."""
        marked = np.diff(start) > 0
        index = np.full(self.grid.n_cells, -1, dtype=np.int64)
        index[marked] = np.arange(marked.sum())
        index = index.reshape(self.grid.shape)
        m = int(marked.sum())
        normals, velocity = np.zeros((m, 3)), np.zeros((m, 3))
        coupling.cell_normals(pos, vel, tris, start, items, index, normals, velocity)
        u, v, w = self.q
        for a in range(3):
            coupling.remove_normal_component(
                self.q[a], a, u, v, w, index, normals, velocity, self.work[a]
            )
        self.q, self.work = self.work, self.q

    def _close_cloth_faces(self, pos, vel, tris, start, items, mobility):
        """``projection``: the faces the cloth crosses (:func:`.coupling.blocked_faces`),
        kept for the boundary fill and the pressure solve; the free-face masks reset."""
        if mobility is None:
            mobility = np.zeros(pos.shape[0])
        self._blocked = coupling.blocked_faces(
            pos,
            vel,
            np.ascontiguousarray(mobility, dtype=np.float64),
            tris,
            start,
            items,
            self.lower,
            self.h,
            np.asarray(self.grid.shape, dtype=np.int64),
        )
        for a in range(3):
            self.free[a][...] = self.free_static[a]

    def _set_membrane_weights(self, rows, weight):
        """The Poisson weights with the cloth's faces (:func:`.coupling.move_membranes`) and
        the pockets of air that closed faces enclose (:func:`.coupling.pockets`)."""
        for a in range(3):
            face_weights(self.free[a], a, self.periodic, self.weights[a])
        coupling.membrane_weights(rows, weight, *self.weights)
        self.poisson.set_weights(*self.weights)
        joined = [f.copy() for f in self.free]
        coupling.open_membranes(rows, weight, *joined)
        self._pockets = coupling.pockets(*joined, self.solid, self.periodic)

    def _pressure_loads(self, dt: float, obstacles: Obstacles) -> None:
        """Pressure force over rho on each cloth triangle
        (:func:`.coupling.triangle_pressure_loads`): p / rho = psi h / dt, psi holding
        dt grad p (``projection`` runs with the first-order schemes only)."""
        self._loads = coupling.triangle_pressure_loads(
            np.ascontiguousarray(obstacles.cloth_positions, dtype=np.float64),
            np.ascontiguousarray(obstacles.cloth_triangles, dtype=np.int64),
            self.psi,
            self.solid,
            tuple(self.free),
            self.lower,
            self.h,
            self.h / dt,
        )

    def cloth_pressure_loads(self) -> np.ndarray | None:
        """``projection`` coupling: the pressure force over the air density on each cloth
        triangle in the last step (m^4 s^-2), else None."""
        return self._loads

    # ------------------------------------------------------------ interface

    def step(self, dt: float, obstacles: Obstacles) -> None:
        t0 = time.perf_counter()
        threads.select(self.grid.n_cells)  # another solver may have chosen since
        self.time += dt
        if self.times.varies:  # the inflow of this step's end
            self.planes = self._boundary_planes()
        if self.moving:  # the bodies at this step's end
            self._move_bodies()
        marked = self._couple(obstacles)
        self._forces(dt)
        te = time.perf_counter()
        nu_max, substeps = self._eddy_diffusion(dt)
        self._ground_drag(dt)
        t1 = time.perf_counter()
        if self.advection == "second_order":
            sweeps = self._advect_diffuse_second_order(dt)
            t2 = t3 = time.perf_counter()  # one phase: advect holds both
        else:
            self._advect(dt)
            t2 = time.perf_counter()
            sweeps = self._diffuse(dt)
            t3 = time.perf_counter()
        iters, res, rhs_norm = self._project(dt)
        if self._blocked is not None:
            self._pressure_loads(dt, obstacles)
        t4 = time.perf_counter()
        peak, squares, count = divergence_norms(*self.q, self.target, self.solid)
        scale = 1.0 / self.scene.reference_speed  # h div u / U_ref
        speed = max(largest_magnitude(x) for x in self.q)
        self._stats = {
            "pressure_iterations": float(iters),
            "pressure_residual": float(res),
            "pressure_rhs_norm": rhs_norm,
            "mac_divergence_max": peak * scale if count else float("nan"),
            "mac_divergence_rms": np.sqrt(squares / count) * scale if count else float("nan"),
            "diffusion_sweeps": float(sweeps),
            "cfl": float(speed * dt / self.h),
            "cloth_cells": float(marked),
            "eddy_viscosity_max": nu_max,
            "eddy_substeps": float(substeps),
            "couple_seconds": te - t0,
            "eddy_seconds": t1 - te,
            "advect_seconds": t2 - t1,
            "diffuse_seconds": t3 - t2,
            "project_seconds": t4 - t3,
        }

    def divergence(self) -> np.ndarray:
        """The MAC divergence (div u - emitted volume rate) per cell in 1/s; NaN in solids."""
        out = np.empty(self.grid.shape)
        face_flux(*self.q, self.target, out)
        out /= self.h
        out[self.solid.astype(bool)] = np.nan
        return out

    def velocity(self) -> np.ndarray:
        if not self._cell_valid:
            cell_centred(*self.q, self.solid, self._u_cell)
            self._cell_valid = True
        return self._u_cell

    def faces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The staggered face velocities without ghosts: u (nx+1,ny,nz), v, w (read-only)."""
        out = []
        for a in range(3):
            sl = [slice(1, -1)] * 3
            out.append(self.q[a][tuple(sl)])
        return tuple(out)

    def stats(self) -> dict[str, float]:
        return dict(self._stats)
