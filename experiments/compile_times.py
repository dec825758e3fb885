"""Where a cold start's time goes: numba compilation per kernel during one windbench command.

    PYTHONPATH=. python experiments/compile_times.py [windbench overrides ...]
        [--top 25] [--out experiments/results/compile_times.csv]

Runs ``windbench <overrides>`` (default: the smoke sweep of the README's first command, on the
basic launcher, and always ``runtime.compile_ahead=false``, so that every compilation
happens here, none in a helper process) in this process with an empty numba
cache (a temporary NUMBA_CACHE_DIR, set before numba is imported) and records numba's
``numba:compile`` events: per compiled function its own compile CPU seconds (process time:
a callee compiled while its caller compiles is counted once, for the callee), the number
of versions compiled and their argument types (two versions of one kernel are one
compilation too many unless both are needed). Prints the
wall and CPU time, the total compile time, the share of the kernels and the slowest ones;
writes one row per function. The machine's load average is printed beside it: compiling
shares the cores with whatever else runs, which stretches the wall time, not the CPU time.
``--keep DIR`` writes the sweep there (to compare its datasets with another build's).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

OUT = Path(__file__).resolve().parent / "results" / "compile_times.csv"
README_FIRST = ["-m", "experiment=smoke", "hydra/launcher=basic"]  # one process: its events


def compile_recorder():
    """A numba:compile listener (numba imported here, after NUMBA_CACHE_DIR is set):
    seconds spent compiling each function, minus the time of the nested compilations it
    triggered (its callees), and the versions compiled."""
    from numba.core import event

    class ExclusiveCompileTimes(event.Listener):
        def __init__(self):
            self.seconds = defaultdict(float)
            self.versions = defaultdict(int)
            self.signatures = defaultdict(list)
            self.stack: list[list] = []  # [name, start, time spent in nested compiles]

        def on_start(self, event):
            func = event.data["dispatcher"].py_func
            name = f"{func.__module__}.{func.__qualname__}"
            self.signatures[name].append(str(tuple(event.data["args"])))
            self.stack.append([name, time.process_time(), 0.0])

        def on_end(self, event):
            name, start, nested = self.stack.pop()
            spent = time.process_time() - start
            self.seconds[name] += spent - nested
            self.versions[name] += 1
            if self.stack:
                self.stack[-1][2] += spent

    recorder = ExclusiveCompileTimes()
    event.register("numba:compile", recorder)
    return recorder


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("overrides", nargs="*", default=None)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--keep", type=Path, default=None, help="write the sweep here")
    args = ap.parse_args()
    overrides = args.overrides or README_FIRST
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as sweep:
        os.environ["NUMBA_CACHE_DIR"] = cache  # before numba is imported: a cold start
        import pandas as pd

        from windbench.cli import main as windbench

        listener = compile_recorder()
        sweep = args.keep or sweep
        here = [*overrides, "runtime.compile_ahead=false"]  # no helper process
        sys.argv = ["windbench", *here, f"hydra.sweep.dir={sweep}", f"hydra.run.dir={sweep}"]
        start, cpu = time.perf_counter(), time.process_time()
        try:
            windbench()
        except SystemExit:
            pass
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    df = pd.DataFrame(
        {"function": list(listener.seconds), "compile_seconds": list(listener.seconds.values())}
    )
    df["versions"] = df.function.map(listener.versions)
    df["signatures"] = df.function.map(lambda f: " | ".join(listener.signatures[f]))
    df = df.sort_values("compile_seconds", ascending=False)
    kernels = df[df.function.str.contains("navier_stokes")].compile_seconds.sum()
    print(df.drop(columns="signatures").head(args.top).to_string(index=False))
    print(
        f"wall {wall:.1f} s, CPU {cpu:.1f} s, compiling {df.compile_seconds.sum():.1f} s "
        f"({kernels:.1f} s navier_stokes) in {len(df)} functions, "
        f"{df.versions.sum()} versions; load average {os.getloadavg()}"
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)


if __name__ == "__main__":
    main()
