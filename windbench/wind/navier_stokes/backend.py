"""Backend ``navier_stokes``: stable fluids (paper §4.1.1, Stam 1999) with cloth coupling
(paper §4.1.2), on the scene's grid of cubic cells (physical sizes, SI units).

Equations (4.1)-(4.2): div u = 0, du/dt = -(u . grad) u - grad p / rho + nu lap u + f.
One step of ``dt`` (operator splitting, each operator in its own module):

1. cloth coupling, "prior to any other operation" (:mod:`.coupling`, ``wind.coupling``);
2. body forces: ``wind.body_force`` (m/s^2) and the interior flow primitives (vortex,
   source, sink) relaxing the air toward their own field w_i inside their core,
   u += (1 - exp(-k dt)) chi_i (w_i - u), chi_i = exp(-(d/r_c)^2), k =
   ``wind.source_relaxation`` (1/s), r_c = max(core_radius, h); a source/sink also
   emits its volume m (m^3/s) as a divergence spread over its core in the projection;
3. advection (:mod:`.advection`): semi-Lagrangian with an RK2 backtrace (once per cell
   centre, faces take the mean of their two cells' displacements), or limited
   MacCormack (``wind.advection``);
4. implicit diffusion with kinematic viscosity ``wind.viscosity`` (:mod:`.diffusion`: a
   Jacobi sweep from the advected field, then Gauss-Seidel until the error bound);
5. pressure projection to the relative residual ``wind.pressure_tol`` (:mod:`.pressure`,
   multigrid-preconditioned CG whose iteration count does not grow with resolution).

Grid: MAC (staggered). Velocity component a lives on the centres of the faces normal to
axis a; pressure at cell centres. Chosen because (i) the discrete divergence and
gradient are adjoint, so the projection is an exact orthogonal projection (idempotent,
divergence zero to the solver tolerance) with the compact 7-point Laplacian, free of the
checkerboard modes of a collocated grid; (ii) "no flux through a wall" is simply a
prescribed face velocity, so bodies, walls and cloth-blocked faces are face weights of
the same Poisson matrix. The paper keeps all values at cell centres; ``velocity()``
returns cell-centred values (mean of the two faces per axis, zero in solid cells) and
``sample()`` interpolates those trilinearly, like every other backend.

Boundaries (:mod:`.boundaries`): per face of ``scene.boundary``. Inflow value: the
superposed scene sources evaluated at the face, where a *uniform* source counts only at
faces it blows in through (U . n_out < 0), so ``opposing_sources`` (+U and -U) gets +U
through x_min and -U through x_max; vortices, sources and sinks count at every inflow
face. If a domain has no outflow face but its inflow carries a net volume flux (again
``opposing_sources``), incompressibility has no solution with prescribed inflow; its
inflow faces then become *openings*: the inflow velocity is imposed before each
projection and the pressure there is zero, so air enters only as far as it can leave.

Initial condition: the superposed field of all sources at the faces, zero on faces
touching a body, then projected (divergence-free from the first step; a scene without
sources starts at rest).

Defaults (``conf/wind/navier_stokes.yaml``): ``advection=semi_lagrangian`` (the paper's
scheme, cheapest; ``maccormack`` is 3-30x less dissipative, see
``experiments/validation_ns/README.md``), ``coupling=paper`` (§4.1.2 as written; cheap,
but air still crosses a flag through the pressure solve — ``projection`` closes it).

Figures per step (``stats()``): ``pressure_iterations``, ``pressure_residual`` (relative),
``pressure_rhs_norm`` (||h div u*||_2 before the projection, m/s), ``mac_divergence_max``/
``_rms`` (|div u| h / U_ref of the MAC divergence on air cells, which is what the
projection zeroes; :meth:`divergence` gives the field to the loop), ``diffusion_sweeps``,
``cfl``, ``cloth_cells`` (cells marked by cloth) and the phases ``couple``, ``advect``,
``diffuse``, ``project`` (``*_seconds``).

Rigid bodies: cells whose centre is inside a body (base-class ``solid_mask()``; thin
``resolve=False`` poles mostly miss every centre) are solid: every face touching one has
zero velocity, so nothing flows through a body and no velocity is ever assigned inside
one (the paper's interior check).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numba
import numpy as np

from windbench.errors import ConfigError
from windbench.geometry.raster import triangle_cells
from windbench.wind.base import Obstacles, WindField
from windbench.wind.navier_stokes import advection, boundaries, coupling, diffusion
from windbench.wind.navier_stokes.boundaries import (
    INFLOW,
    KIND_CODES,
    OPENING,
    OUTFLOW,
    PERIODIC,
    component_origin,
    padded_shape,
)
from windbench.wind.navier_stokes.forcing import add_force, relax_to_primitives
from windbench.wind.navier_stokes.multigrid import MultigridPoisson
from windbench.wind.navier_stokes.projection import (
    cell_centred,
    divergence_norms,
    face_flux,
    face_weights,
    max_abs,
    subtract_gradient,
)
from windbench.wind.primitives import parameter_table, superpose
from windbench.wind.registry import WindConfig, register_backend

ADVECTION = ("semi_lagrangian", "maccormack")
COUPLING = ("none", "paper", "projection")
DIFFUSION_MAX_SWEEPS = 500


@dataclass
class NavierStokesConfig(WindConfig):
    """``wind.*`` keys of the Navier-Stokes backend (paper §4.1)."""

    name: str = "navier_stokes"
    advection: str = "semi_lagrangian"  # semi_lagrangian | maccormack
    viscosity: float = 1.5e-5  # kinematic, m^2/s (air)
    pressure_tol: float = 1e-6  # relative residual of the projection
    pressure_max_iterations: int = 200
    diffusion_tol: float = 1e-8  # bound on the implicit solve's max error / velocity scale
    source_relaxation: float = 10.0  # 1/s: interior primitives pull the air toward w_i
    coupling: str = "paper"  # none | paper | projection (paper §4.1.2)
    body_force: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # m/s^2


def _check(params):
    name = str(params.get("advection", "semi_lagrangian"))
    if name not in ADVECTION:
        raise ConfigError("wind.advection", f"must be one of {list(ADVECTION)}, got {name!r}")
    name = str(params.get("coupling", "paper"))
    if name not in COUPLING:
        raise ConfigError("wind.coupling", f"must be one of {list(COUPLING)}, got {name!r}")
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
    }

    @classmethod
    def check(cls, scene, grid, params) -> None:
        """ConfigError for bad ``wind.*`` values (called by simulate.prepare)."""
        _check(params)

    def __init__(self, scene, grid, params):
        _check(params)
        super().__init__(scene, grid, params)
        self.advection = str(params.advection)
        self.coupling = str(params.coupling)
        self.viscosity = float(params.viscosity)
        self.tol = float(params.pressure_tol)
        self.diffusion_tol = float(params.diffusion_tol)
        self.max_iterations = int(params.pressure_max_iterations)
        self.relaxation = float(params.source_relaxation)
        self.body_force = np.asarray(list(params.body_force), dtype=float)
        shape = grid.shape
        self.h = float(grid.h)
        self.lower = np.asarray(grid.lower, dtype=float)
        self.cells = np.asarray(grid.shape, dtype=np.int64)
        self.solid = self._solid.astype(np.uint8)
        self.kinds = self._face_kinds(scene)
        self.periodic = np.array([self.kinds[2 * a] == PERIODIC for a in range(3)])
        # axes that carry a derivative: not a one-cell periodic axis (2D problems)
        self.axes = np.array([not (self.periodic[a] and shape[a] == 1) for a in range(3)], np.int64)
        self.origins = np.stack([component_origin(self.lower, self.h, a) for a in range(3)])
        walls = [
            np.asarray(scene.wall_velocity.get(f, np.zeros(3)), dtype=float)
            for f in boundaries.FACE_NAMES
        ]
        self.planes = boundaries.boundary_planes(
            self.kinds, walls, self._inflow, self.lower, grid.upper, self.h, shape
        )
        interior = [s for s in scene.sources if s.kind != "uniform"]
        self.prim_kinds, self.prim_params = parameter_table(interior)
        self.prim_radii = np.array([max(p.core_radius, self.h) for p in interior])
        self.target = self._mass_sources(interior)
        # state: the three padded face arrays, pressure (warm start) and work arrays
        self.q = [np.zeros(padded_shape(shape, a)) for a in range(3)]
        self.work = [np.zeros_like(x) for x in self.q]
        self.work2 = [np.zeros_like(x) for x in self.q] if self.advection == "maccormack" else None
        self.qmin = [np.zeros_like(x) for x in self.q] if self.advection == "maccormack" else None
        self.qmax = [np.zeros_like(x) for x in self.q] if self.advection == "maccormack" else None
        self.free_static = [np.zeros(x.shape, np.uint8) for x in self.q]
        for a in range(3):
            boundaries.free_faces(a, self.kinds, self.solid, self.free_static[a])
        self.free = [f.copy() for f in self.free_static]
        self.solid_faces = [self._faces_touching_solid(a) for a in range(3)]
        dirichlet = any(k in (OUTFLOW, OPENING) for k in self.kinds)
        self.poisson = MultigridPoisson(shape, self.periodic, singular=not dirichlet)
        self.weights = [np.zeros(w.shape) for w in self.poisson.fine.w]
        self._set_weights()
        self.psi = np.zeros(shape)
        self.rhs = np.zeros(shape)
        self._u_cell = np.zeros((*shape, 3))
        self._cell_valid = False
        self._stats: dict[str, float] = {}
        self._blocked = None
        self._initial_condition(scene)

    # ------------------------------------------------------------ set-up helpers

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
        """Inflow wind at points of ``face``: uniform sources only where they blow in."""
        b = face // 2
        n_out = -1.0 if face % 2 == 0 else 1.0
        chosen = [s for s in self.scene.sources if s.kind != "uniform" or s.velocity[b] * n_out < 0]
        return superpose(chosen, points)

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

    def _faces_touching_solid(self, a) -> np.ndarray:
        """Flat indices of the faces of component a next to a body (model: bodies are rigid)."""
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
            self.q[a].reshape(-1)[self.solid_faces[a]] = 0.0
            boundaries.fill_boundary(self.q[a], a, self.kinds, self.planes[a], set_normal)
        if self._blocked is not None and len(self._blocked[0]):
            rows, vals = self._blocked
            coupling.apply_blocked(rows, vals, *self.q, *self.free)

    def _fill(self, arrays):
        for a in range(3):
            boundaries.fill_boundary(arrays[a], a, self.kinds, self.planes[a], True)

    def _carry(self, dt_h, src, out, bounds=False):
        """out[a] = src[a](x - d) for the three components, d the backtrace of the current
        velocity over dt_h = dt / h; with ``bounds`` also the limiter's qmin/qmax."""
        qmin, qmax = (self.qmin, self.qmax) if bounds else (out, out)
        advection.advect(
            *self.q, self.cells, self.periodic, dt_h, numba.get_num_threads(),
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
        Jacobi sweep from the advected field into the work arrays, which then become the
        state while the advected field stays as the right-hand side, then red-black
        Gauss-Seidel sweeps until the contraction bound meets ``diffusion_tol``."""
        alpha = self.viscosity * dt / self.h**2
        if alpha == 0.0:
            return 0
        n = max(x.shape[0] for x in self.q)
        changes, peaks = np.zeros(n), np.zeros(n)
        change = peak = 0.0
        for a in range(3):
            diffusion.jacobi_first_sweep(
                self.q[a], self.work[a], alpha, self.axes, self.free[a], changes, peaks
            )
            boundaries.fill_boundary(self.work[a], a, self.kinds, self.planes[a], False)
            change, peak = max(change, changes.max()), max(peak, peaks.max())
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
                        self.q[a], self.work[a], colour, alpha, self.axes, self.free[a], changes
                    )
                    change = max(change, changes.max())
                    boundaries.fill_boundary(self.q[a], a, self.kinds, self.planes[a], False)
        return sweeps

    def _project(self):
        face_flux(*self.q, self.target, self.rhs)
        np.negative(self.rhs, out=self.rhs)  # A psi = -(h div u - target)
        atol = 1e-14 * self.scene.reference_speed * np.sqrt(self.grid.n_cells)
        iters, res = self.poisson.solve(
            self.psi, self.rhs, self.tol, self.max_iterations, atol=atol
        )
        rhs_norm = self.poisson.rhs_norm  # ||rhs||_2, computed by the solve
        for a in range(3):
            subtract_gradient(self.q[a], a, self.psi, self.free[a], self.periodic)
            boundaries.fill_boundary(self.q[a], a, self.kinds, self.planes[a], False)
        self._cell_valid = False
        return iters, res, rhs_norm

    def _couple(self, obstacles: Obstacles):
        """Paper §4.1.2 (``paper``/``projection``): act on the air where the cloth is."""
        self._blocked = None
        tris = obstacles.cloth_triangles
        if self.coupling == "none" or tris is None or len(tris) == 0:
            return 0
        pos = np.ascontiguousarray(obstacles.cloth_positions, dtype=np.float64)
        vel = np.ascontiguousarray(obstacles.cloth_velocities, dtype=np.float64)
        tris = np.ascontiguousarray(tris, dtype=np.int64)
        start, items = triangle_cells(pos, tris, self.grid)
        marked = np.diff(start) > 0
        index = np.full(self.grid.n_cells, -1, dtype=np.int64)
        index[marked] = np.arange(marked.sum())
        index = index.reshape(self.grid.shape)
        m = int(marked.sum())
        normals = np.zeros((m, 3))
        velocity = np.zeros((m, 3))
        coupling.cell_normals(pos, vel, tris, start, items, index, normals, velocity)
        u, v, w = self.q
        for a in range(3):
            coupling.remove_normal_component(
                self.q[a], a, u, v, w, index, normals, velocity, self.work[a]
            )
        self.q, self.work = self.work, self.q
        if self.coupling == "projection":
            rows, vals = coupling.blocked_faces(
                pos,
                vel,
                tris,
                start,
                items,
                self.lower,
                self.h,
                np.asarray(self.grid.shape, dtype=np.int64),
            )
            self._blocked = (rows, vals)
            for a in range(3):
                self.free[a][...] = self.free_static[a]
        self._apply_boundaries(set_normal=True)
        if self.coupling == "projection":
            self._set_weights()
        return m

    # ------------------------------------------------------------ interface

    def step(self, dt: float, obstacles: Obstacles) -> None:
        t0 = time.perf_counter()
        marked = self._couple(obstacles)
        self._forces(dt)
        t1 = time.perf_counter()
        self._advect(dt)
        t2 = time.perf_counter()
        sweeps = self._diffuse(dt)
        t3 = time.perf_counter()
        iters, res, rhs_norm = self._project()
        t4 = time.perf_counter()
        peak, squares, count = divergence_norms(*self.q, self.target, self.solid)
        scale = 1.0 / self.scene.reference_speed  # h div u / U_ref
        speed = max(max_abs(x) for x in self.q)
        self._stats = {
            "pressure_iterations": float(iters),
            "pressure_residual": float(res),
            "pressure_rhs_norm": rhs_norm,
            "mac_divergence_max": peak * scale if count else float("nan"),
            "mac_divergence_rms": np.sqrt(squares / count) * scale if count else float("nan"),
            "diffusion_sweeps": float(sweeps),
            "cfl": float(speed * dt / self.h),
            "cloth_cells": float(marked),
            "couple_seconds": t1 - t0,
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
