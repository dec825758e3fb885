"""The projection's cost against the grid's shape: MGPCG iterations per step and the
median projection time of one windbench run per case, each run in its own process.

    PYTHONPATH=. python experiments/pressure_grid_shape.py [--cases paper:80 ...]
        [--trees . /path/to/other/checkout] [--out CSV]

A case is ``experiment:resolution[:scene]`` (scene two_flags_wall unless given) with
``wind=navier_stokes``. Each ``--trees`` entry is a checkout of windbench put first on
PYTHONPATH and made the working directory of its runs (:mod:`experiments.tree_runs`;
default: this one), so that two versions of the solver are compared case by case, runs
alternated in one invocation; the dataset's own
``git_commit`` names the code each row ran. The statistics are taken over the recorded
window only (after the run's spin-up, ``sim.spinup``): a developed flow.

Appends to experiments/results/pressure_grid_shape.csv (per run: the grid's shape, the
multigrid's coarsest level, the recorded steps, the mean and max MGPCG iterations, the
median projection time and median step (the ``total`` phase), the run's wall seconds
and the load average).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from experiments.tree_runs import case_row, compare, median_ms  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments/results/pressure_grid_shape.csv"
CASES = (
    "paper:72", "paper:80", "paper:96", "paper:40:shirt", "reference:160",
    "fence:94:fence", "fence:188:fence",
)  # fmt: skip
FIELDS = (
    "date", "commit", "experiment", "scene", "resolution", "shape", "coarsest_level",
    "steps", "pressure_iterations_mean", "pressure_iterations_max", "project_ms_median",
    "step_ms_median", "run_seconds", "load_average_1min", "command",
)  # fmt: skip
SHOWN = ("commit", "scene", "resolution", "shape", "coarsest_level", "pressure_iterations_mean")


def coarsest_level(tree: Path, shape: tuple[int, ...]) -> str:
    """The coarsest multigrid level of a grid in the solver of checkout ``tree``."""
    code = (
        "import numpy as np\n"
        "from windbench.wind.navier_stokes.multigrid import MultigridPoisson\n"
        f"s = MultigridPoisson({tuple(shape)}, np.zeros(3, bool), singular=False)\n"
        "print('x'.join(map(str, s.levels[-1].shape)))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tree, env=env, capture_output=True, text=True
    )
    return out.stdout.strip() if out.returncode == 0 else "?"


def run_case(case: str, tree: Path) -> dict:
    """One windbench run of ``case`` with the code of checkout ``tree``."""
    experiment, resolution, *scene = case.split(":")
    scene = scene[0] if scene else "two_flags_wall"
    overrides = [
        f"experiment={experiment}", "wind=navier_stokes", f"scene={scene}",
        f"grid.resolution={resolution}",
    ]  # fmt: skip

    def read(ds):
        iterations = ds.pressure_iterations.values
        shape = tuple(int(n) for n in ds.attrs["grid_shape"])
        return {
            "shape": "x".join(map(str, shape)),
            "coarsest_level": coarsest_level(tree, shape),
            "steps": len(iterations),
            "pressure_iterations_mean": round(float(iterations.mean()), 3),
            "pressure_iterations_max": int(iterations.max()),
            "project_ms_median": median_ms(ds, "project"),
            "step_ms_median": median_ms(ds, "total"),
        }

    row = case_row(tree, overrides, read)
    return {"experiment": experiment, "scene": scene, "resolution": int(resolution), **row}


if __name__ == "__main__":
    compare(__doc__, CASES, ROOT, OUT, run_case, FIELDS, SHOWN)
