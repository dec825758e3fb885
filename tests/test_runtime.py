"""How a run uses the machine: the thread budget, numba's environment before it loads,
CPU time and load in the dataset, progress lines in a log."""

import logging
import os
import subprocess
import sys
from pathlib import Path

import numba
import pytest

import windbench
from windbench import runtime
from windbench.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("cores", "jobs", "threads"), [(2, 1, 2), (2, 2, 1), (8, 3, 2), (1, 4, 1), (4, 0, 4)]
)
def test_auto_threads_share_the_cores_among_the_parallel_runs(cores, jobs, threads):
    expected = min(threads, numba.config.NUMBA_NUM_THREADS)
    assert runtime.thread_count("auto", jobs=jobs, cores=cores) == expected


def test_a_thread_count_is_taken_as_given():
    assert runtime.thread_count(1, jobs=5) == 1


@pytest.mark.parametrize("bad", [0, -1, "two", 2.5, True, 10**6])
def test_a_bad_thread_count_is_refused_with_its_key(bad):
    with pytest.raises(ConfigError, match=r"runtime\.threads: must be 'auto' or an integer"):
        runtime.thread_count(bad)


def test_a_run_uses_its_thread_budget_and_records_cpu_time_and_load(run_config):
    _, ds = run_config(
        ["scene=empty", "grid.resolution=8", "sim.duration=0.05", "runtime.threads=1"]
    )
    assert ds.attrs["numba_threads"] == 1
    assert ds.attrs["cores_available"] >= 1
    for when in ("start", "end"):
        assert len(ds.attrs[f"load_average_{when}"]) == 3
    cpu = ds["step_cpu_seconds"]
    assert cpu.dims == ("time",) and cpu.attrs["units"] == "s" and (cpu >= 0).all()
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # leave the pool as found


def _fresh_python(code: str, **env) -> str:
    base = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", *env)}
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**base, "PYTHONPATH": str(ROOT), **env},
        timeout=120,
        check=True,
    )
    return proc.stdout.strip()


def test_importing_windbench_makes_openmp_wait_passively():
    code = "import os, windbench, numba; print(os.environ['OMP_WAIT_POLICY'])"
    assert _fresh_python(code) == "passive"
    assert _fresh_python(code, OMP_WAIT_POLICY="active") == "active"  # the user's choice


def test_a_read_only_install_caches_kernels_in_the_user_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    assert windbench.numba_cache_dir(tmp_path / "pkg") == tmp_path / "windbench" / "numba"
    monkeypatch.setattr(os, "access", lambda path, mode: True)
    assert windbench.numba_cache_dir(tmp_path / "pkg") is None  # numba's own __pycache__


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_progress_lines_every_tenth_with_rate_and_time_left(caplog):
    clock = Clock()
    progress = runtime.ProgressLog("fence/navier_stokes", 200, clock=clock)
    lines = []
    with caplog.at_level(logging.INFO, logger="windbench"):
        for done in range(1, 201):
            clock.now = 0.5 * done  # 2 steps/s
            line = progress.update(done)
            if line:
                lines.append(line)
    assert len(lines) == 10
    assert lines[0] == "fence/navier_stokes:  10% (20/200 steps), 2 steps/s, ETA 1 min 30 s"
    assert lines[-1].startswith("fence/navier_stokes: 100% (200/200 steps)")
    assert [r.getMessage() for r in caplog.records] == lines


def test_progress_marks_within_seconds_of_the_last_line_are_passed_over():
    clock = Clock()
    progress = runtime.ProgressLog("quick", 100, clock=clock)
    clock.now = 0.1
    assert [progress.update(d) for d in range(1, 101)].count(None) == 100
