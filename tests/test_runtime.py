"""How a run uses the machine: the thread budget, numba's environment before it loads,
CPU time and load in the dataset, progress lines in a log."""

import logging
import os
import subprocess
import sys
import time
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


STAT = """cpu  60 0 40 900 0 0 0 0 0 0
cpu0 10 2 20 400 7 1 2 3 5 0
cpu1 50 0 20 500 0 0 0 0 0 0
intr 12345 0 0
"""


def test_busy_time_of_a_cpu_set_is_read_from_proc_stat():
    """user + nice + system + irq + softirq + steal ticks (idle, iowait, guest left out)."""
    assert runtime.busy_seconds(STAT, [0], 0.01) == pytest.approx(0.38)
    assert runtime.busy_seconds(STAT, [0, 1], 0.01) == pytest.approx(1.08)
    with pytest.raises(ValueError, match="no line"):
        runtime.busy_seconds(STAT, [0, 7], 0.01)


class FakeMachine:
    """Two cores whose busy ticks, this process's CPU time and the wall clock advance
    as the test says."""

    def __init__(self):
        self.ticks, self.own, self.wall = [0, 0], 0.0, 0.0

    def advance(self, seconds: float, elsewhere: float, own: float):
        """``seconds`` of wall time with ``elsewhere`` and ``own`` cores busy."""
        tick = 1.0 / os.sysconf("SC_CLK_TCK")
        total = round((elsewhere + own) * seconds / tick)
        self.ticks = [self.ticks[0] + total // 2, self.ticks[1] + total - total // 2]
        self.own += own * seconds
        self.wall += seconds

    def stat(self) -> str:
        return "".join(f"cpu{i} {t} 0 0 0 0 0 0 0 0 0\n" for i, t in enumerate(self.ticks))

    def watch(self) -> runtime.BusyElsewhere:
        return runtime.BusyElsewhere([0, 1], self.stat, lambda: self.wall, lambda: self.own)


def test_cores_busy_elsewhere_are_the_busy_time_less_this_process_own():
    machine = FakeMachine()
    watch = machine.watch()
    machine.advance(2.0, elsewhere=1.0, own=0.5)
    assert watch.reading() == pytest.approx(1.0)
    machine.advance(1.0, elsewhere=0.0, own=2.0)
    assert watch.reading() == pytest.approx(0.0)
    assert watch.reading() is None  # no wall time has passed


def test_without_proc_stat_or_a_line_for_each_core_nothing_is_said():
    def missing():
        raise OSError("no /proc/stat")

    assert runtime.BusyElsewhere([0, 1], missing).reading() is None
    assert runtime.BusyElsewhere([0, 7], lambda: STAT).reading() is None


@pytest.mark.parametrize(
    ("planned", "cores", "elsewhere", "threads"),
    [(2, 2, 0.0, 2), (2, 2, 0.4, 2), (2, 2, 0.67, 1), (2, 2, 1.0, 1), (2, 2, 2.5, 2),
     (1, 2, 0.0, 1), (4, 16, 12.0, 4), (4, 16, 13.0, 3), (4, 16, 15.0, 4), (8, 8, 3.0, 5),
     (8, 8, 4.0, 4), (8, 8, 6.0, 8)],
)  # fmt: skip
def test_a_run_leaves_busy_cores_where_that_is_faster(planned, cores, elsewhere, threads):
    """A loop over n threads of which some share a core takes 2/n of its one-thread time,
    over n free cores 1/n. 16 cores, four runs of four threads: the three others' twelve
    cores leave four; one core free of 16 is slower than four threads that share."""
    assert runtime.threads_beside(planned, cores, elsewhere) == threads


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs a pool of 2 threads")
def test_the_budget_follows_the_load_every_recheck_and_restores_its_plan():
    machine = FakeMachine()
    budget = runtime.ThreadBudget(
        2, adaptive=True, watch=machine.watch(), clock=lambda: machine.wall
    )
    try:
        machine.advance(runtime.RECHECK / 2, elsewhere=1.0, own=1.0)
        assert budget.update() == 2  # not read yet: RECHECK has not passed
        machine.advance(runtime.RECHECK, elsewhere=1.0, own=1.0)
        assert budget.update() == 1 and numba.get_num_threads() == 1
        assert budget.note() == "1 of 2 threads (cores busy elsewhere)"
        machine.advance(runtime.RECHECK, elsewhere=0.0, own=1.0)
        assert budget.update() == 2 and numba.get_num_threads() == 2
        assert budget.note() == ""
        machine.advance(runtime.RECHECK, elsewhere=1.0, own=1.0)
        assert budget.update() == 1
        assert budget.restore() == 2 and numba.get_num_threads() == 2
        machine.advance(10.0, elsewhere=1.0, own=1.0)  # a long first step beside a compile
        budget.restart()
        machine.advance(runtime.RECHECK, elsewhere=0.0, own=2.0)
        assert budget.update() == 2  # the reading covers the steps only
        fixed = runtime.ThreadBudget(2, adaptive=False, watch=machine.watch())
        machine.advance(10 * runtime.RECHECK, elsewhere=2.0, own=0.0)
        assert fixed.update() == 2
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


@pytest.mark.skipif(not Path("/proc/stat").exists(), reason="reads /proc/stat (Linux)")
def test_a_busy_process_is_seen_on_the_machine():
    """A ``while True`` process holds a core: at least half a core busy elsewhere, whatever
    else the machine runs (more load only adds)."""
    watch = runtime.BusyElsewhere()
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        if watch.reading() is None:  # from here on, with the busy process
            pytest.skip("this system's /proc/stat does not number the process's cores")
        time.sleep(0.5)
        assert watch.reading() >= 0.5
    finally:
        busy.kill()
        busy.wait()


def test_a_run_uses_its_thread_budget_and_records_cpu_time_and_load(run_config):
    _, ds = run_config(
        ["scene=empty", "grid.resolution=8", "sim.duration=0.05", "runtime.threads=1"]
    )
    assert ds.attrs["numba_threads"] == 1
    assert (ds["step_threads"] == 1).all() and ds["step_threads"].dims == ("time",)
    assert ds.attrs["cores_available"] >= 1
    for when in ("start", "end"):
        assert len(ds.attrs[f"load_average_{when}"]) == 3
    cpu = ds["step_cpu_seconds"]
    assert cpu.dims == ("time",) and cpu.attrs["units"] == "s" and (cpu >= 0).all()
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # leave the pool as found


def _fresh_python(code: str, **env) -> str:
    unset = ("OMP_WAIT_POLICY", "NUMBA_CACHE_DIR", *env)  # as a user's shell has them
    base = {k: v for k, v in os.environ.items() if k not in unset}
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


def test_the_package_names_the_variables_it_set_and_not_the_users():
    """set_environment() lists what the import set, so that a benchmark can run another
    program without it; a variable the user had set is theirs and is not listed."""
    code = "import windbench; print(sorted(windbench.set_environment()))"
    assert _fresh_python(code) == "['NUMBA_CACHE_DIR', 'OMP_WAIT_POLICY']"
    assert _fresh_python(code, OMP_WAIT_POLICY="active") == "['NUMBA_CACHE_DIR']"


def _package(folder: Path, callee_value: int) -> Path:
    """A package whose cached kernel ``a.f`` calls ``b.g`` (another module), g = value."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "__init__.py").write_text("")
    (folder / "a.py").write_text(
        "from numba import njit\nfrom .b import g\n\n\n"
        "@njit(cache=True)\ndef f():\n    return g() + 1\n"
    )
    (folder / "b.py").write_text(
        f"from numba import njit\n\n\n@njit\ndef g():\n    return {callee_value}\n"
    )
    return folder


def _cached_f(package: Path, cache: Path) -> str:
    """f() of ``package`` in a new process whose numba caches in ``cache``."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(package.parent)}
    code = f"from {package.name}.a import f; print(f())"
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    return proc.stdout.strip()


def test_a_changed_callee_in_another_module_is_not_read_from_a_stale_cache(tmp_path):
    """numba checks a cached kernel against its own file only: with one cache folder, f
    keeps g's old value after b.py changes; with the folder of the sources' fingerprint
    (:func:`windbench.numba_cache_dir`) it compiles again and sees the new one."""
    package = _package(tmp_path / "pkg", 1)
    fixed = tmp_path / "one_cache"
    assert (
        _cached_f(package, fixed) == "2" == _cached_f(package, windbench.numba_cache_dir(package))
    )
    b = package / "b.py"
    b.write_text(b.read_text().replace("return 1", "return 41"))  # a.py stays as it was
    assert _cached_f(package, fixed) == "2"  # numba's stale kernel
    assert _cached_f(package, windbench.numba_cache_dir(package)) == "42"


def test_the_cache_folder_follows_the_sources_and_a_read_only_install(monkeypatch, tmp_path):
    package = _package(tmp_path / "pkg", 1)
    first = windbench.numba_cache_dir(package)
    assert first.parent == package / ".numba_cache"
    (package / "notes.txt").write_text("not a source")
    (package / "__pycache__").mkdir()
    (package / "__pycache__" / "stale.py").write_text("x = 1")
    assert windbench.numba_cache_dir(package) == first
    (package / "b.py").write_text((package / "b.py").read_text() + "# a change\n")
    assert windbench.numba_cache_dir(package) != first
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home"))
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    assert windbench.numba_cache_dir(package).parent == tmp_path / "home" / "windbench" / "numba"


def test_old_versions_of_the_cache_are_pruned(tmp_path):
    base = tmp_path / "cache"
    for n in range(6):
        (base / f"v{n}").mkdir(parents=True)
        os.utime(base / f"v{n}", (n, n))  # v5 the most recently used
    windbench.prune_cache(base / "v0")  # in use again: kept, with the three newest others
    assert sorted(p.name for p in base.iterdir()) == ["v0", "v3", "v4", "v5"]


def test_importing_windbench_sets_the_cache_folder_unless_the_user_has():
    code = "import os, windbench; print(os.environ['NUMBA_CACHE_DIR'])"
    assert _fresh_python(code) == str(windbench.numba_cache_dir())
    assert _fresh_python(code, NUMBA_CACHE_DIR="/tmp/mine") == "/tmp/mine"


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


def test_a_progress_line_ends_with_its_note():
    clock = Clock()
    progress = runtime.ProgressLog("fence", 10, clock=clock)
    clock.now = 5.0
    line = progress.update(1, "1 of 2 threads (cores busy elsewhere)")
    assert line == (
        "fence:  10% (1/10 steps), 0.2 steps/s, ETA 45 s; 1 of 2 threads (cores busy elsewhere)"
    )


def test_progress_marks_within_seconds_of_the_last_line_are_passed_over():
    clock = Clock()
    progress = runtime.ProgressLog("quick", 100, clock=clock)
    clock.now = 0.1
    assert [progress.update(d) for d in range(1, 101)].count(None) == 100
