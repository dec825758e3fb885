"""Where the test suite's time goes on a fresh clone: numba compilation inside the tests,
by test file, beside the suite's wall and CPU time.

    PYTHONPATH=$PWD python experiments/suite_compile.py [--out experiments/results/suite_compile.csv]

runs ``python -m pytest -p experiments.suite_compile`` (the suite's own options: one test
process per core) on an empty numba cache, so that the conftest compiles the smoke
sweep's kernels first (its wall time is the suite's wall time minus pytest's own clock)
and the tests compile the rest. Loaded as a pytest plugin, this module records every
top-level numba compilation (numba's ``numba:compile`` events, nested ones counted in
their caller) with the test that triggered it, one JSON file per test process. The CSV has
one row per test file (compile seconds, test process) and a ``TOTAL`` row with the
suite's wall and CPU seconds, pytest's clock and the compile seconds in all.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from datetime import UTC, datetime
from pathlib import Path

from experiments.rows import append_rows
from windbench.dataset import git_commit

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "results" / "suite_compile.csv"
LOG_DIR = "WINDBENCH_COMPILE_LOG"  # environment: where the plugin writes its JSON files


def _record_compilations(folder: Path) -> None:
    """Plugin side: log (test file, seconds) of each top-level compilation of this process."""
    from numba.core import event

    rows, starts = [], []

    class Listener(event.Listener):
        def on_start(self, ev):
            starts.append(time.perf_counter())

        def on_end(self, ev):
            seconds = time.perf_counter() - starts.pop()
            if not starts:  # a caller's time includes its callees'
                test = os.environ.get("PYTEST_CURRENT_TEST", "").split("::")[0]
                rows.append((test, seconds))

    event.register("numba:compile", Listener())
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    atexit.register(lambda: (folder / f"{worker}.json").write_text(json.dumps(rows)))


if os.environ.get(LOG_DIR) and __name__ != "__main__":
    _record_compilations(Path(os.environ[LOG_DIR]))


def _rows(folder: Path, wall: float, cpu: float, pytest_seconds: float) -> list[dict]:
    by_file: dict[tuple[str, str], float] = defaultdict(float)
    for path in sorted(folder.glob("*.json")):
        for test, seconds in json.loads(path.read_text()):
            by_file[(test, path.stem)] += seconds
    stamp = dict(date=datetime.now(UTC).isoformat(timespec="seconds"), commit=git_commit())
    rows = [
        {**stamp, "test_file": test, "process": worker, "compile_seconds": round(s, 2)}
        for (test, worker), s in sorted(by_file.items(), key=lambda kv: -kv[1])
    ]
    total = dict(test_file="TOTAL", process="all", compile_seconds=round(sum(by_file.values()), 2))
    times = dict(suite_wall_seconds=round(wall, 1), suite_cpu_seconds=round(cpu, 1))
    rows.append({**stamp, **total, **times, "pytest_seconds": pytest_seconds})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as logs:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, LOG_DIR: logs, "PYTHONPATH": str(ROOT)}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-p", "experiments.suite_compile"],
            cwd=ROOT, env=env, capture_output=True, text=True,
        )  # fmt: skip
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        clock = re.search(r"in ([\d.]+)s", done.stdout.splitlines()[-1] if done.stdout else "")
        print(done.stdout.splitlines()[-1] if done.stdout else done.stderr[-500:])
        rows = _rows(Path(logs), wall, cpu, float(clock.group(1)) if clock else float("nan"))
    append_rows(args.out, rows, list(rows[-1]))  # the TOTAL row has every column
    print(f"wrote {args.out}: {rows[-1]}")


if __name__ == "__main__":
    main()
