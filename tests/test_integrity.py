"""Every file whole and checked: checksums verified by the readers, the user's umask, one
writer per run folder, resume that knows the code, a sweep's exit status."""

import os
import signal
import socket
import subprocess
import sys
import time
from collections import Counter

import netCDF4
import numpy as np
import pytest
import xarray as xr

from windbench.cli import compose_config
from windbench.dataset import code_version, current_code, temporary_name, verify, write_atomic
from windbench.errors import DatasetUnreadable, FolderBusy
from windbench.report.collect import code_versions, combine, find_runs, read_run, read_runs
from windbench.sweep import LOCK_FILE, FolderLock, exit_status, resume_decision, write_status

pytestmark = pytest.mark.heavy  # runs sweeps from the command line

TINY = ["scene=two_flags_wall", "grid.resolution=32", "sim.duration=0.05", "output.snapshots=2"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """One complete run dataset (module-wide: copy it before changing it)."""
    from windbench.simulate import run

    result = run(compose_config(["sim.progress=false", *TINY]), tmp_path_factory.mktemp("tiny"))
    assert result.status == "complete"
    return result.path


def corrupt_middle(path, n=4096, seed=0):
    """Overwrite ``n`` bytes in the middle of the file's largest variable (the wind
    snapshots, stored as they are: found by their own bytes) with random bytes."""
    with netCDF4.Dataset(path) as nc:
        data = np.ascontiguousarray(nc.variables["wind"][:], dtype="<f8").tobytes()
    raw = path.read_bytes()
    start = raw.find(data[len(data) // 2 : len(data) // 2 + 64])
    assert start > 0 and len(data) > 2 * n, "the wind data must be stored contiguously"
    with open(path, "r+b") as fh:
        fh.seek(start)
        fh.write(np.random.default_rng(seed).bytes(n))


def test_every_variable_carries_a_checksum(tiny_run):
    with netCDF4.Dataset(tiny_run) as nc:
        assert len(nc.variables) > 15
        for name, var in nc.variables.items():
            assert var.filters()["fletcher32"], name
            if name in ("component", "cloth", "phase", "probe_box"):
                assert var.dtype == np.dtype("S1"), name  # text inside the checksum
    verify(tiny_run)  # a whole file passes


def test_mid_file_corruption_is_unreadable_checksum_and_never_combined(tiny_run, tmp_path):
    good, bad = tmp_path / "good" / "windbench.nc", tmp_path / "bad" / "windbench.nc"
    for p in (good, bad):
        p.parent.mkdir()
        p.write_bytes(tiny_run.read_bytes())
    corrupt_middle(bad)
    with pytest.raises(DatasetUnreadable, match=r"^checksum: variable '\w+' is damaged"):
        verify(bad)
    records = {r.path.parent.name: r for r in read_runs([good, bad], progress=False)}
    assert records["good"].status == "complete"
    assert records["bad"].status == "unreadable" and records["bad"].reason.startswith("checksum")
    assert combine(list(records.values())).attrs["runs"] == 1


def test_windbench_report_lists_the_corrupted_run_as_unreadable(tiny_run, tmp_path, capsys):
    from windbench.report.cli import main

    sweep = tmp_path / "sweep"
    for n in ("0", "1"):
        (sweep / n).mkdir(parents=True)
        (sweep / n / "windbench.nc").write_bytes(tiny_run.read_bytes())
    corrupt_middle(sweep / "1" / "windbench.nc")
    assert main([str(sweep), "--out", str(tmp_path / "report"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "1 of 2 runs combined" in out
    assert f"skipped {sweep / '1' / 'windbench.nc'}: unreadable: checksum: variable" in out
    with xr.open_dataset(tmp_path / "report" / "results.nc") as ds:
        assert ds.attrs["runs"] == 1


def test_a_resumed_run_with_a_damaged_dataset_runs_again(tiny_run, tmp_path):
    path = tmp_path / "windbench.nc"
    path.write_bytes(tiny_run.read_bytes())
    cfg = compose_config(["sim.progress=false", "resume=true", *TINY])
    assert resume_decision(cfg, path) == (True, "complete with the same config and code")
    corrupt_middle(path)
    skip, why = resume_decision(cfg, path)
    assert not skip and why.startswith("the dataset is unreadable (checksum: variable")


def test_resume_reruns_a_run_made_by_other_code_unless_code_any(tiny_run, tmp_path):
    path = tmp_path / "windbench.nc"
    with xr.open_dataset(tiny_run) as ds:
        old = ds.load()
    old.attrs["git_commit"] = "0" * 40
    write_atomic(old, path)
    same = compose_config(["sim.progress=false", "resume=true", *TINY])
    skip, why = resume_decision(same, path)
    assert not skip
    assert why == (
        f"it was made by {code_version(old.attrs)}, this is {code_version(current_code())} "
        "(resume.code=any keeps it)"
    )
    anycode = compose_config(["sim.progress=false", "resume=true", "resume.code=any", *TINY])
    assert resume_decision(anycode, path)[0]


def test_the_report_lists_mixed_code_versions(tiny_run, tmp_path, capsys):
    from windbench.report.cli import main

    for n, commit in (("0", None), ("1", "f" * 40)):
        with xr.open_dataset(tiny_run) as ds:
            ds = ds.load()
        if commit:
            ds.attrs["git_commit"] = commit
            ds.attrs["seed"] = 1  # another run of the sweep, not a duplicate
        write_atomic(ds, tmp_path / "sweep" / n / "windbench.nc")
    records = read_runs(find_runs([tmp_path / "sweep"]), progress=False)
    assert len(code_versions(records)) == 2
    assert main([str(tmp_path / "sweep"), "--out", str(tmp_path / "r"), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "warning: the runs were made by 2 code versions" in captured.err
    assert f"({'f' * 40})" in captured.out
    with xr.open_dataset(tmp_path / "r" / "results.nc") as ds:
        assert ds.attrs["code_versions"].count("windbench") == 2


def test_files_are_created_with_the_users_umask(tiny_run, tmp_path):
    with xr.open_dataset(tiny_run) as ds:
        ds = ds.load()
    for mask, mode in ((0o022, 0o644), (0o077, 0o600), (0o002, 0o664)):
        old = os.umask(mask)
        try:
            out = tmp_path / f"{mask:o}"
            write_atomic(ds, out / "windbench.nc")
            write_status(out, "complete")
        finally:
            os.umask(old)
        for name in ("windbench.nc", "run_status.yaml"):
            assert (out / name).stat().st_mode & 0o777 == mode, (name, oct(mask))


def test_temporary_names_are_unique_and_name_their_writer(tmp_path):
    a, b = temporary_name(tmp_path / "windbench.nc"), temporary_name(tmp_path / "windbench.nc")
    assert a != b and a.parent == tmp_path
    assert a.name.startswith(f".windbench.nc.{socket.gethostname()}.{os.getpid()}.")
    assert a.name.endswith(".tmp")


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_live_lock_refuses_and_a_stale_one_is_taken_over(tmp_path, caplog):
    host = socket.gethostname()
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / LOCK_FILE).write_text(f"{sleeper.pid} {host} 0\n")
        with pytest.raises(FolderBusy, match=rf"is in use by run {sleeper.pid} on this host"):
            FolderLock(tmp_path, "hydra.run.dir").__enter__()
    finally:
        sleeper.kill()
        sleeper.wait()
    dead = _dead_pid()
    (tmp_path / LOCK_FILE).write_text(f"{dead} {host} 0\n")
    theirs = tmp_path / f".windbench.nc.{host}.{dead}.abcd.tmp"
    other = tmp_path / f".windbench.nc.{host}.{os.getpid()}.abcd.tmp"
    theirs.touch()
    other.touch()
    with caplog.at_level("WARNING", logger="windbench"):
        with FolderLock(tmp_path) as lock:
            assert lock.owned
            assert (tmp_path / LOCK_FILE).read_text().split()[:2] == [str(os.getpid()), host]
            with FolderLock(tmp_path) as inner:  # re-entrant in one process
                assert not inner.owned
            assert (tmp_path / LOCK_FILE).exists()
    assert not (tmp_path / LOCK_FILE).exists()
    assert f"took over the lock of run {dead}, which is no longer running (1 temporary" in (
        caplog.text
    )
    assert not theirs.exists() and other.exists()  # only the dead writer's temporaries


@pytest.mark.parametrize("hard_links", [True, False])
def test_the_lock_file_appears_whole_and_leaves_no_temporary(tmp_path, monkeypatch, hard_links):
    """The lock file holds ``pid host time`` and no temporary is left beside it, taken by
    a hard link of its finished text (never seen empty) or, on a file system without hard
    links, by exclusive create; either way a second taker gets FileExistsError."""
    if not hard_links:

        def no_link(*args):
            raise OSError("this file system has no hard links")

        monkeypatch.setattr(os, "link", no_link)
    with FolderLock(tmp_path):
        pid, host, _ = (tmp_path / LOCK_FILE).read_text().split()
        assert (int(pid), host) == (os.getpid(), socket.gethostname())
        assert sorted(p.name for p in tmp_path.iterdir()) == [LOCK_FILE]
        with pytest.raises(FileExistsError):
            FolderLock(tmp_path)._create()
    assert not any(tmp_path.iterdir())


def test_a_lock_held_on_another_host_is_left_alone(tmp_path):
    (tmp_path / LOCK_FILE).write_text("1234 some-other-host 0\n")
    with pytest.raises(FolderBusy, match="on host some-other-host .* delete it if that run"):
        FolderLock(tmp_path).__enter__()


def test_two_runs_in_one_folder_the_second_refuses_the_first_completes(cli, tmp_path):
    import shutil

    out = tmp_path / "run"
    env_args = [*TINY, "sim.duration=0.2", f"hydra.run.dir={out}", "sim.progress=false"]
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "PYTHONPATH": root, "HYDRA_FULL_ERROR": "0"}
    first = subprocess.Popen(
        [sys.executable, "-m", "windbench", *env_args],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while not (out / LOCK_FILE).exists():
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.02)
        first.send_signal(signal.SIGSTOP)  # hold the first run inside its folder
        second = cli(*env_args, "sim.duration=0.1")
        first.send_signal(signal.SIGCONT)
        stdout, stderr = first.communicate(timeout=300)
    finally:
        first.kill()
    assert second.returncode == 2
    lines = [ln for ln in second.stderr.splitlines() if ln.strip()]
    assert lines == [
        f"windbench: error: hydra.run.dir: {out} is in use by run {first.pid} on this host; "
        "wait for it to finish or choose another folder"
    ]
    assert first.returncode == 0, stderr
    assert read_run(out / "windbench.nc").status == "complete"
    with xr.open_dataset(out / "windbench.nc") as ds:
        assert ds.sizes["time"] == 12  # the first run's 0.2 s, not the second's 0.1 s
    assert not (out / LOCK_FILE).exists() and not list(out.glob(".*.tmp"))
    shutil.rmtree(out)


def test_a_sweep_refuses_a_sweep_folder_in_use(cli, tmp_path):
    with FolderLock(tmp_path / "sweep"):  # this (live) process holds it
        proc = cli("-m", *TINY, "seed=1,2", f"hydra.sweep.dir={tmp_path / 'sweep'}")
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        f"windbench: error: hydra.sweep.dir: {tmp_path / 'sweep'} is in use by run "
        f"{os.getpid()} on this host; wait for it to finish or choose another folder"
    )
    assert not list((tmp_path / "sweep").rglob("*.nc"))


@pytest.mark.parametrize(
    "counts, code",
    [
        ({"complete": 3}, 0),
        ({"complete": 1, "skipped": 2}, 0),
        ({"complete": 3, "failed": 1}, 1),
        ({"complete": 3, "unreadable": 1}, 1),
        ({"complete": 3, "invalid": 1}, 2),
        ({"failed": 1, "invalid": 1}, 2),
    ],
)
def test_sweep_exit_status(counts, code):
    assert exit_status(Counter(counts)) == code


def test_a_sweep_with_an_invalid_run_exits_2(cli, tmp_path):
    proc = cli("-m", *TINY, "grid.resolution=2,32", f"hydra.sweep.dir={tmp_path / 's'}")
    assert proc.returncode == 2, proc.stderr
    assert "windbench sweep: 1 complete, 0 failed, 1 invalid, 0 skipped" in proc.stdout
