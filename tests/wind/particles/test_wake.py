"""The mixing lee's near wake (windbench/wind/particles/wake.py) against answers known
without the code: Fackrell's cavity length at its published limits; the eddy is
divergence-free, passes no net flux through any plane across the wind, none through the
lee face, and has its stated backflow; the cavity's edge reflects particles without moving
them along the wind; the wake K has its stated peak and its drift is its gradient; a box
spanning a periodic domain has an unbounded wake, one on a slip wall a mirrored one."""

from __future__ import annotations

import numpy as np
import pytest

from tests.wind.particles.test_mixing import LOG_WIND, walled_scene
from windbench.cli import compose_config
from windbench.scenes import build_scene
from windbench.wind.particles.wake import (
    CAVITY,
    LENGTH,
    N_HI,
    N_LO,
    SPEED,
    TOP,
    Eddy,
    eddy_wind,
    fackrell_length,
    in_cavity,
    leave_cavity,
    speed_at,
    wake_diffusivity,
    wake_rows,
)

DEFAULTS = compose_config(["wind=particles"]).wind
BACKFLOW, MIXING = DEFAULTS.recirculation_backflow, DEFAULTS.wake_mixing
EDDY = Eddy(BACKFLOW, MIXING, DEFAULTS.recirculation_exponent, DEFAULTS.recirculation_height)
WALL = {"type": "box", "min": [2.0, 0.0, 0.0], "max": [2.5, 2.0, 1.5]}  # across the channel


def wall_rows(backflow=BACKFLOW, mixing=MIXING, exponent=2.0, height=1.0):
    scene = walled_scene([LOG_WIND], [WALL])
    return scene, wake_rows(scene, np.zeros(3), Eddy(backflow, mixing, exponent, height))


def test_fackrell_length_at_its_published_limits():
    assert fackrell_length(2.0, 2.0, 2.0) == pytest.approx(2.0 * 1.8 / 1.24)  # a cube
    two_d = 2.0 * 7.5 * 0.5**-0.3  # W >> H, L = H / 2
    assert fackrell_length(2.0, 1.0, np.inf) == pytest.approx(two_d)
    assert fackrell_length(2.0, 1.0, 1e6) == pytest.approx(two_d, rel=1e-4)


def test_boxes_spanning_or_touching_closed_sides_have_wide_wakes():
    fence = build_scene(compose_config(["scene=fence"]).scene)
    (row,) = wake_rows(fence, np.zeros(3), EDDY)
    assert row[N_LO] == -np.inf and row[N_HI] == np.inf  # periodic span: a 2-D fence
    assert row[LENGTH] == pytest.approx(fackrell_length(2.0, 1.0, np.inf))
    assert row[SPEED] == pytest.approx(6.0 * np.log(2.0 / 0.1) / np.log(10.0 / 0.1))
    walled = build_scene(compose_config(["scene=two_flags_wall"]).scene)
    (row,) = wake_rows(walled, np.zeros(3), EDDY)  # the poles are not resolved
    assert (row[N_LO], row[N_HI]) == (2.0, np.inf)  # its side at y = 4 is a slip wall
    assert row[LENGTH] == pytest.approx(fackrell_length(3.0, 1.0, 4.0))  # W mirrored
    assert row[SPEED] == pytest.approx(6.0 * np.log(3.0 / 0.1) / np.log(6.0 / 0.1))  # at its top


@pytest.mark.parametrize("exponent, height", [(2.0, 1.0), (10.0, 1.3)])
def test_the_eddy_is_divergence_free_and_closed(exponent, height):
    """psi = 0 on the floor, the lee face and the edge: zero net flux through every plane
    across the wind, none through the lee face; div u = 0 inside (central differences)."""
    _, rows = wall_rows(exponent=exponent, height=height)
    (row,) = rows
    length, top = row[LENGTH], row[CAVITY]
    assert top == pytest.approx(height * row[TOP])
    for xi in (0.1, 1 / 3, 0.6, 0.9):
        s = 2.5 + xi * length
        h = top * np.sqrt(1.0 - xi * xi)  # the cavity's height there
        z = (np.arange(20000) + 0.5) * h / 20000
        u = np.array([eddy_wind(rows, (s, 1.0, zz), 0.0)[0] for zz in z])
        assert abs(u.sum() * h / 20000) < 1e-6 * top * row[SPEED]  # midpoint rule
    assert all(
        eddy_wind(rows, (2.5 + 1e-12, 1.0, z), 0.0)[0] == pytest.approx(0.0) for z in (0.3, 1)
    )
    step = 1e-5
    rng = np.random.default_rng(1)
    for _ in range(50):
        p = np.array([2.5 + rng.uniform(0.05, 0.95) * length, 1.0, rng.uniform(0.05, 0.9) * top])
        if not in_cavity(rows, tuple(p), 0.0):
            continue
        div = 0.0
        for ax in (0, 2):
            e = np.eye(3)[ax] * step
            div += (
                eddy_wind(rows, tuple(p + e), 0.0)[ax] - eddy_wind(rows, tuple(p - e), 0.0)[ax]
            ) / (2 * step)
        assert abs(div) < 1e-6 * row[SPEED] / top


def test_the_backflow_peaks_at_the_floor_a_third_along_the_cavity():
    _, rows = wall_rows()
    (row,) = rows
    s = 2.5 + row[LENGTH] / 3.0
    assert eddy_wind(rows, (s, 1.0, 1e-9), 0.0)[0] == pytest.approx(-BACKFLOW * row[SPEED])
    h = row[TOP] * np.sqrt(1.0 - 1.0 / 9.0)
    assert eddy_wind(rows, (s, 1.0, h / np.sqrt(5.0)), 0.0)[0] == pytest.approx(0.0, abs=1e-12)
    assert eddy_wind(rows, (s, 1.0, 0.8 * h), 0.0)[0] > 0.0  # the return flow above
    assert eddy_wind(rows, (1.0, 1.0, 0.2), 0.0) == (0.0, 0.0, 0.0)  # upwind: none
    _, tall = wall_rows(exponent=10.0, height=1.3)  # backflow up to 21^(-1/10) h = 0.738 h
    h = 1.3 * h
    assert eddy_wind(tall, (s, 1.0, 1e-9), 0.0)[0] == pytest.approx(-BACKFLOW * row[SPEED])
    assert eddy_wind(tall, (s, 1.0, 21**-0.1 * h), 0.0)[0] == pytest.approx(0.0, abs=1e-12)
    assert eddy_wind(tall, (s, 1.0, 0.7 * h), 0.0)[0] < 0.0 < eddy_wind(tall, (s, 1, 0.8 * h), 0)[0]
    _, calm = wall_rows(backflow=0.0)
    assert eddy_wind(calm, (s, 1.0, 0.2), 0.0) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("height", [1.0, 1.3])
def test_the_cavity_edge_reflects_particles_across_it_without_moving_them_downwind(height):
    _, rows = wall_rows(height=height)
    (row,) = rows
    rng = np.random.default_rng(2)
    pts = np.column_stack(
        [rng.uniform(0.0, 8.0, 4000), rng.uniform(0, 2, 4000), rng.uniform(0, 3, 4000)]
    )
    for p in pts:
        q = leave_cavity(rows, tuple(p), 0.0)
        if not in_cavity(rows, tuple(p), 0.0):
            assert q == tuple(p)
            continue
        assert not in_cavity(rows, q, 0.0) and q[:2] == tuple(p[:2])
        edge = row[CAVITY] * np.sqrt(1.0 - ((p[0] - 2.5) / row[LENGTH]) ** 2)
        assert q[2] - edge == pytest.approx(edge - p[2])  # as deep outside as inside


def test_a_particle_beside_a_narrow_cavity_leaves_it_sideways():
    _, rows = wall_rows()
    rows[0, N_LO], rows[0, N_HI] = 0.5, 1.5  # a box 1 m wide across y
    inside = (3.0, 0.6, 0.4)  # 0.1 m in from the side y = 0.5, far below the top
    assert leave_cavity(rows, inside, 0.0) == pytest.approx((3.0, 0.4, 0.4))
    assert leave_cavity(rows, (3.0, 1.45, 0.4), 0.0) == pytest.approx((3.0, 1.55, 0.4))


def test_the_wake_diffusivity_peaks_at_reattachment_and_its_drift_is_its_gradient():
    _, rows = wall_rows()
    (row,) = rows
    peak = MIXING * row[SPEED] * row[TOP]
    k, *_ = wake_diffusivity(rows, (2.5 + row[LENGTH], 1.0, 0.5), 0.0)
    assert k == pytest.approx(peak)
    assert wake_diffusivity(rows, (2.0, 1.0, 0.5), 0.0) == (0.0, 0.0, 0.0, 0.0)
    narrow = rows.copy()
    narrow[0, N_LO], narrow[0, N_HI] = 0.5, 1.0  # a gap beside it: K falls off across
    step = 1e-6
    for p in [(6.0, 0.2, 0.7), (9.0, 1.6, 2.2), (20.0, 0.7, 1.0)]:
        k, *grad = wake_diffusivity(narrow, p, 0.0)
        for ax in range(3):
            e = np.eye(3)[ax] * step
            up = wake_diffusivity(narrow, tuple(np.add(p, e)), 0.0)[0]
            down = wake_diffusivity(narrow, tuple(np.subtract(p, e)), 0.0)[0]
            assert grad[ax] == pytest.approx((up - down) / (2 * step), rel=1e-5, abs=1e-9 * peak)
    assert speed_at(walled_scene([LOG_WIND]).sources, 4.0) == pytest.approx(6.0)
