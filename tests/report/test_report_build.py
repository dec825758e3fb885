"""windbench-report on real (tiny) runs: summary, combined dataset, figures, skipped files."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402

from windbench.cli import compose_config  # noqa: E402
from windbench.errors import SimulationDiverged  # noqa: E402
from windbench.report import build_report, figures  # noqa: E402
from windbench.report.cli import main as report_main  # noqa: E402
from windbench.report.collect import (  # noqa: E402
    combine,
    find_runs,
    mark_duplicates,
    read_runs,
    summary_frame,
)
from windbench.report.lee import assign_lee_errors, choose_references  # noqa: E402
from windbench.simulate import Simulation, run  # noqa: E402

pytestmark = pytest.mark.heavy  # runs sweeps and reports from the command line

ROOT = Path(__file__).resolve().parents[2]
RESOLUTIONS = (20, 30)
DTS = (0.05, 0.1)
TINY = [
    "sim.duration=0.2",
    "output.snapshots=2",
    "output.probe_points=3",
    "sim.progress=false",
    "cloth.solver=static",  # two identical flags stay identical through the spin-up
]


UNIFORM_WIND = "scene.sources=[{type: uniform, velocity: [6.0, 0.0, 0.0]}]"


def _run(folder: Path, *overrides: str):
    return run(compose_config([*TINY, *overrides]), folder)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> Path:
    """A smoke-like sweep folder: two_flags_wall x resolution x dt, one run per subfolder,
    in a uniform 6 m/s instead of the scene's log law, so that a wind scaled in the lee
    box has a lee error known without the code."""
    root = tmp_path_factory.mktemp("sweep")
    n = 0
    for res in RESOLUTIONS:
        for dt in DTS:
            result = _run(
                root / str(n),
                "scene=two_flags_wall",
                UNIFORM_WIND,
                f"grid.resolution={res}",
                f"sim.dt={dt}",
            )
            assert result.status == "complete"
            n += 1
    return root


@pytest.fixture(scope="module")
def report(sweep, tmp_path_factory):
    return build_report([sweep], out=tmp_path_factory.mktemp("out") / "rep", progress=False)


def test_summary_has_one_row_per_run(report, sweep):
    summary = pd.read_csv(report.out / "summary.csv")
    assert len(summary) == len(list(sweep.rglob("windbench.nc"))) == 4
    assert set(summary["status"]) == {"complete"}
    assert sorted(zip(summary["resolution"], summary["dt"], strict=True)) == sorted(
        (r, d) for r in RESOLUTIONS for d in DTS
    )
    # two_flags_wall names a sheltered and an exposed flag: the force ratio is measured;
    # the global field has no lee, so both flags see the same wind at the same angle; they
    # sit at different coordinates, so their rounding differs (about 1e-12 after 1.5 s),
    # and where a thread touches the strain limit (cloth.strain_limit) that rounding can
    # decide whether it is solved on one flag and not on the other (8e-5 apart, measured)
    np.testing.assert_allclose(summary["lee_force_ratio"], 1.0, rtol=1e-3)
    assert (summary["seconds_per_step"] > 0).all()


def test_combined_dataset_has_swept_settings_as_dimensions(report):
    with xr.open_dataset(report.out / "results.nc") as ds:
        for dim in ("wind", "scene", "resolution", "dt", "seed"):
            assert dim in ds.dims
        assert list(ds["wind"].values) == ["global"]
        assert list(ds["scene"].values) == ["two_flags_wall"]
        assert list(ds["resolution"].values) == list(RESOLUTIONS)
        np.testing.assert_allclose(ds["dt"].values, DTS)
        assert list(ds["seed"].values) == [0]
        assert set(ds["phase"].values) >= {"wind", "aero", "cloth", "total"}
        # each cell holds its own run: the grid it was run on
        for res in RESOLUTIONS:
            cell = ds.sel(wind="global", scene="two_flags_wall", resolution=res, seed=0)
            path = str(cell["path"].values[0])
            with xr.open_dataset(path) as run_ds:
                assert run_ds.attrs["resolution"] == res
                assert int(cell["grid_cells"].values[0]) == int(np.prod(run_ds.attrs["grid_shape"]))


def test_figures_and_pages_exist(report):
    pngs = sorted((report.out / "figures").glob("*.png"))
    names = {p.stem for p in pngs}
    assert {"fig3_flag", "fig45_two_flags_wall", "cost_vs_cells", "plate_coefficients"} - {
        "fig3_flag"
    } <= names
    for png in pngs:
        img = mpimg.imread(png)
        assert img.shape[0] > 50 and img.shape[1] > 50
        assert img[..., :3].std() > 0.01, f"{png.name} is blank"
        assert png.with_suffix(".svg").stat().st_size > 1000
    md = (report.out / "report.md").read_text()
    html = (report.out / "index.html").read_text()
    for name in names:
        assert f"figures/{name}.png" in md
    assert html.count("data:image/png;base64,") == len(pngs)
    assert "http://" not in html and "https://" not in html  # opens offline
    # the figures that need backends not in the inputs say which runs would produce them
    assert "Not drawn" in md and "wind=particles" in md
    assert f"Made by {report.summary['code'].iloc[0]}." in md  # one version made them all


def test_corrupted_and_failed_runs_are_listed_and_do_not_stop_the_report(
    sweep, tmp_path, monkeypatch, capsys
):
    inputs = tmp_path / "inputs"
    shutil.copytree(sweep / "0", inputs / "good")
    bad = inputs / "corrupt" / "windbench.nc"
    bad.parent.mkdir(parents=True)
    bad.write_bytes(b"CDF\x01" + b"\x00garbage" * 40)

    real_step = Simulation.step

    def blow_up(self, n):
        if n == 2:
            raise SimulationDiverged(n + 1, "wind field is not finite (NaN or inf)")
        real_step(self, n)

    monkeypatch.setattr(Simulation, "step", blow_up)
    failed = _run(
        inputs / "failed",
        "scene=two_flags_wall",
        "grid.resolution=20",
        "sim.dt=0.05",
        "sim.spinup=0",
    )
    assert failed.status == "failed"

    def broken(records):
        raise RuntimeError("boom")

    monkeypatch.setitem(figures.RUN_FIGURES, "fig45_two_flags_wall", broken)
    code = report_main([str(inputs), "--out", str(tmp_path / "rep"), "--quiet"])
    assert code == 0
    out = capsys.readouterr().out
    assert "corrupt" in out and "unreadable" in out and "failed" in out
    summary = pd.read_csv(tmp_path / "rep" / "summary.csv")
    assert len(summary) == 3
    by_status = summary.set_index("status")
    assert "cannot open" in by_status.loc["unreadable", "failure"]
    assert by_status.loc["failed", "failure"] == failed.failure
    assert "not finite" in by_status.loc["failed", "failure"]
    assert by_status.loc["failed", "steps_completed"] == 2
    with xr.open_dataset(tmp_path / "rep" / "results.nc") as ds:
        assert ds.attrs["runs"] == 1  # only the complete run is combined
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "Skipped" in md and str(bad) in md
    assert "drawing failed (RuntimeError: boom)" in md  # one broken figure, the report stands


def test_reference_run_has_zero_lee_error_and_others_finite(sweep):
    records = read_runs(find_runs([sweep]))
    refs = choose_references(records, read_runs(find_runs([sweep / "3"])))  # --reference DIR
    assign_lee_errors(records, refs)
    summary = summary_frame(records).set_index(["resolution", "dt"])
    assert summary.loc[(30, 0.1), "lee_error"] == 0.0  # the reference against itself
    assert bool(summary.loc[(30, 0.1), "is_reference"])
    assert summary["is_reference"].sum() == 1
    # the global field is sampled exactly at the probe points: same wind at every resolution
    np.testing.assert_allclose(summary["lee_error"], 0.0, atol=1e-12)


def test_duplicate_runs_are_skipped_not_combined(sweep, tmp_path):
    shutil.copytree(sweep / "0", tmp_path / "a")
    shutil.copytree(sweep / "0", tmp_path / "b")
    records = read_runs(find_runs([tmp_path / "a", tmp_path / "b", tmp_path / "a"]))
    assert len(records) == 2  # a folder given twice is read once
    mark_duplicates(records)
    assert sorted(r.status for r in records) == ["complete", "duplicate"]
    assert combine(records).attrs["runs"] == 1


def test_hydra_multirun_smoke_then_report(tmp_path):
    """The Quick start: `windbench -m experiment=smoke` then `windbench-report` on its folder."""
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    import os

    env = {**os.environ, **env}
    sweep_dir = tmp_path / "multirun"
    swept = subprocess.run(
        [
            sys.executable,
            "-m",
            "windbench",
            "-m",
            "experiment=smoke",
            "sim.duration=0.1",
            "sim.dt=0.05",
            "grid.resolution=2,20",  # 2 cells cannot hold the wall: refused, listed as invalid
            f"hydra.sweep.dir={sweep_dir}",
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
    )
    assert swept.returncode == 2, swept.stderr  # a sweep with invalid runs exits 2
    done = subprocess.run(
        [sys.executable, "-m", "windbench.report", str(sweep_dir), "--quiet"],
        check=True,
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
    )
    out = tmp_path / "reports" / "smoke"  # default: reports/<experiment>
    assert out.is_dir(), done.stdout
    summary = pd.read_csv(out / "summary.csv")
    n_runs = len(list(sweep_dir.rglob("windbench.nc")))
    assert n_runs >= 1
    # one row per run, the refused ones (resolution 2, one per backend) included
    assert len(summary) == 2 * n_runs
    invalid = summary[summary["status"] == "invalid"]
    assert len(invalid) == n_runs
    assert invalid["failure"].str.contains("grid.resolution").all()
    assert (invalid["resolution"] == 2).all()  # their settings, from Hydra's saved config
    assert set(invalid["wind"]) == set(summary[summary["status"] == "complete"]["wind"])
    assert (out / "index.html").stat().st_size > 10_000


def _as_backend(src: Path, dst: Path, wind: str, edit=None):
    """A copy of a run dataset relabelled as another backend (and optionally edited)."""
    with xr.open_dataset(src) as ds:
        ds = ds.load()
    ds.attrs["wind"] = wind
    if edit is not None:
        edit(ds)
    dst.parent.mkdir(parents=True, exist_ok=True)
    ds.to_netcdf(dst)


def test_navier_stokes_reference_and_particle_figures(sweep, tmp_path):
    """With Navier-Stokes and particle runs in the inputs (here: global runs relabelled, with a
    known lee), the reference is chosen automatically and the paper's figures are drawn."""

    def halve_lee(ds):  # the reference sees half the free-stream wind in the lee box
        lee = (ds["probe_box"] == "lee").values
        ds["probe_wind"].values[:, lee, :] *= 0.5
        ds["probe_wind_mean"].values[lee, :] *= 0.5

    inputs = tmp_path / "inputs"
    for n in range(4):
        shutil.copytree(sweep / str(n), inputs / "global" / str(n))
        _as_backend(
            sweep / str(n) / "windbench.nc",
            inputs / "ns" / str(n) / "windbench.nc",
            "navier_stokes",
            halve_lee,
        )
    opposing = _run(inputs / "opp_global", "scene=opposing_sources", "grid.resolution=20")
    assert opposing.status == "complete"

    def two_sided(ds):  # what per-source particles give: each side keeps its own source
        x = ds["x"].values[None, :, None, None]
        u = np.zeros(ds["wind"].shape)
        u[..., 0] = np.where(x < 3.7, 4.0, np.where(x > 4.3, -4.0, 0.0))
        ds["wind"].values[:] = u

    _as_backend(opposing.path, inputs / "opp_particles" / "windbench.nc", "particles", two_sided)

    rep = build_report([inputs], out=tmp_path / "rep", progress=False)
    summary = rep.summary
    ref = rep.references["two_flags_wall"]
    assert ref.run.settings["wind"] == "navier_stokes" and ref.run.settings["resolution"] == 30
    assert ref.run.settings["dt"] == 0.05  # finest grid, then the smallest time step
    tfw = summary[summary["scene"] == "two_flags_wall"]
    glob = tfw[tfw["wind"] == "global"]["lee_error"]
    # |u - u/2| = 3 m/s everywhere in the lee box, over a free stream of 6 m/s
    np.testing.assert_allclose(glob, 0.5, rtol=1e-12)
    np.testing.assert_allclose(tfw[tfw["wind"] == "navier_stokes"]["lee_error"], 0.0, atol=0)
    assert {"fig45_two_flags_wall", "opposing_sources", "lee_error_vs_resolution"} <= set(rep.drawn)
    assert "opposing_sources" not in rep.missing
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "finest `navier_stokes` run of the scene" in md and str(ref.path) in md
