"""XPBD cloth solver (windbench.cloth.solver): free fall, hanging, bending, contacts, failure.

Reference answers: the free-fall parabola, the rest shape of a pinned cloth, the first-order
reduction of a hinge constraint along its finite-difference gradient, contact heights on
flat body faces, and the energy bound of the divergence check.
"""

import numpy as np
import pytest

from windbench.aero import AeroParams, aerodynamic_forces
from windbench.cloth import make_cloth_solver
from windbench.cloth.collision import max_penetration
from windbench.cloth.mesh import flag_mesh
from windbench.cloth.model import ClothModel
from windbench.cloth.solver import XPBDCloth, fast_atan2, project_hinge, solve_chains
from windbench.cloth.topology import dihedral_angles
from windbench.config import ClothConfig
from windbench.errors import ConfigError, SimulationDiverged
from windbench.geometry.bodies import body_from_config, distances

DT = 1.0 / 60.0


def _cloth(n=12, size=1.0, pin="none", origin=(0.0, 0.0, 0.0), **material):
    spec = {"origin": list(origin), "size": [size, size], "resolution": [n, n], "pin": pin}
    spec.update(u_axis=[1, 0, 0], v_axis=[0, 1, 0], material=material)
    return ClothModel.from_meshes([flag_mesh(spec, "c")])


def _run(solver, model, frames, forces=None, air=False):
    return _run_from(solver, model, model.initial_state(), frames, forces, air)


def _run_from(solver, model, state, frames, forces=None, air=True):
    zero = np.zeros((model.n_vertices, 3))
    energies = []
    for _ in range(frames):
        f = zero if forces is None else forces
        if air:  # still air: the paper's air resistance (§3 with u = 0)
            params = air if isinstance(air, AeroParams) else AeroParams()
            f = aerodynamic_forces(
                state.positions, state.velocities, zero, model.triangles, params
            )[1]
        state = solver.step(state, f, DT)
        energies.append(solver.kinetic_energy(state.velocities))
    return state, np.asarray(energies)


def test_free_fall_matches_half_g_t_squared():
    model = _cloth()
    cfg = ClothConfig()
    solver = XPBDCloth(model, (), cfg)
    frames = 30
    state, _ = _run(solver, model, frames)
    t = frames * DT
    n_sub = frames * cfg.substeps
    drop = model.rest_positions[:, 2] - state.positions[:, 2]
    # symplectic Euler: h^2 g (1 + 2 + ... + N) = g t^2 / 2 (1 + 1/N), -> 1/2 g t^2
    np.testing.assert_allclose(drop, 0.5 * 9.81 * t**2 * (1 + 1 / n_sub), rtol=1e-12)
    assert drop.mean() == pytest.approx(0.5 * 9.81 * t**2, rel=1.0 / n_sub)
    np.testing.assert_allclose(state.velocities[:, 2], -9.81 * t, rtol=1e-12)
    np.testing.assert_allclose(state.positions[:, :2], model.rest_positions[:, :2], atol=1e-12)


def test_pinned_at_two_corners_hangs_with_little_stretch_and_comes_to_rest():
    n = 16
    model = _cloth(n=n, pin="top_corners")  # horizontal at start: it falls and swings
    solver = XPBDCloth(model, (), ClothConfig())
    pins = model.pinned
    state, energy = _run(solver, model, 240, air=True)
    np.testing.assert_array_equal(state.positions[pins], model.rest_positions[pins])
    x = state.positions.reshape(n, n, 3)
    threads = np.concatenate(
        [
            np.linalg.norm(np.diff(x, axis=0), axis=2).sum(0),
            np.linalg.norm(np.diff(x, axis=1), axis=2).sum(1),
        ]
    )
    assert threads.max() < 1.05  # no warp or weft thread longer than 105% of its 1 m
    assert solver.max_stretch(state.positions) < 0.05  # nor any single warp/weft edge
    assert state.positions[:, 2].min() < -0.9  # it does hang (lowest point ~1 m down)
    assert energy.max() > 0.05 and energy[-1] < 1e-3 * energy.max()  # and it comes to rest


def _vertical_chain(rest, inv_mass, alpha):
    """Arguments of solve_chains for one chain down the z axis: vertex k joins edge k-1, k."""
    m = len(rest)
    scale = 1.0 / (inv_mass[:-1] + inv_mass[1:] + alpha)
    ptr, verts = np.array([0, m]), np.arange(m + 1)
    return ptr, verts, rest, alpha, scale, np.zeros(m), np.empty((m, 5))


def test_one_chain_solve_makes_a_straight_inextensible_chain_exact():
    rng = np.random.default_rng(1)
    m = 12
    rest = rng.uniform(0.05, 0.1, m)
    for inv_mass in (np.r_[0.0, rng.uniform(0.5, 2.0, m)], rng.uniform(0.5, 2.0, m + 1)):
        # collinear start: every edge 30% too long or too short, the first vertex a pin or not
        seg = rest * rng.uniform(0.7, 1.3, m)
        p = np.zeros((m + 1, 3))
        p[1:, 2] = -np.cumsum(seg)
        x = p.copy()
        solve_chains(p, inv_mass, *_vertical_chain(rest, inv_mass, np.zeros(m)))
        # along a line the constraints are linear: one direct solve satisfies them all
        np.testing.assert_allclose(-np.diff(p[:, 2]), rest, rtol=1e-12)
        np.testing.assert_array_equal(p[:, :2], 0.0)
        if inv_mass[0] == 0.0:  # hanging from the pin: each vertex at the rest path length
            np.testing.assert_allclose(p[1:, 2], -np.cumsum(rest), rtol=1e-12)
        else:  # free: the mass-weighted centre does not move (momentum conserved)
            mass = 1.0 / inv_mass
            assert mass @ p[:, 2] == pytest.approx(mass @ x[:, 2], rel=1e-12)


def test_strain_limit_brings_the_over_stretched_edges_of_a_chain_to_the_limit():
    """Limit mode of solve_chains on a straight chain (linear constraints: one solve is
    exact): edges longer than (1 + limit) L end at exactly that length (the others are
    free: they move with their ends), repeated solves end with no edge over the trigger
    (1 + 1.1 limit) L; the mass-weighted centre of a free chain stays put, a pin does not
    move; a chain whose edges stay within the slack above the limit is not touched; the
    multipliers are not used."""
    rng = np.random.default_rng(4)
    m, limit = 10, 0.03
    rest = rng.uniform(0.05, 0.1, m)
    factor = np.where(np.arange(m) % 3 == 0, 1.10, rng.uniform(0.9, 1.02, m))
    for inv_mass in (np.r_[0.0, rng.uniform(0.5, 2.0, m)], rng.uniform(0.5, 2.0, m + 1)):
        p = np.zeros((m + 1, 3))
        p[1:, 2] = -np.cumsum(rest * factor)
        x = p.copy()
        ptr, verts, _, alpha, scale, lam, work = _vertical_chain(rest, inv_mass, np.zeros(m))
        lam[:] = 7.0
        solved = solve_chains(p, inv_mass, ptr, verts, rest, alpha, scale, lam, work, limit)
        assert solved == 1
        over = factor > 1 + limit
        np.testing.assert_allclose(-np.diff(p[:, 2])[over], rest[over] * (1 + limit), rtol=1e-12)
        for _ in range(20):  # the passes of xpbd_frame, until no chain is solved
            if solve_chains(p, inv_mass, ptr, verts, rest, alpha, scale, lam, work, limit) == 0:
                break
        assert np.all(-np.diff(p[:, 2]) <= rest * (1 + 1.1 * limit) * (1 + 1e-12))
        np.testing.assert_array_equal(lam, 7.0)
        np.testing.assert_array_equal(p[:, :2], 0.0)
        if inv_mass[0] == 0.0:
            assert p[0, 2] == 0.0
        if inv_mass[0] > 0.0:
            mass = 1.0 / inv_mass
            assert mass @ p[:, 2] == pytest.approx(mass @ x[:, 2], rel=1e-12)
    p = np.zeros((m + 1, 3))
    p[1:, 2] = -np.cumsum(rest * (1 + 1.05 * limit))  # over the limit, within the slack
    before = p.copy()
    assert solve_chains(p, inv_mass, ptr, verts, rest, alpha, scale, lam, work, limit) == 0
    np.testing.assert_array_equal(p, before)


def test_chain_of_springs_hangs_at_the_static_elongation():
    """Implicit Euler by substeps (predict, one exact chain solve, v = dx/h) comes to rest
    where each spring carries the weight below it: elongation_k = g sum_(i>k) m_i / k_k."""
    rng = np.random.default_rng(2)
    m, g, h = 10, 9.81, 0.01
    rest = rng.uniform(0.05, 0.1, m)
    k = rng.uniform(200.0, 2000.0, m)  # N/m
    mass = rng.uniform(0.005, 0.02, m + 1)
    inv_mass = np.r_[0.0, 1.0 / mass[1:]]  # vertex 0 pinned
    args = _vertical_chain(rest, inv_mass, 1.0 / k / h**2)  # alpha~ = alpha / h^2
    lam = args[5]
    x = np.zeros((m + 1, 3))
    x[1:, 2] = -np.cumsum(rest)
    v = np.zeros_like(x)
    for _ in range(1000):
        v[1:, 2] -= h * g
        p = x + h * v
        lam[:] = 0.0
        solve_chains(p, inv_mass, *args)
        v, x = (p - x) / h, p
    weight_below = g * np.cumsum(mass[::-1])[::-1][1:]
    np.testing.assert_allclose(-np.diff(x[:, 2]), rest + weight_below / k, rtol=1e-9)
    assert np.abs(v).max() < 1e-9


def test_hinge_projection_follows_the_angle_gradient():
    rng = np.random.default_rng(3)
    x = np.array([[0, 0, 0], [0, 1, 0], [-1, 0.3, 0.1], [0.9, 0.6, 0.4]], float)
    x += 0.05 * rng.normal(size=x.shape)
    hinge = np.array([[0, 1, 2, 3]])
    theta = dihedral_angles(x, hinge)[0]
    eps = 1e-7
    grad = np.zeros((4, 3))
    for q in range(4):
        for k in range(3):
            y = x.copy()
            y[q, k] += eps
            grad[q, k] = (dihedral_angles(y, hinge)[0] - theta) / eps
    inv_mass = np.array([1.0, 2.0, 0.5, 1.5])
    rest = theta - 1e-3  # a small violation
    p = x.copy()
    project_hinge(p, inv_mass, 0, 1, 2, 3, rest, 0.0)
    step = p - x
    c = theta - rest
    expected = -c * inv_mass[:, None] * grad / np.sum(inv_mass[:, None] * grad**2)
    np.testing.assert_allclose(step, expected, rtol=1e-4, atol=1e-12)
    assert abs(dihedral_angles(p, hinge)[0] - rest) < 1e-3 * c  # fixed to first order


def test_fast_atan2_matches_libm():
    rng = np.random.default_rng(0)
    y, x = rng.normal(size=(2, 2000))
    got = np.array([fast_atan2(a, b) for a, b in zip(y, x, strict=True)])
    np.testing.assert_allclose(got, np.arctan2(y, x), atol=3e-8)
    assert fast_atan2(0.0, -1.0) == pytest.approx(np.pi) and fast_atan2(0.0, 0.0) == 0.0


@pytest.mark.slow
@pytest.mark.parametrize(("cells", "rows", "bend_every"), [(10, 5, 1), (5, 3, 2)])
def test_cantilever_sag_matches_the_hinge_chain_statics(cells, rows, bend_every):
    """A strip clamped along one edge sags as a chain of rotational springs under its weight.

    Small-deflection statics: hinge i (column i, i = 1..N-1) carries the moment of the
    column masses beyond it, M_i = sum_c m_c g (c - i) hu, and turns by M_i / K with
    K = B b / hu; the tip drops by sum_i theta_i (N - i) hu (the discrete Euler-Bernoulli
    cantilever, q L^4 / (8 B) as hu -> 0). The clamp holds the first two columns. XPBD
    reaches it once the substep resolves the bending (see the solver docstring); slow
    because it needs 512 substeps and 10 s to settle (measured: 4% above the chain). With
    5 x 2 cells the hinges are resolved well enough to be projected every other substep
    (BEND_EVERY): the same statics.
    """
    length, width, rho, bend = 0.2, 0.05, 0.1, 0.01
    spec = {"origin": [0, 0, 1], "size": [length, width], "resolution": [cells + 1, rows]}
    spec.update(u_axis=[1, 0, 0], v_axis=[0, 1, 0], pin=list(range(2 * rows)))
    spec["material"] = {"density": rho, "bend_stiffness": bend, "damping": 0.01}
    model = ClothModel.from_meshes([flag_mesh(spec, "c")])
    cfg = ClothConfig()
    cfg.substeps = 512
    solver = XPBDCloth(model, (), cfg)
    solver.substep_constants(DT)
    assert solver.bend_every == bend_every
    # thick still air settles the strip (drag vanishes at rest, so the statics are untouched)
    state, energy = _run(solver, model, 600, air=AeroParams(drag_coefficient=20.0))
    hu = length / cells
    column_mass = np.full(cells + 1, rho * width * hu)
    column_mass[-1] /= 2
    spring = bend * width / hu
    theta = [
        sum(column_mass[c] * 9.81 * (c - i) * hu for c in range(i + 1, cells + 1)) / spring
        for i in range(1, cells)
    ]
    expected = sum(t * (cells - i) * hu for i, t in enumerate(theta, start=1))
    tip = 1.0 - state.positions[-rows:, 2].mean()
    assert energy[-1] < 1e-4 * energy.max()
    assert tip == pytest.approx(expected, rel=0.1)


@pytest.mark.parametrize(
    ("body", "top"),
    [
        ({"type": "plane", "point": [0, 0, 0.2], "normal": [0, 0, 1]}, 0.2),
        ({"type": "box", "min": [-1, -1, -1], "max": [1, 1, 0.2]}, 0.2),
        ({"type": "cylinder", "a": [0, 0, -1], "b": [0, 0, 0.2], "radius": 0.8}, 0.2),
        ({"type": "capsule", "a": [-1, 0, 0], "b": [1, 0, 0], "radius": 0.2}, 0.2),
    ],
)
def test_cloth_falls_onto_a_body_and_rests_on_it(body, top):
    model = _cloth(n=14, size=0.6, origin=(-0.3, -0.3, 0.3))
    cfg = ClothConfig()
    solver = XPBDCloth(model, (body_from_config(body, "b"),), cfg)
    state, _ = _run(solver, model, 90, air=True)
    assert solver.stats(state)["max_penetration"] == 0.0
    centre = np.argmin(np.linalg.norm(model.rest_positions[:, :2], axis=1))
    # rests on the top face (or the capsule's crest) at the collision margin, not sunk
    assert state.positions[centre, 2] == pytest.approx(top + cfg.collision_margin, abs=2e-3)
    if body["type"] != "capsule":  # on a flat top, all of the cloth lies flat
        inner = np.linalg.norm(model.rest_positions[:, :2], axis=1) < 0.25
        np.testing.assert_allclose(state.positions[inner, 2], top + cfg.collision_margin, atol=2e-3)


def test_bounding_box_broad_phase_changes_no_bit():
    """Skipping vertices outside the bodies' grown boxes gives the same contacts exactly."""
    bodies = (
        body_from_config({"type": "capsule", "a": [-1, 0, 0], "b": [1, 0, 0], "radius": 0.2}, "b"),
        body_from_config({"type": "box", "min": [0.2, -1, -1], "max": [0.3, 1, 0.25]}, "w"),
    )
    model = _cloth(n=14, size=0.6, origin=(-0.3, -0.3, 0.3))
    culled = XPBDCloth(model, bodies, ClothConfig())
    every = XPBDCloth(model, bodies, ClothConfig())
    every.body_boxes = np.tile([-np.inf, -np.inf, -np.inf, np.inf, np.inf, np.inf], (2, 1))
    a, _ = _run(culled, model, 40, air=True)
    b, _ = _run(every, model, 40, air=True)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.velocities, b.velocities)
    # and the recorded figures are the brute-force ones
    rng = np.random.default_rng(1)
    pts = np.concatenate([a.positions, rng.uniform(-0.4, 0.4, (200, 3))])
    depth = np.maximum(0.0, -distances(bodies, pts)[0]).max()
    kinds, params, boxes = culled.body_kinds, culled.body_params, culled.body_boxes
    assert depth > 0.01 and max_penetration(kinds, params, boxes, pts) == depth
    e = culled.topology.edges[culled.stretch_edges]
    stretch = np.linalg.norm(pts[e[:, 0]] - pts[e[:, 1]], axis=1)
    stretch = stretch / culled.topology.edge_length[culled.stretch_edges] - 1.0
    assert culled.max_stretch(pts) == pytest.approx(stretch.max(), rel=1e-14)


def test_divergence_is_reported_with_the_step():
    model = _cloth(n=6, pin="top_corners")
    solver = XPBDCloth(model, (), ClothConfig())
    state = model.initial_state()
    state = solver.step(state, np.zeros((36, 3)), DT)
    bad = np.zeros((36, 3))
    bad[7] = np.nan
    with pytest.raises(SimulationDiverged) as err:
        solver.step(state, bad, DT)
    assert err.value.step == 2 and "not finite" in err.value.reason


def test_energy_bound_is_the_work_done_on_the_cloth():
    model = _cloth(n=6, pin="top_corners")
    cfg = ClothConfig()
    solver = XPBDCloth(model, (), cfg)
    state, energy = _run(solver, model, 60)
    assert energy.max() <= solver.work_in  # gravity's work bounds the kinetic energy
    cfg.energy_limit = 1e-3  # a bound below what any falling cloth reaches
    strict = XPBDCloth(model, (), cfg)
    with pytest.raises(SimulationDiverged, match="kinetic energy"):
        _run(strict, model, 5)


def test_same_input_gives_the_same_bits():
    model = _cloth(n=8, pin="top_corners")
    a, _ = _run(XPBDCloth(model, (), ClothConfig()), model, 20, air=True)
    b, _ = _run(XPBDCloth(model, (), ClothConfig()), model, 20, air=True)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.velocities, b.velocities)


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"substeps": 0}, "cloth.substeps"),
        ({"edge_iterations": 1.5}, "cloth.edge_iterations"),
        ({"collision_margin": -0.1}, "cloth.collision_margin"),
        ({"solver": "verlet"}, "cloth.solver"),
        ({"threads": "yes"}, "cloth.threads"),
        ({"strain_limit": -0.01}, "cloth.strain_limit"),
        ({"limit_passes": 0}, "cloth.limit_passes"),
    ],
)
def test_bad_solver_settings_name_their_key(change, key):
    cfg = ClothConfig()
    for k, v in change.items():
        setattr(cfg, k, v)
    with pytest.raises(ConfigError) as err:
        make_cloth_solver(cfg, _cloth(n=4), ())
    assert err.value.key == key


@pytest.mark.parametrize(
    ("material", "key"),
    [
        ({"density": 0.0}, "scene.cloths[0].material.density"),
        ({"stretch_stiffness": -1.0}, "scene.cloths[0].material.stretch_stiffness"),
        ({"bend_stiffness": "soft"}, "scene.cloths[0].material.bend_stiffness"),
        ({"youngs_modulus": 1e6}, "scene.cloths[0].material"),
    ],
)
def test_bad_material_names_its_key(material, key):
    with pytest.raises(ConfigError) as err:
        XPBDCloth(_cloth(n=4, **material), (), ClothConfig())
    assert err.value.key == key


@pytest.mark.parametrize(
    ("n", "bend", "substeps", "expected"),
    [(25, 1e-5, 8, 2), (64, 1e-5, 8, 1), (25, 1e-2, 8, 1), (25, 1e-5, 7, 1)],
)
def test_soft_bending_is_projected_every_other_substep_only_when_resolved(
    n, bend, substeps, expected
):
    """BEND_EVERY applies when omega BEND_EVERY h <= 0.2 for every hinge, with
    omega^2 = k_b sum_q w_q |grad_q theta|^2 (the hinge's own oscillation), and the
    substeps split into such steps: a 1 m cloth of 25 x 25 vertices at 1e-5 N m qualifies,
    64 x 64 vertices or a 1e-2 N m strip do not, nor 7 substeps."""
    model = _cloth(n=n, pin="top", bend_stiffness=bend)
    cfg = ClothConfig()
    cfg.substeps = substeps
    solver = XPBDCloth(model, (), cfg)
    solver.substep_constants(DT)
    assert solver.bend_every == expected
    first = solver.step(model.initial_state(), np.zeros((model.n_vertices, 3)), DT)
    assert np.isfinite(first.positions).all()
