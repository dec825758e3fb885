"""Benchmark of the navier_stokes backend on scene=fence in the cubic domain of
``experiment=scaling``: seconds per step (advect, diffuse, project), pressure iterations
and memory per cell, in both precisions (``wind.precision``), beside the plain numba MGPCG
step of ``../shared/baselines/nb_fluid.py`` (``--solver mgpcg --pdtype f64``) measured in
the same run.

    PYTHONPATH=. python experiments/bench_ns.py [--resolutions 64 128] [--steps 10]
        [--settle 60] [--rounds 2] [--precisions float64 float32]
        [--advection semi_lagrangian second_order] [--no-baseline]
        [--set "KEY=VALUE ..." ...] [--out CSV]
    PYTHONPATH=. python experiments/bench_ns.py --validation


Writes experiments/results/bench_ns.csv: one row per resolution, precision and advection
scheme (medians over the timed steps, after two warm-up steps and the settling ones),
each with the ``date`` and ``code`` it was measured at (:func:`experiments.rows.stamp`),
with ``baseline_seconds`` and ``ratio_to_baseline`` (the baseline as it ships: numba's
default OpenMP wait, whose spinning threads start each parallel loop sooner) and
``baseline_passive_seconds`` and ``ratio_to_baseline_passive`` (the baseline under
windbench's passive wait policy, which this process runs under; the two differ most on
small grids), each with ``baseline..._advect_seconds``: the baseline's own timing of its
advection (first-order, four trilinear lookups per face) beside ``advect_seconds``.
``--set`` adds variants of further overrides (column ``overrides``; ``""``: none). The
variants of one resolution are stepped in turn (A, B, A, B, ...), so that a change in
the machine's load hits them alike, and the steps are split into
``--rounds`` rounds, each followed by one run of the baseline each way: the baseline
figures are the medians of those runs (each run's in ``baseline_rounds`` and
``baseline_passive_rounds``), so that a drift of the machine's speed over the minutes of
a run (the same step took 28 to 40 ms at 64^3 within an hour here) hits windbench and
the baseline alike. Each variant's fields leave the cache while the others step: run one
variant for the figures of a single run (the same 64^3 step took 33-37 ms alone and
52-62 ms as one of four variants). The load average (``uptime``) is printed and
recorded, since the machine's 2 cores are shared. ``setup_seconds`` (backend
construction, incl. loading or compiling the numba kernels) and ``first_step_seconds``
are reported separately; run the script twice to see cached-compile figures (numba
cache=True).

Each variant first takes ``--settle`` untimed steps (column ``settle_steps``), so that
the timed steps are those of a developed flow, as in a run after its spin-up, rather
than the start from rest: the pressure solve's extrapolated guess
(``wind.pressure_guess``) saves iterations once the pressure varies smoothly (at 64^3
from about the 35th step; ``--settle 0`` times steps 3 to 12 from rest).

``--validation`` runs the validation problems (experiments/validation_ns/problems.py) at
64 cells in both precisions instead: Taylor-Green at CFL 0.5 for every scheme and
Poiseuille, their errors and the relative change float32 makes to each, written to
experiments/results/bench_ns_precision.csv.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from itertools import product
from pathlib import Path

import numba
import numpy as np
import pandas as pd

from experiments.rows import stamp
from experiments.validation_ns.problems import poiseuille, taylor_green
from windbench import set_environment
from windbench.cli import compose_config
from windbench.simulate import prepare
from windbench.wind import make_wind
from windbench.wind.base import Obstacles

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "results" / "bench_ns.csv"
SETTLE = 60  # untimed steps before the timed ones (--settle)
BASELINES = ROOT.parent / "shared" / "baselines"
VALIDATION_OUT = ROOT / "experiments" / "results" / "bench_ns_precision.csv"
VALIDATION_CELLS = 64


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


class Variant:
    """One backend configuration at one resolution, built and warmed up."""

    def __init__(self, resolution, precision, advection, turbulence, overrides=()):
        self.key = dict(
            resolution=resolution, precision=precision, advection=advection, turbulence=turbulence
        )
        self.key["overrides"] = " ".join(overrides)
        cfg = compose_config(
            [
                "experiment=scaling",  # scene=fence in a cube: resolution r gives r^3 cells
                "wind=navier_stokes",
                f"grid.resolution={resolution}",
                f"wind.precision={precision}",
                f"wind.advection={advection}",
                *([f"wind.turbulence={turbulence}"] if turbulence else []),
                *overrides,
            ]
        )
        self.cfg, self.setup = cfg, prepare(cfg)
        t0 = time.perf_counter()
        self.wind = make_wind(cfg.wind, self.setup.scene, self.setup.grid)
        t1 = time.perf_counter()
        self.obstacles = Obstacles.rigid_only(self.setup.scene.bodies)
        self.wind.step(self.setup.dt, self.obstacles)
        t2 = time.perf_counter()
        self.wind.step(self.setup.dt, self.obstacles)
        self.setup_seconds, self.first_step_seconds = t1 - t0, t2 - t1
        self.rows = []

    def step(self):
        s = time.perf_counter()
        self.wind.step(self.setup.dt, self.obstacles)
        self.rows.append({"step": time.perf_counter() - s, **self.wind.stats()})

    def row(self) -> dict:
        df = pd.DataFrame(self.rows)
        cells = self.setup.grid.n_cells
        return {
            **self.key,
            "shape": "x".join(map(str, self.setup.grid.shape)),
            "cells": cells,
            "turbulence": str(self.cfg.wind.turbulence),
            "step_seconds": df.step.median(),
            **{f"{p}_seconds": df[f"{p}_seconds"].median() for p in PHASES},
            "pressure_iterations": df.pressure_iterations.median(),
            "pressure_iterations_max": df.pressure_iterations.max(),
            "mac_divergence_max": df.mac_divergence_max.max(),
            "bytes_per_cell": array_bytes(self.wind) / cells,
            "setup_seconds": self.setup_seconds,
            "first_step_seconds": self.first_step_seconds,
            "threads": numba.get_num_threads(),
        }


PHASES = ("advect", "diffuse", "eddy", "project")


def baseline(resolution: int, folder: Path, as_shipped: bool) -> tuple[float, float]:
    """Median step and median advection (s) of the plain numba MGPCG baseline (float64
    pressure; its advection first-order, timed apart by the baseline itself) at N^3 cells:
    ``as_shipped`` in the environment a user runs it in (without the variables windbench
    set on import, so with numba's default, spinning, OpenMP wait), else in this process's
    (windbench's passive wait policy, :mod:`windbench`)."""
    drop = {"PEERS_RESULTS", *(set_environment() if as_shipped else ())}
    proc = subprocess.run(
        [sys.executable, "nb_fluid.py", "--N", str(resolution), "--solver", "mgpcg",
         "--pdtype", "f64"],
        cwd=folder, capture_output=True, text=True, check=True,
        env={k: v for k, v in os.environ.items() if k not in drop},
    )  # fmt: skip
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT "))
    result = json.loads(line.removeprefix("RESULT "))
    return float(result["median_s"]), float(result["advect_median_s"])


def bench(resolution: int, args) -> list[dict]:
    variants = [
        Variant(resolution, p, a, args.turbulence, tuple(o.split()))
        for p, a, o in product(args.precisions, args.advection, args.set)
    ]
    for _ in range(args.settle):  # untimed: the flow develops
        for v in variants:
            v.step()
    for v in variants:
        v.rows.clear()
    bases = {"": [], "_passive": []}
    per_round = -(-args.steps // args.rounds)
    for done in range(0, args.steps, per_round):
        for _ in range(min(per_round, args.steps - done)):  # in turn: the load hits all alike
            for v in variants:
                v.step()
        for as_shipped, suffix in ((True, ""), (False, "_passive")):
            if args.baselines:
                bases[suffix].append(baseline(resolution, args.baselines, as_shipped))
    load, provenance = os.getloadavg()[0], stamp()
    rows = [
        {**provenance, **v.row(), "settle_steps": args.settle, "load_average_1min": load}
        for v in variants
    ]
    del variants
    for suffix, runs in bases.items():
        times, advects = zip(*runs, strict=True) if runs else ((), ())
        base = float(np.median(times)) if times else np.nan
        for row in rows:
            row[f"baseline{suffix}_seconds"] = base
            row[f"ratio_to_baseline{suffix}"] = row["step_seconds"] / base
            row[f"baseline{suffix}_rounds"] = " ".join(f"{t:.4f}" for t in times)
            row[f"baseline{suffix}_advect_seconds"] = (
                float(np.median(advects)) if advects else np.nan
            )
    for row in rows:
        row["load_average_after_baseline"] = os.getloadavg()[0]
    return rows


def validation(n: int = VALIDATION_CELLS) -> pd.DataFrame:
    """The validation errors at n cells in float64 and float32, and float32's relative
    change of each (|e32 / e64 - 1|)."""
    rows = []
    for precision in ("float64", "float32"):
        for scheme in ("semi_lagrangian", "maccormack", "second_order"):
            row, _ = taylor_green(n, scheme, dt=0.5 * 2 * np.pi / n, precision=precision)
            for key in ("rate_rel_error", "linf_rel_error"):
                rows.append(dict(problem="taylor_green", scheme=scheme, error=key,
                                 precision=precision, value=row[key]))  # fmt: skip
        row, _ = poiseuille(n, precision=precision)
        for key in ("linf_rel_error", "l2_rel_error"):
            rows.append(dict(problem="poiseuille", scheme="semi_lagrangian", error=key,
                             precision=precision, value=row[key]))  # fmt: skip
    df = pd.DataFrame(rows).pivot_table(
        index=["problem", "scheme", "error"], columns="precision", values="value"
    )
    df["relative_change"] = (df.float32 / df.float64 - 1).abs()
    df["cells"] = n
    return pd.concat([pd.DataFrame([stamp()] * len(df)), df.reset_index()], axis=1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--resolutions", type=int, nargs="+", default=[16, 32, 64, 128])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=2, help="baseline runs between the steps")
    ap.add_argument("--settle", type=int, default=SETTLE, help="untimed steps before the timed")
    ap.add_argument("--precisions", nargs="+", default=["float64", "float32"])
    ap.add_argument("--advection", nargs="+", default=["semi_lagrangian"])
    ap.add_argument("--turbulence", default=None, help="wind.turbulence (default: the config's)")
    ap.add_argument(
        "--set",
        nargs="+",
        default=[""],
        help='override sets, each a variant: --set "" "wind.pressure_tol=1e-5"',
    )
    ap.add_argument("--baselines", type=Path, default=BASELINES)
    ap.add_argument("--no-baseline", dest="baselines", action="store_const", const=None)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--validation", action="store_true", help="the errors, not the timings")
    args = ap.parse_args()
    if args.rounds < 1 or args.steps < 1:
        ap.error(f"--steps and --rounds must be >= 1, got {args.steps} and {args.rounds}")
    if args.validation:
        df = validation()
        print(df.to_string())
        df.to_csv(VALIDATION_OUT, index=False)
        print(f"wrote {VALIDATION_OUT}; largest change {df.relative_change.max():.2e}")
        return
    rows = []
    for res in args.resolutions:
        for row in bench(res, args):
            shown = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}
            print(shown, flush=True)
            rows.append(row)
    df = pd.DataFrame(rows)
    for (prec, adv), g in df.groupby(["precision", "advection"]):
        if len(g) > 1:
            slope = np.polyfit(np.log(g.cells), np.log(g.step_seconds), 1)[0]
            print(f"{prec} {adv}: cost ~ cells^{slope:.2f} over {list(g.resolution)}")
    print(
        df.pivot_table(
            index="resolution",
            columns=["precision", "advection", "overrides"],
            values="step_seconds",
        ).mul(1e3).round(2).to_string()
        + "\n(ms per step; baseline ms: "
        + ", ".join(f"{r}: {b * 1e3:.1f}" for r, b in df.groupby("resolution").baseline_seconds.first().items())
        + ")"
    )  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    print(f"wrote {args.out}; uptime: {os.popen('uptime').read().strip()}")


if __name__ == "__main__":
    main()
