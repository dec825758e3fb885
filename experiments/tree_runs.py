"""One windbench run with the code of a given checkout, in a process of its own: for
comparing two versions run by run (``--trees`` of the scripts that use it)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import xarray as xr


def run_in_tree(tree: Path, overrides: list[str], read: Callable[[xr.Dataset], dict]) -> dict:
    """``windbench OVERRIDES`` with checkout ``tree`` first on PYTHONPATH and as the working
    directory (``python -m`` puts it first on sys.path), into a temporary run folder;
    returns ``read(dataset)`` with the run's wall seconds (``run_seconds``) and the
    dataset's code version (``commit``: short hash, ``+dirty`` for uncommitted code)."""
    with tempfile.TemporaryDirectory() as folder:
        env = {**os.environ, "PYTHONPATH": str(tree)}
        cmd = [sys.executable, "-m", "windbench", *overrides, f"hydra.run.dir={folder}"]
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=tree, env=env, check=True, capture_output=True)
        seconds = time.perf_counter() - t0
        with xr.open_dataset(Path(folder) / "windbench.nc") as ds:
            commit = str(ds.attrs["git_commit"])
            row = read(ds)
    return {
        "commit": commit[:7] + ("+dirty" if "dirty" in commit else ""),
        **row,
        "run_seconds": round(seconds, 1),
    }


def median_ms(ds: xr.Dataset, phase: str) -> float:
    """The median over the recorded steps of one phase of ``step_seconds``, in ms."""
    return round(1e3 * float(ds.step_seconds.sel(phase=phase).median()), 2)
