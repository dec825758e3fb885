"""Spin-up, steady windows and the fence wake through the run loop: the spin-up only
stops recording (the same numbers as the end of a longer run), the window starts after
two flow-through times, a run without a window is unsettled, and the wake probe measures
u/u0 (exactly 1 in the global wind, which has no lee)."""

from __future__ import annotations

import numpy as np
import pytest

from windbench.cli import compose_config
from windbench.config import ConfigError
from windbench.metrics import unsettled_reason
from windbench.simulate import FLOW_THROUGHS, MIN_WINDOW, prepare

EMPTY = ["scene=empty", "grid.resolution=8", "sim.dt=0.05"]  # 4 m at 6 m/s: T = 2/3 s


def test_the_spin_up_only_stops_recording(run_config):
    """Steps 9-16 of a run that spins up for 8 steps are steps 9-16 of one that records
    all 16: the same wind, bit for bit."""
    common = [
        "wind=navier_stokes",
        *EMPTY,
        "scene.bodies=[{type: box, min: [1,0,0], max: [1.5,2,1]}]",
    ]
    _, long = run_config([*common, "sim.duration=0.8"], name="long")
    _, spun = run_config([*common, "sim.spinup=0.4", "sim.duration=0.4"], name="spun")
    np.testing.assert_allclose(spun.time.values, long.time.values[8:], rtol=1e-12)
    np.testing.assert_array_equal(spun.wind.isel(snapshot=-1), long.wind.isel(snapshot=-1))
    np.testing.assert_array_equal(spun.divergence_rms.values, long.divergence_rms.values[8:])


def test_auto_spin_up_is_two_flow_through_times():
    setup = prepare(compose_config([*EMPTY, "sim.spinup=auto"]))
    assert setup.flow_through_time == pytest.approx(4.0 / 6.0)
    assert setup.start_time == pytest.approx(FLOW_THROUGHS * 4.0 / 6.0, abs=0.05)
    assert setup.analysis_start == pytest.approx(setup.start_time)
    short = prepare(compose_config([*EMPTY, "sim.spinup=0", "sim.duration=2"]))
    assert short.analysis_start == pytest.approx(FLOW_THROUGHS * 4.0 / 6.0)


def test_auto_duration_records_one_flow_through_time_at_least_the_minimum():
    """two_flags_wall: L = 24 m at U = 6 m/s, T = 4 s (2.5 T with sim.window_flow_throughs
    = 2.5); the empty 4 m box: T = 2/3 s, so the shortest window MIN_WINDOW applies."""
    keys = ["scene=two_flags_wall", "sim.dt=0.05", "sim.duration=auto"]
    wall = prepare(compose_config(keys))
    assert wall.n_steps * wall.dt == pytest.approx(4.0)
    longer = prepare(compose_config([*keys, "sim.window_flow_throughs=2.5"]))
    assert longer.n_steps * longer.dt == pytest.approx(10.0)
    empty = prepare(compose_config([*EMPTY, "sim.duration=auto"]))
    assert empty.n_steps * empty.dt == pytest.approx(max(MIN_WINDOW, 4.0 / 6.0))


@pytest.mark.parametrize("key", ["duration", "spinup"])
@pytest.mark.parametrize("value", ["soon", "-1"])
def test_a_bad_window_length_is_refused_naming_the_key(key, value):
    with pytest.raises(ConfigError, match=rf"sim\.{key}: must be 'auto' or a number"):
        prepare(compose_config([*EMPTY, f"sim.{key}={value}"]))


def test_a_run_without_a_window_is_unsettled_with_the_reason():
    times = np.arange(1, 21) * 0.05  # 1 s recorded
    assert unsettled_reason(times, 0.5) == "" and unsettled_reason(times, 1.0) == ""
    reason = unsettled_reason(times, 1.3)
    assert "no steady window" in reason and "1.3" in reason


def test_the_global_wind_has_no_lee_behind_the_fence(run_config):
    _, ds = run_config(
        ["scene=fence", "grid.resolution=48", "sim.dt=0.5", "sim.spinup=auto", "sim.duration=5"],
        name="fence",
    )
    assert ds.wake_speed_ratio.dims == ("time", "wake_distance", "wake_height")
    np.testing.assert_allclose(ds.wake_speed_ratio.values, 1.0, rtol=1e-12)
    np.testing.assert_allclose(ds.wake_distance.values, [2, 5, 10, 15])
    # the window mean of the probes equals the (steady) global wind itself
    np.testing.assert_allclose(ds.probe_wind_mean.values, ds.probe_wind.isel(snapshot=-1).values)


def test_the_navier_stokes_fence_wake_recovers(run_config):
    """The default Navier-Stokes wind on the fence scene at 64 cells: the domain reaches
    15 H behind the fence, and the time-mean u/u0 at 10 H, 0.5 H high is at least 0.5
    (dense-windbreak measurements: about 0.45-0.65)."""
    _, ds = run_config(
        ["wind=navier_stokes", "scene=fence", "grid.resolution=64", "sim.spinup=auto"],
        name="ns_fence",
    )
    window = ds.time >= ds.attrs["analysis_start"]
    wake = ds.wake_speed_ratio.where(window).mean("time")
    assert float(ds.wake_distance.max()) >= 15
    assert float(wake.sel(wake_distance=10, wake_height=0.5)) >= 0.5
    assert float(wake.sel(wake_distance=2, wake_height=0.5)) < 0.5  # a lee behind the fence


def test_the_dataset_keeps_the_probe_wind_of_each_block_of_the_steady_window(run_config):
    """output.window_blocks=4 over the window of 14 steps (t = 1.35..2.0 s): four block
    means of the probe wind; the global wind is steady, so each equals the window mean."""
    _, ds = run_config([*EMPTY, "sim.duration=2", "output.window_blocks=4"])
    blocks = ds["probe_wind_block_mean"]
    assert blocks.dims == ("window_block", "probe_point", "component")
    assert blocks.sizes["window_block"] == 4 and blocks.attrs["units"] == "m s-1"
    for block in blocks.values:
        np.testing.assert_allclose(block, ds["probe_wind_mean"].values, rtol=1e-12)
