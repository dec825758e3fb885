"""Same configuration and seed, same numbers, whatever the state of numba's cache.

A run compiles its kernels on first use and links them from the on-disk cache after that.
With fast-math flags LLVM optimised a kernel differently when its callees came from the
cache, and a coupled Navier-Stokes run drifted apart between a cold and a warm cache. The
study runs the same short coupled run twice in fresh processes, first with an empty cache
(everything compiled) and then with the cache it filled (everything loaded), and asks for
the same bits in the wind and the cloth.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr

RUN = [
    "experiment=smoke", "wind=navier_stokes", "grid.resolution=24", "sim.spinup=0",
    "sim.duration=0.3", "sim.progress=false",
]  # fmt: skip


def _run(folder, cache) -> xr.Dataset:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "NUMBA_NUM_THREADS": "1"}
    subprocess.run(
        [sys.executable, "-m", "windbench", *RUN, f"hydra.run.dir={folder}"],
        check=True, env=env, capture_output=True,
    )  # fmt: skip
    return xr.load_dataset(folder / "windbench.nc")


@pytest.mark.slow
def test_a_cold_and_a_warm_cache_give_the_same_bits(tmp_path):
    cold = _run(tmp_path / "cold", tmp_path / "cache")  # compiles into the empty cache
    warm = _run(tmp_path / "warm", tmp_path / "cache")  # links every kernel from it
    for name in ("wind", "cloth_position", "lee_force_ratio"):
        np.testing.assert_array_equal(cold[name].values, warm[name].values, err_msg=name)
