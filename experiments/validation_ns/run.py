"""Validation of the navier_stokes backend against analytic solutions; writes data only.

    PYTHONPATH=. python experiments/validation_ns/run.py [--quick]

Studies (each one netCDF dataset + one CSV under experiments/validation_ns/results/):

- ``taylor_green``: 2D Taylor-Green vortex in a periodic box (L = 2 pi, U = 1,
  nu = 0.05), u = U exp(-2 nu t) (sin x cos y, -cos x sin y); measured decay rate and
  the L-infinity error at t = 1 s, for both advection schemes, (a) refining h and dt
  together (CFL 0.5) and (b) refining dt alone at 64 cells.
- ``poiseuille``: plane channel between no-slip walls (H = 1 m, nu = 1 m^2/s, body force
  f = 8 m/s^2, periodic x and z one cell thick), steady u(y) = f/(2 nu) y (H - y).
- ``free_stream``: a uniform oblique wind (2, 0.5, -0.3) m/s through an empty box with
  inflow and outflow faces; largest deviation after 20 steps.

``plot.py`` draws the figures and the convergence orders from these files.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from omegaconf import OmegaConf

from windbench.config import NavierStokesWindConfig
from windbench.grid import Grid
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.navier_stokes import NavierStokesWind

OUT = Path(__file__).resolve().parent / "results"
FACES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
NONE = Obstacles.rigid_only(())


def backend(spec, resolution, **params):
    scene = build_scene(spec)
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    return NavierStokesWind(scene, grid, OmegaConf.structured(NavierStokesWindConfig(**params)))


def taylor_green(n, scheme, dt, duration=1.0, nu=0.05):
    L = 2 * np.pi
    spec = dict(
        name="taylor_green",
        domain={"min": [0, 0, 0], "max": [L, L, L / n]},
        boundary={f: "periodic" for f in FACES},
        reference_speed=1.0,
    )
    wind = backend(spec, n, viscosity=nu, advection=scheme, pressure_tol=1e-10)

    def field(p, t=0.0):
        out = np.zeros_like(p)
        decay = np.exp(-2 * nu * t)
        out[:, 0] = decay * np.sin(p[:, 0]) * np.cos(p[:, 1])
        out[:, 1] = -decay * np.cos(p[:, 0]) * np.sin(p[:, 1])
        return out

    wind.set_velocity(field)
    u0 = wind.faces()[0].copy()
    steps = int(round(duration / dt))
    for _ in range(steps):
        wind.step(dt, NONE)
    t = steps * dt
    u = wind.faces()[0]
    rate = -np.log((u * u0).sum() / (u0 * u0).sum()) / t
    exact = field(wind.grid.cell_centres().reshape(-1, 3), t).reshape(wind.velocity().shape)
    err = np.abs(wind.velocity() - exact).max()
    return dict(
        cells=n, scheme=scheme, dt=dt, t=t, rate=rate, rate_exact=2 * nu,
        rate_rel_error=rate / (2 * nu) - 1, linf_error=err, linf_rel_error=err / np.exp(-2 * nu * t),
    ), wind.velocity()[:, :, 0, :2].copy()


def poiseuille(n, H=1.0, nu=1.0, f=8.0, duration=3.0):
    spec = dict(
        name="poiseuille",
        domain={"min": [0, 0, 0], "max": [H / n, H, H / n]},
        boundary=dict(x_min="periodic", x_max="periodic", y_min="no_slip", y_max="no_slip",
                      z_min="periodic", z_max="periodic"),
        reference_speed=1.0,
    )
    dt = 10.0 * (H / n) ** 2 / nu  # alpha = nu dt / h^2 = 10
    wind = backend(spec, n, viscosity=nu, body_force=[f, 0.0, 0.0], diffusion_tol=1e-13)
    for _ in range(int(round(duration / dt))):
        wind.step(dt, NONE)
    y = wind.grid.axes()[1]
    exact = f / (2 * nu) * y * (H - y)
    got = wind.velocity()[0, :, 0, 0]
    umax = f * H**2 / (8 * nu)
    return dict(cells=n, dt=dt, linf_rel_error=np.abs(got - exact).max() / umax,
                l2_rel_error=np.sqrt(np.mean((got - exact) ** 2)) / umax), (y, got, exact)


def free_stream(n, scheme, U=(2.0, 0.5, -0.3), steps=20):
    spec = dict(
        name="free_stream",
        domain={"min": [0, 0, 0], "max": [4.0, 2.0, 2.0]},
        boundary=dict(x_min="inflow", x_max="outflow", y_min="inflow", y_max="outflow",
                      z_min="outflow", z_max="inflow"),
        sources=[{"type": "uniform", "velocity": list(U)}],
    )
    wind = backend(spec, n, advection=scheme)
    for _ in range(steps):
        wind.step(0.05, NONE)
    dev = np.abs(wind.velocity() - np.asarray(U)).max() / np.linalg.norm(U)
    return dict(cells=n, scheme=scheme, steps=steps, max_rel_deviation=dev,
                pressure_iterations=wind.stats()["pressure_iterations"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="coarser sweep (CI-sized)")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    sizes = [16, 32, 64] if args.quick else [16, 32, 64, 128]

    rows, fields = [], {}
    for scheme in ("semi_lagrangian", "maccormack"):
        for n in sizes:  # (a) h and dt together, CFL 0.5
            row, uv = taylor_green(n, scheme, dt=0.5 * 2 * np.pi / n)
            rows.append({**row, "study": "h_and_dt"})
            fields[(scheme, n)] = uv
            print(rows[-1], flush=True)
        for dt in (0.05, 0.025, 0.0125) + (() if args.quick else (0.00625,)):  # (b) dt alone
            row, _ = taylor_green(64, scheme, dt=dt)
            rows.append({**row, "study": "dt_at_64"})
            print(rows[-1], flush=True)
    tg = pd.DataFrame(rows)
    tg.to_csv(OUT / "taylor_green.csv", index=False)
    xr.Dataset.from_dataframe(tg).to_netcdf(OUT / "taylor_green.nc")

    rows, profiles = [], {}
    for n in ([8, 16, 32] if args.quick else [8, 16, 32, 64]):
        row, prof = poiseuille(n)
        rows.append(row)
        profiles[n] = prof
        print(row, flush=True)
    po = pd.DataFrame(rows)
    po.to_csv(OUT / "poiseuille.csv", index=False)
    ds = xr.Dataset.from_dataframe(po)
    for n, (y, got, exact) in profiles.items():
        ds[f"u_{n}"] = (f"y_{n}", got, {"units": "m/s"})
        ds[f"u_exact_{n}"] = (f"y_{n}", exact, {"units": "m/s"})
        ds = ds.assign_coords({f"y_{n}": y})
    ds.to_netcdf(OUT / "poiseuille.nc")

    rows = [free_stream(n, s) for s in ("semi_lagrangian", "maccormack") for n in (8, 16, 32)]
    for r in rows:
        print(r, flush=True)
    fs = pd.DataFrame(rows)
    fs.to_csv(OUT / "free_stream.csv", index=False)
    xr.Dataset.from_dataframe(fs).to_netcdf(OUT / "free_stream.nc")


if __name__ == "__main__":
    main()
