"""Step cost of the ``particles`` backend against grid size and particle count.

For each grid resolution (cells along the longest axis) and particle count, the fence
scene (6 m/s through an 8 m x 4 m x 4 m box with a wall) is filled with that many
particles at seeded random places in the air, emission off, and a few steps of
``sim.dt = 1/60 s`` are timed after ``SORT_EVERY`` warm-up steps (numba compiled, caches
warm, particles once reordered by cell as in a long run). Each row records the median
wall time of ``step()`` and of its tracing phase, the cell crossings per step, the
derived rates, and the crossings per CPU second of the whole steps (process time: what
the rate would be on an unshared core); ``load1`` is the machine's 1-minute load average
when the row was measured (the 2 cores are shared with other work).

    PYTHONPATH=. python experiments/bench_particles.py            # full table
    PYTHONPATH=. python experiments/bench_particles.py --quick    # 16, 32 x 1e4, 1e5

Writes ``experiments/results/bench_particles.csv``. Targets: at least 5e6
cell crossings per second, and step time growing no faster than linearly in particles.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from windbench.cli import compose_config
from windbench.geometry.bodies import inside
from windbench.grid import Grid
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.particles import SORT_EVERY, ParticleWind

OUT = Path(__file__).resolve().parent / "results" / "bench_particles.csv"
DT = 1.0 / 60.0


def measure(resolution: int, n_particles: int, steps: int, seed: int = 0) -> dict:
    cfg = compose_config(["wind=particles", "scene=fence", "wind.particles_per_second=0"])
    scene = build_scene(cfg.scene)
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    wind = ParticleWind(scene, grid, cfg.wind)
    rng = np.random.default_rng(seed)
    pts = scene.lower + rng.random((int(1.2 * n_particles) + 16, 3)) * (scene.upper - scene.lower)
    pts = pts[~inside(scene.bodies, pts)][:n_particles]
    wind.add_particles(pts, np.zeros(len(pts), dtype=np.int64))
    obstacles = Obstacles.rigid_only(scene.bodies)
    for _ in range(SORT_EVERY):  # warm-up (and compile on a cold cache)
        wind.step(DT, obstacles)
    total, trace, crossings, live = [], [], [], []
    cpu = 0.0
    for _ in range(steps):
        live.append(wind.stats()["live_particles"])
        c0, t0 = time.process_time(), time.perf_counter()
        wind.step(DT, obstacles)
        total.append(time.perf_counter() - t0)
        cpu += time.process_time() - c0
        st = wind.stats()
        trace.append(st["trace_seconds"])
        crossings.append(st["cell_crossings"])
    step_s, trace_s, cross = (float(np.median(v)) for v in (total, trace, crossings))
    return {
        "resolution": resolution,
        "cells": grid.n_cells,
        "particles": float(np.mean(live)),
        "step_seconds": step_s,
        "trace_seconds": trace_s,
        "cell_crossings": cross,
        "crossings_per_second": cross / trace_s,
        "crossings_per_step_second": cross / step_s,
        "particle_steps_per_second": float(np.mean(live)) / trace_s,
        "crossings_per_cpu_second": float(np.sum(crossings)) / cpu,
        "load1": os.getloadavg()[0],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small table for a smoke check")
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    resolutions = (16, 32) if args.quick else (16, 32, 64, 128)
    counts = (10_000, 100_000) if args.quick else (10_000, 100_000, 1_000_000)
    rows = []
    for res in resolutions:
        for n in counts:
            row = measure(res, n, args.steps)
            rows.append(row)
            print(
                f"res {res:4d}  particles {row['particles']:>9.0f}  step {row['step_seconds'] * 1e3:8.2f} ms"
                f"  trace {row['trace_seconds'] * 1e3:8.2f} ms  crossings/s {row['crossings_per_second']:.3g}"
                f"  per cpu-s {row['crossings_per_cpu_second']:.3g}"
                f"  load {row['load1']:.2f}",
                flush=True,
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(args.out, index=False)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
