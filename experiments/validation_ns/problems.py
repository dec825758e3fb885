"""Validation problems of the navier_stokes backend with known answers (paper §4.1):
shared by the tests (``tests/wind/navier_stokes/test_validation.py``, small sizes) and the study
``experiments/validation_ns/run.py`` (refinement series).

- :func:`taylor_green`: 2D Taylor-Green vortex in a periodic box (L = 2 pi, U = 1),
  u = U exp(-2 nu t) (sin x cos y, -cos x sin y): decay rate and L-infinity error.
- :func:`poiseuille`: plane channel between no-slip walls driven by a body force f,
  steady u(y) = f/(2 nu) y (H - y).
- :func:`free_stream`: a uniform oblique wind through an empty box with inflow/outflow
  faces must stay uniform.

Each takes ``precision`` (``wind.precision``: float64 or float32).
"""

from __future__ import annotations

import numpy as np
from omegaconf import OmegaConf

from windbench.grid import Grid
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.navier_stokes import NavierStokesConfig, NavierStokesWind
from windbench.wind.navier_stokes.boundaries import FACE_NAMES

NONE = Obstacles.rigid_only(())


def backend(spec, resolution, **params) -> NavierStokesWind:
    """The backend on the scene ``spec`` (a scene config dict) with ``params`` overrides;
    laminar (``turbulence="none"``) unless ``params`` say otherwise: the problems' answers
    are solutions of the Navier-Stokes equations without an eddy viscosity."""
    params.setdefault("turbulence", "none")
    scene = build_scene(spec)
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    return NavierStokesWind(scene, grid, OmegaConf.structured(NavierStokesConfig(**params)))


def taylor_green(n, scheme, dt, duration=1.0, nu=0.05, precision="float64"):
    """Run the Taylor-Green vortex on n x n cells; (figures dict, final (n, n, 2) field)."""
    L = 2 * np.pi
    spec = dict(
        name="taylor_green",
        domain={"min": [0, 0, 0], "max": [L, L, L / n]},
        boundary={f: "periodic" for f in FACE_NAMES},
        reference_speed=1.0,
    )
    wind = backend(spec, n, viscosity=nu, advection=scheme, pressure_tol=1e-10, precision=precision)

    def field(p, t=0.0):
        out = np.zeros_like(p)
        decay = np.exp(-2 * nu * t)
        out[:, 0] = decay * np.sin(p[:, 0]) * np.cos(p[:, 1])
        out[:, 1] = -decay * np.cos(p[:, 0]) * np.sin(p[:, 1])
        return out

    wind.set_velocity(field)
    u0 = wind.faces()[0].astype(np.float64)  # sums in float64 whatever the precision
    steps = int(round(duration / dt))
    for _ in range(steps):
        wind.step(dt, NONE)
    t = steps * dt
    u = wind.faces()[0].astype(np.float64)
    rate = -np.log((u * u0).sum() / (u0 * u0).sum()) / t
    exact = field(wind.grid.cell_centres().reshape(-1, 3), t).reshape(wind.velocity().shape)
    err = np.abs(wind.velocity() - exact).max()
    return dict(
        cells=n,
        scheme=scheme,
        dt=dt,
        t=t,
        rate=rate,
        rate_exact=2 * nu,
        rate_rel_error=rate / (2 * nu) - 1,
        linf_error=err,
        linf_rel_error=err / np.exp(-2 * nu * t),
    ), wind.velocity()[:, :, 0, :2].copy()


def poiseuille(n, H=1.0, nu=1.0, f=8.0, duration=1.5, precision="float64"):
    """Run the channel to steady state on n cells across; (figures, (y, u, u_exact))."""
    spec = dict(
        name="poiseuille",
        domain={"min": [0, 0, 0], "max": [H / n, H, H / n]},
        boundary=dict(
            x_min="periodic",
            x_max="periodic",
            y_min="no_slip",
            y_max="no_slip",
            z_min="periodic",
            z_max="periodic",
        ),
        reference_speed=1.0,
    )
    dt = 10.0 * (H / n) ** 2 / nu  # alpha = nu dt / h^2 = 10
    wind = backend(
        spec, n, viscosity=nu, body_force=[f, 0.0, 0.0], diffusion_tol=1e-11, precision=precision
    )
    for _ in range(int(round(duration / dt))):
        wind.step(dt, NONE)
    y = wind.grid.axes()[1]
    exact = f / (2 * nu) * y * (H - y)
    got = wind.velocity()[0, :, 0, 0]
    umax = f * H**2 / (8 * nu)
    return dict(
        cells=n,
        dt=dt,
        linf_rel_error=np.abs(got - exact).max() / umax,
        l2_rel_error=np.sqrt(np.mean((got - exact) ** 2)) / umax,
    ), (y, got, exact)


def free_stream(n, scheme, U=(2.0, 0.5, -0.3), steps=20, precision="float64"):
    """Uniform wind U through an empty 4 x 2 x 2 m box; largest relative deviation."""
    spec = dict(
        name="free_stream",
        domain={"min": [0, 0, 0], "max": [4.0, 2.0, 2.0]},
        boundary=dict(
            x_min="inflow",
            x_max="outflow",
            y_min="inflow",
            y_max="outflow",
            z_min="outflow",
            z_max="inflow",
        ),
        sources=[{"type": "uniform", "velocity": list(U)}],
    )
    wind = backend(spec, n, advection=scheme, precision=precision)
    for _ in range(steps):
        wind.step(0.05, NONE)
    dev = np.abs(wind.velocity() - np.asarray(U)).max() / np.linalg.norm(U)
    return dict(
        cells=n,
        scheme=scheme,
        steps=steps,
        max_rel_deviation=dev,
        pressure_iterations=wind.stats()["pressure_iterations"],
    )
