"""Validation of the navier_stokes backend against analytic solutions; writes data only.

    PYTHONPATH=. python experiments/validation_ns/run.py [--quick]

Studies (each one netCDF dataset + one CSV under experiments/validation_ns/results/):

- ``taylor_green``: 2D Taylor-Green vortex in a periodic box (L = 2 pi, U = 1,
  nu = 0.05), u = U exp(-2 nu t) (sin x cos y, -cos x sin y); measured decay rate and
  the L-infinity error at t = 1 s, for every ``wind.advection`` scheme, (a) refining h and
  dt together (CFL 0.5) and (b) refining dt alone at 64 cells.
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

from experiments.validation_ns.problems import free_stream, poiseuille, taylor_green

OUT = Path(__file__).resolve().parent / "results"
SCHEMES = ("semi_lagrangian", "maccormack", "second_order")  # wind.advection


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="coarser sweep (CI-sized)")
    ap.add_argument("--studies", nargs="+", default=["taylor_green", "poiseuille", "free_stream"])
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    sizes = [16, 32, 64] if args.quick else [16, 32, 64, 128]

    if "taylor_green" in args.studies:
        run_taylor_green(sizes, args.quick)
    if "poiseuille" in args.studies:
        run_poiseuille([8, 16, 32])
    if "free_stream" in args.studies:
        run_free_stream()


def run_taylor_green(sizes, quick):
    rows = []
    for scheme in SCHEMES:
        for n in sizes:  # (a) h and dt together, CFL 0.5
            row, _ = taylor_green(n, scheme, dt=0.5 * 2 * np.pi / n)
            rows.append({**row, "study": "h_and_dt"})
            print(rows[-1], flush=True)
        for dt in (0.05, 0.025, 0.0125) + (() if quick else (0.00625,)):  # (b) dt alone
            row, _ = taylor_green(64, scheme, dt=dt)
            rows.append({**row, "study": "dt_at_64"})
            print(rows[-1], flush=True)
    tg = pd.DataFrame(rows)
    tg.to_csv(OUT / "taylor_green.csv", index=False)
    xr.Dataset.from_dataframe(tg).to_netcdf(OUT / "taylor_green.nc")


def run_poiseuille(sizes):
    rows, profiles = [], {}
    for n in sizes:
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


def run_free_stream():
    rows = [free_stream(n, s) for s in SCHEMES for n in (8, 16, 32)]
    for r in rows:
        print(r, flush=True)
    fs = pd.DataFrame(rows)
    fs.to_csv(OUT / "free_stream.csv", index=False)
    xr.Dataset.from_dataframe(fs).to_netcdf(OUT / "free_stream.nc")


if __name__ == "__main__":
    main()
