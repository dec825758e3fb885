"""The Navier-Stokes kernels' serial against their parallel versions
(windbench/wind/navier_stokes/threads.py): the step time of each, per grid and thread count.

    PYTHONPATH=. python experiments/bench_kernel_versions.py [--cases fence:16 fence:24 ...]
        [--threads 1 2] [--steps 30]

Per case (scene:resolution) and thread count, two backends are built on the same scene
and stepped in turn (A, B, A, B, ...), one with every kernel's parallel version and one
with the serial versions, rigid bodies only; medians of the step and its phases over the
steps after the first three. The two must give the same bits (``same_bits``). Writes
experiments/results/bench_kernel_versions.csv; the threshold ``PARALLEL_CELLS`` in
threads.py is read off it.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numba
import numpy as np
import pandas as pd

from windbench.cli import compose_config
from windbench.simulate import prepare
from windbench.wind import make_wind
from windbench.wind.base import Obstacles
from windbench.wind.navier_stokes import threads as versions

OUT = Path(__file__).resolve().parent / "results" / "bench_kernel_versions.csv"
CASES = ["fence:16", "two_flags_wall:40", "fence:32", "two_flags_wall:80", "fence:48", "fence:64"]
PHASES = ("advect_seconds", "diffuse_seconds", "project_seconds")
WARM_STEPS = 3
ALWAYS, NEVER = 0, 1 << 62  # PARALLEL_CELLS that choose the parallel / serial versions


def build(scene: str, resolution: int, parallel_cells: int):
    """(setup, backend, obstacles) with the kernel versions chosen by ``parallel_cells``;
    ``scene=fence`` is the cubic box of ``experiment=scaling``."""
    versions.PARALLEL_CELLS = parallel_cells
    base = ["experiment=scaling"] if scene == "fence" else [f"scene={scene}"]
    cfg = compose_config([*base, "wind=navier_stokes", f"grid.resolution={resolution}"])
    setup = prepare(cfg)
    wind = make_wind(cfg.wind, setup.scene, setup.grid)
    return setup, wind, Obstacles.rigid_only(setup.scene.bodies)


def timed_step(run, parallel_cells: int) -> list[float]:
    """One step of ``run`` with the given versions: [seconds, advect, diffuse, project]."""
    setup, wind, obstacles = run
    versions.PARALLEL_CELLS = parallel_cells
    t0 = time.perf_counter()
    wind.step(setup.dt, obstacles)
    seconds = time.perf_counter() - t0
    return [seconds] + [wind.stats()[p] for p in PHASES]


def compare(scene: str, resolution: int, threads: int, steps: int) -> dict:
    numba.set_num_threads(threads)
    runs = {cells: build(scene, resolution, cells) for cells in (ALWAYS, NEVER)}
    times = {cells: [] for cells in runs}
    for step in range(steps):
        for cells, run in runs.items():
            figures = timed_step(run, cells)
            if step >= WARM_STEPS:
                times[cells].append(figures)
    parallel, serial = (np.median(times[c], axis=0) for c in (ALWAYS, NEVER))
    row = dict(scene=scene, resolution=resolution, cells=runs[ALWAYS][0].grid.n_cells)
    row.update(threads=threads, steps=steps - WARM_STEPS)
    for name, figures in (("parallel", parallel), ("serial", serial)):
        row[f"{name}_step_seconds"] = figures[0]
        row.update({f"{name}_{p}": v for p, v in zip(PHASES, figures[1:], strict=True)})
    row["serial_over_parallel"] = serial[0] / parallel[0]
    row["same_bits"] = bool(np.array_equal(runs[ALWAYS][1].velocity(), runs[NEVER][1].velocity()))
    row["load_average_1min"] = os.getloadavg()[0]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=CASES, help="scene:resolution")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    rows = []
    for case in args.cases:
        scene, resolution = case.split(":")
        for threads in args.threads:
            row = compare(scene, int(resolution), threads, args.steps)
            print(
                f"{case} ({row['cells']} cells), {threads} thread(s): parallel "
                f"{row['parallel_step_seconds'] * 1e3:.2f} ms, serial "
                f"{row['serial_step_seconds'] * 1e3:.2f} ms, same bits {row['same_bits']}",
                flush=True,
            )
            rows.append(row)
    pd.DataFrame(rows).to_csv(args.out, index=False)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
