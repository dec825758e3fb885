"""Time-varying wind (windbench/wind/envelope.py) against answers known without the code:
the on/off schedule, the steady field kept bit for bit, the fluctuation the global field
and the Navier-Stokes inflow share, and a gust switching the force on a static flag in
all three backends."""

from __future__ import annotations

import numpy as np
import pytest

from windbench.cli import compose_config
from windbench.scenes import build_scene
from windbench.simulate import Simulation, prepare
from windbench.wind.envelope import SourceTimes, envelope_factor
from windbench.wind.particles.emission import GustSchedule
from windbench.wind.primitives import superpose

GUSTY = "scene.sources=[{type:uniform,velocity:[6.0,0.0,0.0],gusts:{on:1.0,off:1.0}}]"
TURBULENT = (
    "scene.sources=[{type:uniform,velocity:[6.0,0.0,0.0],"
    "turbulence:{intensity:0.2,length_scale:0.5}}]"
)


def test_envelope_is_on_during_the_schedule_and_off_before_its_start():
    schedule = GustSchedule(on=1.0, off=2.0, start=0.5)
    times = [0.4, 0.5, 1.49, 1.5, 3.49, 3.5, 4.49]
    assert [envelope_factor(schedule, t) for t in times] == [0, 1, 1, 0, 0, 1, 1]
    assert envelope_factor(GustSchedule(), 123.0) == 1.0  # no gusts: always on


def _scene(*overrides):
    return build_scene(compose_config(["scene=flag", *overrides]).scene)


def test_steady_sources_give_the_superposed_field_and_gusts_switch_it():
    points = np.random.default_rng(0).uniform(0, 3, (20, 3))
    steady = SourceTimes.build(_scene(), 0)
    assert not steady.varies
    assert np.array_equal(steady.wind(points, 7.0), superpose(_scene().sources, points))
    gusty = SourceTimes.build(_scene(GUSTY), 0)
    assert gusty.gusty
    assert np.allclose(gusty.wind(points, 0.5), [6.0, 0.0, 0.0], rtol=0, atol=1e-12)
    assert np.array_equal(gusty.wind(points, 1.5), np.zeros((20, 3)))


def _simulation(wind, *overrides):
    cfg = compose_config(
        [
            "scene=flag",
            f"wind={wind}",
            "grid.resolution=16",
            "sim.spinup=0",
            "sim.duration=4.0",
            "sim.progress=false",
            *overrides,
        ]
    )
    return Simulation(prepare(cfg))


def test_global_field_and_navier_stokes_inflow_carry_the_same_fluctuation():
    """Same scene, same seed: the global wind at points of the inflow face equals what the
    Navier-Stokes backend lets in there, at every time."""
    glob = _simulation("global", TURBULENT).wind
    ns = _simulation("navier_stokes", TURBULENT).wind
    points = np.column_stack([np.zeros(5), np.linspace(0.2, 2.8, 5), np.linspace(0.3, 2.7, 5)])
    for dt in (0.1, 0.35):
        glob.step(dt, None)
        ns.time += dt
        along = glob.sample(points)
        assert np.allclose(along, ns._inflow(points, 0), rtol=1e-12, atol=1e-12)
        assert np.abs(along - [6.0, 0.0, 0.0]).max() > 0.1  # it does fluctuate


@pytest.mark.parametrize("wind", ["global", "navier_stokes", "particles"])
def test_a_gust_envelope_switches_the_force_on_a_static_flag(wind):
    """On for 1 s, off for 1 s: near the end of the second off second the static flag feels
    under a tenth of the force it feels near the end of the second on second."""
    sim = _simulation(wind, GUSTY, "cloth.solver=static")
    for n in range(240):
        sim.step(n)
    force = np.linalg.norm(np.asarray(sim.recorder.rows["aero_force"])[:, 0], axis=-1)
    t = (np.arange(force.size) + 1) / 60.0
    on = force[(t > 2.7) & (t < 3.0)].mean()
    off = force[(t > 3.7) & (t < 4.0)].mean()
    assert on > 1.0  # N
    assert off < 0.1 * on
