"""What one array operation costs to compile the first time a process uses it.

Each case compiles, in a fresh Python process with an empty numba cache and after a
warm-up kernel (numba's own start-up is not counted), one tiny kernel that uses the
operation, and records that compilation's CPU time (``time.process_time``): the loop that
copies a row, the same copy as a slice assignment (``a[:] = b``), ``np.cross``,
``ndarray.transpose(axes)`` and ``np.sort``. An operation whose error path formats its
message at run time makes numba compile its string machinery on first use; the kernels
avoid those (``windbench/arrays.py``).

    PYTHONPATH=$PWD python experiments/compile_first_use.py [--runs 3]

appends one row per case (median and spread over the runs) to
``experiments/results/compile_first_use.csv``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numba
import numpy as np

from experiments.rows import measured_at, show_and_append

OUT = Path(__file__).resolve().parent / "results" / "compile_first_use.csv"
FIELDS = ["date", "numba", "case", "cpu_seconds_median", "cpu_seconds_min", "cpu_seconds_max",
          "runs", "load_average_1min"]  # fmt: skip
CASES = {
    "loop copy": "for i in range(a.shape[0]):\n        a[i] = b[i]\n    return a[0]",
    "slice assignment a[:] = b": "a[:] = b\n    return a[0]",
    "np.cross": "return np.cross(a, b)[0]",
    "transpose(axes)": "return a.transpose((0,))[0]",
    "np.sort": "return np.sort(b)[0]",
}
PROGRAM = """
import time
import numpy as np
from numba import njit

@njit
def warm(a):
    return a[0] + 1.0

warm(np.zeros(3))

@njit
def case(a, b):
    {body}

start = time.process_time()
case(np.zeros(3), np.ones(3))
print(time.process_time() - start)
"""


def first_use_seconds(body: str) -> float:
    """CPU seconds to compile a kernel of ``body`` in a fresh process, empty cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        done = subprocess.run(
            [sys.executable, "-c", PROGRAM.format(body=body)],
            capture_output=True, text=True, env=env, check=True,
        )  # fmt: skip
    return float(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    rows = []
    for name, body in CASES.items():
        times = [first_use_seconds(body) for _ in range(args.runs)]
        rows.append(
            {
                "date": measured_at(),
                "numba": numba.__version__,
                "case": name,
                "cpu_seconds_median": round(float(np.median(times)), 3),
                "cpu_seconds_min": round(min(times), 3),
                "cpu_seconds_max": round(max(times), 3),
                "runs": args.runs,
                "load_average_1min": round(os.getloadavg()[0], 2),
            }
        )
    show_and_append(args.out, rows, FIELDS, ["case", "cpu_seconds_median"])


if __name__ == "__main__":
    main()
