"""Report pieces against answers known without the code: lee error, fits, Hoerner, tagging."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from omegaconf import OmegaConf

from windbench.aero import AeroParams
from windbench.cli import compose_config
from windbench.report.build import cloth_table
from windbench.report.collect import (
    RunRecord,
    _window_max,
    contention,
    flatten,
    swept_keys,
    window_mask,
    with_backend,
)
from windbench.report.comparison import pareto_front, spans_a_decade
from windbench.report.figures import (
    BACKEND_COLORS,
    _wake_span,
    cost_exponents,
    fig_force_ratio_resolution,
    fit_exponent,
    hoerner_long_plate,
    pick,
    plate_table,
    tagging_field,
)
from windbench.report.lee import assign_lee_errors, choose_references, lee_error


def _record(points, u, free=6.0, **settings) -> RunRecord:
    rec = RunRecord(Path(f"/runs/{settings}/windbench.nc"), "complete", settings=settings)
    rec.lee_points, rec.lee_wind, rec.reference_speed = points, u, free
    return rec


@pytest.fixture
def lattice():
    g = np.linspace(0.1, 0.9, 4)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


def test_lee_error_of_a_uniform_offset_is_its_size_over_the_free_stream(lattice):
    rng = np.random.default_rng(1)
    u_ref = rng.normal(size=lattice.shape)
    offset = np.array([0.9, -1.2, 0.0])  # |offset| = 1.5
    ref = _record(lattice, u_ref, free=6.0)
    run = _record(lattice, u_ref + offset)
    assert lee_error(run, ref) == pytest.approx(1.5 / 6.0, rel=1e-12)
    assert lee_error(ref, ref) == 0.0


def test_lee_error_matches_points_by_position_not_order(lattice):
    rng = np.random.default_rng(2)
    u_ref = rng.normal(size=lattice.shape)
    diff = rng.normal(size=lattice.shape)
    ref = _record(lattice, u_ref, free=2.0)
    # the run holds the points shuffled, only half of them, plus points the reference lacks
    keep = rng.permutation(len(lattice))[: len(lattice) // 2]
    extra = lattice[:5] + 10.0
    run = _record(
        np.concatenate([lattice[keep], extra]),
        np.concatenate([u_ref[keep] + diff[keep], np.full((5, 3), 99.0)]),
    )
    expected = math.sqrt(np.mean(np.sum(diff[keep] ** 2, axis=1))) / 2.0
    assert lee_error(run, ref) == pytest.approx(expected, rel=1e-12)
    assert math.isnan(lee_error(_record(extra, np.zeros((5, 3))), ref))  # nothing in common


def test_reference_is_the_finest_navier_stokes_run_of_each_scene(lattice):
    u = np.zeros_like(lattice)
    runs = [
        _record(lattice, u, wind="navier_stokes", scene="fence", resolution=32, dt=0.01, seed=0),
        _record(lattice, u, wind="navier_stokes", scene="fence", resolution=64, dt=0.02, seed=0),
        _record(lattice, u, wind="navier_stokes", scene="fence", resolution=64, dt=0.01, seed=0),
        _record(lattice, u, wind="particles", scene="fence", resolution=128, dt=0.01, seed=0),
        _record(lattice, u, wind="global", scene="flag", resolution=128, dt=0.01, seed=0),
    ]
    refs = choose_references(runs)
    assert refs["fence"].run is runs[2]
    assert "flag" not in refs  # no Navier-Stokes run of the flag: no reference
    # given a reference folder, its finest run serves even when it is not Navier-Stokes;
    # scenes it lacks keep the inputs' Navier-Stokes reference
    given = choose_references(runs, [runs[4]])
    assert given["flag"].run is runs[4] and given["fence"].run is runs[2]


def _level(points, u, resolution, advection="second_order"):
    rec = _record(points, u, wind="navier_stokes", scene="fence", resolution=resolution, dt=0.01)
    rec.config = {"wind.advection": advection, "wind.turbulence": "mixing_length", "seed": 0}
    return rec


def test_the_reference_is_second_order_and_its_gci_follows_roache(lattice):
    """Three levels whose lee winds differ by 0.8 and 0.2 m/s (ratio 4 at r = 2: observed
    order 2) give GCI = 1.25 e21 / (2^2 - 1); a finer first-order run is not chosen."""
    base = np.zeros_like(lattice)
    shift = np.array([1.0, 0.0, 0.0])
    levels = [_level(lattice, base, 128), _level(lattice, base + 0.2 * shift, 64)]
    levels.append(_level(lattice, base + 1.0 * shift, 32))
    first_order = _level(lattice, base, 256, advection="semi_lagrangian")
    ref = choose_references([first_order, *levels])["fence"]
    assert ref.run is levels[0] and [r.settings["resolution"] for r in ref.levels] == [128, 64, 32]
    e21 = 0.2 / 6.0
    assert ref.difference == pytest.approx(e21)
    assert ref.observed and ref.order == pytest.approx(2.0)
    assert ref.gci == pytest.approx(1.25 * e21 / 3.0)
    two = choose_references(levels[:2])["fence"]  # two levels: formal order, F_s = 3
    assert not two.observed and two.gci == pytest.approx(3.0 * e21 / 3.0)


def test_a_reference_whose_uncertainty_exceeds_the_errors_it_ranks_is_flagged(lattice):
    base = np.zeros_like(lattice)
    levels = [_level(lattice, base, 64), _level(lattice, base + [0.6, 0, 0], 32)]
    close = _record(lattice, base + [0.05, 0, 0], wind="particles", scene="fence", resolution=32)
    close.figures = {"lee_error": 0.0}
    for r in levels:
        r.figures = {"lee_error": 0.0}
    refs = choose_references([*levels, close])
    assign_lee_errors([*levels, close], refs)
    assert close.figures["lee_error"] == pytest.approx(0.05 / 6.0)
    assert refs["fence"].gci > close.figures["lee_error"] and refs["fence"].converged is False


def test_pareto_front_keeps_the_points_nothing_beats_in_both():
    cost = np.array([1.0, 2.0, 3.0, 2.5, 0.5])
    error = np.array([0.5, 0.2, 0.1, 0.3, 0.9])
    np.testing.assert_array_equal(pareto_front(cost, error), [True, True, True, False, True])


def test_fit_exponent_recovers_a_power_law():
    cells = np.array([1e3, 8e3, 64e3, 512e3])
    assert fit_exponent(cells, 3e-7 * cells**1.37) == pytest.approx(1.37, rel=1e-12)
    assert math.isnan(fit_exponent([1000, 1000], [1.0, 2.0]))


def _timed_run(wall, cpu, load=(0.1, 0.3), cores=2) -> xr.Dataset:
    n = len(wall)
    seconds = np.zeros((n, 4))
    seconds[:, 3] = wall
    ds = xr.Dataset(
        {"step_seconds": (("time", "phase"), seconds), "step_cpu_seconds": ("time", cpu)},
        coords={"phase": ["wind", "aero", "cloth", "total"]},
    )
    ds.attrs.update(cpu_count=cores, load_average_start=[load[0], 0, 0])
    ds.attrs["load_average_end"] = [load[1], 0, 0]
    return ds


def test_a_run_that_waited_for_a_core_or_shared_a_loaded_machine_is_contended():
    # the first step (compile) is left out; then wall/CPU = 1 (two threads: 0.5) and 2
    own = contention(_timed_run([9.0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0]))
    assert own == {"wall_cpu_ratio": 1.0, "load_average_peak": 0.3, "contended": False}
    assert not contention(_timed_run([1.0, 0.5, 0.5], [1.0, 1.0, 1.0]))["contended"]
    assert contention(_timed_run([1.0, 2.0, 2.0], [1.0, 1.0, 1.0]))["contended"]
    assert contention(_timed_run([1.0] * 3, [1.0] * 3, load=(2.4, 2.6)))["contended"]
    assert not contention(_timed_run([1.0] * 3, [1.0] * 3, load=(2.4, 2.5)))["contended"]


def test_a_run_that_gave_threads_up_to_other_processes_is_contended():
    """Its steps on one thread of the two it planned are not the two-thread cost; the first
    step (compile) is left out, as from the wall/CPU ratio."""
    ds = _timed_run([1.0] * 3, [1.0] * 3).assign(step_threads=("time", [2.0, 1.0, 2.0]))
    ds.attrs["numba_threads"] = 2
    assert contention(ds)["contended"]
    assert not contention(ds.assign(step_threads=("time", [2.0] * 3)))["contended"]
    assert not contention(ds.assign(step_threads=("time", [1.0, 2.0, 2.0])))["contended"]


def test_the_cost_fit_leaves_out_contended_runs_and_counts_them():
    cells = np.array([1e3, 8e3, 64e3, 512e3, 512e3])
    seconds = 1e-6 * cells**1.2
    seconds[-1] *= 7.0  # measured while another process held a core
    df = pd.DataFrame(
        {
            "wind": "navier_stokes",
            "scene": "fence",
            "grid_cells": cells,
            "wind_seconds_median": seconds,
            "contended": [False, False, False, False, True],
        }
    )
    row = cost_exponents(df).iloc[0]
    assert row["exponent p"] == pytest.approx(1.2, rel=1e-12)
    assert row["runs"] == 4 and row["left out (contended)"] == 1
    kept = cost_exponents(df, contended=True).iloc[0]
    assert kept["runs"] == 5 and kept["exponent p"] > 1.25


def test_hoerner_long_plate_and_the_model_at_normal_incidence():
    cd, cl = hoerner_long_plate(np.radians([90.0, 0.0]))
    assert cd[0] == pytest.approx(1.0 / (0.222 + 0.283), rel=1e-12)  # C_N at 90 degrees
    assert cl[0] == pytest.approx(0.0, abs=1e-12) and cd[1] == 0.0 and cl[1] == 0.0
    table = plate_table(AeroParams(drag_coefficient=1.17, lift_coefficient=0.6))
    normal = table.set_index("alpha_deg").loc[90]
    assert normal["C_D model"] == pytest.approx(1.17)  # Hoerner's square plate, normal
    assert table.set_index("alpha_deg").loc[45, "C_L model"] == pytest.approx(0.3)


def test_flatten_config_keys():
    flat = flatten({"a": {"b": 1, "c": [1, 2]}, "d": "x", "e": [{"r": [4, 5]}, {"r": [6]}]})
    assert flat == {"a.b": 1, "a.c": (1, 2), "d": "x", "e.0.r": (4, 5), "e.1.r": (6,)}


def _field_dataset(scene: str, wind: np.ndarray | None = None) -> xr.Dataset:
    cfg = compose_config([f"scene={scene}", "grid.resolution=8"])
    lo = np.asarray(cfg.scene.domain.min, float)
    hi = np.asarray(cfg.scene.domain.max, float)
    h = float((hi - lo).max()) / 8
    axes = [lo[a] + h * (np.arange(round((hi[a] - lo[a]) / h)) + 0.5) for a in range(3)]
    shape = (1, *(len(a) for a in axes), 3)
    ds = xr.Dataset(
        {
            "wind": (
                ("snapshot", "x", "y", "z", "component"),
                np.ones(shape) if wind is None else wind,
            )
        },
        coords={"x": axes[0], "y": axes[1], "z": axes[2]},
    )
    ds.attrs["config"] = OmegaConf.to_yaml(cfg, resolve=True)
    return ds


def test_tagging_with_the_superposed_field_cancels_opposing_sources():
    """§4.2.2: two equal, opposite directional sources superpose to zero everywhere."""
    ds = _field_dataset("opposing_sources")
    assert np.array_equal(tagging_field(ds), np.zeros(ds["wind"].shape[1:]))


def test_tagging_gives_the_superposed_wind_on_reached_cells_only():
    ds = _field_dataset("flag")
    reached = np.ones(ds["wind"].shape, bool)
    reached[0, :, 0, :, :] = False  # an untouched row of cells
    ds["wind"] = ds["wind"].where(reached, 0.0)
    tagged = tagging_field(ds)
    assert np.array_equal(tagged[:, 0], np.zeros_like(tagged[:, 0]))
    np.testing.assert_array_equal(
        tagged[:, 1:], np.broadcast_to([6.0, 0.0, 0.0], tagged[:, 1:].shape)
    )


def test_a_mixing_lee_key_is_no_dimension_of_runs_that_do_not_read_it():
    """wind.recirculation_backflow is read by the mixing lee only: paper-lee runs made with
    another default add no dimension; two mixing runs that differ in it do."""

    def rec(lee, backflow, seed):
        cfg = {"wind.lee_model": lee, "wind.recirculation_backflow": backflow}
        r = RunRecord(Path(f"/r/{lee}{backflow}{seed}"), "complete", config=cfg)
        r.settings = {"wind": "particles", "scene": "fence", "resolution": 16, "dt": 0.1}
        r.settings["seed"] = seed
        return r

    ns = RunRecord(Path("/r/ns"), "complete", config={})
    ns.settings = {"wind": "navier_stokes", "scene": "fence", "resolution": 16, "dt": 0.1}
    ns.settings["seed"] = 0
    runs = [rec("paper", 0.3, 0), rec("mixing", 0.4, 0), ns]
    assert "wind.recirculation_backflow" not in swept_keys(runs)
    assert "wind.lee_model" in swept_keys(runs)
    assert "wind.recirculation_backflow" in swept_keys([*runs, rec("mixing", 0.3, 1)])


def test_swept_keys_are_the_settings_plus_config_keys_that_vary():
    def rec(lift, domain, res):
        cfg = {"aero.lift_coefficient": lift, "scene.domain.max": domain, "grid.resolution": res}
        r = RunRecord(Path(f"/r/{lift}{domain}{res}"), "complete", config=cfg)
        r.settings = {
            "wind": "global",
            "scene": str(domain),
            "resolution": res,
            "dt": 0.1,
            "seed": 0,
        }
        return r

    runs = [rec(0.3, (8, 4, 4), 16), rec(0.6, (6, 3, 3), 16), rec(0.6, (8, 4, 4), 32)]
    dims = swept_keys(runs)
    # scene contents follow from the scene; resolution is a canonical setting already
    assert dims == ["wind", "scene", "resolution", "dt", "seed", "aero.lift_coefficient"]
    # ... unless a scene key is swept within one scene (experiment=scaling_cloth)
    cloth = [rec(0.3, (8, 4, 4), 16) for _ in range(2)]
    for r, size in zip(cloth, ((40, 25), (64, 64)), strict=True):
        r.config["scene.cloths.0.resolution"] = size
    assert swept_keys(cloth)[-1] == "scene.cloths.0.resolution"
    # a cloth key set otherwise in a scene without cloth (the fence) is no dimension ...
    fence = rec(0.3, (8, 4, 4), 16)
    fence.config["scene.cloths"] = ()
    for r in (*cloth, fence):
        r.config["cloth.self_collision"] = r is not fence
    assert "cloth.self_collision" not in swept_keys([*cloth, fence])
    # ... one that varies among runs with cloth is
    cloth[0].config["cloth.self_collision"] = False
    assert swept_keys([*cloth, fence])[-1] == "cloth.self_collision"


def test_a_crossing_in_one_step_of_the_window_is_the_runs_peak_and_its_scenes():
    """The window mean of self_intersections dilutes one crossing step; its peak does not,
    and steps before the steady window (t < analysis_start) do not count. The cloth table
    keeps the largest peak per scene and backend and leaves out scenes without cloth."""
    t = np.arange(6.0)
    ds = xr.Dataset(
        {
            "self_intersections": ("time", [9.0, 0.0, 0.0, 4.0, 0.0, 0.0]),
            "max_penetration": ("time", [0.5, 0.0, 0.001, 0.0, 0.0, 0.0]),
            "max_stretch": ("time", [0.2, 0.01, 0.02, 0.03, 0.01, 0.01]),
        },
        coords={"time": t},
        attrs={"analysis_start": 1.0},
    )
    window = window_mask(ds)
    assert _window_max(ds, "self_intersections", window) == 4.0  # the window mean: 0.8
    assert _window_max(ds, "max_penetration", window) == 0.001
    assert math.isnan(_window_max(ds, "kinetic_energy", window))  # not in the run
    df = pd.DataFrame(
        {
            "wind": ["global", "global", "particles", "global"],
            "scene": ["flag", "flag", "flag", "fence"],
            "self_intersections_peak": [0.0, 4.0, 0.0, 0.0],
            "max_penetration_peak": [0.0, 0.001, 0.002, 0.0],
            "max_stretch_peak": [0.02, 0.03, 0.01, 0.0],
        }
    )
    table = cloth_table(df).set_index("backend")
    assert list(table["scene"]) == ["flag", "flag"]
    assert table.loc["global", "runs"] == 2
    assert table.loc["global", "intersecting triangle pairs"] == 4.0
    assert table.loc["particles", "deepest body penetration (mm)"] == pytest.approx(2.0)


@pytest.mark.parametrize(
    ("lo", "hi", "expected"),
    [
        (2.6, 8.0, False),
        (0.5, 20.0, True),
        (1.0, 3.0, True),
        (0.11, 0.99, False),
        (1e-3, 1.2, True),
    ],
)
def test_a_cost_axis_spans_a_decade_when_it_holds_a_power_of_ten(lo, hi, expected):
    """The accuracy-against-cost panels drop their minor tick labels only where a power of
    ten gives a labelled major tick: the shirt's costs, 2.6 to 8 s, would have none."""
    assert spans_a_decade(lo, hi) is expected


def test_a_lee_slice_spans_the_near_wake_inside_the_domain():
    """Fig. 4/5's slices run from the inflow end to twice the view box's length beyond it
    (two_flags_wall: the wall and flags within x = 1-4.9 m of a 24 m domain), and stop at
    the outflow end of a shorter domain."""
    scene = SimpleNamespace(lower=np.zeros(3), upper=np.array([24.0, 4.0, 6.0]))
    lo, hi = np.array([1.0, 0.6, 0.0]), np.array([4.9, 4.0, 3.0])
    assert _wake_span(scene, lo, hi) == pytest.approx((0.0, 12.7))
    scene.upper[0] = 10.0
    assert _wake_span(scene, lo, hi) == (0.0, 10.0)


def _force_ratios() -> pd.DataFrame:
    """Sheltered-flag force ratios of two models of each of two backends at two
    resolutions, each model's constant: a mean over models would be none of them."""
    ratio = {
        ("particles", "paper"): 0.001,
        ("particles", "mixing"): 0.07,
        ("navier_stokes", "paper"): 0.01,
        ("navier_stokes", "projection"): 0.1,
    }
    rows = [
        {
            "wind": wind,
            "wind.lee_model": model if wind == "particles" else "",
            "wind.coupling": model if wind == "navier_stokes" else "",
            "scene": "two_flags_wall",
            "resolution": res,
            "dt": 0.02,
            "lee_force_ratio": value,
        }
        for (wind, model), value in ratio.items()
        for res in (20, 40)
    ]
    return pd.DataFrame(rows)


def test_the_measured_figures_keep_the_models_of_a_backend_apart():
    """One line per model (particles/mixing, navier_stokes/projection beside the paper's
    models), each at its own ratio, in the model's colour."""
    drawn = fig_force_ratio_resolution(_force_ratios())
    lines = [ln for ln in drawn.figure.axes[0].get_lines() if len(ln.get_xdata())]
    got = sorted((ln.get_color(), *ln.get_ydata()) for ln in lines)
    want = {"particles": 0.001, "particles/mixing": 0.07, "navier_stokes": 0.01}
    want["navier_stokes/projection"] = 0.1
    assert got == sorted((BACKEND_COLORS[m], v, v) for m, v in want.items())
    assert len(set(BACKEND_COLORS.values())) == len(BACKEND_COLORS)


def test_the_papers_figures_pick_the_papers_model():
    """A finer run of another model does not stand for the backend in the paper's figures."""
    settings = dict(wind="navier_stokes", scene="two_flags_wall", dt=0.02, seed=0)
    paper = RunRecord(Path("/a/windbench.nc"), "complete", settings={**settings, "resolution": 40})
    paper.config = {"wind.coupling": "paper"}
    finer = RunRecord(Path("/b/windbench.nc"), "complete", settings={**settings, "resolution": 80})
    finer.config = {"wind.coupling": "projection"}
    assert pick([finer, paper], "two_flags_wall", "navier_stokes") is paper
    assert pick([finer], "two_flags_wall", "navier_stokes") is finer


def test_model_labels_follow_the_rows_not_the_index():
    """A frame concatenated from others may repeat index values: each row keeps its label."""
    rows = _force_ratios()
    repeated = rows.set_axis([0] * len(rows))
    labels = with_backend(repeated)["backend"].tolist()
    assert labels == with_backend(rows)["backend"].tolist()
    assert labels[::2] == [
        "particles",
        "particles/mixing",
        "navier_stokes",
        "navier_stokes/projection",
    ]
