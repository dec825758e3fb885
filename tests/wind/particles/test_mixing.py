"""The ``mixing`` lee (windbench/wind/particles/mixing.py) against answers known without the
code: a point release spreads with variance 2 K t and drifts with the wind; an undisturbed
log-law wind comes out as itself (a uniform density stays uniform in K(z), the well-mixed
condition, and the cell estimate is unbiased); the volume flux through every plane behind
a wall equals the inflow's (the paper's lee loses the blocked part, the near wake's cavity
and eddy keep it); a surface keeps the speed of the wind it turns; the shadow behind a
fence is shallow near it and fills in downstream; bad settings name their key."""

from __future__ import annotations

import numpy as np
import pytest

from tests.wind.particles.test_backend import FACES, advance, params, scene_of
from windbench.cli import compose_config
from windbench.errors import ConfigError
from windbench.geometry.bodies import body_table
from windbench.grid import Grid
from windbench.metrics import plane_flux_ratio
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.particles import ParticleWind
from windbench.wind.particles.mixing import (
    LEAVE,
    MIRROR,
    _bounce,
    diffusivity_table,
    escape_direction,
    unit_triple,
)
from windbench.wind.primitives import superpose
from windbench.wind.surface_layer import sources_viscosity

pytestmark = pytest.mark.heavy  # compiles the mixing lee's tracer

MIXING = "wind.lee_model=mixing"
LOG_WIND = {
    "type": "uniform",
    "velocity": [6.0, 0.0, 0.0],
    "profile": {"type": "log", "roughness": 0.1, "reference_height": 4.0},
}


def mixing_wind(scene, resolution, *overrides):
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    return ParticleWind(scene, grid, params(MIXING, *overrides)), grid


def walled_scene(sources, bodies=(), domain=((0, 0, 0), (8, 2, 4)), boundary=None):
    """A channel: the wind in through x_min, out through x_max, walls elsewhere."""
    faces = dict.fromkeys(FACES, "slip") | {"x_min": "inflow", "x_max": "outflow"}
    return build_scene(
        {
            "name": "t",
            "domain": {"min": list(domain[0]), "max": list(domain[1])},
            "boundary": faces | (boundary or {}),
            "sources": list(sources),
            "bodies": list(bodies),
        }
    )


def mean_wind(wind, seconds, dt, obstacles=None):
    """Time mean of the cell wind over the next ``seconds``."""
    obstacles = obstacles or Obstacles.rigid_only(wind.scene.bodies)
    total = np.zeros((*wind.grid.shape, 3))
    steps = int(round(seconds / dt))
    for _ in range(steps):
        wind.step(dt, obstacles)
        total += wind.velocity()
    return total / steps


# ---------------------------------------------------------------- the random walk


def test_random_numbers_are_uniform_independent_and_reproducible():
    u = np.array([unit_triple(7, 3, q) for q in range(40000)])
    assert u.min() > 0.0 and u.max() < 1.0
    np.testing.assert_allclose(u.mean(axis=0), 0.5, atol=0.005)
    np.testing.assert_allclose(u.var(axis=0), 1.0 / 12.0, rtol=0.02)
    assert np.abs(np.corrcoef(u.T)[np.triu_indices(3, 1)]).max() < 0.02
    assert np.abs(np.corrcoef(u[:-1, 0], u[1:, 0])[0, 1]) < 0.02  # neighbours in q
    assert unit_triple(7, 3, 5) == unit_triple(7, 3, 5) != unit_triple(8, 3, 5)


def test_a_point_release_spreads_with_variance_2_k_t_and_drifts_with_the_wind():
    """Inflow turbulence of intensity I and length L gives K = I |U| L everywhere (no shear):
    after t every axis has variance 2 K t (any increments of zero mean and variance 2 K dt
    add up to it), the mean moves by U t."""
    U, intensity, length = 2.0, 0.1, 0.5
    k = intensity * U * length
    source = {
        "type": "uniform",
        "velocity": [U, 0.0, 0.0],
        "turbulence": {"intensity": intensity, "length_scale": length},
        "emit": {"rate": 0.0},  # only the released particles
    }
    scene = scene_of([source], domain=((0, 0, 0), (8, 6, 6)))
    wind, _ = mixing_wind(scene, 16)
    start = np.array([2.0, 3.0, 3.0])
    wind.add_particles(np.tile(start, (20000, 1)), np.zeros(20000, dtype=np.int64))
    dt, steps = 0.02, 50
    advance(wind, dt * steps)  # the shared helper steps by its own DT
    t = wind.time
    pos = wind.particles[0]
    assert len(pos) == 20000  # nobody reached a wall
    np.testing.assert_allclose(pos.mean(axis=0), start + [U * t, 0.0, 0.0], atol=0.02)
    np.testing.assert_allclose(pos.var(axis=0), 2 * k * t, rtol=0.05)


def test_the_diffusivity_is_the_navier_stokes_surface_layer_k_of_the_profile():
    scene = walled_scene([LOG_WIND])
    grid = Grid.from_domain(scene.lower, scene.upper, 32)
    table, z_first, dz = diffusivity_table(scene, grid, 40.0)
    heights = z_first + dz * np.arange(len(table))
    shared = sources_viscosity(scene.sources, heights, grid.lower, grid.upper, 40.0, 1e-3 * dz)
    sheared = shared > 0
    np.testing.assert_array_equal(table[sheared], shared[sheared])
    assert sheared[-1] and not sheared[0]  # no shear below the roughness height ...
    assert np.all(table[~sheared] == table[sheared][0])  # ... so K is held there


def test_a_log_law_wind_without_obstacles_comes_out_as_itself():
    """Flux-weighted emission makes the particle density uniform, the drift dK/dz keeps it
    so, and the cells' running mean of dwell time x wind over that density is w(z)."""
    scene = walled_scene([LOG_WIND])
    wind, grid = mixing_wind(scene, 24, "wind.averaging_time=0.5")
    advance(wind, 4.0)  # two flow-throughs of the slowest air above z = 0.5 m
    u = mean_wind(wind, 3.0, 1.0 / 30.0)
    expected = superpose(scene.sources, grid.cell_centres().reshape(-1, 3))
    expected = expected.reshape(*grid.shape, 3)
    x, _, z = grid.axes()
    inner = (x > 1.0) & (x < 7.0)
    layers = u[inner].mean(axis=(0, 1))
    truth = expected[inner].mean(axis=(0, 1))
    above = z > 0.5  # the layer next to the ground holds the slow air below z0
    np.testing.assert_allclose(layers[above, 0], truth[above, 0], rtol=0.05)
    np.testing.assert_allclose(layers[:, 1:], 0.0, atol=0.05 * 6.0)


# ---------------------------------------------------------------- bodies


def test_a_surface_keeps_the_speed_of_the_wind_it_turns():
    n = (-1.0, 0.0, 0.0)
    a, r = _bounce((3.0, 4.0, 0.0), (1.0, 0.5, 0.2), n, (0.0, 0.0, 0.0))
    np.testing.assert_allclose(a, (0.0, 5.0, 0.0))  # |a| = 5 kept, along the face
    np.testing.assert_allclose(r, (-1.0, 0.5, 0.2))  # the random part mirrored
    a, _ = _bounce((6.0, 0.0, 0.0), (0.0, 0.0, 0.0), n, (0.0, 0.0, 1.0))
    np.testing.assert_allclose(a, (0.0, 0.0, 6.0))  # head-on: along the escape direction


def test_head_on_air_leaves_a_box_face_toward_its_nearest_free_edge():
    fence = walled_scene([LOG_WIND], [{"type": "box", "min": [3, 0, 0], "max": [4, 2, 1.5]}])
    table = body_table(fence.bodies)
    lo, hi = np.asarray(fence.lower, float), np.asarray(fence.upper, float)
    n = (-1.0, 0.0, 0.0)
    walls = np.full((3, 2), MIRROR, dtype=np.int64)  # every face a wall: edges on them closed
    # spanning the channel on the ground: only the top edge is free
    assert escape_direction(table, 0, (3.0, 1.0, 0.2), n, lo, hi, walls) == (0.0, 0.0, 1.0)
    wall = walled_scene([LOG_WIND], [{"type": "box", "min": [3, 1, 0], "max": [4, 2, 3]}])
    table = body_table(wall.bodies)
    # half the width, against the y_max wall: the free side edge or the top, the nearer
    assert escape_direction(table, 0, (3.0, 1.2, 1.0), n, lo, hi, walls) == (0.0, -1.0, 0.0)
    assert escape_direction(table, 0, (3.0, 1.8, 2.7), n, lo, hi, walls) == (0.0, 0.0, 1.0)
    assert escape_direction(table, -1, (3.0, 1.8, 2.7), n, lo, hi, walls) == (0.0, 0.0, 0.0)


def test_a_wall_across_the_domain_sends_head_on_air_to_the_outflow_face():
    full = {"type": "box", "min": [3, 0, 0], "max": [4, 2, 4]}  # the whole cross-section
    scene = walled_scene([LOG_WIND], [full])
    table = body_table(scene.bodies)
    lo, hi = np.asarray(scene.lower, float), np.asarray(scene.upper, float)
    walls = np.full((3, 2), MIRROR, dtype=np.int64)
    head_on = (table, 0, (3.0, 1.0, 1.0), (-1.0, 0.0, 0.0), lo, hi)
    assert escape_direction(*head_on, walls) == (0.0, 0.0, 0.0)  # closed on every side
    top_open = walls.copy()
    top_open[2, 1] = LEAVE  # an outflow face over the wall: its top edge is open
    assert escape_direction(*head_on, top_open) == (0.0, 0.0, 1.0)


def _wall_flux(lee_model: str) -> tuple[np.ndarray, np.ndarray]:
    wall = {"type": "box", "min": [2.0, 0.0, 0.0], "max": [2.5, 2.0, 1.5]}
    scene = walled_scene([LOG_WIND], [wall])
    grid = Grid.from_domain(scene.lower, scene.upper, 32)
    wind = ParticleWind(scene, grid, params(f"wind.lee_model={lee_model}"))
    advance(wind, 8.0)  # the air at 0.2 m (1.1 m/s) has crossed the channel
    u = mean_wind(wind, 2.0, 1.0 / 30.0)
    undisturbed = superpose(scene.sources, grid.cell_centres().reshape(-1, 3))
    ratio = plane_flux_ratio(u, undisturbed.reshape(u.shape), wind.solid_mask())
    x = grid.axes()[0]
    return ratio[(x > 2.6) & (x < 7.5)], ratio[(x > 0.3) & (x < 1.5)]


def test_the_volume_flux_through_every_plane_behind_a_wall_is_the_inflows():
    """Particles are conserved and carry the air's flux, so every plane behind a wall
    across the channel (up to 1.5 m of 4) passes the inflow's volume; the paper's lee
    drops what the wall blocked."""
    behind, ahead = _wall_flux("mixing")
    np.testing.assert_allclose(behind, 1.0, atol=0.06)
    np.testing.assert_allclose(ahead, 1.0, atol=0.06)
    paper_behind, _ = _wall_flux("paper")
    assert paper_behind.max() < 0.9


def test_the_fence_shadow_is_shallow_near_the_fence_and_fills_in_downstream(run_config):
    """The mixing lee's acceptance check: ``windbench wind=particles wind.lee_model=mixing
    scene=fence grid.resolution=64`` keeps >= 90 % of the flux through every plane behind
    the fence; at half the fence height u/u0 is <= 0.5 at 2 H and >= 0.4 at 10 H (steady
    window)."""
    overrides = ["wind=particles", MIXING, "scene=fence", "grid.resolution=64"]
    _, ds = run_config([*overrides, "sim.spinup=auto", "output.snapshots=8"])
    assert ds.attrs["status"] == "complete"
    scene = build_scene(compose_config(["scene=fence"]).scene)
    grid = Grid.from_domain(scene.lower, scene.upper, 64)
    u = ds["wind"].mean("snapshot").values
    undisturbed = superpose(scene.sources, grid.cell_centres().reshape(-1, 3))
    solid = np.linalg.norm(ds["wind"].values, axis=-1).max(axis=0) == 0.0
    ratio = plane_flux_ratio(u, undisturbed.reshape(u.shape), solid)
    behind = grid.axes()[0] > scene.bodies[0].params[3]
    assert ratio[behind].min() >= 0.9
    window = ds["time"] >= ds.attrs["analysis_start"] - 1e-9
    wake = ds["wake_speed_ratio"].sel(time=window).mean("time").sel(wake_height=0.5)
    assert float(wake.sel(wake_distance=2.0)) <= 0.5
    assert float(wake.sel(wake_distance=10.0)) >= 0.4


# ---------------------------------------------------------------- reproducibility, input


def test_same_seed_same_field_other_seed_other_field():
    scene = build_scene(compose_config(["scene=fence"]).scene)
    grid = Grid.from_domain(scene.lower, scene.upper, 16)
    runs = [advance(ParticleWind(scene, grid, params(MIXING, f"seed={s}")), 0.5) for s in (3, 3, 4)]
    np.testing.assert_array_equal(runs[0].velocity(), runs[1].velocity())
    np.testing.assert_array_equal(runs[0].particles[0], runs[1].particles[0])
    assert not np.array_equal(runs[0].velocity(), runs[2].velocity())


@pytest.mark.parametrize(
    "override",
    [
        "wind.lee_model=eddies",
        "wind.averaging_time=0",
        "wind.mixing_length_limit=-1",
        "wind.recirculation_backflow=1.5",
        "wind.wake_mixing=-0.1",
        "wind.recirculation_exponent=0.5",
        "wind.recirculation_height=0",
    ],
)
def test_bad_mixing_settings_name_the_key(override):
    scene = walled_scene([LOG_WIND])
    grid = Grid.from_domain(scene.lower, scene.upper, 8)
    for build in (ParticleWind.check, ParticleWind):
        with pytest.raises(ConfigError) as err:
            build(scene, grid, params(MIXING, override))
        assert err.value.key == override.split("=")[0]


def test_a_mixing_lee_needs_winds_entering_through_the_faces():
    vortex = {"type": "vortex", "center": [2.0, 1.0, 1.0], "strength": 1.0}
    scene = walled_scene([LOG_WIND, vortex])
    grid = Grid.from_domain(scene.lower, scene.upper, 8)
    with pytest.raises(ConfigError, match=r"sources\[1\] is a vortex") as err:
        ParticleWind.check(scene, grid, params(MIXING))
    assert err.value.key == "wind.lee_model"
    ParticleWind.check(scene, grid, params())  # the paper's lee takes any source
