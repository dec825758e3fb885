"""The wheel works outside a checkout: built from a copy of the sources, installed into a
fresh venv (``--no-deps``: no download; the dependencies are the test environment's own,
whether that is the system's Python or a venv), ``windbench --help`` and one tiny run from
a folder with no ``conf/`` in sight. The venv is made without pip of its own (installing
pip into it took 7.7 of the test's 19 s): the test environment's pip, which it sees,
installs the wheel into it."""

import os
import shutil
import site
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
import xarray as xr

pytestmark = pytest.mark.heavy  # builds a wheel and installs it in a new environment

ROOT = Path(__file__).resolve().parent.parent
SOURCES = ("pyproject.toml", "setup.py", "README.md", "windbench", "conf")


def _run(args, **kw):
    proc = subprocess.run(args, capture_output=True, text=True, timeout=600, **kw)
    assert proc.returncode == 0, f"{args}\n{proc.stdout}\n{proc.stderr}"
    return proc


def _see_the_test_environments_packages(venv: Path) -> None:
    """``--system-site-packages`` shows the base interpreter's packages only: when the tests
    run in a venv, its site-packages reach the new venv through a .pth file (appended to
    sys.path, after the new venv's own site-packages, so that the wheel comes first)."""
    purelib = Path(sysconfig.get_path("purelib", vars={"base": venv, "platbase": venv}))
    (purelib / "test_environment.pth").write_text("\n".join(site.getsitepackages()) + "\n")


def test_a_built_wheel_runs_from_a_fresh_venv(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, src / name)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PIP_NO_INDEX"] = "1"  # nothing may be downloaded
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    _run(
        [*pip, "wheel", "--no-build-isolation", "--no-deps", "-w", tmp_path / "dist", src], env=env
    )
    (wheel,) = (tmp_path / "dist").glob("windbench-*.whl")
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", "--system-site-packages", venv], env=env)
    _see_the_test_environments_packages(venv)
    _run([venv / "bin" / "python", "-m", "pip", "install", "-q", "--no-deps", wheel], env=env)

    work = tmp_path / "elsewhere"
    work.mkdir()
    where = _run(
        [venv / "bin" / "python", "-c", "import windbench.cli as c; print(c.CONFIG_DIR)"],
        cwd=work,
        env=env,
    ).stdout.strip()
    assert where.startswith(str(venv)) and where.endswith("windbench/conf")
    assert (Path(where) / "scene" / "flag.yaml").is_file()
    assert (Path(where) / "mesh" / "character.ply").is_file()  # the shirt scene's meshes
    assert (Path(where) / "mesh" / "shirt.obj").is_file()

    helped = _run([venv / "bin" / "windbench", "--help"], cwd=work, env=env).stdout
    assert "scene       empty, fence, flag*" in helped and f"Config files: {where}" in helped

    # the numerics are tested elsewhere: skip numba's compilation in the fresh install
    tiny = ["scene=empty", "grid.resolution=8", "sim.duration=0.05", "hydra.run.dir=run"]
    _run([venv / "bin" / "windbench", *tiny], cwd=work, env={**env, "NUMBA_DISABLE_JIT": "1"})
    with xr.open_dataset(work / "run" / "windbench.nc") as ds:
        assert ds.attrs["status"] == "complete" and ds.sizes["time"] == 3
        assert ds.attrs["git_commit"] == "unknown"  # no source tree beside an installed wheel
