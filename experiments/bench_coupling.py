"""The projection coupling's kernels (``wind.coupling=projection``) and the segment-triangle
test, A/B in one process: the modules of another git revision against this checkout's,
both loaded from copies (so compiled alike), called in turn on the same inputs.

- ``segment_triangle``: :func:`windbench.geometry.raster.segment_triangle` on SEGMENTS
  random segments and triangles, ns per call: the test of the projection coupling's
  grid faces and of the particle tracing's path pieces near a cloth triangle;
- a case ``scene:resolution``: the scene with ``wind=navier_stokes
  wind.coupling=projection`` at dt 1/60 from rest, stepped ``--settle`` steps, keeping
  the arguments of its last :func:`~windbench.wind.navier_stokes.coupling.blocked_faces`
  and :func:`~windbench.wind.navier_stokes.coupling.triangle_pressure_loads` calls; then
  each version runs ``--repeats`` times in turn on them, ms per call.

    PYTHONPATH=. python experiments/bench_coupling.py --base REV [--cases two_flags_wall:64]
        [--settle 60] [--repeats 30] [--out CSV]

appends to experiments/results/bench_coupling.csv one row per kernel and case: both
medians, whether the two versions give the same bits, and the load average.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from experiments.rows import show_and_append  # noqa: E402
from experiments.tree_runs import module_at  # noqa: E402
from windbench.cli import compose_config  # noqa: E402
from windbench.dataset import code_version, current_code  # noqa: E402
from windbench.simulate import Simulation, prepare  # noqa: E402
from windbench.wind.navier_stokes import backend  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments/results/bench_coupling.csv"
COUPLING = "windbench/wind/navier_stokes/coupling.py"
RASTER = "windbench/geometry/raster.py"
KERNELS = ("blocked_faces", "triangle_pressure_loads")
SEGMENTS = 200_000
CASES = ("two_flags_wall:64",)
FIELDS = (
    "date", "code", "base", "kernel", "case", "base_time", "new_time", "unit", "same_bits",
    "load_average_1min",
)  # fmt: skip


def versions(rev: str, folder: Path) -> dict:
    """{"base": (coupling, raster) of revision ``rev``, "new": this checkout's}, each
    coupling module importing the raster module of its own version."""
    out = {}
    for tag, version in (("base", rev), ("new", None)):
        raster = module_at(version, RASTER, folder, f"raster_{tag}")
        imports = {"from windbench.geometry.raster import": f"from raster_{tag} import"}
        out[tag] = (module_at(version, COUPLING, folder, f"coupling_{tag}", imports), raster)
    return out


def alternate(calls: dict, repeats: int) -> dict:
    """Median seconds of each of ``calls`` (name -> function), called in turn."""
    times = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - start)
    return {name: float(np.median(t)) for name, t in times.items()}


def _segment_loop(test):
    """A compiled loop of ``test`` over rows of segment and triangle corners."""

    @njit
    def loop(p0, p1, a, b, c, out):
        for i in range(p0.shape[0]):
            out[i] = test(p0[i], p1[i], a[i], b[i], c[i])

    return loop


def segment_row(mods: dict, repeats: int) -> dict:
    """ns per call of each version's segment-triangle test on SEGMENTS random cases."""
    rng = np.random.default_rng(0)
    corners = [rng.normal(size=(SEGMENTS, 3)) for _ in range(5)]
    out = {tag: np.empty(SEGMENTS) for tag in mods}
    loops = {tag: _segment_loop(mods[tag][1].segment_triangle) for tag in mods}
    calls = {tag: (lambda t=tag: loops[t](*corners, out[t])) for tag in mods}
    seconds = alternate(calls, repeats)
    return {
        "kernel": "segment_triangle",
        "case": f"{SEGMENTS} random",
        "base_time": round(1e9 * seconds["base"] / SEGMENTS, 1),
        "new_time": round(1e9 * seconds["new"] / SEGMENTS, 1),
        "unit": "ns per call",
        "same_bits": bool(np.array_equal(out["base"], out["new"])),
    }


def kernel_arguments(case: str, settle: int) -> dict:
    """The arguments of the last call of each of KERNELS in a projection-coupled run of
    ``case`` (``scene:resolution``) after ``settle`` steps."""
    scene, resolution = case.split(":")
    kept, package = {}, backend.coupling
    originals = {name: getattr(package, name) for name in KERNELS}

    def keep(name):
        def call(*args):
            kept[name] = tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args)
            return originals[name](*args)

        return call

    overrides = [
        f"scene={scene}", "wind=navier_stokes", "wind.coupling=projection",
        f"grid.resolution={resolution}", f"sim.dt={1.0 / 60.0}", "sim.duration=2.0",
        "sim.spinup=0", "sim.progress=false",
    ]  # fmt: skip
    try:
        for name in KERNELS:
            setattr(package, name, keep(name))
        sim = Simulation(prepare(compose_config(overrides)))
        for n in range(settle):
            sim.step(n)
    finally:
        for name, fn in originals.items():
            setattr(package, name, fn)
    return kept


def _same(a, b) -> bool:
    a, b = (a, b) if isinstance(a, tuple) else ((a,), (b,))
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def case_rows(case: str, mods: dict, args) -> list[dict]:
    """One row per kernel of KERNELS on the arguments of ``case``'s run."""
    kept, rows = kernel_arguments(case, args.settle), []
    for name in KERNELS:
        fns, inputs = {tag: getattr(mods[tag][0], name) for tag in mods}, kept[name]
        results = {tag: fn(*inputs) for tag, fn in fns.items()}  # compiled, compared
        calls = {tag: (lambda f=fn, x=inputs: f(*x)) for tag, fn in fns.items()}
        seconds = alternate(calls, args.repeats)
        rows.append(
            {
                "kernel": name,
                "case": case,
                "base_time": round(1e3 * seconds["base"], 4),
                "new_time": round(1e3 * seconds["new"], 4),
                "unit": "ms per call",
                "same_bits": _same(results["base"], results["new"]),
            }
        )
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", required=True, help="git revision to compare with")
    parser.add_argument("--cases", nargs="+", default=list(CASES))
    parser.add_argument("--settle", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        mods = versions(args.base, Path(folder))
        rows = [segment_row(mods, args.repeats)]
        rows += [row for case in args.cases for row in case_rows(case, mods, args)]
    stamp = {
        "date": datetime.date.today().isoformat(),
        "code": code_version(current_code()),
        "base": args.base,
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    rows = [{**stamp, **row} for row in rows]
    show_and_append(args.out, rows, FIELDS, ("kernel", "case", "base_time", "new_time", "unit"))


if __name__ == "__main__":
    main()
