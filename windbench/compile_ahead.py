"""Compile ahead: on a cold numba cache, a second process compiles the cloth's kernels while
the run compiles its wind's.

numba compiles one function at a time in a process (its compiler holds a lock), so a run
on an empty cache compiles its geometry, wind, aerodynamics and cloth kernels one after
the other on one core, the second core idle: a first Navier-Stokes run of the smoke scene
spends nearly all its time compiling, nearly half of it on the cloth
(``experiments/compile_times.py``). Here a helper process (``python -m
windbench.compile_ahead``, one numba thread, the run's config on its standard input)
builds the scene's cloth and steps it once in still air, with the aerodynamic forces and
the cloth's per-step figures: every cloth kernel the run will call, with the argument
types the run will give them, compiled into numba's cache. The run meanwhile compiles its
wind; when it reaches the cloth, numba's dispatchers find in the cache what the helper
has finished (each looks there before it compiles) and compile only the rest. The
numbers are the same either way: the same code, compiled once.

It starts only when it can help: ``runtime.compile_ahead`` is on, the cache holds no
cloth frame kernel yet, the scene has cloth, the wind backend has many kernels of its own
to compile meanwhile (``WindField.compiles_kernels``: the global field has few, and its
run reaches the cloth at once) and a core is spare (the cores available at least twice
the runs the launcher has in flight: a parallel sweep's runs already use every core). It
is stopped once the run's first step is done (every kernel is compiled or loaded then,
and the timed steps do not share their cores with it), or when the run ends sooner;
stopped halfway, it leaves only whole cache files (numba writes each to a temporary file
and renames it).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

log = logging.getLogger("windbench")
PACKAGE_ROOT = Path(__file__).resolve().parent.parent  # the helper imports this windbench


def cache_is_cold() -> bool:
    """Whether numba's cache holds no version of the cloth frame kernel (a fresh clone,
    an empty ``NUMBA_CACHE_DIR``)."""
    from windbench.cloth.solver import xpbd_frame

    cache_file = getattr(getattr(xpbd_frame, "_cache", None), "_cache_file", None)
    index = getattr(cache_file, "_index_path", None)  # numba's index of the cached versions
    return index is not None and not os.path.exists(index)


def wanted(cfg: DictConfig, jobs: int, cores: int | None = None) -> bool:
    """Whether a run of ``cfg`` with ``jobs`` runs in flight starts the helper (module
    docstring)."""
    from windbench.runtime import available_cores
    from windbench.wind import backend_class

    cores = available_cores() if cores is None else cores
    if not (cfg.runtime.compile_ahead and cfg.scene.get("cloths")):
        return False
    return backend_class(cfg.wind.name).compiles_kernels and cores >= 2 * max(1, jobs)


def start(cfg: DictConfig, jobs: int) -> subprocess.Popen | None:
    """The helper process compiling ``cfg``'s cloth kernels, or None when it would not
    help (:func:`wanted`, :func:`cache_is_cold`)."""
    if not (wanted(cfg, jobs) and cache_is_cold()):
        return None
    config = OmegaConf.to_yaml(cfg, resolve=True)  # as the dataset records it
    path = os.pathsep.join(p for p in (str(PACKAGE_ROOT), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": path}
    helper = subprocess.Popen(
        [sys.executable, "-m", "windbench.compile_ahead"],
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
        text=True,
    )
    try:
        helper.stdin.write(config)
        helper.stdin.close()
    except OSError:  # it died at once: the run compiles everything itself
        stop(helper)
        return None
    log.info("empty numba cache: process %d compiles the cloth kernels meanwhile", helper.pid)
    return helper


def stop(helper: subprocess.Popen | None) -> None:
    """End the helper if it still runs; a warning if it failed (the run then compiled
    what the helper did not)."""
    if helper is None:
        return
    if helper.poll() is None:
        helper.terminate()
        helper.wait()
    elif helper.returncode not in (0, -signal.SIGTERM):  # SIGTERM: stopped here before
        log.warning(
            "the compile helper (process %d) failed with status %d; this run compiled its "
            "cloth kernels itself (python -m windbench.compile_ahead < config.yaml shows why)",
            helper.pid,
            helper.returncode,
        )


@contextmanager
def cloth_kernels(cfg: DictConfig, jobs: int):
    """The helper (:func:`start`) for the duration of the block."""
    helper = start(cfg, jobs)
    try:
        yield helper
    finally:
        stop(helper)


def compile_cloth(cfg: DictConfig) -> None:
    """Build ``cfg``'s scene and cloth and step the cloth once in still air, with the
    aerodynamic forces and the per-step figures: every kernel of the run's cloth path."""
    from windbench.aero import AeroParams, aerodynamic_forces
    from windbench.cloth import make_cloth_solver
    from windbench.cloth.model import ClothModel
    from windbench.scenes import build_scene

    scene = build_scene(cfg.scene)
    model = ClothModel.from_meshes(scene.cloths)
    solver = make_cloth_solver(cfg.cloth, model, scene.bodies)
    state = model.initial_state()
    aero = AeroParams(**OmegaConf.to_container(cfg.aero))
    still = np.zeros((model.n_vertices, 3))
    _, forces = aerodynamic_forces(state.positions, state.velocities, still, model.triangles, aero)
    state = solver.step(state, forces, float(cfg.sim.dt))
    solver.stats(state)


if __name__ == "__main__":
    compile_cloth(OmegaConf.create(sys.stdin.read()))
