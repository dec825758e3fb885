"""Kernels of the particle-tracing backend (paper §4.2.2) against answers known without
the code: analytic ray/sphere and ray/box intersections, exact cell lists of segments,
the explicit Euler step, and the slide along a plane after w <- w - (n . w) n."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from windbench.cli import compose_config
from windbench.geometry.bodies import BOX, CAPSULE, CYLINDER, PLANE
from windbench.geometry.raster import occupied_cells, triangle_cells
from windbench.grid import Grid
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.particles import ParticleWind
from windbench.wind.particles.tracing import (
    TRIANGLES,
    CellGrid,
    Particles,
    convex_first_hit,
    sort_by_cell,
)


@pytest.fixture(scope="module")
def particle_params():
    return compose_config(["wind=particles"]).wind


def hit(kind, prm, a, b):
    n = np.zeros(3)
    a, b = np.asarray(a, float), np.asarray(b, float)
    e = b - a
    s = convex_first_hit(kind, np.asarray(prm, float), tuple(a), tuple(e), np.empty((2, 3)), n)
    return s, n


SPHERE = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]  # capsule with a == b: the unit ball


def test_box_face_hit_at_the_analytic_fraction():
    box = [1.0, 0.0, 0.0, 2.0, 1.0, 1.0, 0.0]
    s, n = hit(BOX, box, [0.0, 0.5, 0.5], [2.0, 0.5, 0.5])
    assert s == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_allclose(n, [-1.0, 0.0, 0.0])


def test_sphere_entry_point_and_normal():
    a, b = np.array([-3.0, 0.5, 0.0]), np.array([3.0, 0.5, 0.0])
    s, n = hit(CAPSULE, SPHERE, a, b)
    x = -np.sqrt(1 - 0.25)
    assert s == pytest.approx((x + 3.0) / 6.0, abs=1e-12)
    np.testing.assert_allclose(n, [x, 0.5, 0.0], atol=1e-9)


def test_thin_pole_hit_when_both_ends_are_outside():
    """The convex dip case: a 5 cm pole between the two ends of a 2 m piece."""
    pole = [0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.05]
    s, n = hit(CYLINDER, pole, [-1.0, 0.02, 0.5], [1.0, 0.02, 0.5])
    x = -np.sqrt(0.05**2 - 0.02**2)
    assert s == pytest.approx((x + 1.0) / 2.0, abs=1e-12)
    np.testing.assert_allclose(n, np.array([x, 0.02, 0.0]) / 0.05, atol=1e-9)
    assert hit(CYLINDER, pole, [-1.0, 0.06, 0.5], [1.0, 0.06, 0.5])[0] == -1.0


def test_contact_rules_on_a_plane():
    floor = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert hit(PLANE, floor, [0.0, 0.0, 1e-7], [1.0, 0.0, 1e-7])[0] == -1.0  # sliding
    assert hit(PLANE, floor, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0])[0] == -1.0  # leaving
    assert hit(PLANE, floor, [0.0, 0.0, 0.0], [1.0, 0.0, -1.0])[0] == 0.0  # pushing in


coord = st.floats(-3.0, 3.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(st.tuples(coord, coord, coord), st.tuples(coord, coord, coord))
def test_first_hit_matches_the_analytic_ray_sphere_root(a, b):
    a, b = np.array(a), np.array(b)
    if np.linalg.norm(a) <= 1.0 + 1e-6:
        return  # the particle never starts inside
    e = b - a
    # |a + s e|^2 = 1: s^2 e.e + 2 s a.e + a.a - 1 = 0, smallest root in [0, 1]
    qa, qb, qc = e @ e, 2 * a @ e, a @ a - 1.0
    disc = qb * qb - 4 * qa * qc
    expected = -1.0
    if qa > 0 and disc > 1e-9:
        r = (-qb - np.sqrt(disc)) / (2 * qa)
        if 0.0 <= r <= 1.0:
            expected = r
    s, _ = hit(CAPSULE, SPHERE, a, b)
    if expected < 0:
        assert s == -1.0 or np.linalg.norm(a + s * e) == pytest.approx(1.0, abs=1e-9)
    else:
        assert s == pytest.approx(expected, abs=1e-9)


@settings(max_examples=300, deadline=None)
@given(st.tuples(coord, coord, coord), st.tuples(coord, coord, coord))
def test_first_hit_matches_the_slab_test_for_a_box(a, b):
    lo, hi = np.array([-1.0, -0.5, -0.25]), np.array([1.0, 0.5, 0.25])
    a, b = np.array(a), np.array(b)
    if np.all((a >= lo) & (a <= hi)):
        return
    e = b - a
    t0, t1 = 0.0, 1.0  # Kay-Kajiya slabs
    for k in range(3):
        if e[k] == 0:
            if not lo[k] <= a[k] <= hi[k]:
                t0, t1 = 1.0, 0.0
            continue
        with np.errstate(over="ignore"):  # a subnormal e[k]: the slab's t is +-inf, as it should be
            u, v = sorted(((lo[k] - a[k]) / e[k], (hi[k] - a[k]) / e[k]))
        t0, t1 = max(t0, u), min(t1, v)
    s, _ = hit(BOX, [*lo, *hi, 0.0], a, b)
    if t0 <= t1 and (t1 - t0) * np.linalg.norm(e) > 1e-9:
        assert s == pytest.approx(t0, abs=1e-9)
    elif t0 > t1 + 1e-9:
        assert s == -1.0


def _scene(sources, bodies=(), domain=((0, 0, 0), (4, 1, 1))):
    spec = {
        "name": "t",
        "domain": {"min": list(domain[0]), "max": list(domain[1])},
        "boundary": dict.fromkeys(("x_min", "x_max", "y_min", "y_max", "z_min", "z_max"), "slip"),
        "sources": [dict(s, emit={"rate": 0.0}) for s in sources],
        "bodies": list(bodies),
    }
    return build_scene(spec)


def _wind(scene, resolution, params):
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    return ParticleWind(scene, grid, params), grid


def _cells_crossed(a, b, grid):
    """Cells whose box the segment a-b passes through for a positive length (slab test)."""
    lo_idx = np.floor((np.minimum(a, b) - grid.lower) / grid.h).astype(int)
    hi_idx = np.floor((np.maximum(a, b) - grid.lower) / grid.h).astype(int)
    out = set()
    e = b - a
    for i in range(lo_idx[0], hi_idx[0] + 1):
        for j in range(lo_idx[1], hi_idx[1] + 1):
            for k in range(lo_idx[2], hi_idx[2] + 1):
                lo = np.asarray(grid.lower) + grid.h * np.array([i, j, k])
                hi = lo + grid.h
                t0, t1 = 0.0, 1.0
                for ax in range(3):
                    u, v = sorted(((lo[ax] - a[ax]) / e[ax], (hi[ax] - a[ax]) / e[ax]))
                    t0, t1 = max(t0, u), min(t1, v)
                if t1 - t0 > 1e-9:
                    out.add((i, j, k))
    return out


def test_euler_step_and_every_crossed_cell_marked(particle_params):
    """p_{t+dt} = p_t + w_i(p_t) dt, and the marked cells are exactly those the path cuts."""
    rng = np.random.default_rng(3)
    vortex = {
        "type": "vortex",
        "center": [2.0, 2.0, 0.0],
        "axis": [0.3, 0.2, 1.0],
        "strength": 30.0,
    }
    scene = _scene([vortex], domain=((0, 0, 0), (4, 4, 4)))
    checked = 0
    while checked < 6:
        wind, grid = _wind(scene, 16, particle_params)
        p0 = rng.uniform(0.5, 3.5, size=3)
        dt = 0.3
        p1 = p0 + scene.sources[0](p0[None])[0] * dt
        if not grid.contains(p1[None])[0]:
            continue
        wind.add_particles(p0[None], [0])
        wind.step(dt, Obstacles.rigid_only(()))
        np.testing.assert_allclose(wind.particles[0][0], p1, atol=1e-12)
        marked = set(map(tuple, np.argwhere(wind.reached()[0])))
        assert marked == _cells_crossed(p0, p1, grid)
        assert len(marked) >= 3
        checked += 1


@pytest.mark.parametrize(("mode", "deflected"), [("bodies", True), ("all", True), ("none", False)])
def test_slide_along_a_plane_after_the_hit(mode, deflected):
    """Wind (1, 0, -1) onto the floor z = 0.3: hit at t = 0.4 s, then slide at (1, 0, 0) for 0.5 s."""
    scene = _scene(
        [{"type": "uniform", "velocity": [1.0, 0.0, -1.0]}],
        [{"type": "plane", "point": [0.0, 0.0, 0.3], "normal": [0.0, 0.0, 1.0]}],
    )
    params = compose_config(["wind=particles", f"wind.deflected_cells={mode}"]).wind
    wind, grid = _wind(scene, 16, params)
    wind.add_particles([[0.5, 0.5, 0.7]], [0])
    wind.step(0.9, Obstacles.rigid_only(scene.bodies))
    pos = wind.particles[0][0]
    np.testing.assert_allclose(pos, [1.4, 0.5, 0.3], atol=1e-5 * grid.h)
    assert pos[2] > 0.3  # rests outside the surface
    u = wind.velocity()
    rest = grid.cell_index(pos)[0]
    # u . n = 0 where the particle slid, unless marks stay free
    np.testing.assert_allclose(u[tuple(rest)], [1.0, 0.0, 0.0 if deflected else -1.0], atol=1e-12)
    start = grid.cell_index([[0.5, 0.5, 0.7]])[0]
    np.testing.assert_allclose(u[tuple(start)], [1.0, 0.0, -1.0])  # free before the hit


def test_head_on_hit_ends_the_particle_and_leaves_zero(particle_params):
    scene = _scene(
        [{"type": "uniform", "velocity": [2.0, 0.0, 0.0]}],
        [{"type": "box", "min": [2.0, 0.0, 0.0], "max": [3.0, 1.0, 1.0]}],
    )
    wind, grid = _wind(scene, 16, particle_params)
    wind.add_particles([[1.1, 0.4, 0.4]], [0])
    wind.step(1.0, Obstacles.rigid_only(scene.bodies))
    assert len(wind.particles[0]) == 0
    u = wind.velocity()
    i_wall = grid.cell_index([[1.99, 0.4, 0.4]])[0]
    np.testing.assert_array_equal(u[tuple(i_wall)], 0.0)
    np.testing.assert_array_equal(u[tuple(grid.cell_index([[1.2, 0.4, 0.4]])[0])], [2.0, 0, 0])
    assert not wind.ever_reached()[grid.cell_index([[2.1, 0.4, 0.4]])[0][0] :].any()


@pytest.mark.parametrize(("mode", "deflected"), [("bodies", False), ("all", True)])
def test_cloth_triangle_deflects_and_shadows(mode, deflected):
    """A tilted triangle: the particle slides in its plane and never reaches behind it."""
    scene = _scene([{"type": "uniform", "velocity": [1.0, 0.0, 0.0]}])
    params = compose_config(["wind=particles", f"wind.deflected_cells={mode}"]).wind
    wind, grid = _wind(scene, 16, params)
    # plane x + z = 2.5 (normal (1, 0, 1)/sqrt 2), a big triangle across the particle's path
    tri = np.array([[2.5, -1.0, 0.0], [2.5, 3.0, 0.0], [1.5, 1.0, 1.0]])
    obstacles = Obstacles((), tri, np.zeros_like(tri), np.array([[0, 1, 2]]))
    wind.add_particles([[1.0, 0.5, 0.3]], [0])
    wind.step(1.5, obstacles)
    # hit at x = 2.2 after 1.2 s; then 0.3 s along (1, 0, -1)/2 -> (2.35, 0.5, 0.15)
    pos = wind.particles[0][0]
    np.testing.assert_allclose(pos, [2.35, 0.5, 0.15], atol=1e-5)
    assert pos @ [1, 0, 1] < 2.5
    u = wind.velocity()[tuple(grid.cell_index(pos)[0])]
    np.testing.assert_allclose(u, [0.5, 0.0, -0.5] if deflected else [1.0, 0.0, 0.0])


def test_a_moved_cloth_no_longer_blocks_its_old_cells(particle_params):
    """The cells a triangle overlapped last step are cleared: after the sheet moves away
    downstream, a particle crosses its old place on the free Euler path, and the cells
    flagged for tests are those of the moved sheet alone."""
    scene = _scene([{"type": "uniform", "velocity": [1.0, 0.0, 0.0]}])
    wind, grid = _wind(scene, 16, particle_params)
    sheet = np.array([[2.1, -1.0, -1.0], [2.1, 3.0, -1.0], [2.1, 1.0, 3.0]])  # plane x = 2.1
    tris = np.array([[0, 1, 2]])
    wind.add_particles([[1.0, 0.5, 0.5]], [0])
    wind.step(1.5, Obstacles((), sheet, np.zeros_like(sheet), tris))
    assert len(wind.particles[0]) == 0  # head-on at x = 2.1: stagnated
    assert not wind.ever_reached()[grid.cell_index([[2.26, 0.5, 0.5]])[0][0] :].any()
    moved = sheet + [1.6, 0.0, 0.0]  # now at x = 3.7
    wind.add_particles([[1.0, 0.7, 0.3]], [0])
    wind.step(1.5, Obstacles((), moved, np.zeros_like(moved), tris))
    np.testing.assert_allclose(wind.particles[0][0], [2.5, 0.7, 0.3], atol=1e-12)  # free
    # the cells flagged are exactly those the grid-wide registration gives the moved sheet
    flagged = (wind.state.cells.flags & TRIANGLES).astype(bool).reshape(grid.shape)
    np.testing.assert_array_equal(
        flagged, occupied_cells(triangle_cells(moved, tris, grid)[0], grid.shape)
    )


def test_sort_by_cell_is_a_stable_sort_by_cell_id():
    """Against numpy's stable argsort of c = (i ny + j) nz + k; 24000 cells take two radix
    passes; the buffer beyond the first n particles is left alone."""
    rng = np.random.default_rng(5)
    lower, h, shape = np.array([-1.0, 0.0, 2.0]), 0.25, np.array([40, 30, 20])
    n = 5000
    pos = lower + rng.random((n + 7, 3)) * (shape * h)
    pos[:50] = pos[50:100]  # equal cells: order must be kept
    src, ages = rng.integers(0, 3, n + 7), rng.random(n + 7)
    idx = np.floor((pos[:n] - lower) / h).astype(int)
    order = np.argsort((idx[:, 0] * 30 + idx[:, 1]) * 20 + idx[:, 2], kind="stable")
    expected = pos[order], src[order], ages[order], pos[n:].copy()
    grid = CellGrid(tuple(lower), tuple(lower + h * shape), h, tuple(int(m) for m in shape))
    sort_by_cell(grid, n, Particles(pos, src, ages))
    np.testing.assert_array_equal(pos[:n], expected[0])
    np.testing.assert_array_equal(src[:n], expected[1])
    np.testing.assert_array_equal(ages[:n], expected[2])
    np.testing.assert_array_equal(pos[n:], expected[3])
