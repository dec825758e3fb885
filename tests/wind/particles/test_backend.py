"""Backend ``particles`` (paper §4.2.2) on whole scenes: per-source wind on each side of a
wall, the lee of a fence, closed bodies never entered, a cloth's shadow, agreement with
the ``global`` backend where no object interferes, gusts and memory, determinism; and
the emission model (regions, counts, gust schedule, bad input)."""

from __future__ import annotations

import numpy as np
import pytest

from windbench.cli import compose_config
from windbench.cloth.mesh import rectangle_triangles
from windbench.errors import ConfigError
from windbench.geometry.bodies import distances
from windbench.grid import Grid
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.global_field import GlobalWind
from windbench.wind.particles import ParticleWind
from windbench.wind.primitives import superpose

DT = 1.0 / 60.0
FACES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")


def params(*overrides):
    return compose_config(["wind=particles", *overrides]).wind


def scene_of(sources, bodies=(), domain=((0, 0, 0), (4, 2, 2))):
    return build_scene(
        {
            "name": "t",
            "domain": {"min": list(domain[0]), "max": list(domain[1])},
            "boundary": dict.fromkeys(FACES, "slip"),
            "sources": list(sources),
            "bodies": list(bodies),
        }
    )


def assert_all(field, vector, **tol):
    """Every vector of ``field`` (..., 3) equals ``vector``."""
    field = np.asarray(field)
    assert field.size > 0
    np.testing.assert_allclose(field, np.broadcast_to(vector, field.shape), **tol)


def advance(wind, seconds, obstacles=None, each=None):
    obstacles = obstacles or Obstacles.rigid_only(wind.scene.bodies)
    for _ in range(int(round(seconds / DT))):
        wind.step(DT, obstacles)
        if each:
            each(wind)
    return wind


# ---------------------------------------------------------------- the paper's scenes


def test_opposing_sources_each_side_has_its_own_source(run_config):
    """§4.2.2's thought experiment: superposed tagging gives 0, per-source particles do not."""
    _, ds = run_config(
        ["scene=opposing_sources", "wind=particles", "grid.resolution=32", "sim.duration=1.2"]
    )
    u = ds["wind"].isel(snapshot=-1).values
    x = ds["x"].values
    left, right = x < 3.45, x > 4.55  # one cell clear of the wall [3.7, 4.3]
    assert_all(u[left], [4.0, 0.0, 0.0])  # blows away from x_min's source
    assert_all(u[right], [-4.0, 0.0, 0.0])  # away from x_max's source
    scene = build_scene(compose_config(["scene=opposing_sources"]).scene)
    centres = Grid.from_domain(scene.lower, scene.upper, 32).cell_centres()
    np.testing.assert_allclose(superpose(scene.sources, centres[left]), 0.0, atol=1e-12)
    np.testing.assert_allclose(superpose(scene.sources, centres[right]), 0.0, atol=1e-12)


def test_fence_lee_and_free_stream(run_config):
    _, ds = run_config(["scene=fence", "wind=particles", "grid.resolution=48", "sim.duration=1.5"])
    assert ds.attrs["status"] == "complete"
    assert float(ds["lee_speed_ratio"].isel(time=-1)) < 0.05
    free = ds["probe_wind"].isel(snapshot=-1).sel(probe_point=ds.probe_box == "free_stream")
    points = ds["probe_points"].sel(probe_point=ds.probe_box == "free_stream").values
    scene = build_scene(compose_config(["scene=fence"]).scene)
    # reached cells hold the source's own wind there (the log profile, sampled trilinearly)
    np.testing.assert_allclose(free.values, superpose(scene.sources, points), rtol=0.02)
    assert {"live_particles", "particle_steps_per_second", "cell_crossings"} <= set(ds)
    assert "trace" in ds["phase"].values


BODIES = [
    {"type": "box", "min": [1.6, 0.55, 0.45], "max": [2.45, 1.4, 1.35]},
    {"type": "capsule", "a": [3.0, 0.5, 0.7], "b": [3.0, 1.5, 1.3], "radius": 0.3},
    {"type": "cylinder", "a": [0.8, 1.0, 0.3], "b": [1.1, 1.0, 1.7], "radius": 0.25},
]


@pytest.mark.parametrize("body", BODIES, ids=lambda b: b["type"])
def test_closed_body_is_never_entered(body):
    """Oblique wind and a vortex around the body: particles hit and slide, never get in."""
    scene = scene_of(
        [
            {"type": "uniform", "velocity": [5.0, 1.0, -0.7]},
            {"type": "vortex", "center": [2.0, 1.0, 1.0], "axis": [0.2, 0.1, 1.0], "strength": 4.0},
        ],
        [body],
    )
    grid = Grid.from_domain(scene.lower, scene.upper, 32)
    wind = ParticleWind(scene, grid, params())
    lo = np.asarray(grid.lower)
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    idx = np.indices(grid.shape).reshape(3, -1).T
    d_corners = np.stack(
        [distances(scene.bodies, lo + grid.h * (idx + c))[0] for c in corners], axis=1
    )
    deep = (d_corners < 0).all(axis=1).reshape(grid.shape)  # cells wholly inside (convex)
    touching = ((d_corners < 0).any(axis=1) & ~(d_corners < 0).all(axis=1)).reshape(grid.shape)
    assert deep.sum() >= 8

    def outside(w):
        pos = w.particles[0]
        assert (distances(scene.bodies, pos)[0] >= 0.0).all()

    advance(wind, 1.0, each=outside)
    assert not wind.ever_reached()[deep].any()
    assert wind.ever_reached()[touching].mean() > 0.5  # the flow did come up to the surface


def test_static_cloth_sheet_shadows_the_cells_behind_it():
    scene = scene_of([{"type": "uniform", "velocity": [6.0, 0.0, 0.0]}])
    grid = Grid.from_domain(scene.lower, scene.upper, 32)  # h = 0.125
    nu = nv = 13
    s = np.linspace(0.4, 1.6, nu)
    yy, zz = np.meshgrid(s, s, indexing="ij")
    verts = np.stack([np.full(nu * nv, 2.03), yy.ravel(), zz.ravel()], axis=1)
    cloth = Obstacles((), verts, np.zeros_like(verts), rectangle_triangles(nu, nv))
    wind = advance(ParticleWind(scene, grid, params()), 1.0, cloth)
    u = wind.velocity()
    x, y, z = grid.axes()
    shade = (y > 0.5)[:, None] & (y < 1.5)[:, None] & ((z > 0.5) & (z < 1.5))[None, :]
    behind = u[x > 2.2][:, shade]
    assert np.all(behind == 0.0)
    assert not wind.reached()[0][x > 2.2][:, shade].any()
    assert_all(u[x < 1.9][:, shade], [6.0, 0.0, 0.0])  # in front
    beside = ((y < 0.3)[:, None] | (y > 1.7)[:, None]) & np.ones_like(z, bool)[None, :]
    assert_all(u[x > 2.2][:, beside], [6.0, 0.0, 0.0])


def test_without_obstacles_the_field_is_the_global_one_where_particles_arrived():
    dense = {"emit": {"rate": 20000.0}}
    scene = scene_of(
        [
            {"type": "uniform", "velocity": [3.0, 0.5, 0.0]},
            {
                "type": "vortex",
                "center": [2.0, 1.0, 0],
                "strength": 8.0,
                "core_radius": 0.2,
                **dense,
            },
            {
                "type": "source",
                "center": [1.0, 1.0, 1.0],
                "strength": 10.0,
                "core_radius": 0.2,
                **dense,
            },
        ]
    )
    grid = Grid.from_domain(scene.lower, scene.upper, 16)
    wind = advance(ParticleWind(scene, grid, params("wind.memory=0.5")), 1.5)
    all_sources = wind.reached().all(axis=0)
    assert all_sources.mean() > 0.5
    expected = GlobalWind(scene, grid, compose_config(["wind=global"]).wind).velocity()
    np.testing.assert_allclose(
        wind.velocity()[all_sources], expected[all_sources], rtol=1e-12, atol=1e-12
    )
    # elsewhere: the sum over the sources that did arrive, zero where none did
    none = ~wind.reached().any(axis=0)
    assert np.all(wind.velocity()[none] == 0.0)


def test_field_kept_at_the_marks_equals_the_field_rebuilt_from_them():
    """u is refreshed only where marks are made or lapse; at every step it must equal
    sum_s [s reached the cell within memory] w_s(centre), rebuilt over the whole grid.
    Two gusty sources make cells where one, both or neither count; 64 x 32 x 32 cells
    take the prefetching path of the tracing kernel."""
    scene = scene_of(
        [
            {
                "type": "uniform",
                "velocity": [6.0, 1.0, 0.0],
                "gusts": {"on": 0.1, "off": 0.1},
                "emit": {"rate": 3000.0},
            },
            {
                "type": "vortex",
                "center": [2.0, 1.0, 0.0],
                "strength": 4.0,
                "core_radius": 0.2,
                "gusts": {"on": 0.15, "off": 0.05, "start": 0.05},
                "emit": {"rate": 3000.0},
            },
        ]
    )
    grid = Grid.from_domain(scene.lower, scene.upper, 64)
    assert grid.n_cells >= 1 << 16
    centres = grid.cell_centres().reshape(-1, 3)
    w = [src(centres).reshape(*grid.shape, 3) for src in scene.sources]
    seen = {"partial": 0, "lapsed": 0}

    def check(wind):
        reached = wind.reached()
        rebuilt = sum(np.where(r[..., None], ws, 0.0) for r, ws in zip(reached, w, strict=True))
        np.testing.assert_allclose(wind.velocity(), rebuilt, rtol=0, atol=1e-12)
        seen["partial"] += int((reached.any(axis=0) & ~reached.all(axis=0)).sum() > 0)
        seen["lapsed"] += int((wind.ever_reached() & ~reached.any(axis=0)).sum() > 0)

    advance(ParticleWind(scene, grid, params("wind.memory=0.05")), 0.4, each=check)
    assert seen["partial"] > 5 and seen["lapsed"] > 5


def test_a_gust_passes_and_memory_forgets_it():
    """On for 0.3 s: the windy band runs downstream at U; cells are calm memory after it."""
    U, memory = 6.0, 0.1
    scene = scene_of(
        [{"type": "uniform", "velocity": [U, 0.0, 0.0], "gusts": {"on": 0.3, "off": 100.0}}]
    )
    grid = Grid.from_domain(scene.lower, scene.upper, 32)
    wind = advance(ParticleWind(scene, grid, params(f"wind.memory={memory}")), 0.5)
    t = wind.time
    windy = np.linalg.norm(wind.velocity(), axis=-1).mean(axis=(1, 2)) > 0
    x = grid.axes()[0]
    # a cell at x is reached during [x/U, 0.3 + x/U] (+ one cell and one step of slack)
    tail = U * (t - 0.3 - memory)
    head = U * t
    assert not windy[x < tail - grid.h - U * DT].any()
    assert windy[(x > tail + grid.h + U * DT) & (x < head - grid.h - U * DT)].all()
    assert not windy[x > head + grid.h].any()


def test_same_seed_same_field_other_seed_other_particles():
    scene = build_scene(compose_config(["scene=fence"]).scene)
    grid = Grid.from_domain(scene.lower, scene.upper, 16)
    runs = [advance(ParticleWind(scene, grid, params(f"seed={s}")), 0.5) for s in (7, 7, 8)]
    np.testing.assert_array_equal(runs[0].velocity(), runs[1].velocity())
    np.testing.assert_array_equal(runs[0].particles[0], runs[1].particles[0])
    assert not np.array_equal(runs[0].particles[0], runs[2].particles[0])


# ---------------------------------------------------------------- emission


@pytest.mark.parametrize(
    "override",
    [
        "wind.memory=0",
        "wind.max_particles=0",
        "wind.max_age=-1",
        "wind.max_hits=0",
        "wind.deflected_cells=some",
    ],
)
def test_bad_wind_settings_name_the_key(override):
    scene = scene_of([{"type": "uniform", "velocity": [1.0, 0, 0]}])
    grid = Grid.from_domain(scene.lower, scene.upper, 8)
    for build in (ParticleWind.check, ParticleWind):  # check: what prepare() can call
        with pytest.raises(ConfigError) as err:
            build(scene, grid, params(override))
        assert err.value.key == override.split("=")[0]


def test_particle_count_stays_bounded():
    scene = scene_of(
        [
            {
                "type": "vortex",
                "center": [2.0, 1.0, 1.0],
                "axis": [0, 0, 1],
                "strength": 1.0,
                "emit": {"rate": 20000},
            }
        ]
    )
    grid = Grid.from_domain(scene.lower, scene.upper, 16)
    counts = []
    advance(
        ParticleWind(scene, grid, params("wind.max_particles=3000", "wind.max_age=0.2")),
        0.6,
        each=lambda w: counts.append(w.stats()["live_particles"]),
    )
    assert max(counts) <= 3000
    assert counts[-1] == pytest.approx(counts[-2], rel=0.1)  # steady: emission = deaths by age


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("wind.memory=0", "wind.memory"),
        ("scene.sources.0.velocity=[0.0,0.0,0.0]", "scene.sources[0].velocity"),
    ],
)
def test_a_run_with_bad_settings_stops_before_any_output(run_config, override, key, tmp_path):
    with pytest.raises(ConfigError) as err:
        run_config(["scene=fence", "wind=particles", override])
    assert err.value.key == key
    assert not any(tmp_path.rglob("*.nc"))


def _deep_cells(bodies, grid, time):
    """Cells whose eight corners all lie inside the (convex) bodies posed at ``time``."""
    lo = np.asarray(grid.lower)
    idx = np.indices(grid.shape).reshape(3, -1).T
    corners = [[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    d = np.stack([distances(bodies, lo + grid.h * (idx + c), time)[0] for c in corners], axis=1)
    return (d < 0).all(axis=1).reshape(grid.shape)


def test_particles_meet_a_placed_body_where_its_pose_puts_it():
    """A box moved 1.2 m downwind and turned 30 degrees (a held keyframe pose): no particle
    enters the posed box and the cells inside it stay unreached, while the flow fills the
    cells of its rest place."""
    place = {"type": "keyframes", "times": [0.0], "positions": [[1.2, 0, 0]], "rotations": [30.0]}
    box = {"type": "box", "min": [0.5, 0.55, 0.45], "max": [1.35, 1.4, 1.35], "motion": place}
    scene = scene_of([{"type": "uniform", "velocity": [5.0, 0.3, 0.0]}], [box])
    grid = Grid.from_domain(scene.lower, scene.upper, 32)
    wind = ParticleWind(scene, grid, params())

    def outside(w):
        assert (distances(scene.bodies, w.particles[0], 1.0)[0] >= 0.0).all()

    advance(wind, 1.0, each=outside)
    posed = _deep_cells(scene.bodies, grid, 1.0)
    rest = _deep_cells([scene_of([], [{**box, "motion": None}]).bodies[0]], grid, 0.0)
    assert posed.sum() >= 8 and (rest & ~posed).sum() >= 8
    assert not wind.ever_reached()[posed].any()
    assert wind.ever_reached()[rest & ~posed].all()


def test_a_turning_body_moves_its_solid_cells_and_its_lee():
    """A box turning about a vertical axis: the solid cells follow its current pose, u = 0
    deep inside it, and the particles it sweeps over are pushed out, not left inside."""
    spin = {"type": "rotation", "axis": [0, 0, 1], "point": [2, 1, 1], "angular_speed": 1.5}
    box = {"type": "box", "min": [1.2, 0.8, 0.4], "max": [2.8, 1.2, 1.6], "motion": spin}
    scene = scene_of([{"type": "uniform", "velocity": [5.0, 0.0, 0.0]}], [box])
    grid = Grid.from_domain(scene.lower, scene.upper, 32)
    wind = advance(ParticleWind(scene, grid, params()), 0.5)
    t = wind.time
    assert t == pytest.approx(0.5)
    deep = _deep_cells(scene.bodies, grid, t)
    np.testing.assert_array_equal(
        wind.solid_mask(),
        distances(scene.bodies, grid.cell_centres().reshape(-1, 3), t)[0].reshape(grid.shape) < 0,
    )
    assert deep.sum() >= 8 and not _deep_cells(scene.bodies, grid, 0.0)[deep].all()
    assert_all(wind.velocity()[deep], [0.0, 0.0, 0.0])
    assert (distances(scene.bodies, wind.particles[0], t)[0] >= 0.0).all()  # none swept in
