"""The eddy-viscosity phase of the navier_stokes backend (``wind.turbulence``), A/B in
one process on the same developed fields: the forward-Euler substeps with the kernel of
another git revision (nu_t per cell, seven face viscosities per face and substep), the
same substeps with this checkout's kernel (face viscosities computed for the step: the
same bits), and this checkout's phase as a run takes it (one Runge-Kutta-Legendre step,
:func:`windbench.wind.navier_stokes.turbulence.legendre_stage`).

    PYTHONPATH=. python experiments/bench_eddy.py --base REV [--cases fence:94 ...]
        [--settle 20] [--repeats 20] [--out CSV]
    PYTHONPATH=. python experiments/bench_eddy.py --wake OTHER_CHECKOUT [--resolutions 94 188]

A case is ``scene:resolution`` in the scene's own experiment (``fence`` for the fence,
``paper`` otherwise). Each case's wind is built and stepped ``--settle`` steps, then each
way runs ``--repeats`` times in turn from the same velocity (restored after each): the
medians go to experiments/results/bench_eddy.csv with the substeps and stages, whether
the two kernels give the same bits, and how far the Runge-Kutta-Legendre step's change
of the velocity lies from the substeps' (largest difference over the largest change).

``--wake`` runs the fence of ``experiment=fence`` (``wind=navier_stokes``) instead, once
with this checkout and once with another (a checkout of the base revision), each in its
own process, and writes to experiments/results/bench_eddy_wake.csv the eddy phase's and
the whole step's medians, the stages or substeps per step, and the largest difference
between the two runs' time-mean wake speed ratios (u/u0 at the wake probes): what the
change of scheme does to the lee the fence comparison reports.
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from experiments.rows import show_and_append  # noqa: E402
from experiments.tree_runs import case_row, median_ms, module_at  # noqa: E402
from windbench.cli import compose_config  # noqa: E402
from windbench.simulate import Obstacles, prepare  # noqa: E402
from windbench.wind import make_wind  # noqa: E402
from windbench.wind.navier_stokes import boundaries, turbulence  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments/results/bench_eddy.csv"
WAKE_OUT = OUT.with_name("bench_eddy_wake.csv")
WAKE_FIELDS = (
    "date", "commit", "resolution", "eddy_ms_median", "step_ms_median", "eddy_steps_mean",
    "wake_ratio_max_difference", "run_seconds", "load_average_1min", "command",
)  # fmt: skip
MODULE = "windbench/wind/navier_stokes/turbulence.py"
CASES = ("fence:94", "fence:188", "two_flags_wall:80")
FIELDS = (
    "date", "commit", "base", "scene", "resolution", "shape", "substeps", "stages",
    "base_ms", "faces_ms", "legendre_ms", "faces_same_bits", "legendre_apart",
    "load_average_1min",
)  # fmt: skip


def euler_substeps(wind, dt: float, substep) -> int:
    """The forward-Euler substeps of the eddy term on ``wind``'s velocity, each
    component's by ``substep(q, a, dt_h2, out)`` and its ghost layer filled after each;
    returns the substeps taken (the result is in wind.q)."""
    stable = turbulence.SUBSTEP_LIMIT / (2 * int(wind.axes.sum()))
    substeps = max(1, int(np.ceil(float(wind.nu_t.max()) * dt / wind.h**2 / stable)))
    dt_h2 = dt / substeps / wind.h**2
    for _ in range(substeps):
        for a in range(3):
            substep(wind.q[a], a, dt_h2, wind.work[a])
            boundaries.fill_boundary(wind.work[a], a, wind.kinds, wind.planes[a], True)
        wind.q, wind.work = wind.work, wind.q
    return substeps


def ways(wind, base, dt: float) -> dict:
    """The three ways to time (module docstring), each a function of no arguments that
    returns the substeps or stages it took."""
    faces = [np.zeros(x.shape) for x in wind.q]
    euler = np.array([1.0, 0.0, 1.0])

    def old(q, a, dt_h2, out):
        base.eddy_diffusion(q, a, wind.nu_t, wind.axes, dt_h2, wind.free[a], out)

    def new(q, a, dt_h2, out):
        turbulence.eddy_diffusion(q, q, faces[a], wind.axes, dt_h2, wind.free[a], euler, out)

    def new_substeps():
        for a in range(3):
            turbulence.face_viscosity(wind.nu_t, a, faces[a])
        return euler_substeps(wind, dt, new)

    return {
        "base": lambda: euler_substeps(wind, dt, old),
        "faces": new_substeps,
        "legendre": lambda: wind._eddy_diffusion(dt)[1],
    }


def bench(case: str, base, args) -> dict:
    scene, resolution = case.split(":")
    experiment = "fence" if scene == "fence" else "paper"
    cfg = compose_config(
        [f"experiment={experiment}", f"scene={scene}", "wind=navier_stokes",
         f"grid.resolution={resolution}"]
    )  # fmt: skip
    setup = prepare(cfg)
    wind = make_wind(cfg.wind, setup.scene, setup.grid)
    obstacles = Obstacles.rigid_only(setup.scene.bodies)
    for _ in range(args.settle):
        wind.step(setup.dt, obstacles)
    start = [x.copy() for x in wind.q]
    times, after, counts = {}, {}, {}
    for _ in range(args.repeats + 1):  # the first of each: compilation
        for key, run in ways(wind, base, setup.dt).items():
            t0 = time.perf_counter()
            counts[key] = run()
            times.setdefault(key, []).append(time.perf_counter() - t0)
            after[key] = [x.copy() for x in wind.q]
            for x, x0 in zip(wind.q, start, strict=True):
                x[...] = x0
    ms = {k: 1e3 * float(np.median(v[1:])) for k, v in times.items()}
    change = max(float(np.abs(b - x0).max()) for b, x0 in zip(after["base"], start, strict=True))
    apart = max(
        float(np.abs(g - b).max()) for g, b in zip(after["legendre"], after["base"], strict=True)
    )
    same = all(np.array_equal(a, b) for a, b in zip(after["base"], after["faces"], strict=True))
    return {
        "date": datetime.date.today().isoformat(),
        "commit": subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip(),
        "base": args.base,
        "scene": scene,
        "resolution": int(resolution),
        "shape": "x".join(map(str, setup.grid.shape)),
        "substeps": counts["base"],
        "stages": counts["legendre"],
        "base_ms": round(ms["base"], 3),
        "faces_ms": round(ms["faces"], 3),
        "legendre_ms": round(ms["legendre"], 3),
        "faces_same_bits": same,
        "legendre_apart": apart / change if change else 0.0,
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def wake(resolution: int, trees: list[Path]) -> list[dict]:
    """The fence at ``resolution`` cells run with each checkout of ``trees`` (``--wake``)."""
    overrides = [
        "experiment=fence", "wind=navier_stokes", "scene=fence", f"grid.resolution={resolution}"
    ]  # fmt: skip
    ratios = []

    def read(ds):
        ratios.append(ds.wake_speed_ratio.mean("time").values)
        return {
            "eddy_ms_median": median_ms(ds, "eddy"),
            "step_ms_median": median_ms(ds, "total"),
            "eddy_steps_mean": float(ds.eddy_substeps.mean()),
        }

    rows = [case_row(tree, overrides, read) for tree in trees]
    apart = float(np.abs(ratios[0] - ratios[1]).max())
    for row in rows:
        row |= {"resolution": resolution, "wake_ratio_max_difference": round(apart, 5)}
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", help="git revision of the kernels to compare with")
    parser.add_argument("--wake", type=Path, help="another checkout: whole fence runs")
    parser.add_argument("--resolutions", nargs="+", type=int, default=[94, 188])
    parser.add_argument("--cases", nargs="+", default=list(CASES))
    parser.add_argument("--settle", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    if args.wake:
        rows = [r for n in args.resolutions for r in wake(n, [ROOT, args.wake.resolve()])]
        shown = ("commit", "resolution", "eddy_ms_median", "step_ms_median")
        show_and_append(WAKE_OUT, rows, WAKE_FIELDS, (*shown, "wake_ratio_max_difference"))
        return
    if not args.base:
        parser.error("--base REV or --wake CHECKOUT is required")
    with tempfile.TemporaryDirectory() as folder:
        base = module_at(args.base, MODULE, Path(folder), f"turbulence_{args.base}")
        rows = [bench(case, base, args) for case in args.cases]
    shown = ("scene", "resolution", "substeps", "stages", "base_ms", "faces_ms", "legendre_ms")
    show_and_append(args.out, rows, FIELDS, shown)


if __name__ == "__main__":
    main()
