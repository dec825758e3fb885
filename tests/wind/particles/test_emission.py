"""Particle emission (paper §4.2.2: every wind source is a particle source): regions by
flux, exact counts over many steps, gust schedules, automatic rates, bad settings."""

from __future__ import annotations

import numpy as np
import pytest

from tests.wind.particles.test_backend import DT, advance, params, scene_of
from windbench.errors import ConfigError
from windbench.grid import Grid
from windbench.wind.particles import ParticleWind
from windbench.wind.particles.emission import GustSchedule, emitters_from_scene


def test_uniform_source_emits_on_its_inflow_faces_by_flux():
    scene = scene_of([{"type": "uniform", "velocity": [3.0, -4.0, 0.0], "emit": {"rate": 6000.0}}])
    grid = Grid.from_domain(scene.lower, scene.upper, 16)
    (e,) = emitters_from_scene(scene, grid, params(), seed=0)
    pos, instants, carry, counter = e.emit(0.0, 1.0, 0.0, 0)
    assert counter == 6000 and len(pos) == 6000
    on_x = np.isclose(pos[:, 0], 0.0)
    on_y = np.isclose(pos[:, 1], 2.0, atol=1e-6)
    assert np.all(on_x ^ on_y)
    # flux through x_min: 3 * (2 * 2); through y_max: 4 * (4 * 2)
    assert on_x.mean() == pytest.approx(12.0 / 44.0, abs=0.005)
    assert np.all((instants >= 0.0) & (instants <= 1.0))


def test_emission_counts_are_exact_over_many_steps_and_respect_gusts():
    scene = scene_of(
        [
            {
                "type": "uniform",
                "velocity": [1.0, 0, 0],
                "emit": {"rate": 123.4},
                "gusts": {"on": 0.25, "off": 0.5, "start": 0.1},
            }
        ]
    )
    grid = Grid.from_domain(scene.lower, scene.upper, 8)
    (e,) = emitters_from_scene(scene, grid, params(), seed=0)
    carry, counter, instants = 0.0, 0, []
    for n in range(180):
        _, t_e, carry, counter = e.emit(n * DT, (n + 1) * DT, carry, counter)
        instants.append(t_e)
    t_e = np.concatenate(instants)
    # 3 s: on during [0.1, 0.35), [0.85, 1.1), [1.6, 1.85), [2.35, 2.6) -> 1.0 s in all
    assert counter == int(np.floor(123.4 * 1.0 + 1e-9))
    phase = np.mod(t_e - 0.1, 0.75)
    assert np.all((t_e >= 0.1) & (phase <= 0.25 + 1e-12))


def test_gust_schedule_inverse():
    g = GustSchedule(on=0.3, off=0.7, start=0.2)
    t = np.array([0.2, 0.35, 0.5, 1.2, 1.45])
    f = np.array([g.on_time(v) for v in t])
    np.testing.assert_allclose(f, [0.0, 0.15, 0.3, 0.3, 0.55])
    np.testing.assert_allclose(g.instant(np.array([0.15, 0.45])), [0.35, 1.35])


def test_point_source_and_vortex_regions():
    scene = scene_of(
        [
            {
                "type": "source",
                "center": [2.0, 1.0, 1.0],
                "strength": 1.0,
                "emit": {"radius": 0.4, "rate": 500},
            },
            {
                "type": "vortex",
                "center": [2.0, 1.0, 1.0],
                "axis": [0, 0, 1],
                "strength": 1.0,
                "emit": {"radius": 0.5, "rate": 500},
            },
            {
                "type": "uniform",
                "velocity": [1.0, 0, 0],
                "emit": {"rate": 500, "box": {"min": [1, 1, 0.5], "max": [1, 1.5, 1.0]}},
            },
        ]
    )
    grid = Grid.from_domain(scene.lower, scene.upper, 16)
    src, vor, box = (
        e.emit(0.0, 1.0, 0.0, 0)[0] for e in emitters_from_scene(scene, grid, params(), 0)
    )
    np.testing.assert_allclose(np.linalg.norm(src - [2, 1, 1], axis=1), 0.4)
    np.testing.assert_allclose(src.mean(axis=0), [2, 1, 1], atol=0.02)  # even on the sphere
    radial = np.linalg.norm(vor[:, :2] - [2, 1], axis=1)
    assert radial.max() <= 0.5 and (vor[:, 2].min(), vor[:, 2].max()) == pytest.approx(
        (0, 2), abs=0.02
    )
    assert np.mean(radial < 0.5 / np.sqrt(2)) == pytest.approx(0.5, abs=0.03)  # uniform in area
    assert np.all(box[:, 0] == 1.0) and box[:, 1:].min() >= 0.5 and box[:, 1].max() <= 1.5


def test_auto_rate_keeps_every_inflow_cell_marked():
    """particles_per_cell new particles per memory on each inflow cell: no cell left unmarked."""
    scene = scene_of([{"type": "uniform", "velocity": [6.0, 0.0, 0.0]}])
    grid = Grid.from_domain(scene.lower, scene.upper, 32)
    wind = advance(ParticleWind(scene, grid, params()), 1.0)
    assert wind.reached()[0].all()


@pytest.mark.parametrize(
    ("source_extra", "key"),
    [
        ({"emit": {"rate": -1.0}}, "scene.sources[0].emit.rate"),
        ({"emit": {"speed": 1.0}}, "scene.sources[0].emit"),
        ({"emit": {"radius": 1.0}}, "scene.sources[0].emit.radius"),
        ({"gusts": {"on": 1.0}}, "scene.sources[0].gusts"),
        ({"gusts": {"on": 0.0, "off": 1.0}}, "scene.sources[0].gusts.on"),
        ({"emit": {"box": {"min": [1, 1, 1], "max": [0, 2, 2]}}}, "scene.sources[0].emit.box.max"),
    ],
)
def test_bad_emission_settings_name_the_key(source_extra, key):
    scene = scene_of([{"type": "uniform", "velocity": [1.0, 0, 0], **source_extra}])
    grid = Grid.from_domain(scene.lower, scene.upper, 8)
    for build in (ParticleWind.check, ParticleWind):  # check: what prepare() calls
        with pytest.raises(ConfigError) as err:
            build(scene, grid, params())
        assert err.value.key == key
