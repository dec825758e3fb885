"""Self-collision in the paper's cloth scenes: intersecting triangle pairs and cloth cost.

Each case is one run of the paper comparison's configuration (``experiment=paper``: its
spin-up and steady window, seed 0) at ``sim.dt=0.01`` and the experiment's 40 cells, with
``cloth.self_collision`` on and off: the largest and the mean number of intersecting
triangle pairs over the recorded steps (``self_intersections``), the deepest body
penetration, and the median cloth phase of ``step_seconds`` (wall s per step, bodies and
self-contact included), beside the whole run's wall time.

    PYTHONPATH=$PWD python experiments/self_collision_scenes.py [--quick]

writes ``experiments/results/self_collision_scenes.csv``; ``--quick`` runs the
``global`` wind only (no Navier-Stokes runs).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # before numba is imported
import time
from pathlib import Path

import numpy as np

from experiments.bench_cloth import write_rows
from experiments.rows import measured_at
from windbench.cli import compose_config
from windbench.dataset import run_dataset
from windbench.simulate import Simulation, prepare

OUT = Path(__file__).resolve().parent / "results" / "self_collision_scenes.csv"
SCENES = ("flag", "two_flags_wall", "shirt")
WINDS = ("global", "navier_stokes")


def case(scene: str, wind: str, self_collision: bool) -> dict:
    """One paper-configuration run and its self-contact figures."""
    cfg = compose_config(
        [
            "experiment=paper",
            f"scene={scene}",
            f"wind={wind}",
            "sim.dt=0.01",
            "sim.progress=false",
            f"cloth.self_collision={str(self_collision).lower()}",
        ]
    )
    setup = prepare(cfg)
    start = time.perf_counter()
    recorder = Simulation(setup).run(progress=False)
    wall = time.perf_counter() - start
    ds = run_dataset(setup, recorder, "complete")
    pairs = np.asarray(ds["self_intersections"].values, dtype=float)
    cloth = ds["step_seconds"].sel(phase="cloth").values
    return {
        "scene": scene,
        "wind": wind,
        "self_collision": self_collision,
        "steps_recorded": pairs.size,
        "self_intersections_max": float(np.nanmax(pairs)),
        "self_intersections_mean": float(np.nanmean(pairs)),
        "max_penetration": float(np.nanmax(ds["max_penetration"].values)),
        "cloth_ms_median": 1e3 * float(np.median(cloth)),
        "run_wall_s": wall,
        "load_average_1min": os.getloadavg()[0],
        "date": measured_at(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the global wind only")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    rows = []
    for wind in WINDS[:1] if args.quick else WINDS:
        for scene in SCENES:
            for on in (True, False):
                rows.append(case(scene, wind, on))
                r = rows[-1]
                print(
                    f"{scene:15s} {wind:14s} self_collision={on!s:5s} pairs max "
                    f"{r['self_intersections_max']:.0f} mean {r['self_intersections_mean']:.1f}, "
                    f"cloth {r['cloth_ms_median']:.2f} ms/step, run {r['run_wall_s']:.1f} s"
                )
    write_rows(rows, args.out, args.out)


if __name__ == "__main__":
    main()
