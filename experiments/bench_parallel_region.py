"""What one parallel loop costs before it does any work, per threading set-up.

Every ``prange`` loop of a kernel wakes numba's other threads and waits for them. With
windbench's passive OpenMP wait (:mod:`windbench`: sleeping workers leave the cores to
other processes) that wake-up is what a step of a few hundred parallel loops pays on
every loop, and what a short kernel (a cloth self-contact pass of 0.2 ms) would pay per
call if it were threaded. Each set-up runs in its own process, since the threading layer
and the wait policy are read once when numba's runtime loads: an empty two-iteration
``prange`` loop called back to back ``--calls`` times, the best of ``--rounds`` rounds
(microseconds per call), beside the same loop compiled serially.

    PYTHONPATH=. python experiments/bench_parallel_region.py [--calls 2000] [--rounds 5]

appends one row per set-up to ``experiments/results/parallel_region.csv``: windbench's
default (OpenMP, passive wait), OpenMP with an active (spinning) wait, numba's workqueue
layer, and TBB where the ``tbb`` package can be loaded (else that row is left out).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from experiments.rows import measured_at, show_and_append

OUT = Path(__file__).resolve().parent / "results" / "parallel_region.csv"
FIELDS = ["date", "setup", "layer", "threads", "us_parallel", "us_serial", "load_average_1min"]
SETUPS = {
    "windbench default (OpenMP, passive wait)": {},
    "OpenMP, active wait": {"OMP_WAIT_POLICY": "active"},
    "workqueue": {"NUMBA_THREADING_LAYER": "workqueue"},
    "tbb": {"NUMBA_THREADING_LAYER": "tbb"},
}
CHILD = """
import json, sys, time
import numpy as np
import windbench  # its environment first: the passive wait unless the caller set a policy
import numba
from numba import njit, prange

@njit(parallel=True)
def parallel(a):
    for t in prange(2):
        a[t] += 1.0

@njit
def serial(a):
    for t in range(2):
        a[t] += 1.0

calls, rounds = int(sys.argv[1]), int(sys.argv[2])
a = np.zeros(2)
out = {}
for name, f in (("parallel", parallel), ("serial", serial)):
    f(a)
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(calls):
            f(a)
        times.append((time.perf_counter() - start) / calls * 1e6)
    out[name] = min(times)
out["layer"] = numba.threading_layer()
out["threads"] = numba.get_num_threads()
print(json.dumps(out))
"""


def measure(env: dict, calls: int, rounds: int) -> dict | None:
    """The child's figures under ``env`` added to this environment; None if it failed (a
    layer that cannot load)."""
    run = subprocess.run(
        [sys.executable, "-c", CHILD, str(calls), str(rounds)],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
    )
    if run.returncode != 0:
        return None
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    rows = []
    for setup, env in SETUPS.items():
        got = measure(env, args.calls, args.rounds)
        if got is None:
            print(f"{setup}: not available here")
            continue
        rows.append(
            {
                "date": measured_at(),
                "setup": setup,
                "layer": got["layer"],
                "threads": got["threads"],
                "us_parallel": round(got["parallel"], 2),
                "us_serial": round(got["serial"], 3),
                "load_average_1min": round(os.getloadavg()[0], 2),
            }
        )
    show_and_append(args.out, rows, FIELDS, ["setup", "layer", "us_parallel", "us_serial"])


if __name__ == "__main__":
    main()
