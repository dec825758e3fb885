"""CF-1.10 metadata on every variable and coordinate of the run datasets (each backend, so
that every backend and cloth figure is covered) and of the combined ``results.nc``."""

import numpy as np
import pytest
import xarray as xr

from windbench.cli import compose_config
from windbench.dataset import write_atomic
from windbench.report.collect import combine, find_runs, mark_duplicates, read_runs
from windbench.simulate import run
from windbench.wind import backends

cf_xarray = pytest.importorskip("cf_xarray")
from cf_xarray.units import units as udunits  # noqa: E402 - needs cf_xarray (and pint)

RUN = [
    "scene=two_flags_wall",
    "grid.resolution=20",
    "sim.dt=0.05",
    "sim.duration=0.1",
    "sim.progress=false",
]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A run dataset of every backend, and the results.nc combining them."""
    root = tmp_path_factory.mktemp("cf")
    runs = []
    for backend in sorted(backends()):
        result = run(compose_config([f"wind={backend}", *RUN]), root / "sweep" / backend)
        assert result.status == "complete", result.failure
        runs.append(result.path)
    records = read_runs(find_runs([root / "sweep"]), progress=False)
    mark_duplicates(records)
    results = write_atomic(combine(records), root / "results.nc")
    return runs, results


def assert_cf_complete(ds: xr.Dataset, where: str):
    assert ds.attrs["Conventions"] == "CF-1.10", where
    for name, var in ds.variables.items():
        assert var.attrs.get("long_name"), f"{where}: {name} has no long_name"
        if var.dtype.kind in "fiu":
            assert "units" in var.attrs, f"{where}: {name} has no units"
            udunits.parse_units(var.attrs["units"])  # a UDUNITS string ("1": dimensionless)
        else:  # labels (component, cloth, phase, ...): CF gives strings no units
            assert var.dtype.kind in "OUS" and "units" not in var.attrs, f"{where}: {name}"


def test_every_variable_of_every_run_dataset_is_cf_complete(files):
    runs, _ = files
    for path in runs:
        with xr.open_dataset(path) as ds:
            assert_cf_complete(ds, path.parent.name)
            assert ds.cf.axes == {"X": ["x"], "Y": ["y"], "Z": ["z"]}
            assert {ds[a].attrs["units"] for a in "xyz"} == {"m"}
            assert ds["wind"].attrs["units"] == "m s-1" and ds["aero_force"].attrs["units"] == "N"


def test_backend_and_cloth_figures_declare_their_units(files):
    runs, _ = files
    expected = {
        "navier_stokes": {"pressure_iterations": "1", "pressure_rhs_norm": "m s-1", "cfl": "1"},
        "particles": {"live_particles": "1", "particle_steps_per_second": "s-1"},
        "global": {"kinetic_energy": "J", "max_penetration": "m", "max_stretch": "1"},
    }
    for path in runs:
        with xr.open_dataset(path) as ds:
            for name, unit in expected[path.parent.name].items():
                assert ds[name].attrs["units"] == unit, (path.parent.name, name)


def test_every_variable_of_the_combined_results_is_cf_complete(files):
    _, results = files
    with xr.open_dataset(results) as ds:
        assert ds.attrs["runs"] == 3 and ds.sizes["wind"] == 3
        assert_cf_complete(ds, "results.nc")
        assert ds["lee_speed_ratio"].attrs["long_name"].startswith("mean |u| in the lee box")
        assert ds["dt"].attrs["units"] == "s" and ds["resolution"].attrs["units"] == "1"
        assert ds["pressure_iterations"].attrs["units"] == "1"
        assert np.isfinite(ds["seconds_per_step"].values).all()
