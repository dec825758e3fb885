"""The cold-start helper: when it starts, what it compiles, that it ends, and that a run
with it gives the numbers of a run without it."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest
import xarray as xr
from omegaconf import OmegaConf

from windbench import compile_ahead
from windbench.cli import compose_config
from windbench.dataset import MACHINE_VARIABLES
from windbench.wind import backend_class

SMOKE = ["experiment=smoke", "sim.spinup=0", "sim.duration=0.04", "sim.progress=false"]


@pytest.mark.parametrize(
    ("overrides", "cores", "jobs", "starts"),
    [
        (["wind=navier_stokes"], 2, 1, True),
        (["wind=particles"], 2, 1, True),
        (["wind=navier_stokes"], 2, 2, False),  # a parallel sweep's runs use every core
        (["wind=navier_stokes"], 1, 1, False),
        (["wind=navier_stokes"], 8, 4, True),
        (["wind=global"], 2, 1, False),  # reaches the cloth at once: nothing to overlap
        (["wind=navier_stokes", "runtime.compile_ahead=false"], 2, 1, False),
        (["wind=navier_stokes", "scene=fence"], 2, 1, False),  # no cloth
    ],
)
def test_the_helper_starts_only_where_it_can_help(overrides, cores, jobs, starts):
    cfg = compose_config([*SMOKE, *overrides])
    assert compile_ahead.wanted(cfg, jobs, cores) is starts


def test_the_backends_with_many_kernels_say_so():
    assert backend_class("navier_stokes").compiles_kernels
    assert backend_class("particles").compiles_kernels
    assert not backend_class("global").compiles_kernels


def _helper(cfg, env=None):
    return subprocess.run(
        [sys.executable, "-m", "windbench.compile_ahead"],
        input=OmegaConf.to_yaml(cfg, resolve=True),
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )


def test_the_helper_steps_the_cloth_of_a_config():
    """The helper's path through the cloth runs on a real config (warm cache: it loads)."""
    done = _helper(compose_config([*SMOKE, "wind=navier_stokes", "cloth.self_collision=true"]))
    assert done.returncode == 0, done.stderr


def test_a_helper_that_failed_is_a_warning(caplog):
    failed = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    failed.wait()
    with caplog.at_level("WARNING", logger="windbench"):
        compile_ahead.stop(failed)
    assert "failed with status 3" in caplog.text


def test_stop_ends_a_helper_that_still_runs_and_says_nothing_of_it(caplog):
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    start = time.monotonic()
    with caplog.at_level("WARNING", logger="windbench"):
        compile_ahead.stop(sleeper)
        compile_ahead.stop(sleeper)  # after the first step, then as the run ends
    assert sleeper.returncode is not None and time.monotonic() - start < 30
    assert caplog.text == ""
    compile_ahead.stop(None)  # no helper: nothing to do


@pytest.mark.slow
def test_on_an_empty_cache_the_helper_fills_it_with_the_cloth_frame(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    is_cold = [
        sys.executable,
        "-c",
        "from windbench import compile_ahead as c; print(c.cache_is_cold())",
    ]
    before = subprocess.run(is_cold, env=env, capture_output=True, text=True, check=True)
    assert _helper(compose_config([*SMOKE, "wind=navier_stokes"]), env).returncode == 0
    after = subprocess.run(is_cold, env=env, capture_output=True, text=True, check=True)
    assert (before.stdout.strip(), after.stdout.strip()) == ("True", "False")


@pytest.mark.slow
def test_a_cold_run_with_the_helper_has_the_numbers_of_one_without(tmp_path):
    """Each run in a process of its own on an empty cache, with and without the helper:
    every variable but the timings is equal."""
    datasets = []
    for ahead in ("true", "false"):
        env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / f"cache_{ahead}")}
        out = tmp_path / f"run_{ahead}"
        args = [*SMOKE, "wind=navier_stokes", f"runtime.compile_ahead={ahead}"]
        subprocess.run(
            [sys.executable, "-m", "windbench", *args, f"hydra.run.dir={out}"],
            env=env, check=True, capture_output=True, cwd=tmp_path,
        )  # fmt: skip
        datasets.append(xr.load_dataset(out / "windbench.nc"))
    for name in set(datasets[0].data_vars) - set(MACHINE_VARIABLES):
        a, b = datasets[0][name].values, datasets[1][name].values
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
