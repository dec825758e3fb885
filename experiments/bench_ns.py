"""Benchmark of the navier_stokes backend on scene=fence in the cubic domain of
``experiment=scaling``: seconds per step (advect, diffuse, project), pressure iterations
and memory per cell, for 16^3 .. 128^3 cells.

    PYTHONPATH=. python experiments/bench_ns.py [--resolutions 16 32 64 128] [--steps 10]

Writes experiments/results/bench_ns.csv (one row per resolution: medians over the timed
steps after two warm-up steps) and prints the machine load (``uptime``) beside it, since the
machine's 2 cores are shared. ``setup_seconds`` (backend construction, incl. loading or
compiling the numba kernels) and ``first_step_seconds`` are reported separately; run the
script twice to see cached-compile figures (numba cache=True).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from windbench.cli import compose_config
from windbench.simulate import prepare
from windbench.wind import make_wind
from windbench.wind.base import Obstacles

OUT = Path(__file__).resolve().parent / "results" / "bench_ns.csv"


def array_bytes(obj) -> int:
    """Bytes held in numpy arrays reachable from the backend's attributes (one level deep)."""
    seen, total = set(), 0

    def visit(x, depth):
        nonlocal total
        if isinstance(x, np.ndarray):
            base = x if x.base is None else x.base
            if id(base) not in seen and isinstance(base, np.ndarray):
                seen.add(id(base))
                total += base.nbytes
        elif isinstance(x, list | tuple) and depth < 3:
            for y in x:
                visit(y, depth + 1)
        elif hasattr(x, "__dict__") and depth < 3:
            for y in vars(x).values():
                visit(y, depth + 1)

    visit(obj, 0)
    return total


def bench(resolution: int, steps: int, advection: str, turbulence: str | None) -> dict:
    cfg = compose_config(
        [
            "experiment=scaling",  # scene=fence in a cube: resolution r gives r^3 cells
            "wind=navier_stokes",
            f"grid.resolution={resolution}",
            f"wind.advection={advection}",
            *([f"wind.turbulence={turbulence}"] if turbulence else []),
        ]
    )
    setup = prepare(cfg)
    t0 = time.perf_counter()
    wind = make_wind(cfg.wind, setup.scene, setup.grid)
    t1 = time.perf_counter()
    obstacles = Obstacles.rigid_only(setup.scene.bodies)
    wind.step(setup.dt, obstacles)
    t2 = time.perf_counter()
    wind.step(setup.dt, obstacles)
    rows = []
    for _ in range(steps):
        s = time.perf_counter()
        wind.step(setup.dt, obstacles)
        e = time.perf_counter()
        rows.append({"step": e - s, **wind.stats()})
    df = pd.DataFrame(rows)
    cells = setup.grid.n_cells
    # a cold solve (zero initial pressure) of the uniform inflow against the fence
    for a in range(3):
        wind.q[a][...] = setup.scene.sources[0].velocity[a]
    wind._apply_boundaries(set_normal=True)
    wind.psi[...] = 0.0
    cold_iterations = wind._project()[0]
    return {
        "resolution": resolution,
        "shape": "x".join(map(str, setup.grid.shape)),
        "cells": cells,
        "advection": advection,
        "turbulence": str(cfg.wind.turbulence),
        "step_seconds": df.step.median(),
        "advect_seconds": df.advect_seconds.median(),
        "diffuse_seconds": df.diffuse_seconds.median(),
        "eddy_seconds": df.eddy_seconds.median(),
        "project_seconds": df.project_seconds.median(),
        "pressure_iterations": df.pressure_iterations.median(),
        "pressure_iterations_max": df.pressure_iterations.max(),
        "pressure_iterations_cold": cold_iterations,
        "mac_divergence_max": df.mac_divergence_max.max(),
        "float64_per_cell": array_bytes(wind) / 8 / cells,
        "setup_seconds": t1 - t0,
        "first_step_seconds": t2 - t1,
        "threads": int(os.environ.get("NUMBA_NUM_THREADS", os.cpu_count() or 1)),
        "load_average_1min": os.getloadavg()[0],
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--resolutions", type=int, nargs="+", default=[16, 32, 64, 128])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--advection", default="semi_lagrangian")
    ap.add_argument("--turbulence", default=None, help="wind.turbulence (default: the config's)")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    rows = []
    for res in args.resolutions:
        row = bench(res, args.steps, args.advection, args.turbulence)
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
        rows.append(row)
    df = pd.DataFrame(rows)
    if len(df) > 1:
        slope = np.polyfit(np.log(df.cells), np.log(df.step_seconds), 1)[0]
        print(f"cost ~ cells^{slope:.2f} over {list(df.resolution)}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    print(f"wrote {args.out}; uptime: {os.popen('uptime').read().strip()}")


if __name__ == "__main__":
    main()
