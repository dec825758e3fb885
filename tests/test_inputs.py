"""Every bad input is refused before any work: one line naming the key, exit status 2, no
dataset. The table runs in-process through the same two gates as the command line
(``checked_compose``: overrides and config files; ``run`` -> ``prepare``: values); a few
rows also go through ``python -m windbench`` to pin the exit status and the single line."""

import math
import re

import pytest
from omegaconf import OmegaConf

from windbench.cli import checked_compose, compose_config, composition_error, preflight, shorthand
from windbench.config import allowed, check_values, schema_fields
from windbench.errors import ConfigError
from windbench.simulate import run

BAD_SCENE = "defaults:\n  - scene_schema\n  - _self_\nname: bad\ndomain: {min: [0, 0, 0]\n"

# (overrides, key named, words the message must hold)
TABLE = [
    (["+foo=1"], "foo", "unknown key"),
    (["+sim.foo=1"], "sim.foo", "unknown key"),
    (["aero.air_density=-1"], "aero.air_density", "> 0 kg m-3"),
    (["aero.lift_coefficient=-5"], "aero.lift_coefficient", "in [0, 3]"),
    (["aero.drag_coefficient=nan"], "aero.drag_coefficient", "finite"),
    (["wind=particles", "seed=-1"], "seed", "in [0, 4294967295]"),
    (["sim.duration=inf"], "sim.duration", "finite"),
    (["output.probe_points=3000"], "output.probe_points", "GiB"),
    (["output.window_blocks=1"], "output.window_blocks", ">= 2"),
    (["sim.window_flow_throughs=0"], "sim.window_flow_throughs", "> 0"),
    (["output.filename=''"], "output.filename", "plain file name"),
    (["output.filename=../../escaped.nc"], "output.filename", "inside the run folder"),
    (["output.filename=.windbench.nc"], "output.filename", "no leading '.'"),
    (["scene.cloths.0.resolution=[30000,20000]"], "scene.cloths[0].resolution", "GiB"),
    (
        ["wind=particles", "wind.particles_per_second=1e10", "wind.max_particles=1000000000"],
        "wind.max_particles",
        "live particles",
    ),
    (["wind=particles", "wind.particles_per_second=1e10"], "wind.particles_per_second", "GiB"),
    (["wind=particles", "wind.max_particles=1e9"], "wind.max_particles", "an integer"),
    (["sim.dt=abc"], "sim.dt", "must be a number, got 'abc'"),
    (["seed=1.5"], "seed", "must be an integer"),
    (["sim.progress=maybe"], "sim.progress", "true or false"),
    (["grid.cells=8"], "grid.cells", "allowed ['resolution']"),
    (["sim.dt=["], "sim.dt", "cannot parse the override"),
    (["sim.dt=1e-6"], "sim.dt", "1000000 steps, more than sim.max_steps = 100000"),
    (["grid.resolution=4000"], "grid.resolution", "GiB"),
    (["resume.code=maybe"], "resume.code", "one of ['same', 'any']"),
    (["sim.fail_at_step=0"], "sim.fail_at_step", ">= 1"),
]


def refusal(overrides: list[str], out_dir) -> ConfigError:
    """The ConfigError the command line would print for ``overrides`` (none: fail)."""
    try:
        cfg = checked_compose(shorthand(["scene=flag", *overrides]))
        run(cfg, out_dir)
    except ConfigError as err:
        return err
    pytest.fail(f"{overrides} was accepted")


@pytest.mark.parametrize("overrides, key, words", TABLE, ids=[" ".join(t[0]) for t in TABLE])
def test_bad_input_is_refused_naming_the_key_and_writes_nothing(overrides, key, words, tmp_path):
    err = refusal(overrides, tmp_path / "run")
    assert err.key == key
    line = f"windbench: error: {err}"
    assert line.startswith(f"windbench: error: {key}: ") and "\n" not in line
    assert words in err.message
    assert not list(tmp_path.rglob("*")), "nothing is written for a refused run"


def test_a_malformed_scene_file_is_one_line_with_file_and_line(tmp_path):
    (tmp_path / "extra" / "scene").mkdir(parents=True)
    (tmp_path / "extra" / "scene" / "bad.yaml").write_text(BAD_SCENE)
    search = f"hydra.searchpath=[file://{tmp_path / 'extra'}]"
    err = refusal([search, "scene=bad"], tmp_path / "run")
    assert err.key == str(tmp_path / "extra" / "scene" / "bad.yaml")
    assert err.message.startswith("line 6, column 1: not valid YAML: expected ',' or '}'")


def test_every_bound_of_the_schema_is_enforced():
    """Each setting with a range refuses the value just outside it and says the range."""
    base = compose_config(["scene=flag"])
    checked = 0
    for key, f in schema_fields():
        meta = f.metadata
        if meta["choices"]:
            bad = "none_of_them"
        elif meta["gt"] is not None:
            bad = meta["gt"]  # the open bound itself
        elif meta["ge"] is not None:
            bad = meta["ge"] - 1
        else:
            continue
        if "int" in f.type and not isinstance(bad, str):
            bad = int(bad)
        cfg = base.copy()
        OmegaConf.update(cfg, key, bad)
        with pytest.raises(ConfigError, match=rf"^{key}: must be {re.escape(allowed(meta))}, got"):
            check_values(cfg)
        checked += 1
    assert checked >= 10


def test_non_finite_numbers_are_refused_anywhere_in_the_config():
    cfg = compose_config(["scene=flag"])
    OmegaConf.update(cfg, "scene.cloths.0.size", [1.5, math.inf])
    with pytest.raises(ConfigError, match=r"^scene\.cloths\[0\]\.size\[1\]: must be a finite"):
        check_values(cfg)


def test_memory_estimate_names_the_largest_share(monkeypatch, tmp_path):
    """On a machine of 1 GiB, the 60 snapshots (one per step: 100 asked) of 128 x 64 x 64
    cells, 60 x 524288 x 3 x 8 bytes kept twice (1.41 GiB), are refused."""
    monkeypatch.setattr("windbench.simulate.memory_bytes", lambda: 2**30)
    err = refusal(["output.snapshots=100", "grid.resolution=128"], tmp_path)
    assert err.key == "output.snapshots"
    assert err.message.startswith("60 wind snapshots of 524288 cells: the run would need about 1.5")
    assert "grid.resolution 0.156" in err.message  # the other shares: 524288 x 320 bytes
    assert err.message.endswith("this machine allows 0.8 GiB")


def test_preflight_returns_the_folder_with_the_time_resolved(tmp_path):
    folder, where = preflight(["scene=fence", "wind=particles"])
    assert where == "hydra.run.dir" and folder.parts[:3] == ("outputs", "fence", "particles")
    assert "${" not in str(folder)
    folder, where = preflight(["-m", "scene=fence,flag", f"hydra.sweep.dir={tmp_path}"])
    assert (folder, where) == (tmp_path, "hydra.sweep.dir")


def test_resume_true_is_short_for_resume_enabled():
    assert shorthand(["resume=true", "resume.code=any", "x=resume=1"]) == [
        "resume.enabled=true",
        "resume.code=any",
        "x=resume=1",
    ]
    cfg = checked_compose(shorthand(["resume=true"]))
    assert cfg.resume.enabled is True and cfg.resume.code == "same"


def test_an_unknown_key_in_a_backend_lists_its_keys():
    err = refusal(["wind=navier_stokes", "wind.viscosty=1"], None)
    assert err.key == "wind.viscosty" and "'viscosity'" in err.message


@pytest.mark.parametrize(
    "args, line",
    [
        (["+foo=1"], "windbench: error: foo: unknown key: +foo would add it"),
        (["seed=1.5"], "windbench: error: seed: must be an integer, got '1.5'"),
        (
            ["output.filename=../../escaped.nc"],
            "windbench: error: output.filename: must be a plain file name",
        ),
    ],
)
def test_cli_refusals_exit_2_with_one_line(cli, tmp_path, args, line):
    out = tmp_path / "deep" / "er" / "run"
    proc = cli("scene=flag", *args, f"hydra.run.dir={out}")
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(line), proc.stderr
    assert not list(tmp_path.rglob("*.nc"))


def test_help_lists_groups_keys_units_and_the_backend(cli):
    proc = cli("--help", "wind=navier_stokes")
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert "_schema" not in text
    assert "wind        global, navier_stokes*, particles" in text
    assert "scene       empty, fence, flag*" in text
    assert "sim.dt " in text and "0.0166667 s" in text and "(> 0 s)" in text
    assert "aero.air_density" in text and "kg m-3" in text
    assert "wind.viscosity" in text and "m^2/s, air" in text
    assert "README.md" in text and "exit status" in text


def test_composition_error_without_details_is_still_one_line():
    err = composition_error(RuntimeError("first line\nsecond line"))
    assert str(err) == "config: first line"
