"""Two-way coupling through pressure (``wind.coupling=projection``) against answers known
without the code: a square plate's drag coefficient, a membrane across a channel carried at
the channel's flow rate with the pressure jump that accelerates it, air enclosed by closed
faces found and its Poisson right-hand side balanced, moving flags that stay finite, a
flag on a coarse grid that flies, and a flag in a wall's lee that feels it."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from tests.wind.navier_stokes.test_backend import box_scene, make
from windbench.aero import cloth_forces
from windbench.cli import compose_config
from windbench.cloth.mesh import flag_mesh
from windbench.config import AeroConfig
from windbench.errors import ConfigError
from windbench.simulate import run
from windbench.wind.base import Obstacles
from windbench.wind.navier_stokes import coupling

CHANNEL = dict(
    x_min="inflow", x_max="outflow", y_min="slip", y_max="slip", z_min="slip", z_max="slip"
)
U = 2.0  # m/s, the uniform inflow


def _sheet(origin, size, mobility=0.0, velocity=0.0):
    """A square sheet normal to x (8 x 8 cells of cloth), static or moving along x."""
    mesh = flag_mesh(
        {
            "name": "sheet",
            "type": "flag",
            "origin": list(origin),
            "size": [size, size],
            "resolution": [8, 8],
            "u_axis": [0.0, 1.0, 0.0],
            "v_axis": [0.0, 0.0, 1.0],
        },
        "sheet",
    )
    n = mesh.vertices.shape[0]
    moving = np.tile([velocity, 0.0, 0.0], (n, 1))
    return Obstacles((), mesh.vertices, moving, mesh.triangles, np.full(n, mobility))


def test_static_square_plate_has_a_plate_drag_coefficient():
    """Force / (1/2 rho U^2 A) of a 1 m square plate normal to the wind, 32 cells (4 x 4
    cells on the plate, 6 % blockage): Hoerner's 1.17 for a free plate, somewhat more with
    the channel's walls and the coarse edge; between 1.0 and 2.0, from the pressure jump
    alone and with the §3 law on the air at the plate added (``aero.subgrid_law``: the
    blocked air is nearly still there, the law adds little)."""
    spec = box_scene(CHANNEL, [{"type": "uniform", "velocity": [U, 0, 0]}], domain=(8, 4, 4))
    wind = make(spec, 32, coupling="projection")
    plate = _sheet((3.0, 1.5, 1.5), 1.0)
    for _ in range(40):
        wind.step(0.0625, plate)
    loads = wind.cloth_pressure_loads()
    force = loads.sum(axis=0)  # over rho, m^4 s^-2
    drag = force[0] / (0.5 * U**2 * 1.0)
    assert 1.0 < drag < 2.0
    assert abs(force[1]) < 1e-6 * force[0] and abs(force[2]) < 1e-6 * force[0]  # symmetric
    air = AeroConfig()
    at_plate = wind.sample(plate.cloth_positions)
    still = (plate.cloth_positions, plate.cloth_velocities)
    tri, _ = cloth_forces(*still, at_plate, plate.cloth_triangles, loads, air)
    total = tri.sum(axis=0)[0] / (0.5 * air.air_density * U**2 * 1.0)
    assert drag < total < 2.0


def _field_and_sheet(axis, offset):
    """A 6^3 grid of 0.5 m cells (no solid, every face open) and one triangle normal to
    ``axis`` (tilted 6 degrees off it) whose centroid lies ``offset`` m past the centre
    1.25 m."""
    shape, h = (6, 6, 6), 0.5
    solid = np.zeros(shape, dtype=np.bool_)
    free = tuple(
        np.ones(tuple(n + 2 + (a == b) for b, n in enumerate(shape)), np.uint8) for a in range(3)
    )
    centre = np.full(3, 1.4)
    centre[axis] = 1.25 + offset
    u, v = np.roll([0.0, 1.0, 0.0], axis), np.roll([0.0, 0.0, 1.0], axis)
    tilt = 0.3 * np.roll([1.0, 0.0, 0.0], axis)
    corners = np.array([centre - 0.3 * u - 0.3 * v, centre + 0.6 * u, centre + 0.6 * v])
    corners += np.outer([-1.0, 0.5, 0.5], tilt) * 0.2
    corners += centre - corners.mean(axis=0)  # the centroid at ``centre``
    return shape, h, solid, free, corners


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("offset", [0.02, 0.1, 0.25, 0.45])
def test_a_pressure_gradient_through_a_sheet_puts_no_force_on_it(axis, offset):
    """psi linear in x (a uniform pressure gradient, as across a wake or at rest under a
    body force) gives a sheet of no thickness no net force wherever it lies between two
    cell centres; a step in psi at the sheet gives it the step times its area, along its
    normal; with the farther cell of one side behind a closed face that side keeps its
    nearer cell's psi (first order there)."""
    shape, h, solid, free, corners = _field_and_sheet(axis, offset)
    centres = (np.indices(shape).transpose(1, 2, 3, 0) + 0.5) * h
    grad = np.array([0.7, -1.3, 2.1])
    psi = centres @ grad
    tri = np.array([[0, 1, 2]])
    n = np.cross(corners[1] - corners[0], corners[2] - corners[0])  # 2 A n
    load = coupling.triangle_pressure_loads(corners, tri, psi, solid, free, np.zeros(3), h, 1.0)
    assert np.abs(load).max() < 1e-12 * np.abs(grad).max() * np.linalg.norm(n)
    x = corners.mean(axis=0)[axis]
    step = np.where(centres[..., axis] < x, 3.0, 1.0)  # psi 3 behind +axis, 1 before
    load = coupling.triangle_pressure_loads(corners, tri, step, solid, free, np.zeros(3), h, 1.0)
    np.testing.assert_allclose(load[0], 0.5 * (3.0 - 1.0) * n * np.sign(n[axis]), rtol=1e-12)
    closed = tuple(f.copy() for f in free)
    closed[axis][3, 3, 3] = 0  # the lower face of cell (2, 2, 2), the sheet's lower side
    load = coupling.triangle_pressure_loads(corners, tri, psi, solid, closed, np.zeros(3), h, 1.0)
    near_minus_sheet = grad[axis] * (1.25 - x)  # psi of that cell less psi at the sheet
    expected = 0.5 * near_minus_sheet * n * np.sign(n[axis])
    np.testing.assert_allclose(load[0], expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("mobility", [0.5, 4.0])
def test_membrane_across_a_channel_moves_with_the_flow(mobility):
    """A sheet across the whole channel at rest: the air it blocks must pass at U (volume),
    so the projection carries the sheet's faces at U, and the pressure jump across the
    faces it closes is the one that accelerates the sheet (mass per area rho / mobility)
    from 0 to U in one step, ``(p_- - p_+) / rho = (U - 0) / (dt mobility)``. The loads
    read the pressure at the sheet itself, each side's extrapolated from its two cells
    (:func:`coupling.triangle_pressure_loads`); downstream the advected face next to the
    sheet, which stood still, leaves a step in the pressure one cell wide: they differ
    from the closed faces' jump by at most the two extrapolations (0.35 % and 2.8 %)."""
    spec = box_scene(CHANNEL, [{"type": "uniform", "velocity": [U, 0, 0]}], domain=(4, 2, 2))
    wind = make(spec, 16, coupling="projection")  # h = 0.25
    sheet = _sheet((2.1, -0.01, -0.01), 2.02, mobility=mobility)
    dt = 0.05
    wind.step(dt, sheet)
    u = wind.faces()[0]
    assert np.abs(u - U).max() < 1e-6 * U  # air and sheet at U everywhere
    closed = (wind.psi[7] - wind.psi[8]) * 0.25 / dt  # across the face between x = 1.875, 2.125
    np.testing.assert_allclose(closed, U / (dt * mobility), rtol=1e-6)
    jump = wind.cloth_pressure_loads().sum(axis=0)[0] / 2.02**2  # (p_- - p_+) / rho
    theta = 2.1 / 0.25 - 7.5  # where the sheet lies between the centres of cells 7 and 8
    psi = wind.psi
    reach = theta * np.abs(psi[7] - psi[6]) + (1 - theta) * np.abs(psi[8] - psi[9])
    assert 0 < abs(jump - U / (dt * mobility)) <= reach.max() * 0.25 / dt


def test_air_enclosed_by_closed_faces_is_a_pocket_and_its_rhs_sums_to_zero():
    """A cell whose six faces are closed is a pocket; the cells joined to an outflow are not;
    balancing leaves the pocket's right-hand side with zero sum and the rest untouched."""
    shape = (3, 3, 3)
    free = [
        np.zeros(tuple(s + 2 + (a == b) for b, s in enumerate(shape)), np.uint8) for a in range(3)
    ]
    for a in range(3):
        free[a][1:-1, 1:-1, 1:-1] = 1  # every face open ...
    for a in range(3):  # ... except the six around the centre cell (1, 1, 1)
        for side in (1, 2):
            index = [2, 2, 2]
            index[a] = side + 1
            free[a][tuple(index)] = 0
    solid = np.zeros(shape, np.uint8)
    label, count = coupling.pockets(*free, solid, np.zeros(3, np.bool_))
    assert count == 1 and label[1, 1, 1] == 0
    assert (label >= 0).sum() == 1
    rhs = np.arange(27.0).reshape(shape)
    before = rhs.copy()
    coupling.balance_pockets(rhs, label, count)
    assert rhs[1, 1, 1] == 0.0
    mask = label < 0
    assert np.array_equal(rhs[mask], before[mask])


def _flags_run(tmp_path, mode, resolution, *extra):
    """two_flags_wall with coupling ``mode``: (|F| per recorded step and flag, names,
    each recorded step's largest x of flag_a's vertices)."""
    cfg = compose_config(
        [
            "wind=navier_stokes",
            "scene=two_flags_wall",
            f"wind.coupling={mode}",
            f"grid.resolution={resolution}",
            "sim.progress=false",
            *extra,
        ]
    )
    result = run(cfg, tmp_path / mode)
    assert result.status == "complete", result.failure
    with xr.open_dataset(result.path) as ds:
        force = np.linalg.norm(ds.aero_force.values, axis=-1)  # (time, cloth)
        names = list(ds.cloth.values)
        flag_a = ds.vertex_cloth.values == names.index("flag_a")
        reach = ds.cloth_position.values[:, flag_a, 0].max(axis=1)
    return force, names, reach


@pytest.mark.parametrize("dt", [1 / 60, 0.01])
def test_flags_coupled_through_pressure_stay_finite_and_feel_the_wind(tmp_path, dt):
    """Both flags of two_flags_wall, moving, coupled through pressure for 1 s at 24 cells:
    the run completes and the exposed flag feels at least half the force it feels with the
    paper's coupling."""
    steps = ("sim.spinup=0", "sim.duration=1.0", f"sim.dt={dt}")
    mean = {}
    for mode in ("projection", "paper"):
        force, names, _ = _flags_run(tmp_path, mode, 24, *steps)
        exposed = force[:, names.index("flag_a")]
        mean[mode] = exposed[exposed.size // 2 :].mean()
    assert mean["projection"] >= 0.5 * mean["paper"]


def test_a_flag_coupled_through_pressure_on_a_coarse_grid_flies(tmp_path):
    """two_flags_wall at 32 cells (0.75 m: the 1.5 x 1 m flags lie within a layer of cells
    and close few faces), 2 s of spin-up, then 1.5 s: with the §3 law on the air that passes
    through the cloth (``aero.subgrid_law``, the default) the exposed flag streams from
    its pole, its free end on average beyond 80 % of its length downstream (pole at x = 3 m),
    and feels at least half the force of the paper's coupling. The pressure jump alone
    (``aero.subgrid_law=false``) leaves it hanging by its pole: 0.39 N against the paper
    coupling's 3.56 N in a developed flow at dt 1/60
    (``experiments/results/projection_coupling_jump_only.csv``)."""
    steps = ("sim.spinup=2", "sim.duration=1.5", f"sim.dt={1 / 60}")
    force, names, reach = _flags_run(tmp_path, "projection", 32, *steps)
    late = force.shape[0] // 2
    assert reach[late:].mean() > 3.05 + 0.8 * 1.5
    paper, _, _ = _flags_run(tmp_path, "paper", 32, *steps)
    exposed = names.index("flag_a")
    assert force[late:, exposed].mean() >= 0.5 * paper[late:, exposed].mean()


def test_the_sheltered_flag_coupled_through_pressure_feels_the_walls_lee(tmp_path):
    """two_flags_wall at 32 cells in a uniform 6 m/s, 3 s from rest: behind the wall,
    which stands twice as high as the flag, the sheltered flag feels under a third of the
    force on the exposed one over the last 1.5 s (the paper's coupling: 0.03). The paper's
    removal of the normal velocity in the cut cells is not applied as well: its changing
    set of cells would make the pressure loads noisy (:mod:`windbench.wind.navier_stokes.
    coupling`). In the scene's own log-law wind, developed flow, the ratio is 0.10-0.12 at
    32 and at 64 cells against 0.05 and 0.08-0.095 with one-way coupling and 0.012-0.045
    with the paper's (``experiments/results/projection_coupling.csv``)."""
    uniform = "scene.sources=[{type: uniform, velocity: [6.0, 0.0, 0.0]}]"
    steps = ("sim.spinup=0", "sim.duration=3.0", f"sim.dt={1 / 60}")
    force, names, _ = _flags_run(tmp_path, "projection", 32, uniform, *steps)
    late = force[force.shape[0] // 2 :].mean(axis=0)
    assert late[names.index("flag_b")] < late[names.index("flag_a")] / 3.0


def test_projection_coupling_with_the_second_order_scheme_is_refused():
    spec = box_scene(CHANNEL, [{"type": "uniform", "velocity": [U, 0, 0]}])
    with pytest.raises(ConfigError, match="wind.coupling"):
        make(spec, 8, coupling="projection", advection="second_order")


def test_paper_coupling_removes_the_relative_normal_velocity_beside_marked_cells():
    """In a uniform air velocity U, every face beside one marked cell (normal n, cloth
    velocity v) becomes U_a - ((U - v) . n) n_a; a face between two marked cells uses the
    normalised sum of their normals and the mean of their velocities; other faces keep U."""
    from windbench.wind.navier_stokes.boundaries import padded_shape

    shape, air = (4, 3, 5), np.array([3.0, -1.0, 0.5])
    q = [np.full(padded_shape(shape, a), air[a]) for a in range(3)]
    index = np.full(shape, -1, np.int64)
    index[1, 1, 2], index[2, 1, 2] = 0, 1  # two marked cells, neighbours along x
    normals = np.array([[0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    velocity = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, -1.0]])

    def removed(n, v, a):
        return air[a] - np.dot(air - v, n) * n[a]

    shared = (normals[0] + normals[1]) / np.linalg.norm(normals[0] + normals[1])
    for a in range(3):
        out = np.zeros_like(q[a])
        coupling.remove_normal_component(q[a], a, *q, index, normals, velocity, out)
        expected = np.full(out.shape, air[a])
        for cell, m in (((1, 1, 2), 0), ((2, 1, 2), 1)):
            for side in (0, 1):  # the cell's - and + face of component a (padded indices)
                face = [c + 1 for c in cell]
                face[a] += side
                expected[tuple(face)] = removed(normals[m], velocity[m], a)
        if a == 0:  # the face between the two cells: both at once
            expected[3, 2, 3] = removed(shared, velocity.mean(axis=0), a)
        inner = (slice(1, -1),) * 3
        np.testing.assert_allclose(out[inner], expected[inner], rtol=1e-12)
