"""experiment=paper: its sweep covers the paper's scenes and backends, and every run of it
that this tree can compose passes the run checks (no ConfigError mid-sweep)."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from windbench.cli import CONFIG_DIR, compose_config
from windbench.simulate import prepare

PAPER_SCENES = {"flag", "two_flags_wall", "shirt", "opposing_sources", "fence"}
BACKENDS = {"global", "particles", "navier_stokes"}


def _sweep() -> dict[str, list[str]]:
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = compose(
            config_name="config", overrides=["experiment=paper"], return_hydra_config=True
        )
    assert cfg.experiment == "paper"
    return {k: str(v).split(",") for k, v in cfg.hydra.sweeper.params.items()}


def test_paper_sweep_covers_every_backend_and_paper_scene():
    params = _sweep()
    assert set(params["wind"]) == BACKENDS
    assert set(params["scene"]) == PAPER_SCENES
    assert len(params["grid.resolution"]) >= 3  # cost exponent and convergence need sizes
    assert len(params["sim.dt"]) >= 2  # lee_force_ratio against time step


def test_every_composable_paper_run_passes_the_run_checks():
    params = _sweep()
    conf = Path(CONFIG_DIR)
    scenes = [s for s in params["scene"] if (conf / "scene" / f"{s}.yaml").is_file()]
    winds = [w for w in params["wind"] if (conf / "wind" / f"{w}.yaml").is_file()]
    if not scenes or not winds:
        pytest.skip("no scene or backend of the paper sweep in this tree")
    dt = min(params["sim.dt"], key=float)  # the time step does not change what is checked
    for scene, wind, res in itertools.product(scenes, winds, params["grid.resolution"]):
        cfg = compose_config(
            [
                "experiment=paper",
                f"scene={scene}",
                f"wind={wind}",
                f"grid.resolution={res}",
                f"sim.dt={dt}",
            ]
        )
        prepare(cfg)  # raises ConfigError naming the key if the sweep holds a bad run
