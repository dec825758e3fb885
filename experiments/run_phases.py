"""Where a run's step goes, checkout against checkout: the median of every phase of
``step_seconds`` over the recorded window (after the spin-up) of one windbench run per
case and checkout, each run in its own process, the runs of one case in turn.

    PYTHONPATH=. python experiments/run_phases.py --trees . OTHER_CHECKOUT
        [--cases paper:80:two_flags_wall ...] [--out CSV]

A case is ``experiment:resolution:scene`` with ``wind=navier_stokes``, then any further
``:key=value`` overrides (``paper:64:two_flags_wall:wind.coupling=projection``). Appends to
experiments/results/run_phases.csv one row per run: the code version the dataset
records, the phases' medians in ms, the run's wall seconds and the load average.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from experiments.tree_runs import case_row, compare, median_ms  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments/results/run_phases.csv"
CASES = ("paper:80:two_flags_wall", "paper:40:shirt")
PHASES = ("total", "wind", "couple", "eddy", "advect", "diffuse", "project", "cloth", "aero")
FIELDS = (
    "date", "commit", "case", *(f"{p}_ms" for p in PHASES), "run_seconds",
    "load_average_1min", "command",
)  # fmt: skip


def run_case(case: str, tree: Path) -> dict:
    experiment, resolution, scene, *extra = case.split(":")
    overrides = [
        f"experiment={experiment}", "wind=navier_stokes", f"scene={scene}",
        f"grid.resolution={resolution}", *extra,
    ]  # fmt: skip
    read = lambda ds: {f"{p}_ms": median_ms(ds, p) for p in PHASES}  # noqa: E731
    return {"case": case, **case_row(tree, overrides, read)}


if __name__ == "__main__":
    shown = ("commit", "case", "total_ms", "couple_ms")
    compare(__doc__, CASES, ROOT, OUT, run_case, FIELDS, shown)
