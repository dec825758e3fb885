"""Every config group option composes against the schema; experiments carry their sweeps."""

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from windbench.cli import compose_config
from windbench.simulate import prepare

CONF = Path(__file__).resolve().parent.parent / "conf"


def options(group):
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


@pytest.mark.parametrize("scene", options("scene"))
def test_every_scene_composes_and_passes_validation(scene):
    cfg = compose_config([f"scene={scene}", "grid.resolution=32"])
    assert cfg.scene.name == scene
    setup = prepare(cfg)
    assert {"lee", "free_stream"} <= set(setup.probe_points)


@pytest.mark.parametrize("wind", options("wind"))
def test_every_wind_backend_composes(wind):
    cfg = compose_config([f"wind={wind}"])
    assert cfg.wind.name == wind


@pytest.mark.parametrize("experiment", options("experiment"))
def test_every_experiment_composes_with_a_sweep(experiment):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(version_base="1.3", config_dir=str(CONF)):
        cfg = compose(
            config_name="config", overrides=[f"experiment={experiment}"], return_hydra_config=True
        )
    assert cfg.experiment == experiment
    assert OmegaConf.select(cfg, "hydra.sweeper.params"), "an experiment sets its sweep"


@pytest.mark.parametrize("launcher", ["joblib", "basic", "submitit_local"])
def test_the_smoke_sweep_takes_any_launcher(launcher):
    """experiment=smoke picks joblib (one job per core) and sets none of its keys, so that
    another launcher on the command line composes."""
    cfg = compose_config(["experiment=smoke", f"hydra/launcher={launcher}"], hydra_node=True)
    assert launcher.split("_")[0] in cfg.hydra.launcher._target_.lower()
