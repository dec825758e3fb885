"""Adding a wind backend is one module plus one config file: a backend written here,
outside windbench, registers itself through the entry-point group of an installed
package and runs through the command line; a config whose schema is not registered is
refused in one line naming the file."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from windbench.errors import ConfigError
from windbench.wind import backend_class, backends
from windbench.wind.registry import ENTRY_POINT_GROUP, register_backend

MODULE = '''
from dataclasses import dataclass, field

import numpy as np

from windbench.wind.base import WindField
from windbench.wind.registry import WindConfig, register_backend


@dataclass
class SteadyConfig(WindConfig):
    name: str = "steady_test"
    velocity: list[float] = field(default_factory=lambda: [1.0, 2.0, 3.0])  # m/s


@register_backend("steady_test", config=SteadyConfig)
class SteadyWind(WindField):
    """The same wind everywhere, from the config."""

    def __init__(self, scene, grid, params):
        super().__init__(scene, grid, params)
        self._field = np.broadcast_to(np.asarray(params.velocity, float), (*grid.shape, 3))

    def step(self, dt, obstacles):
        pass

    def velocity(self):
        return self._field
'''


@pytest.fixture
def plugin(tmp_path):
    """A package installed on PYTHONPATH (module + dist-info) and its config directory."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "steady_backend.py").write_text(MODULE)
    info = site / "steady_backend-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: steady-backend\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nsteady_test = steady_backend\n")
    conf = tmp_path / "conf" / "wind"
    conf.mkdir(parents=True)
    (conf / "steady_test.yaml").write_text(
        "defaults:\n  - steady_test_schema\n  - _self_\nname: steady_test\nvelocity: [4.0, 0.5, -1.0]\n"
    )
    return site, tmp_path / "conf"


def test_a_backend_from_an_installed_package_runs_through_the_cli(cli, tmp_path, plugin):
    site, conf = plugin
    out = tmp_path / "run"
    proc = cli(
        "wind=steady_test",
        "scene=empty",
        "grid.resolution=8",
        "sim.duration=0.05",
        f"hydra.searchpath=[file://{conf}]",
        f"hydra.run.dir={out}",
        pythonpath=site,
    )
    assert proc.returncode == 0, proc.stderr
    with xr.open_dataset(out / "windbench.nc") as ds:
        assert ds.attrs["wind"] == "steady_test"
        wind = ds.wind.isel(snapshot=-1).values
    np.testing.assert_array_equal(wind, np.broadcast_to([4.0, 0.5, -1.0], wind.shape))


def test_a_config_without_a_registered_schema_is_one_line_naming_the_file(cli, tmp_path):
    conf = tmp_path / "conf" / "wind"
    conf.mkdir(parents=True)
    (conf / "nobody.yaml").write_text("defaults:\n  - nobody_schema\n  - _self_\nname: nobody\n")
    proc = cli("wind=nobody", f"hydra.searchpath=[file://{tmp_path / 'conf'}]")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "wind/nobody.yaml" in lines[0] and "register_backend('nobody'" in lines[0]


def test_a_wrong_key_in_a_backend_config_names_the_key_and_the_file(cli, tmp_path):
    conf = tmp_path / "conf" / "wind"
    conf.mkdir(parents=True)
    (conf / "ns_typo.yaml").write_text(
        "defaults:\n  - navier_stokes_schema\n  - _self_\nname: navier_stokes\nviscosty: 1.0\n"
    )
    proc = cli("wind=ns_typo", f"hydra.searchpath=[file://{tmp_path / 'conf'}]")
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "windbench: error: wind.viscosty: Key 'viscosty' not in 'NavierStokesConfig' "
        "(in wind/ns_typo.yaml)"
    )


def test_the_built_in_backends_register_themselves():
    assert {"global", "particles", "navier_stokes"} <= set(backends())
    assert backend_class("navier_stokes").name == "navier_stokes"
    with pytest.raises(ConfigError, match="unknown backend 'nope'"):
        backend_class("nope")


def test_a_schema_must_be_a_wind_config():
    with pytest.raises(TypeError, match="WindConfig"):
        register_backend("bad", config=dict)
