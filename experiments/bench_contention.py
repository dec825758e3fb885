"""Navier-Stokes step time with and without a CPU-bound neighbour on one core.

A run's parallel kernels share the machine with whatever else runs. With spinning worker
threads a busy neighbour on one core can slow a step several-fold (every parallel region
waits for its slowest thread). This benchmark measures how much a step slows:

    PYTHONPATH=. python experiments/bench_contention.py [--resolution 64] [--steps 10]
        [--rounds 3] [--threads auto 1] [--chunksize 0]
    PYTHONPATH=. python experiments/bench_contention.py --launchers [--sweep 48 64 80 96]
    python experiments/bench_contention.py --runs 3 [--checkouts A B]

For each thread setting it builds the ``experiment=scaling`` fence (resolution^3 cells,
``navier_stokes``), then alternates rounds of ``--steps`` steps alone and ``--steps`` steps
beside a ``while True: pass`` process, so that a drift of the machine hits both alike.
Each step runs on the threads a run's :class:`windbench.runtime.ThreadBudget` gives it:
under ``auto`` fewer while the busy process holds a core. Appends to
experiments/results/bench_contention.csv, per thread setting: when (UTC) and with which
code, the median step alone, the median step beside the busy process, their ratio, the
median thread count of each, and the load average before and after (the busy process
adds 1 to it; the idle rounds are only idle if the machine is); with a one-thread row,
``one_core_ratio``: the one-thread step alone over the row's step alone, the ratio a run
shows when it leaves the busy process's core to it. The file keeps every measurement: the
ratio moves with the machine's speed from hour to hour. ``--chunksize N`` hands each
parallel loop's iterations out N at a time to whichever thread is free
(``numba.set_parallel_chunksize``; column ``chunksize``, 0: numba's default, one equal
share per thread): with ``--threads 2``, whether a run that keeps two threads beside the
busy process gains from the share of its core that the scheduler gives it.

``--launchers`` runs the ``experiment=scaling`` Navier-Stokes sweep over ``--sweep``
resolutions three times: the basic launcher (one run at a time, ``runtime.threads=auto``:
every core), the joblib launcher with ``n_jobs=2`` (two runs at once, one thread each) and
the basic launcher with ``runtime.threads=1`` (each run alone on one core: the idle
one-core time). It writes experiments/results/bench_launchers.csv: each sweep's wall time
and, per run, the median step and its ratio to the same run alone on one core.

``--runs N`` checks it as a user sees it: separate ``windbench experiment=scaling
wind=navier_stokes`` runs (``--resolution``, default threads), alone and then beside the
busy process, N times; with ``--checkouts`` each round runs every checkout's code in turn
(``PYTHONPATH``), an A/B in one alternation. It writes
experiments/results/bench_contention_runs.csv: per run pair the code version, the median
step (first excluded) and thread count alone and beside, and their ratio.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numba
import numpy as np
import pandas as pd

from experiments.bench_ns import Variant
from experiments.rows import append_rows, stamp
from windbench.runtime import AUTO, ThreadBudget, load_average

RESULTS = Path(__file__).parent / "results"
OUT = RESULTS / "bench_contention.csv"
FIELDS = (
    "date", "code", "resolution", "runtime_threads", "threads", "steps_per_round", "rounds",
    "alone_step_seconds", "busy_step_seconds", "ratio", "alone_threads", "busy_threads",
    "load_before", "load_after", "one_core_ratio", "chunksize",
)  # fmt: skip
LAUNCHERS = {
    "basic": [],
    "joblib_2": ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"],
    "basic_1thread": ["runtime.threads=1"],
}
BUSY = "while True: pass"
SETTLE = 0.5  # s: let the scheduler (and the thread budget) see the busy process come or go


def timed_steps(variant: Variant, budget: ThreadBudget, steps: int) -> list[tuple[float, int]]:
    """Wall seconds and thread count of each of ``steps`` backend steps."""
    variant.rows.clear()
    threads = []
    for _ in range(steps):
        threads.append(budget.update())
        variant.step()
    return [(r["step"], n) for r, n in zip(variant.rows, threads, strict=True)]


@contextmanager
def busy_neighbour():
    """One CPU-bound process (``BUSY``) for the time of the block, given SETTLE s to start."""
    busy = subprocess.Popen([sys.executable, "-c", BUSY])
    try:
        time.sleep(SETTLE)
        yield
    finally:
        busy.kill()
        busy.wait()


def beside_busy(variant: Variant, budget: ThreadBudget, steps: int) -> list[tuple[float, int]]:
    """As :func:`timed_steps` while one CPU-bound process runs."""
    try:
        with busy_neighbour():
            return timed_steps(variant, budget, steps)
    finally:
        time.sleep(SETTLE)  # the budget sees the busy process gone before the next round


def measure(setting, args) -> dict:
    budget = ThreadBudget.of(setting)
    variant = Variant(args.resolution, "float64", "semi_lagrangian", None)
    provenance = stamp()
    load0 = load_average()[0]
    alone, busy = [], []
    for _ in range(args.rounds):
        alone += timed_steps(variant, budget, args.steps)
        busy += beside_busy(variant, budget, args.steps)
    (a, a_threads), (b, b_threads) = (np.median(np.array(x), axis=0) for x in (alone, busy))
    budget.restore()
    return {
        **provenance,
        "resolution": args.resolution,
        "runtime_threads": str(setting),
        "threads": budget.planned,
        "steps_per_round": args.steps,
        "rounds": args.rounds,
        "alone_step_seconds": a,
        "busy_step_seconds": b,
        "ratio": b / a,
        "alone_threads": a_threads,
        "busy_threads": b_threads,
        "load_before": load0,
        "load_after": load_average()[0],
        "chunksize": numba.get_parallel_chunksize(),
    }


def median_step(ds) -> float:
    """A run dataset's median step time (wall, total), the first step (compile) left out."""
    names = [str(p) for p in ds["phase"].values]
    return float(np.median(ds["step_seconds"].values[1:, names.index("total")]))


def separate_run(checkout: str | None, resolution: int, folder: Path) -> dict:
    """One ``experiment=scaling`` Navier-Stokes run with the code of ``checkout`` (None:
    as installed): its code version, median step (first excluded) and thread count."""
    import os

    import xarray as xr

    env = {**os.environ, **({"PYTHONPATH": checkout} if checkout else {})}
    cmd = ["windbench", "experiment=scaling", "wind=navier_stokes",
           f"grid.resolution={resolution}", f"hydra.run.dir={folder}"]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    with xr.open_dataset(folder / "windbench.nc") as ds:
        threads = ds["step_threads"].values[1:] if "step_threads" in ds else [np.nan]
        return {"commit": ds.attrs["git_commit"], "step": median_step(ds),
                "threads": float(np.median(threads))}  # fmt: skip


def separate_runs(args) -> pd.DataFrame:
    """``--runs``: each checkout's run alone, then beside the busy process, per round."""
    import tempfile

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for checkout in args.checkouts:  # warm each version's numba cache
            separate_run(checkout, args.resolution, Path(tmp) / "warm")
        for round_ in range(args.runs):
            for checkout in args.checkouts:
                alone = separate_run(checkout, args.resolution, Path(tmp) / "alone")
                with busy_neighbour():
                    beside = separate_run(checkout, args.resolution, Path(tmp) / "beside")
                rows.append({
                    "round": round_, "commit": alone["commit"], "resolution": args.resolution,
                    "alone_step_seconds": alone["step"], "busy_step_seconds": beside["step"],
                    "ratio": beside["step"] / alone["step"], "alone_threads": alone["threads"],
                    "busy_threads": beside["threads"], "load_after": load_average()[0],
                })  # fmt: skip
                print(rows[-1], flush=True)
    return pd.DataFrame(rows)


def sweep(name: str, resolutions, folder: Path) -> tuple[float, pd.DataFrame]:
    """Run the scaling sweep with launcher ``name``: (wall seconds, median step per run)."""
    out = folder / name
    cmd = ["windbench", "-m", "experiment=scaling", "wind=navier_stokes",
           f"grid.resolution={','.join(map(str, resolutions))}", f"hydra.sweep.dir={out}",
           *LAUNCHERS[name]]  # fmt: skip
    start = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - start
    runs = collect(out)
    return wall, runs


def collect(folder: Path) -> pd.DataFrame:
    """Resolution, median step (first excluded) and threads of each run under ``folder``."""
    import xarray as xr

    rows = []
    for path in sorted(folder.glob("*/windbench.nc")):
        with xr.open_dataset(path) as ds:
            rows.append({
                "resolution": int(ds.attrs["grid_shape"][0]),
                "step_seconds": median_step(ds),
                "threads": int(ds.attrs.get("numba_threads", 0)),
            })  # fmt: skip
    return pd.DataFrame(rows).set_index("resolution")


def launchers(args) -> pd.DataFrame:
    """The three sweeps of ``--launchers``, one after the other."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        results = {name: sweep(name, args.sweep, Path(tmp)) for name in LAUNCHERS}
    alone = results["basic_1thread"][1]["step_seconds"]
    rows = []
    for name, (wall, runs) in results.items():
        for res, run in runs.iterrows():
            rows.append({
                "launcher": name, "sweep_wall_seconds": wall, "resolution": res,
                "threads": run["threads"], "step_seconds": run["step_seconds"],
                "ratio_to_alone_one_core": run["step_seconds"] / alone[res],
                "load_after": load_average()[0],
            })  # fmt: skip
    return pd.DataFrame(rows)


def with_one_core_ratio(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with ``one_core_ratio`` (module docstring), when it has a one-thread row."""
    one = table.loc[table.threads == 1, "alone_step_seconds"]
    if not one.empty:
        table["one_core_ratio"] = float(one.iloc[0]) / table["alone_step_seconds"]
    return table


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", nargs="+", default=["auto", "1"])
    parser.add_argument("--launchers", action="store_true")
    parser.add_argument("--sweep", type=int, nargs="+", default=[48, 64, 80, 96])
    parser.add_argument("--runs", type=int, default=0)
    parser.add_argument("--checkouts", nargs="+", default=[None])
    parser.add_argument("--chunksize", type=int, default=0)
    args = parser.parse_args()
    if args.chunksize < 0 or (args.chunksize and (args.runs or args.launchers)):
        parser.error(f"--chunksize must be >= 0, and only without --runs and --launchers "
                     f"(their runs are other processes), got {args.chunksize}")  # fmt: skip
    if args.runs or args.launchers:  # the last measurement of each
        table, out = (
            (separate_runs(args), RESULTS / "bench_contention_runs.csv")
            if args.runs
            else (launchers(args), RESULTS / "bench_launchers.csv")
        )
        print(table.to_string(index=False))
        table.to_csv(out, index=False)
        print(f"wrote {out}")
        return
    numba.set_parallel_chunksize(args.chunksize)
    rows = [measure(s if s == AUTO else int(s), args) for s in args.threads]
    table = with_one_core_ratio(pd.DataFrame(rows)).reindex(columns=FIELDS)
    print(table.to_string(index=False))
    append_rows(OUT, table.to_dict("records"), FIELDS)  # every measurement
    print(f"appended {len(table)} rows to {OUT}")


if __name__ == "__main__":
    main()
