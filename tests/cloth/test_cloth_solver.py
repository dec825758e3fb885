"""XPBD cloth solver (windbench.cloth.solver): free fall, hanging, bending, contacts, failure.

Reference answers: the free-fall parabola, the rest shape of a pinned cloth, the first-order
reduction of a hinge constraint along its finite-difference gradient, contact heights on
flat body faces, and the energy bound of the divergence check.
"""

import numpy as np
import pytest

from windbench.aero import aerodynamic_forces
from windbench.cloth import check_cloth_solver, make_cloth_solver
from windbench.cloth.collision import max_penetration
from windbench.cloth.mesh import flag_mesh
from windbench.cloth.model import ClothModel
from windbench.cloth.solver import XPBDCloth
from windbench.config import AeroConfig, ClothConfig
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
            params = air if isinstance(air, AeroConfig) else AeroConfig()
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
    assert solver.frame_constants(DT).bend_every == bend_every
    # thick still air settles the strip (drag vanishes at rest, so the statics are untouched)
    state, energy = _run(solver, model, 600, air=AeroConfig(drag_coefficient=20.0))
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
    everywhere = np.tile([-np.inf, -np.inf, -np.inf, np.inf, np.inf, np.inf], (2, 1))
    every.tables = every.tables._replace(contacts=every.tables.contacts._replace(boxes=everywhere))
    a, _ = _run(culled, model, 40, air=True)
    b, _ = _run(every, model, 40, air=True)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.velocities, b.velocities)
    # and the recorded figures are the brute-force ones
    rng = np.random.default_rng(1)
    pts = np.concatenate([a.positions, rng.uniform(-0.4, 0.4, (200, 3))])
    depth = np.maximum(0.0, -distances(bodies, pts)[0]).max()
    bodies, boxes, _, _ = culled.tables.contacts
    assert depth > 0.01 and max_penetration(bodies, boxes, pts) == depth
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
    assert energy.max() <= state.work_in  # gravity's work bounds the kinetic energy
    assert state.frames == 60
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
    for build in (check_cloth_solver, lambda c, m: make_cloth_solver(c, m, ())):
        with pytest.raises(ConfigError) as err:
            build(cfg, _cloth(n=4))  # check_cloth_solver: what prepare() calls
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
    for build in (XPBDCloth.check, lambda m, c: XPBDCloth(m, (), c)):
        with pytest.raises(ConfigError) as err:
            build(_cloth(n=4, **material), ClothConfig())
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
    assert solver.frame_constants(DT).bend_every == expected
    first = solver.step(model.initial_state(), np.zeros((model.n_vertices, 3)), DT)
    assert np.isfinite(first.positions).all()


def test_contact_clearance_skips_no_contact():
    """The contact query at p is skipped while LIPSCHITZ |p - q| < d(q) - margin (q: where
    the distance was last computed). Point pairs near a capsule, a box and a tabulated mesh
    (the shirt's character): none so skipped lies within the margin. The slope bound holds
    everywhere but where p leaves the mesh's lattice, out where the distance is that to
    its bounding box, PAD_CELLS spacings or more, far beyond the margin."""
    from windbench.cli import compose_config
    from windbench.cloth.collision import LIPSCHITZ
    from windbench.scenes import build_scene

    bodies = (
        body_from_config({"type": "capsule", "a": [-1, 0, 0], "b": [1, 0, 0], "radius": 0.2}, "b"),
        body_from_config({"type": "box", "min": [0.2, -1, -1], "max": [0.3, 1, 0.25]}, "w"),
        *build_scene(compose_config(["scene=shirt"]).scene).bodies,
    )
    rng = np.random.default_rng(5)
    centres = np.concatenate([[[0, 0, 0]], [[1.5, 1.5, 1.2]]])
    q = centres[rng.integers(0, 2, 4000)] + rng.uniform(-0.5, 0.5, (4000, 3))
    p = q + rng.normal(0.0, 0.02, q.shape)
    dq, dp = distances(bodies, q)[0], distances(bodies, p)[0]
    step = np.linalg.norm(p - q, axis=1)
    margin = ClothConfig().collision_margin
    skipped = LIPSCHITZ * step < dq - margin
    assert skipped.sum() > 1000 and np.all(dp[skipped] >= margin)
    near = np.abs(dq) < 0.02  # well inside the lattice (spacing 1 cm, padded by 3)
    assert np.all(dp[near] >= dq[near] - LIPSCHITZ * step[near])
    assert np.any(np.abs(dp - dq) > 0.5 * step)  # the pairs do probe the slope


@pytest.mark.parametrize("friction", [0.3, 0.0])
def test_a_body_turning_under_a_draped_cloth_carries_it_by_friction(friction):
    """A cylinder turning about its vertical axis at 1 rad/s under a cloth lying on its top:
    with friction the cloth turns with it (mean angular velocity L_z / I_z -> 1 rad/s),
    without it the contact normals are vertical and radial and nothing turns the cloth."""
    spin = {"type": "rotation", "axis": [0, 0, 1], "point": [0, 0, 0], "angular_speed": 1.0}
    body = {"type": "cylinder", "a": [0, 0, -1], "b": [0, 0, 0.2], "radius": 0.4}
    turning = body_from_config({**body, "motion": {**spin, "start": 0.25}}, "b")
    model = _cloth(n=14, size=0.6, origin=(-0.3, -0.3, 0.3))
    solver = XPBDCloth(model, (turning,), ClothConfig(friction=friction))
    state, _ = _run(solver, model, 60, air=True)
    x, v, m = state.positions, state.velocities, solver.tables.constraints.mass
    omega = np.sum(m * (x[:, 0] * v[:, 1] - x[:, 1] * v[:, 0])) / np.sum(
        m * (x[:, 0] ** 2 + x[:, 1] ** 2)
    )
    assert omega == pytest.approx(1.0 if friction else 0.0, abs=0.02)
    assert solver.stats(state)["max_penetration"] == 0.0
