"""The paper comparison's sweeps (conf/experiment/paper.yaml lists them): together they
cover the paper's scenes, every backend, three resolutions spanning 4x, two time steps,
three particle seeds, the particles' mixing lee beside the paper's and, per scene, a
second-order reference at least twice as fine as the finest compared run with two coarser
levels; every run they hold passes the run checks (no ConfigError mid-sweep)."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from windbench.cli import CONFIG_DIR, compose_config
from windbench.simulate import prepare
from windbench.wind import make_wind

pytestmark = pytest.mark.heavy  # runs a run of each paper sweep

PAPER_SCENES = {"flag", "two_flags_wall", "shirt", "opposing_sources"}
BACKENDS = {"global", "particles", "navier_stokes"}
CONF = Path(CONFIG_DIR)


def _sweep(experiment: str, *overrides: str) -> dict[str, list[str]]:
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = compose(
            config_name="config",
            overrides=[f"experiment={experiment}", *overrides],
            return_hydra_config=True,
        )
    params = {k: str(v).split(",") for k, v in cfg.hydra.sweeper.params.items()}
    params.setdefault("scene", [str(cfg.scene.name)])
    params.setdefault("wind", [str(cfg.wind.name)])
    for key in ("grid.resolution", "sim.dt", "seed"):
        params.setdefault(key, [str(OmegaConf.select(cfg, key))])
    params["wind.advection"] = [str(cfg.wind.advection)] if "advection" in cfg.wind else []
    params["wind.lee_model"] = [str(cfg.wind.lee_model)] if "lee_model" in cfg.wind else []
    return params


def _resolutions(params) -> list[int]:
    return sorted(int(r) for r in params["grid.resolution"])


def test_the_sweeps_cover_backends_scenes_resolutions_seeds_and_references():
    paper, seeds, fence = _sweep("paper"), _sweep("paper_seeds"), _sweep("fence")
    assert set(paper["wind"]) == BACKENDS == set(fence["wind"])
    assert set(paper["scene"]) == PAPER_SCENES == set(seeds["scene"])
    compared = _resolutions(paper)
    assert len(compared) >= 3 and compared[-1] >= 4 * compared[0]  # spanning 4x
    assert len(paper["sim.dt"]) >= 2  # lee_force_ratio against time step
    assert seeds["wind"] == ["particles"] and len({*paper["seed"], *seeds["seed"]}) == 3
    reference = _sweep("reference")
    assert reference["wind.advection"] == ["second_order"]
    assert set(reference["scene"]) == PAPER_SCENES
    levels = _resolutions(reference)
    assert len(levels) == 3 and levels[-1] >= 2 * compared[-1]
    assert _fence_reference_levels()[-1] >= 2 * _resolutions(fence)[-1]


def _fence_reference_levels() -> list[int]:
    """The fence reference's resolutions, from the command in paper.yaml's header."""
    text = (CONF / "experiment" / "paper.yaml").read_text()
    (levels,) = re.findall(r"scene=fence grid\.resolution=([\d,]+)", text)
    return sorted(int(r) for r in levels.split(","))


def test_every_fence_level_resolves_the_same_fence():
    """The compared fence runs and the fence reference resolve the same fence: at each
    level the solid cells (those whose centre lies in the fence) fill exactly the fence's
    box, 2 m tall and 1 m thick, because cell faces lie on its faces (at 128 cells along the
    47 m it would be 1.84 m tall, at 256 2.02 m)."""
    for res in sorted({*_resolutions(_sweep("fence")), *_fence_reference_levels()}):
        cfg = compose_config(["scene=fence", "wind=global", f"grid.resolution={res}"])
        setup = prepare(cfg)
        (fence,) = cfg.scene.bodies
        grid = setup.grid
        solid = make_wind(cfg.wind, setup.scene, grid).solid_mask()
        cells = np.argwhere(solid)
        filled = [
            grid.lower + cells.min(axis=0) * grid.h,
            grid.lower + (cells.max(axis=0) + 1) * grid.h,
        ]
        assert np.allclose(filled, [fence.min, fence.max], atol=1e-9), res
        assert len(cells) == round(np.prod(np.subtract(fence.max, fence.min)) / grid.h**3), res


@pytest.mark.parametrize("experiment", ["paper", "paper_seeds", "paper_mixing", "reference"])
def test_the_compared_cloths_and_their_references_keep_out_of_each_other(experiment):
    """Every run of the comparison with cloth, and every reference, has self-collision on:
    its cloth figures (self_intersections) and the flow around the cloth come from cloth
    that does not pass through itself or another cloth."""
    assert compose_config([f"experiment={experiment}"]).cloth.self_collision is True


def test_the_mixing_lee_is_swept_where_the_papers_lee_is():
    """paper_mixing and fence_mixing run the particles' mixing lee on the scenes, at the
    resolutions and with the seeds that the paper's lee has in paper, paper_seeds, fence."""
    paper, seeds, fence = _sweep("paper"), _sweep("paper_seeds"), _sweep("fence")
    for mixing, lee in ((_sweep("paper_mixing"), paper), (_sweep("fence_mixing"), fence)):
        assert mixing["wind"] == ["particles"] and mixing["wind.lee_model"] == ["mixing"]
        assert set(mixing["scene"]) == set(lee["scene"])
        assert _resolutions(mixing) == _resolutions(lee)
    assert set(_sweep("paper_mixing")["seed"]) == {*paper["seed"], *seeds["seed"]}
    assert set(_sweep("paper_mixing")["sim.dt"]) == set(seeds["sim.dt"])


def test_the_couplings_are_swept_where_the_papers_coupling_is():
    """paper_coupling runs the Navier-Stokes wind's other cloth couplings on the scene with
    a sheltered flag, at every resolution and time step that paper runs its coupling at."""
    paper, coupling = _sweep("paper"), _sweep("paper_coupling")
    assert coupling["wind"] == ["navier_stokes"] and coupling["scene"] == ["two_flags_wall"]
    assert set(coupling["wind.coupling"]) == {"projection", "none"}
    assert "navier_stokes" in paper["wind"] and "two_flags_wall" in paper["scene"]
    assert _resolutions(coupling) == _resolutions(paper)
    assert set(coupling["sim.dt"]) == set(paper["sim.dt"])
    assert compose_config(["experiment=paper"]).wind.get("coupling") is None  # global's
    assert compose_config(["experiment=paper", "wind=navier_stokes"]).wind.coupling == "paper"


@pytest.mark.parametrize(
    "experiment", ["paper", "fence", "reference", "paper_mixing", "fence_mixing", "paper_coupling"]
)
def test_every_run_of_the_sweeps_passes_the_run_checks(experiment):
    params = _sweep(experiment)
    dt = min(params["sim.dt"], key=float)  # the time step does not change what is checked
    for scene, wind, res in itertools.product(
        params["scene"], params["wind"], params["grid.resolution"]
    ):
        overrides = [f"experiment={experiment}", f"scene={scene}", f"grid.resolution={res}"]
        prepare(compose_config([*overrides, f"wind={wind}", f"sim.dt={dt}"]))
