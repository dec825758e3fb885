"""End to end: every scene runs with the global backend and writes the documented dataset."""

import numpy as np
import pytest

from windbench.cli import compose_config
from windbench.errors import ConfigError
from windbench.scenes import build_scene
from windbench.simulate import prepare
from windbench.wind.primitives import superpose

SCENES = ["flag", "two_flags_wall", "opposing_sources", "fence", "empty"]
EXPECTED = {
    "wind",
    "cloth_position",
    "aero_force",
    "divergence_rms",
    "divergence_max",
    "lee_speed_ratio",
    "step_seconds",
    "probe_wind",
    "probe_points",
}


@pytest.mark.parametrize("scene", SCENES)
def test_each_scene_writes_a_readable_dataset(run_config, scene):
    resolution = {"fence": 48, "two_flags_wall": 24}.get(scene, 16)  # walls 1 m thick
    result, ds = run_config(
        [
            f"scene={scene}",
            f"grid.resolution={resolution}",
            "sim.duration=0.05",
            "output.snapshots=2",
        ]
    )
    assert result.status == "complete"
    assert EXPECTED <= set(ds.data_vars)
    assert ds.attrs["status"] == "complete" and ds.attrs["scene"] == scene
    assert ds.attrs["wind"] == "global" and ds.attrs["resolution"] == resolution
    assert "grid:" in ds.attrs["config"] and ds.attrs["windbench_version"]
    assert ds.attrs["numba_threads"] >= 1 and ds.attrs["cpu_count"] >= 1
    assert ds.sizes["time"] == 3 and ds.sizes["snapshot"] == 2
    assert ds["wind"].attrs["units"] == "m s-1" and ds["aero_force"].attrs["long_name"]
    assert list(ds.phase.values[:4]) == ["wind", "aero", "cloth", "total"]


def test_global_backend_has_no_lee_behind_the_fence(run_config):
    _, ds = run_config(["scene=fence", "grid.resolution=48", "sim.duration=0.05"])
    # the superposed field ignores the fence: the lee box holds the source's own wind
    scene = build_scene(compose_config(["scene=fence"]).scene)
    lee = ds.probe_box == "lee"
    points = ds.probe_points.sel(probe_point=lee).values
    wind = ds.probe_wind.isel(snapshot=-1).sel(probe_point=lee).values
    np.testing.assert_allclose(wind, superpose(scene.sources, points), rtol=1e-12)
    assert ds.divergence_max.max() < 1e-12  # u(z) along x is divergence-free


def test_flag_in_the_global_wind_is_pushed_downwind(run_config):
    _, ds = run_config(["scene=flag", "grid.resolution=16", "sim.duration=0.05"])
    force = ds.aero_force.isel(time=-1, cloth=0).values
    assert force[0] > 0  # the wind blows along +x


@pytest.mark.parametrize(
    "override, message",
    [
        ("sim.dt=0", "sim.dt: must be > 0"),
        ("sim.dt=-0.1", "sim.dt: must be > 0"),
        ("sim.duration=0.001", "sim.duration: must be at least sim.dt"),
        ("grid.resolution=3", "grid.resolution: must be at least 4"),
        ("grid.resolution=4", "grid.resolution: .* cannot resolve scene.bodies"),
        ("scene.probes.lee.max=[9,3,3]", "scene.probes.lee: box .* leaves the domain"),
        ("scene.cloths.0.origin=[5.9,1.5,1.5]", r"scene.cloths\[0\]: cloth 'flag' spans"),
        ("scene.boundary.x_min=open", "scene.boundary.x_min: must be one of"),
        ("scene.boundary.y_min=periodic", "periodic comes in pairs"),
        ("output.snapshots=0", "output.snapshots: must be >= 1"),
        ("cloth.solver=rigid", "cloth.solver: unknown solver 'rigid'; allowed"),
    ],
)
def test_bad_input_is_one_clear_error_before_any_work(override, message):
    scene = "fence" if "resolution=4" in override else "flag"
    cfg = compose_config([f"scene={scene}", override])
    with pytest.raises(ConfigError, match=message):
        prepare(cfg)


def test_cli_bad_input_exits_2_with_one_line_and_writes_no_dataset(cli, tmp_path):
    proc = cli("scene=flag", "sim.dt=-1", f"hydra.run.dir={tmp_path / 'out'}")
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines == ["windbench: error: sim.dt: must be > 0 s, got -1.0"]
    assert not list(tmp_path.rglob("*.nc"))


def test_cli_unknown_scene_and_key_list_the_choices(cli):
    proc = cli("scene=moon")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert proc.stderr.startswith("windbench: error: scene: no config 'moon'; allowed [")
    assert "'fence'" in proc.stderr and "scene_schema" not in proc.stderr
    proc = cli("grid.cells=8")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert proc.stderr.startswith("windbench: error: grid.cells: Key 'cells' not in 'GridConfig'")


def test_smoke_experiment_runs_from_the_command_line(cli, tmp_path):
    proc = cli("experiment=smoke", f"hydra.run.dir={tmp_path / 'smoke'}")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "smoke" / "windbench.nc").exists()
