"""The particles' lee model in the report: ``wind.lee_model`` becomes a dimension of
``results.nc`` when both are run (a key only the particle runs have), the two are not
taken for duplicates, and the comparison tells them apart (``particles`` is the paper's
lee, ``particles/mixing`` the mixing one) in its table, figures and wake profiles."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402

from tests.report.tiny_runs import run_ok  # noqa: E402
from windbench.report import build_report  # noqa: E402
from windbench.report import comparison as C  # noqa: E402
from windbench.report.collect import backend_label, read_runs, swept_keys  # noqa: E402

FENCE = ["scene=fence", "grid.resolution=48", "sim.dt=0.4", "sim.duration=1.2"]


@pytest.fixture(scope="module")
def lee_runs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("lee")
    run_ok(root / "paper", *FENCE, "wind=particles")
    run_ok(root / "mixing", *FENCE, "wind=particles", "wind.lee_model=mixing")
    run_ok(root / "ns", *FENCE, "wind=navier_stokes")
    return root


@pytest.fixture(scope="module")
def lee_report(lee_runs):
    return build_report([lee_runs], out=lee_runs.parent / "rep", progress=False)


def test_the_lee_model_is_a_dimension_and_no_duplicate(lee_runs, lee_report):
    records = read_runs(sorted(lee_runs.rglob("windbench.nc")), progress=False)
    assert "wind.lee_model" in swept_keys(records)
    assert not lee_report.skipped  # paper and mixing differ in wind.lee_model
    with xr.open_dataset(lee_report.out / "results.nc") as ds:
        assert set(ds["wind.lee_model"].values) == {"", "paper", "mixing"}
        assert ds["wind.lee_model"].attrs["long_name"]


def test_the_comparison_tells_the_lee_models_apart(lee_report):
    summary = lee_report.summary
    table = C.accuracy_cost_table(summary[summary["status"] == "complete"])
    assert set(table["backend"]) == {"particles", "particles/mixing"}
    wake = C.wake_frame(lee_report.records, lee_report.references)
    assert {"particles", "particles/mixing", "reference"} <= set(wake["backend"])
    mixing = wake[wake["backend"] == "particles/mixing"]
    assert np.isfinite(mixing["u_over_u0"]).all()
    assert "particles/mixing" in (lee_report.out / "report.md").read_text()


@pytest.mark.parametrize(
    ("wind", "lee", "label"),
    [
        ("particles", "mixing", "particles/mixing"),
        ("particles", "paper", "particles"),
        ("particles", None, "particles"),  # a run made before the lee model existed
        ("navier_stokes", float("nan"), "navier_stokes"),
        ("navier_stokes", "paper", "navier_stokes"),  # the paper's cloth coupling (§4.1.2)
        ("navier_stokes", "projection", "navier_stokes/projection"),
        ("navier_stokes", "none", "navier_stokes/none"),
        ("global", "mixing", "global"),  # no models: a stray value names none
    ],
)
def test_backend_labels(wind, lee, label):
    assert backend_label(wind, lee) == label
