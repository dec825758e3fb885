"""Sweeps that survive faults: launchers, failure isolation, resume, atomic writes,
validation before work, reproducibility."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import xarray as xr
import yaml

from windbench.cli import compose_config
from windbench.dataset import MACHINE_VARIABLES
from windbench.errors import ConfigError
from windbench.simulate import prepare

pytestmark = pytest.mark.heavy  # runs sweeps under three launchers

SWEEP = [
    "scene=empty",
    "grid.resolution=8",
    "sim.spinup=0",
    "sim.duration=0.05",
    "sim.fail_at_step=99,2",  # run 0 completes before step 99, run 1 fails at step 2
]


def statuses(sweep_dir):
    out = {}
    for f in sorted(sweep_dir.glob("*/run_status.yaml")):
        out[f.parent.name] = yaml.safe_load(f.read_text())["status"]
    return out


def test_submitit_sweep_isolates_a_diverging_run_and_resume_reruns_only_it(cli, tmp_path):
    sweep = tmp_path / "sweep"
    proc = cli("-m", "hydra/launcher=submitit_local", *SWEEP, f"hydra.sweep.dir={sweep}")
    assert proc.returncode == 1, proc.stderr  # a sweep with a failed run exits 1
    assert "windbench sweep: 1 complete, 1 failed, 0 invalid, 0 skipped" in proc.stdout
    assert statuses(sweep) == {"0": "complete", "1": "failed"}
    with xr.open_dataset(sweep / "1" / "windbench.nc") as ds:
        assert ds.attrs["status"] == "failed"
        assert (
            ds.attrs["failure"]
            == "diverged at step 2: fault injected by sim.fail_at_step (testing)"
        )
        assert ds.sizes["time"] == 1  # what it recorded before the blow-up
    mtime = (sweep / "0" / "windbench.nc").stat().st_mtime_ns

    proc = cli(
        "-m", "hydra/launcher=submitit_local", *SWEEP, f"hydra.sweep.dir={sweep}", "resume=true"
    )
    assert "windbench sweep: 0 complete, 1 failed, 0 invalid, 1 skipped" in proc.stdout
    assert proc.returncode == 1
    assert (sweep / "0" / "windbench.nc").stat().st_mtime_ns == mtime


def test_joblib_launcher_runs_the_sweep_in_parallel(cli, tmp_path):
    sweep = tmp_path / "sweep"
    proc = cli(
        "-m",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        "scene=empty,flag",
        "grid.resolution=16",
        "sim.duration=0.05",
        f"hydra.sweep.dir={sweep}",
    )
    assert proc.returncode == 0, proc.stderr
    assert "2 complete, 0 failed" in proc.stdout
    assert len(list(sweep.glob("*/windbench.nc"))) == 2
    assert "windbench sweep: 2/2 runs done (0 failed)" in proc.stdout + proc.stderr
    for path in sweep.glob("*/windbench.nc"):  # two runs on the cores at once: a share each
        with xr.open_dataset(path) as ds:
            assert ds.attrs["numba_threads"] == max(1, ds.attrs["cores_available"] // 2)


@pytest.mark.parametrize(
    ("overrides", "runs"),
    [
        (["experiment=smoke"], 3),  # the experiment's sweeper params: three backends
        (["experiment=smoke", "grid.resolution=16,24"], 6),
        (["experiment=smoke", "wind=global"], 1),  # the command line wins over the params
        (["scene=empty", "seed=range(0,4)"], 4),
    ],
)
def test_a_sweep_knows_how_many_runs_it_plans(overrides, runs):
    from windbench.sweep import planned_runs

    cfg = compose_config(overrides[:1], hydra_node=True)  # the first is not a sweep
    cfg.hydra.overrides.task = overrides  # what Hydra stores of the command line
    assert planned_runs(cfg) == runs


def test_the_sweep_count_reads_this_sweep_s_status_files(tmp_path):
    from windbench.sweep import SWEEP_FILE, progress_line, write_status

    write_status(tmp_path / "old", "failed")  # a run of an earlier sweep in the folder
    os.utime(tmp_path / "old" / "run_status.yaml", (1.0, 1.0))
    (tmp_path / SWEEP_FILE).write_text(yaml.safe_dump({"runs": 4, "started": 10.0}))
    for name, status in (("0", "complete"), ("1", "failed"), ("2", "skipped")):
        write_status(tmp_path / name, status)
    assert progress_line(tmp_path) == "windbench sweep: 3/4 runs done (1 failed)"


def test_resume_does_not_skip_a_run_whose_config_changed(cli, tmp_path):
    out = tmp_path / "run"
    assert (
        cli(
            "scene=empty", "grid.resolution=8", "sim.duration=0.05", f"hydra.run.dir={out}"
        ).returncode
        == 0
    )
    proc = cli(
        "scene=empty",
        "grid.resolution=8",
        "sim.duration=0.1",
        "resume=true",
        f"hydra.run.dir={out}",
    )
    assert proc.returncode == 0 and "skipped" not in proc.stderr
    assert yaml.safe_load((out / "run_status.yaml").read_text())["status"] == "complete"
    with xr.open_dataset(out / "windbench.nc") as ds:
        assert ds.sizes["time"] == 6


KILLER = textwrap.dedent("""
    import sys, numpy as np, xarray as xr
    from pathlib import Path
    from windbench.dataset import write_atomic
    path = Path(sys.argv[1])
    for i in range(1000):
        big = np.full((40, 64, 64, 64), float(i))
        write_atomic(xr.Dataset({"v": (("a", "b", "c", "d"), big)}, attrs={"status": "complete",
                     "i": i}), path)
        print(i, flush=True)
""")


@pytest.mark.parametrize("delay", [0.0, 0.05, 0.15, 0.3])
def test_sigkill_during_a_write_leaves_no_corrupt_dataset(tmp_path, delay):
    path = tmp_path / "windbench.nc"
    proc = subprocess.Popen([sys.executable, "-c", KILLER, str(path)], stdout=subprocess.PIPE)
    assert proc.stdout.readline().strip() == b"0"  # one whole file is there; more are coming
    time.sleep(delay)  # the kill lands somewhere in the next writes
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with xr.open_dataset(path) as ds:  # the last whole file, never a torn one
        assert ds.attrs["status"] == "complete"
        assert float(ds.v[0, 0, 0, 0]) == ds.attrs["i"] == float(ds.v[-1, -1, -1, -1])


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            ["grid.resolution=4000"],
            r"grid.resolution: 4000 gives .* cells: the run would need about .* GiB",
        ),
        (["sim.dt=5", "sim.duration=10"], r"sim.dt: 5.0 s lets the wind .* cross the whole domain"),
        (
            ["scene=fence", "scene.bodies.0.min=[50,0,0]", "scene.bodies.0.max=[51,4,2]"],
            r"scene.bodies\[0\]: body lies entirely outside the domain",
        ),
        (["sim.duration=-1"], "sim.duration: must be .auto. or a number of seconds > 0"),
    ],
)
def test_validation_refuses_before_work(overrides, message):
    with pytest.raises(ConfigError, match=message):
        prepare(compose_config(["scene=flag", *overrides]))


def test_cfl_above_the_backend_range_warns(caplog):
    cfg = compose_config(
        ["wind=navier_stokes", "scene=flag", "grid.resolution=16", "sim.dt=0.5", "sim.duration=1"]
    )
    with caplog.at_level("WARNING", logger="windbench"):
        setup = prepare(cfg)
    assert setup.cfl == pytest.approx(8.0)  # 6 m/s x 0.5 s / (6 m / 16)
    assert "CFL number 8 exceeds 5, the stable range of backend navier_stokes" in caplog.text


def test_still_air_has_cfl_zero():
    """A scene without sources or moving walls (cloth hanging in still air) is valid."""
    setup = prepare(compose_config(["scene=flag", "scene.sources=[]", "grid.resolution=8"]))
    assert setup.cfl == 0.0


def test_cfl_is_reported_in_the_dataset(run_config):
    _, ds = run_config(["scene=empty", "grid.resolution=8", "sim.duration=0.05"])
    assert ds.attrs["cfl"] == pytest.approx(6.0 * (1 / 60) / 0.5)


def test_wrong_type_fails_at_composition(cli):
    proc = cli("grid.resolution=fine")
    assert proc.returncode != 0 and "grid.resolution" in proc.stderr


def assert_same_numbers(a: xr.Dataset, b: xr.Dataset):
    for name in a.data_vars:
        if name in MACHINE_VARIABLES or "per_second" in name or name.endswith("_seconds"):
            continue
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)
    assert a.attrs.keys() == b.attrs.keys()
    for key in a.attrs:
        if not key.startswith("load_average_"):  # the machine's, not the run's
            np.testing.assert_array_equal(a.attrs[key], b.attrs[key], err_msg=key)


@pytest.mark.parametrize("scene", ["two_flags_wall"])
def test_same_config_and_seed_reproduce_every_number(run_config, scene):
    from windbench.wind import backends

    for backend in backends():
        args = [
            f"wind={backend}",
            f"scene={scene}",
            "grid.resolution=20",
            "sim.duration=0.1",
            "seed=3",
        ]
        _, a = run_config(args, name=f"{backend}_a")
        _, b = run_config(args, name=f"{backend}_b")
        assert_same_numbers(a, b)
