"""Code of another version, for comparing two versions: one windbench run with the code
of a given checkout, in a process of its own (``--trees`` of the scripts that use it),
or one module as a git revision has it, loaded beside this checkout's (``--base``)."""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import xarray as xr

from experiments.rows import show_and_append

ROOT = Path(__file__).resolve().parents[1]


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


def module_at(rev: str | None, path: str, folder: Path, name: str, imports=None):
    """File ``path`` of this repository as git revision ``rev`` has it (None: this
    checkout's file), loaded as module ``name`` from a copy in ``folder``, which goes on
    sys.path so that ``imports`` (old -> new text of its import lines) can point it at
    modules loaded beside it: two versions of a kernel compiled alike in one process."""
    if rev is None:
        source = (ROOT / path).read_text()
    else:
        git = ["git", "show", f"{rev}:{path}"]
        source = subprocess.run(git, cwd=ROOT, capture_output=True, text=True, check=True).stdout
    for old, new in (imports or {}).items():
        source = source.replace(old, new)
    file = folder / f"{name}.py"
    file.write_text(source)
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def median_ms(ds: xr.Dataset, phase: str) -> float:
    """The median over the recorded steps of one phase of ``step_seconds``, in ms."""
    return round(1e3 * float(ds.step_seconds.sel(phase=phase).median()), 2)


def case_row(tree: Path, overrides: list[str], read: Callable[[xr.Dataset], dict]) -> dict:
    """:func:`run_in_tree` with the date, the load average after the run and the command."""
    row = run_in_tree(tree, overrides, read)
    return {
        "date": datetime.date.today().isoformat(),
        **row,
        "load_average_1min": round(os.getloadavg()[0], 2),
        "command": "windbench " + " ".join(overrides),
    }


def compare(doc: str, cases, root: Path, out: Path, run_case, fields, shown) -> None:
    """The command line of a script that runs ``run_case(case, tree)`` for every case
    (``--cases``) and checkout (``--trees``, runs of one case in turn) and appends the
    rows to ``out`` (``--out``)."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", default=list(cases))
    parser.add_argument("--trees", nargs="+", type=Path, default=[root])
    parser.add_argument("--out", type=Path, default=out)
    args = parser.parse_args()
    for case in args.cases:
        rows = [run_case(case, tree.resolve()) for tree in args.trees]
        show_and_append(args.out, rows, fields, shown)
