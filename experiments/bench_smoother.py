"""The pressure smoother by slabs against the plain half sweeps, A/B in one process.

On the fence of ``experiment=scaling`` (as ``bench_ns.py`` builds it, float32, after two
steps), each multigrid level that sweeps by slabs (:func:`~windbench.wind.navier_stokes.
multigrid.smooth_by_slabs`) runs its smoothing of one cycle visit (2 sweeps, with CG's dot)
``--calls`` times, alternately with its slabs and with one slab (the plain half sweeps,
one parallel loop each), and the two medians and their ratio are recorded. Both give the
same bits (``tests/wind/navier_stokes/test_multigrid.py``); alternating call by call
puts a change of the machine's speed on both alike.

    PYTHONPATH=. python experiments/bench_smoother.py [--resolutions 64 128] [--calls 400]

appends to ``experiments/results/bench_smoother.csv``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numba
import numpy as np

from experiments.bench_ns import Variant
from experiments.rows import show_and_append, stamp
from windbench.wind.navier_stokes import multigrid as mg

OUT = Path(__file__).resolve().parent / "results" / "bench_smoother.csv"
FIELDS = [
    "date", "code", "resolution", "level", "slabs", "calls", "ms_plain", "ms_slabs",
    "ratio", "threads", "load_average_1min",
]  # fmt: skip


def level_rows(resolution: int, calls: int) -> list[dict]:
    """One row per level of the 'resolution' fence that sweeps by slabs."""
    v = Variant(resolution, "float32", "semi_lagrangian", None)
    for _ in range(2):
        v.wind.step(v.setup.dt, v.obstacles)
    rows = []
    for lev in v.wind.poisson.levels:
        if len(lev.slabs) < 3:
            continue
        versions = {"slabs": lev.slabs, "plain": mg.slab_bounds(lev.shape[0], 0)}
        r = np.random.default_rng(0).random(lev.shape)
        times = {"slabs": [], "plain": []}
        for k in range(2 * calls):
            mode = "slabs" if k % 2 else "plain"
            lev.slabs = versions[mode]
            start = time.perf_counter()
            lev.smooth(lev.x, lev.b, mg.PRE_SWEEPS, bool(k % 4 > 1), r)
            times[mode].append(time.perf_counter() - start)
        lev.slabs = versions["slabs"]
        plain, slabs = (1e3 * float(np.median(times[m])) for m in ("plain", "slabs"))
        rows.append(dict(
            **stamp(), resolution=resolution,
            level="x".join(map(str, lev.shape)), slabs=len(lev.slabs) - 1, calls=calls,
            ms_plain=round(plain, 4), ms_slabs=round(slabs, 4), ratio=round(slabs / plain, 3),
            threads=numba.get_num_threads(), load_average_1min=round(os.getloadavg()[0], 2),
        ))  # fmt: skip
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--resolutions", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--calls", type=int, default=400)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    rows = [row for res in args.resolutions for row in level_rows(res, args.calls)]
    show_and_append(
        args.out, rows, FIELDS, ["resolution", "level", "ms_plain", "ms_slabs", "ratio"]
    )


if __name__ == "__main__":
    main()
