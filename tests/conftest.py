"""Shared fixtures: compose configs and run them into tmp_path without a Hydra app; on an
empty numba cache, one compilation of the kernels before the test processes start."""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from windbench.cli import compose_config
from windbench.compile_ahead import cache_is_cold
from windbench.simulate import run

ROOT = Path(__file__).resolve().parent.parent
# The smoke sweep, two steps per backend: it calls every kernel of the cloth, the three
# backends and the geometry that most tests use, the backends side by side (joblib)
WARM_UP = ["-m", "experiment=smoke", "sim.spinup=0", "sim.duration=0.04", "output.snapshots=1"]


def pytest_configure(config):
    """With several test processes (pytest-xdist) and an empty numba cache, compile the
    kernels once here, before the processes start: each would otherwise compile the same
    kernels at the same time (the cache is shared only once a kernel is written)."""
    if hasattr(config, "workerinput") or (config.getoption("numprocesses", 0) or 0) < 2:
        return
    if not cache_is_cold():  # no compiled cloth frame: a fresh clone
        return
    print("windbench: empty numba cache: compiling the kernels once (about a minute on 2 cores)")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryDirectory() as tmp:
        done = subprocess.run(
            [sys.executable, "-m", "windbench", *WARM_UP, f"hydra.sweep.dir={tmp}/sweep"],
            cwd=tmp, env=env, capture_output=True, text=True,
        )  # fmt: skip
    if done.returncode != 0:  # the tests that use these kernels will say what is wrong
        print(f"windbench: the compile run failed ({done.returncode}): {done.stderr[-500:]}")


@pytest.fixture
def run_config(tmp_path):
    """run_config(overrides, name="run") -> (RunResult, xarray.Dataset) for a small run."""
    import xarray as xr

    def _run(overrides, name="run"):
        cfg = compose_config(["sim.progress=false", "sim.spinup=0", *overrides])
        result = run(cfg, tmp_path / name)
        with xr.open_dataset(result.path) as ds:
            return result, ds.load()

    return _run


@pytest.fixture
def cli(tmp_path):
    """cli(*args) -> CompletedProcess of ``python -m windbench`` with output under tmp_path."""

    def _cli(*args, cwd=None, pythonpath=None):
        path = os.pathsep.join(str(p) for p in (ROOT, pythonpath) if p)
        env = {**os.environ, "PYTHONPATH": path, "HYDRA_FULL_ERROR": "0"}
        return subprocess.run(
            [sys.executable, "-m", "windbench", *args],
            capture_output=True,
            text=True,
            cwd=cwd or tmp_path,
            env=env,
            timeout=300,
        )

    return _cli


def pytest_collection_modifyitems(items):
    """The heavy test files (marked ``heavy``) first, then the rest by their number of
    tests, most first: the order the test processes are handed whole files in
    (``--dist loadfile --no-loadscope-reorder``), so that the long ones do not start last
    and leave one process working alone at the end. Stable: a file's tests keep their
    order, and every process sorts alike."""
    counts, heavy = {}, set()
    for item in items:
        counts[item.path] = counts.get(item.path, 0) + 1
        if item.get_closest_marker("heavy"):
            heavy.add(item.path)
    items.sort(key=lambda item: (item.path not in heavy, -counts[item.path]))
