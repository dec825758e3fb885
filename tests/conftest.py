"""Shared fixtures: compose configs and run them into tmp_path without a Hydra app."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from windbench.cli import compose_config
from windbench.simulate import run

ROOT = Path(__file__).resolve().parent.parent


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
