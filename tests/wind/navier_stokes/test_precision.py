"""``wind.precision=float32``: the velocity and the solver's vectors in single precision, the
answers of the validation problems as in double precision (their errors are discretisation
errors, orders of magnitude above float32's rounding), every scheme and closure running."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.validation_ns.problems import free_stream, poiseuille, taylor_green
from windbench.cli import compose_config
from windbench.errors import ConfigError
from windbench.simulate import prepare
from windbench.wind import make_wind
from windbench.wind.base import Obstacles

pytestmark = pytest.mark.heavy  # compiles the float32 kernels


@pytest.mark.slow  # a study (four Taylor-Green runs); the fence tests below cover float32
def test_float32_keeps_the_taylor_green_and_poiseuille_errors():
    """The validation errors change by less than 1 % relative (32 cells here; the study's
    64 cells: experiments/results/bench_ns_precision.csv)."""
    for scheme in ("semi_lagrangian", "maccormack"):
        double, _ = taylor_green(32, scheme, dt=0.02)
        single, _ = taylor_green(32, scheme, dt=0.02, precision="float32")
        for key in ("rate_rel_error", "linf_rel_error"):
            assert single[key] == pytest.approx(double[key], rel=0.01), (scheme, key)
    double, _ = poiseuille(16)
    single, (_, got, exact) = poiseuille(16, precision="float32")
    assert single["linf_rel_error"] == pytest.approx(double["linf_rel_error"], rel=0.01)
    assert single["linf_rel_error"] <= 0.01


def test_float32_free_stream_stays_uniform_to_its_rounding():
    row = free_stream(12, "semi_lagrangian", steps=10, precision="float32")
    assert row["max_rel_deviation"] <= 10 * np.finfo(np.float32).eps


@pytest.mark.parametrize(
    "overrides",
    [
        # slow: compiles the second-order scheme in both precisions (16 CPU s on an empty
        # cache)
        pytest.param(
            ["wind.advection=second_order", "wind.turbulence=mixing_length"],
            marks=pytest.mark.slow,
        ),
        ["wind.advection=semi_lagrangian", "wind.turbulence=smagorinsky"],
    ],
    ids=["second_order", "smagorinsky"],
)
def test_float32_fence_steps_like_float64(overrides):
    """The fence at 24 cells, 10 steps: the state is float32, the velocity handed out is
    float64, divergence-free to float32's rounding, within 1e-4 of U of the float64 run."""
    winds = {}
    for precision in ("float64", "float32"):
        cfg = compose_config(
            ["scene=fence", "wind=navier_stokes", "grid.resolution=24", *overrides,
             f"wind.precision={precision}"]
        )  # fmt: skip
        setup = prepare(cfg)
        wind = make_wind(cfg.wind, setup.scene, setup.grid)
        for _ in range(10):
            wind.step(setup.dt, Obstacles.rigid_only(setup.scene.bodies))
        winds[precision] = wind
    single, double = winds["float32"], winds["float64"]
    assert all(q.dtype == np.float32 for q in single.q)
    assert single.velocity().dtype == np.float64
    assert single.stats()["mac_divergence_max"] < 1e-5
    speed = setup.scene.reference_speed
    assert np.abs(single.velocity() - double.velocity()).max() < 1e-4 * speed


def test_float32_tolerances_stop_at_what_float32_can_hold():
    cfg = compose_config(
        ["experiment=scaling", "wind=navier_stokes", "grid.resolution=16",
         "wind.precision=float32", "wind.pressure_tol=1e-9", "wind.diffusion_tol=1e-12"]
    )  # fmt: skip
    setup = prepare(cfg)
    wind = make_wind(cfg.wind, setup.scene, setup.grid)
    assert wind.tol == 1e-6 and wind.diffusion_tol == 1e-12


def test_an_unknown_precision_is_refused():
    cfg = compose_config(["experiment=scaling", "wind=navier_stokes", "wind.precision=half"])
    with pytest.raises(ConfigError, match=r"wind\.precision: must be one of"):
        prepare(cfg)
