"""XPBD cloth solver with small substeps (``cloth.solver=xpbd``, the default).

The paper's cloth system is a finite-element solver [EKS03]; the wind models only need
vertex positions and velocities and hand back per-vertex aerodynamic forces (§3), so any
stable cloth integrator serves them. We use extended position-based dynamics (Macklin,
Mueller, Chentanez 2016) in the small-steps form (Macklin et al. 2019: many substeps, one
constraint pass each): stiffness enters as a compliance alpha = 1/k, so it is stable at
``sim.dt = 1/60 s`` for any stiffness (stiff cloth: alpha -> 0), contacts are position
projections inside each substep. Free fall is the exact symplectic-Euler parabola.

A frame of length dt (:func:`xpbd_frame`), with ``h = dt / cloth.substeps``, does per substep

1. ``v += h (g + f_ext / m)``; ``p = x + h v`` (pinned vertices: inverse mass 0);
2. the constraint projections of :mod:`windbench.cloth.constraints`: ``edge_iterations``
   passes over the stretch threads (the first also over the shear edges), the bending
   hinges, the tethers to the pins;
3. contacts: edges and triangles (:mod:`~windbench.cloth.edge_contact`), then every free
   vertex with Coulomb friction (:mod:`~windbench.cloth.collision`) moved out to
   ``cloth.collision_margin`` from the bodies, and with ``cloth.self_collision`` the
   cloths kept ``cloth.thickness`` apart (:mod:`~windbench.cloth.self_contact`); then up to
   ``cloth.limit_passes`` strain-limit passes (stretch edges at most ``1 + strain_limit``
   times their rest length: a lattice's threads as chains, each pass followed by the
   contacts; an irregular mesh's edges one by one, their contacts after the last pass);
4. ``v = (p - x) / h``; ``x = p``;

and after the last substep 5. the cloth's crossings of itself undone (positions only,
with ``cloth.self_collision``: :func:`~windbench.cloth.self_contact.untangle`), 6.
Rayleigh damping of the constraint rates. Hinges that a step of BEND_EVERY substeps
resolves are projected every BEND_EVERY-th substep with that many substeps' impulse. The
forces are held over the frame: the explicit coupling is stable while ``dt rho_air C_D
|v_rel| / (mass per area) < 2``.

The model (:class:`XPBDModel`: the constraint tables in solve order, contacts, settings)
is fixed at construction; the per-dt constants (:class:`FrameConstants`) and the scratch
live in a :class:`Workspace`; the state (:class:`~windbench.cloth.model.ClothState`:
positions, velocities, frames done, work done) is taken and returned by ``step``.
Divergence: a step raises :class:`~windbench.errors.SimulationDiverged` when positions or
velocities are not finite or when the kinetic energy exceeds ``cloth.energy_limit`` times
the accumulated positive work ``W = sum max(0, sum_i (f_i + m_i g) . dx_i)`` (plus 1 nJ).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
from numba import njit

from windbench.arrays import copy_rows
from windbench.cloth.collision import (
    body_boxes,
    contact_vertex,
    follow_track,
    max_penetration,
    near_a_body,
)
from windbench.cloth.constraints import (
    LIMIT_SLACK,
    damp_velocities,
    edge_stretch,
    hinge_weights,
    limit_edges,
    project_hinges,
    project_shear_edges,
    project_tethers,
    solve_chains,
)
from windbench.cloth.edge_contact import surface_boxes, surface_contacts, surface_penetration
from windbench.cloth.model import ClothModel, ClothState
from windbench.cloth.near_bodies import NearBodies, hold_near, near_bodies
from windbench.cloth.self_contact import (
    SelfContact,
    TreeFit,
    self_contact_model,
    self_contact_substep,
    self_contacts,
    self_intersections,
    tree_fit,
    untangle,
)
from windbench.cloth.topology import build_topology, colour_order, tethers, thread_chains
from windbench.errors import ConfigError, SimulationDiverged
from windbench.geometry.bodies import MOVING, BodyTable, body_table, set_track

BEND_EVERY = 2  # soft hinges are projected every BEND_EVERY-th substep ...
BEND_RESOLVED = 0.04  # ... when (omega BEND_EVERY h)^2 <= this for every hinge
CONTACT_TIMING_EVERY = 10  # frames between two timings of the contact pass (a figure)
MATERIAL_KEYS = ("density", "stretch_stiffness", "shear_stiffness", "bend_stiffness", "damping")
_POSITIVE = {"density", "stretch_stiffness"}  # the others may be 0


class Constraints(NamedTuple):
    """The constraint tables in solve order (:func:`constraint_tables`), fixed."""

    mass: np.ndarray  # (n,) kg
    inv_mass: np.ndarray  # (n,) 1/kg, 0 for pinned vertices
    gravity: np.ndarray  # (3,) m/s^2
    edges: np.ndarray  # (E, 2): stretch edges thread by thread, then shear edges
    edge_rest: np.ndarray  # (E,) m
    edge_compliance: np.ndarray  # (E,) alpha = 1/k, m/N
    edge_damping: np.ndarray  # (E,) c = damping * k, N s/m
    n_stretch: int  # the first n_stretch edges are stretch edges
    n_lattice: int  # the first n_lattice of them belong to lattice cloths
    chain_ptr: np.ndarray  # threads (solve_chains)
    chain_vert: np.ndarray
    n_lattice_chains: int  # the chains of the lattice edges come first
    hinges: np.ndarray  # (H, 4) by colour
    hinge_rest: np.ndarray  # (H,) rad
    hinge_compliance: np.ndarray  # (H,)
    hinge_damping: np.ndarray  # (H,)
    tether_anchor: np.ndarray  # (n,) nearest pin, -1: none
    tether_length: np.ndarray  # (n,) m


class Contacts(NamedTuple):
    """The rigid bodies as the contact kernels read them."""

    bodies: BodyTable
    boxes: np.ndarray  # (m, 6) bounding boxes grown by the margin
    margin: float  # m
    friction: float  # Coulomb coefficient


class Settings(NamedTuple):
    """The ``cloth.*`` counts and limits the frame kernel reads."""

    substeps: int
    edge_iterations: int
    strain_limit: float
    limit_passes: int


class XPBDModel(NamedTuple):
    constraints: Constraints
    contacts: Contacts
    settings: Settings
    self_contact: SelfContact
    surface: Contacts  # ``contacts`` with the boxes of the edge contacts' bodies alone


class FrameConstants(NamedTuple):
    """What depends on the frame length dt (:func:`frame_constants`)."""

    dt: float
    edge_alpha: np.ndarray  # alpha~ = alpha / h^2
    edge_scale: np.ndarray  # 1 / (w_i + w_j + alpha~), 0: the edge cannot move
    hinge_alpha: np.ndarray  # alpha~ / bend_every
    bend_every: int


@njit(cache=True)
def _predict(c, f_ext, h, x, p, v):
    """Step 1: v += h (g + f / m), p = x + h v; pinned vertices stay (v = 0)."""
    for i in range(x.shape[0]):
        if c.inv_mass[i] > 0.0:
            for k in range(3):
                v[i, k] += h * (c.gravity[k] + f_ext[i, k] * c.inv_mass[i])
                p[i, k] = x[i, k] + h * v[i, k]
        else:
            for k in range(3):
                v[i, k] = 0.0
                p[i, k] = x[i, k]


@njit(cache=True)
def _distance_passes(c, frame, iterations, p, lam, chain_work):
    """Step 2a: ``iterations`` passes over the threads, the first also over the shear edges."""
    alpha, scale = frame.edge_alpha, frame.edge_scale
    for it in range(iterations):
        solve_chains(
            p,
            c.inv_mass,
            c.chain_ptr,
            c.chain_vert,
            c.edge_rest,
            alpha,
            scale,
            lam,
            chain_work,
            0.0,
        )
        if it == 0:
            project_shear_edges(p, c.inv_mass, c.edges, c.edge_rest, alpha, scale, lam, c.n_stretch)


@njit(cache=True)
def _hold_near(model, p, near):
    """The parts of the cloth that may touch a body, held at ``p``
    (:func:`~windbench.cloth.near_bodies.hold_near`)."""
    c = model.constraints
    hold_near(
        model.contacts.boxes,
        model.surface.boxes,
        c.inv_mass,
        c.edges,
        model.self_contact.triangles,
        p,
        near,
    )


@njit(cache=True)
def _contacts(model, p, xp, normal, clear, near):
    """Step 3: every free vertex that may touch a body moved out to the margin
    (:func:`~windbench.cloth.collision.contact_vertex`, friction against its motion from
    xp; ``normal`` (3,) work space, ``clear`` the clearances), of those ``near`` holds."""
    _hold_near(model, p, near)
    contacts = model.contacts
    for q in range(near.counts[0]):  # the box test in scalars first: no array views
        i = near.vertices[q]
        if near_a_body(contacts.boxes, p[i, 0], p[i, 1], p[i, 2]):
            contact_vertex(contacts, i, xp[i], p[i], normal, clear)


@njit(cache=True)
def _frame_start(fit, x):
    """The self-contacts' sides at the frame's start ``x`` and their pass count reset (an
    argument: numba leaves the branch out for ``fit`` None)."""
    if fit is not None:
        copy_rows(fit.anchor, x, x.shape[0])
        fit.passes[0] = 0


@njit(cache=True)
def _frame_end(model, fit, p):
    """Step 5 with ``cloth.self_collision`` (whose patch fit ``fit`` is None otherwise):
    the crossings of the cloth with itself at the frame's end positions ``p`` undone
    (:func:`~windbench.cloth.self_contact.untangle`), after the last velocities were taken
    from the positions: a repair of the positions that adds no velocity."""
    if fit is not None:
        untangle(model.self_contact, model.constraints.inv_mass, p, fit)


@njit(cache=True)
def _all_contacts(model, p, xp, normal, clear, near, fit, last):
    """Step 3: the cloth's edges and triangles
    (:func:`~windbench.cloth.edge_contact.surface_contacts`) and its vertices
    (:func:`_contacts`) against the bodies, then the cloth against itself and the other
    cloths (:func:`~windbench.cloth.self_contact.self_contact_substep`, with
    ``cloth.self_collision``, whose patch fit ``fit`` is None otherwise: in the frame's
    ``last`` substep and whenever the cloth moved far enough since the last pass). A layer
    pressed onto a body by another is pushed back by the body first, so that the
    self-contact then lifts the upper layer (which moves it into the body's margin by at
    most the thickness, until the next contact pass)."""
    c = model.constraints
    if model.contacts.bodies.kinds.shape[0] > 0:
        _hold_near(model, p, near)
        tris = model.self_contact.triangles
        surface_contacts(model.surface, c.inv_mass, c.edges, tris, p, clear, near)
        _contacts(model, p, xp, normal, clear, near)
    if fit is not None:  # None without cloth.self_collision: the branch is not compiled
        self_contact_substep(model.self_contact, c.inv_mass, p, xp, fit, last)


@njit(cache=True)
def _contacts_moved(contacts, inv_mass, p, xp, normal, clear, moved):
    """The contacts of step 3 for the vertices flagged in ``moved`` alone (then unflagged)."""
    for i in range(p.shape[0]):
        if moved[i]:
            moved[i] = False
            if inv_mass[i] > 0.0 and near_a_body(contacts.boxes, p[i, 0], p[i, 1], p[i, 2]):
                contact_vertex(contacts, i, xp[i], p[i], normal, clear)


@njit(cache=True)
def _strain_limit(model, frame, p, xp, work, normal):
    """Step 3b: strain-limit passes until every thread and edge keeps the limit (at most
    ``limit_passes``): the threads of lattice cloths as chains
    (:func:`~windbench.cloth.constraints.solve_chains`), all contacts again after each pass
    that moved one; the edges of irregular cloths one by one
    (:func:`~windbench.cloth.constraints.limit_edges`), the contacts of the vertices they
    moved once after the last pass.

    The limit is a projection that the contacts override and that stops after
    ``limit_passes`` passes. On a lattice each pass solves whole threads and the pins'
    tethers carry the load, so it holds. An irregular garment held by the bodies alone (no
    pins) is limited edge by edge, each pass carrying a correction only a few edges far:
    where the wind presses it on the body its largest stretch stays above the limit, by as
    much as ``max_stretch`` and ``over_strain_limit`` (:meth:`XPBDCloth.stretch`) record."""
    c, s = model.constraints, model.settings
    _, lam, chain_work, moved, clear, stamps, near, _ = work
    stamps[1][:] = -1  # every edge is tested in the first pass
    has_bodies = model.contacts.bodies.kinds.shape[0] > 0
    ptr = c.chain_ptr[: c.n_lattice_chains + 1]
    for _ in range(s.limit_passes if s.strain_limit > 0.0 else 0):
        solved = solve_chains(
            p,
            c.inv_mass,
            ptr,
            c.chain_vert,
            c.edge_rest,
            frame.edge_alpha,
            frame.edge_scale,
            lam,
            chain_work,
            s.strain_limit,
        )
        edges = limit_edges(
            p,
            c.inv_mass,
            c.edges,
            c.edge_rest,
            c.n_lattice,
            c.n_stretch,
            s.strain_limit,
            moved,
            stamps,
        )
        if solved + edges == 0:  # every thread and edge kept it: nothing moved
            break
        if has_bodies and solved > 0:  # the contacts again, so that they hold at the end
            _contacts(model, p, xp, normal, clear, near)
    if has_bodies and c.n_stretch > c.n_lattice:
        _contacts_moved(model.contacts, c.inv_mass, p, xp, normal, clear, moved)


@njit(cache=True)
def _frame_figures(c, f_ext, x, p, v):
    """(W, K, finite): the work ``sum_i (f_i + m_i g) . (p_i - x_i)`` (J), the kinetic
    energy ``1/2 sum m v^2`` (J) and whether p and v are finite."""
    work = 0.0
    energy = 0.0
    finite = True
    for i in range(x.shape[0]):
        for k in range(3):
            work += (f_ext[i, k] + c.mass[i] * c.gravity[k]) * (p[i, k] - x[i, k])
            energy += 0.5 * c.mass[i] * v[i, k] * v[i, k]
            finite = finite and math.isfinite(p[i, k]) and math.isfinite(v[i, k])
    return work, energy, finite


@njit(cache=True)
def xpbd_frame(model, frame, x, v, f_ext, out, work):
    """One frame of ``substeps`` XPBD substeps (module docstring, steps 1-6).

    Inputs x, v, f_ext (n, 3); outputs ``out`` = (x_out, v_out); ``work`` = the
    :class:`Workspace` arrays in field order (x scratch (n, 3), multipliers (E,), chain
    scratch (S, 5), strain-limit flags, contact clearances, strain-limit clocks, parts
    near the bodies, patch fit). Returns (W, K, finite) of :func:`_frame_figures` for the
    new state.
    """
    c, s = model.constraints, model.settings
    h = frame.dt / s.substeps
    inv_h = 1.0 / h
    p, vv = out
    xp, lam, chain_work, _, clear, _, near, fit = work
    copy_rows(xp, x, x.shape[0])
    copy_rows(vv, v, v.shape[0])
    normal = np.empty(3)
    _frame_start(fit, x)
    moving = np.any(model.contacts.bodies.params[:, MOVING] != 0.0)
    for sub in range(s.substeps):
        if moving:  # the bodies' poses at the substep's end (collision.follow_track)
            follow_track(model.contacts.bodies, sub, clear[1])
        _predict(c, f_ext, h, xp, p, vv)  # 1.
        lam[:] = 0.0  # XPBD multipliers of the substep
        _distance_passes(c, frame, s.edge_iterations, p, lam, chain_work)  # 2a.
        if (sub + 1) % frame.bend_every == 0:  # 2b. soft bending: every bend_every-th
            project_hinges(p, c.inv_mass, c.hinges, c.hinge_rest, frame.hinge_alpha)
        project_tethers(p, c.inv_mass, c.tether_anchor, c.tether_length)  # 2c.
        _all_contacts(model, p, xp, normal, clear, near, fit, sub == s.substeps - 1)  # 3.
        _strain_limit(model, frame, p, xp, work, normal)  # 3b.
        for i in range(x.shape[0]):  # 4. v = (p - x)/h ; x = p
            for k in range(3):
                vv[i, k] = (p[i, k] - xp[i, k]) * inv_h
                xp[i, k] = p[i, k]
    _frame_end(model, fit, p)  # 5.
    damp_velocities(p, vv, c.inv_mass, c.edges, c.edge_damping, c.hinges, c.hinge_damping, frame.dt)
    return _frame_figures(c, f_ext, x, p, vv)


def _count(params, key: str) -> int:
    """The integer >= 1 at ``cloth.<key>``, or a ConfigError naming the key."""
    value = getattr(params, key)
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(f"cloth.{key}", f"must be an integer >= 1, got {value!r}")
    return value


def _number(value, key: str, positive: bool) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ConfigError(key, f"must be a number, got {value!r}") from None
    if not math.isfinite(x) or x < 0 or (positive and x == 0):
        raise ConfigError(key, f"must be a finite number {'> 0' if positive else '>= 0'}, got {x}")
    return x


@dataclass(frozen=True)
class SolverSettings:
    """The checked ``cloth.*`` values of the XPBD solver (schema: ``ClothConfig``)."""

    substeps: int
    edge_iterations: int
    strain_limit: float
    limit_passes: int
    threads: bool
    gravity: float
    margin: float
    friction: float
    self_collision: bool
    thickness: float
    energy_limit: float

    @classmethod
    def from_params(cls, params) -> SolverSettings:
        """Check every value; ConfigError naming the first bad key."""
        for key in ("threads", "self_collision"):
            if not isinstance(getattr(params, key), bool):
                raise ConfigError(
                    f"cloth.{key}", f"must be true or false, got {getattr(params, key)!r}"
                )
        return cls(
            substeps=_count(params, "substeps"),
            edge_iterations=_count(params, "edge_iterations"),
            strain_limit=_number(params.strain_limit, "cloth.strain_limit", False),
            limit_passes=_count(params, "limit_passes"),
            threads=params.threads,
            gravity=_number(params.gravity, "cloth.gravity", False),
            margin=_number(params.collision_margin, "cloth.collision_margin", False),
            friction=_number(params.friction, "cloth.friction", False),
            self_collision=params.self_collision,
            thickness=_number(params.thickness, "cloth.thickness", True),
            energy_limit=_number(params.energy_limit, "cloth.energy_limit", True),
        )


def cloth_materials(model: ClothModel, params) -> list[dict[str, float]]:
    """Material of each cloth: the mesh's ``material`` dict over ``cloth.material``.

    Keys (SI): density (kg/m^2), stretch_stiffness (N/m), shear_stiffness (N/m),
    bend_stiffness (N m), damping (s). Raises ConfigError naming the faulty key.
    """
    base = {
        key: _number(getattr(params.material, key), f"cloth.material.{key}", key in _POSITIVE)
        for key in MATERIAL_KEYS
    }
    out = []
    for c, mesh in enumerate(model.meshes):
        own = dict(mesh.material or {})
        unknown = set(own) - set(MATERIAL_KEYS)
        if unknown:
            raise ConfigError(
                f"scene.cloths[{c}].material",
                f"unknown key(s) {sorted(unknown)}; allowed {list(MATERIAL_KEYS)}",
            )
        mat = dict(base)
        for key, value in own.items():
            mat[key] = _number(value, f"scene.cloths[{c}].material.{key}", key in _POSITIVE)
        out.append(mat)
    return out


def _compliance(k: np.ndarray) -> np.ndarray:
    """alpha = 1/k (m/N); an infinite stiffness is compliance 0, zero stiffness inf."""
    k = np.asarray(k, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), np.inf)


@dataclass(frozen=True)
class Stiffness:
    """Masses and constraint stiffnesses in mesh order (before the solve order)."""

    mass: np.ndarray
    inv_mass: np.ndarray
    edge_k: np.ndarray  # N/m: k = Y A_e / L^2 (stretch), G L^2 / A_e (shear)
    hinge_k: np.ndarray  # N m / rad^2: k_b = B L^2 / A_e
    edge_damping: np.ndarray  # c = damping * k
    hinge_damping: np.ndarray


def stiffness(model: ClothModel, topo, materials) -> Stiffness:
    """Lumped masses and the stiffness mapping of :mod:`windbench.cloth.topology`."""
    mat = {k: np.array([m[k] for m in materials] or [0.0]) for k in MATERIAL_KEYS}
    vc = model.vertex_cloth
    mass = mat["density"][vc] * topo.vertex_area if vc.size else np.zeros(0)
    inv = np.where(mass > 0, 1.0 / np.where(mass > 0, mass, 1.0), 0.0)
    inv[model.pinned] = 0.0
    ec = model.triangle_cloth[topo.edge_triangle] if topo.edges.size else np.zeros(0, int)
    L, A = topo.edge_length, topo.edge_area
    k_edge = np.where(
        topo.edge_shear,
        mat["shear_stiffness"][ec] * L**2 / A,  # k = G L^2 / A_e
        mat["stretch_stiffness"][ec] * A / L**2,  # k = Y A_e / L^2
    )
    hc = model.triangle_cloth[topo.hinge_triangle] if topo.hinges.size else np.zeros(0, int)
    k_hinge = mat["bend_stiffness"][hc] * topo.hinge_length**2 / topo.hinge_area
    return Stiffness(
        mass, inv, k_edge, k_hinge, mat["damping"][ec] * k_edge, mat["damping"][hc] * k_hinge
    )


class SolveOrder(NamedTuple):
    """Gauss-Seidel order of the constraints (:func:`solve_order`)."""

    edges: np.ndarray  # (E,) lattice stretch, irregular stretch, shear edges
    chain_ptr: np.ndarray  # chains of the stretch edges (solve_chains)
    chain_vert: np.ndarray
    hinges: np.ndarray  # (H,)
    n_stretch: int
    n_lattice: int  # the first n_lattice edges are stretch edges of lattice cloths ...
    n_lattice_chains: int  # ... in this many chains


def edge_chains(rest: np.ndarray, edges: np.ndarray, priority: np.ndarray, threads: bool):
    """(order, ptr, vertices) of :func:`~windbench.cloth.topology.thread_chains`, or with
    ``threads`` false one chain per edge in the given order."""
    if threads:
        return thread_chains(rest, edges, priority)
    n = edges.shape[0]
    vertices = np.empty(2 * n, dtype=np.int64)
    vertices[0::2], vertices[1::2] = edges[:, 0], edges[:, 1]
    return np.arange(n, dtype=np.int64), np.arange(n + 1, dtype=np.int64), vertices


def solve_order(model: ClothModel, topo, path: np.ndarray, threads: bool) -> SolveOrder:
    """Gauss-Seidel order of the edges and hinges.

    Outwards from the pins (``path``: each vertex's edge-path distance to its nearest pin,
    :func:`~windbench.cloth.topology.tethers`), so that one pass carries a pin's hold down
    the cloth; the stretch edges of lattice cloths first, as threads
    (:func:`~windbench.cloth.topology.thread_chains`) or, with ``threads`` false, one chain
    per edge; then the edges of irregular cloths the same way, then the shear edges; within
    a band of equal distance from the pins (one edge length wide) edges and hinges go by
    colour (consecutive constraints share no vertex,
    :func:`~windbench.cloth.topology.colour_order`).
    """
    step = topo.edge_length.min() if topo.edges.size else 1.0
    near_e, near_h = path[topo.edges].min(axis=1), path[topo.hinges].min(axis=1)
    band_e, band_h = (
        np.where(np.isfinite(d), np.round(d / step), -1).astype(np.int64) for d in (near_e, near_h)
    )
    kind = np.where(topo.edge_shear, 2, np.where(topo.edge_lattice, 0, 1))
    edge_order, _ = colour_order(topo.edges, near_e, kind * (band_e.max(initial=0) + 2) + band_e)
    n_lattice = int(np.count_nonzero(kind == 0))
    n_stretch = n_lattice + int(np.count_nonzero(kind == 1))
    orders, ptrs, verts = [], [np.zeros(1, np.int64)], []
    for part in (edge_order[:n_lattice], edge_order[n_lattice:n_stretch]):
        order, ptr, vert = edge_chains(
            model.rest_positions, topo.edges[part], near_e[part], threads
        )
        orders.append(part[order])
        ptrs.append(ptr[1:] + sum(o.size for o in orders[:-1]))
        verts.append(vert)
    return SolveOrder(
        edges=np.concatenate([*orders, edge_order[n_stretch:]]),
        chain_ptr=np.concatenate(ptrs),
        chain_vert=np.concatenate(verts),
        hinges=colour_order(topo.hinges, near_h, band_h)[0],
        n_stretch=n_stretch,
        n_lattice=n_lattice,
        n_lattice_chains=len(ptrs[1]),
    )


def constraint_tables(model: ClothModel, topo, k: Stiffness, settings) -> Constraints:
    """The :class:`Constraints` of ``model`` in solve order (contiguous arrays)."""
    anchor, length, path = tethers(model.rest_positions, topo.edges, model.pinned)
    so = solve_order(model, topo, path, settings.threads)

    def ordered(a, order):
        return np.ascontiguousarray(a[order])

    eo, ho = so.edges, so.hinges
    return Constraints(
        mass=k.mass,
        inv_mass=k.inv_mass,
        gravity=np.array([0.0, 0.0, -settings.gravity]),  # z is up
        edges=ordered(topo.edges, eo),
        edge_rest=ordered(topo.edge_length, eo),
        edge_compliance=ordered(_compliance(k.edge_k), eo),
        edge_damping=ordered(k.edge_damping, eo),
        n_stretch=so.n_stretch,
        n_lattice=so.n_lattice,
        chain_ptr=so.chain_ptr,
        chain_vert=so.chain_vert,
        n_lattice_chains=so.n_lattice_chains,
        hinges=ordered(topo.hinges, ho),
        hinge_rest=ordered(topo.hinge_angle, ho),
        hinge_compliance=ordered(_compliance(k.hinge_k), ho),
        hinge_damping=ordered(k.hinge_damping, ho),
        tether_anchor=anchor,
        tether_length=length,
    )


def frame_constants(model: XPBDModel, hinge_s: np.ndarray, dt: float) -> FrameConstants:
    """alpha~ = alpha / h^2 (h = dt / substeps), the edge scales 1 / (w_i + w_j + alpha~)
    (0 for an edge that cannot move: two pins, or zero stiffness) and the bending rate:
    BEND_EVERY when every hinge's own oscillation is resolved by a step of that many
    substeps, (omega N h)^2 = N^2 S / alpha~ <= BEND_RESOLVED (S: ``hinge_s``, the
    :func:`~windbench.cloth.constraints.hinge_weights` at rest), and the substeps divide
    into such steps; else 1 (every substep)."""
    c, substeps = model.constraints, model.settings.substeps
    inv_h = 1.0 / (dt / substeps)
    with np.errstate(divide="ignore", invalid="ignore"):  # a rigid hinge: never resolved
        omega_h2 = np.where(
            c.hinge_compliance > 0,
            hinge_s / (c.hinge_compliance * inv_h**2),
            np.where(hinge_s > 0, np.inf, 0),
        )
    n = BEND_EVERY
    resolved = omega_h2.size == 0 or n * n * float(np.max(omega_h2)) <= BEND_RESOLVED
    bend_every = n if (resolved and substeps % n == 0) else 1
    e_alpha = c.edge_compliance * (inv_h * inv_h)
    den = c.inv_mass[c.edges[:, 0]] + c.inv_mass[c.edges[:, 1]] + e_alpha
    ok = (den > 0.0) & (den < np.inf)
    e_scale = np.where(ok, 1.0 / np.where(ok, den, 1.0), 0.0)
    h_alpha = c.hinge_compliance * (inv_h * inv_h) / bend_every
    return FrameConstants(float(dt), e_alpha, e_scale, h_alpha, bend_every)


@dataclass
class Workspace:
    """Scratch of the frame kernel and the constants of the last frame length."""

    x: np.ndarray  # (n, 3)
    lam: np.ndarray  # (E,) XPBD multipliers
    chain: np.ndarray  # (n_stretch, 5) Thomas algorithm
    moved: np.ndarray  # (n,) bool: vertices the edge-by-edge strain limit moved
    clear: tuple  # contact clearances: probe (n, 3), clearance (n,)
    stamps: tuple  # the strain limit's clocks (limit_edges): per vertex, per edge, clock (1,)
    near: NearBodies  # the parts of the cloth that may touch a body
    fit: TreeFit | None  # the self-contacts' patch boxes and cones (None: self-collision off)
    frame: FrameConstants | None = None


class XPBDCloth:
    """The XPBD solver (module docstring): ``step(state, forces, dt) -> state``."""

    stats_units = {
        "kinetic_energy": ("kinetic energy of the cloth", "J"),
        "max_penetration": (
            "deepest penetration of a cloth vertex, edge or triangle into a body",
            "m",
        ),
        "self_intersections": ("number of intersecting pairs of cloth triangles", "1"),
        "max_stretch": ("largest relative elongation of a stretch edge", "1"),
        "over_strain_limit": (
            "fraction of stretch edges beyond the strain limit, longer than "
            f"(1 + {1 + LIMIT_SLACK:g} cloth.strain_limit) times their rest length (contacts "
            "override the limit; it stops after cloth.limit_passes passes)",
            "1",
        ),
    }

    @classmethod
    def check(cls, model: ClothModel, params) -> None:
        """ConfigError for a bad ``cloth.*`` value or cloth material, before any work."""
        SolverSettings.from_params(params)
        cloth_materials(model, params)

    def __init__(self, model: ClothModel, bodies, params):
        self.model = model
        self.settings = SolverSettings.from_params(params)
        self.materials = cloth_materials(model, params)
        self.topology = build_topology(model.rest_positions, model.triangles, model.triangle_cloth)
        self.stiffness = k = stiffness(model, self.topology, self.materials)  # mesh order
        self.stretch_edges = ~self.topology.edge_shear
        s = self.settings
        self.bodies = tuple(bodies)
        contacts = Contacts(
            body_table(self.bodies, track=s.substeps + 1),
            body_boxes(self.bodies, s.margin),
            s.margin,
            s.friction,
        )
        rest = np.ascontiguousarray(model.rest_positions, np.float64)
        triangles = np.asarray(model.triangles, dtype=np.int64)
        self.tables = XPBDModel(
            constraint_tables(model, self.topology, k, s),
            contacts,
            Settings(s.substeps, s.edge_iterations, s.strain_limit, s.limit_passes),
            self_contact_model(
                model.rest_positions, model.triangles, s.thickness, numba.get_num_threads()
            ),
            contacts._replace(
                boxes=surface_boxes(contacts.bodies, contacts.boxes, rest, triangles)
            ),
        )
        c = self.tables.constraints
        self._contact_timing = (0, 0.0)  # (calls of contact_seconds, its last measurement)
        self.hinge_s = hinge_weights(rest, c.inv_mass, c.hinges)  # sum_q w_q |grad_q theta|^2
        n_e = self.topology.edges.shape[0]
        self.workspace = Workspace(
            np.empty((model.n_vertices, 3)),
            np.empty(n_e),
            np.empty((c.n_stretch, 5)),
            np.zeros(model.n_vertices, dtype=np.bool_),
            (np.zeros((model.n_vertices, 3)), np.zeros(model.n_vertices)),
            (
                np.full(model.n_vertices, -1, np.int64),
                np.full(n_e, -1, np.int64),
                np.zeros(1, np.int64),
            ),
            near_bodies(model.n_vertices, n_e, self.tables.self_contact.triangles.shape[0]),
            tree_fit(self.tables.self_contact, model.n_vertices) if s.self_collision else None,
        )

    def frame_constants(self, dt: float) -> FrameConstants:
        """The per-dt constants, kept in the workspace for the next frame of that length."""
        if self.workspace.frame is None or self.workspace.frame.dt != dt:
            self.workspace.frame = frame_constants(self.tables, self.hinge_s, dt)
        return self.workspace.frame

    def step(self, state: ClothState, external_forces, dt: float) -> ClothState:
        """Advance all cloths by one frame ``dt`` under gravity and ``external_forces`` (N);
        moving bodies follow their motion from ``state.frames dt`` (frames of equal dt).
        With ``cloth.self_collision`` the first frame starts from positions whose
        crossings with themselves are undone (a mesh made that way; every frame undoes
        them at its end, step 5 of the module docstring)."""
        x = np.ascontiguousarray(state.positions, dtype=np.float64)
        if state.frames == 0 and self.workspace.fit is not None:
            x = x.copy()
            inv_mass = self.tables.constraints.inv_mass
            untangle(self.tables.self_contact, inv_mass, x, self.workspace.fit)
        v = np.ascontiguousarray(state.velocities, dtype=np.float64)
        f = np.ascontiguousarray(external_forces, dtype=np.float64).reshape(x.shape)
        frame = self.frame_constants(float(dt))
        if any(b.motion is not None for b in self.bodies):  # poses over the frame
            t0, subs = state.frames * dt, self.settings.substeps
            set_track(
                self.tables.contacts.bodies, self.bodies, t0 + dt * np.arange(subs + 1) / subs
            )
        out = (np.empty_like(x), np.empty_like(v))
        w = self.workspace
        work, energy, finite = xpbd_frame(
            self.tables,
            frame,
            x,
            v,
            f,
            out,
            (w.x, w.lam, w.chain, w.moved, w.clear, w.stamps, w.near, w.fit),
        )
        frames = state.frames + 1
        if not finite:
            raise SimulationDiverged(frames, "cloth positions or velocities are not finite")
        work_in = state.work_in + max(0.0, work)
        limit = self.settings.energy_limit
        if energy > limit * work_in + 1e-9:
            raise SimulationDiverged(
                frames,
                f"cloth kinetic energy {energy:.4g} J exceeds {limit:g} x the work "
                f"done on it by gravity and wind ({work_in:.4g} J)",
            )
        return ClothState(out[0], out[1], frames, work_in)

    def contact_seconds(self, positions: np.ndarray) -> float:
        """The contacts' share of a frame (wall s, an estimate): one pass of step 3 on a copy
        of ``positions``, timed, the body contacts (:func:`_all_contacts`) times the
        substeps, the self-contacts times the passes of the last frame, and step 5's
        search for crossings. The frame kernel carries no clock, so the figures call this
        apart from the step; to keep the estimate from costing a pass every frame it is
        re-measured every CONTACT_TIMING_EVERY calls and held in between."""
        if self.workspace.fit is None and not self.tables.contacts.bodies.kinds.shape[0]:
            return 0.0
        calls, held = self._contact_timing
        self._contact_timing = (calls + 1, held)
        if calls % CONTACT_TIMING_EVERY:
            return held
        x = np.ascontiguousarray(positions, dtype=np.float64)
        p, clear = x.copy(), tuple(a.copy() for a in self.workspace.clear)
        start = time.perf_counter()
        _all_contacts(self.tables, p, x, np.empty(3), clear, self.workspace.near, None, False)
        held = (time.perf_counter() - start) * self.settings.substeps
        fit = self.workspace.fit
        if fit is not None:
            start = time.perf_counter()
            inv_mass = self.tables.constraints.inv_mass
            self_contacts(self.tables.self_contact, inv_mass, p, x, fit)
            held += (time.perf_counter() - start) * int(fit.passes[0])
            start = time.perf_counter()
            untangle(self.tables.self_contact, inv_mass, p, fit)  # step 5's search
            held += time.perf_counter() - start
        self._contact_timing = (calls + 1, held)
        return held

    def _near_parts(self, x) -> tuple[np.ndarray, np.ndarray] | None:
        """(edge ids, triangle ids) that may touch a body at ``x``, the contacts' held parts
        (:func:`_hold_near`); None without bodies."""
        if not self.tables.contacts.bodies.kinds.shape[0]:
            return None
        near = self.workspace.near
        _hold_near(self.tables, x, near)
        return near.edges[: near.counts[1]], near.triangles[: near.counts[2]]

    def mobility(self) -> np.ndarray:
        """1 / (mass per area) of each vertex (m^2/kg): its lumped area over its mass, 0 for
        a pinned vertex."""
        return self.tables.constraints.inv_mass * self.topology.vertex_area

    def kinetic_energy(self, velocities) -> float:
        """1/2 sum m v^2 (J)."""
        m = self.tables.constraints.mass
        return 0.5 * float(np.sum(m * np.einsum("ij,ij->i", velocities, velocities)))

    def stretch(self, positions) -> tuple[float, float]:
        """(largest relative elongation |x_i - x_j| / L - 1 of a stretch edge (a lattice's
        warp and weft, every edge of an irregular mesh), fraction of the stretch edges longer
        than the strain limit lets them be, ``(1 + (1 + LIMIT_SLACK) cloth.strain_limit) L``)."""
        c = self.tables.constraints
        if c.n_stretch == 0:
            return 0.0, 0.0
        x = np.ascontiguousarray(positions, np.float64)
        top, over = edge_stretch(
            x, c.edges[: c.n_stretch], c.edge_rest, (1.0 + LIMIT_SLACK) * self.settings.strain_limit
        )
        return float(top), over / c.n_stretch

    def max_stretch(self, positions) -> float:
        """The largest relative elongation of a stretch edge (:meth:`stretch`)."""
        return self.stretch(positions)[0]

    def stats(self, state: ClothState) -> dict[str, float]:
        """Figures recorded per step: kinetic energy (J), deepest body penetration of a
        vertex, edge or triangle (m), largest stretch of a stretch edge and the fraction
        beyond the strain limit, intersecting triangle pairs, and the CPU seconds of the
        last step's contacts (a phase of ``step_seconds``)."""
        bodies, boxes, _, _ = self.tables.contacts
        thin = self.tables.surface.boxes
        c, sc = self.tables.constraints, self.tables.self_contact
        top, over = self.stretch(state.positions)
        x = np.ascontiguousarray(state.positions, dtype=np.float64)
        return {
            "kinetic_energy": self.kinetic_energy(state.velocities),
            "max_penetration": max(
                max_penetration(bodies, boxes, x),
                surface_penetration(
                    bodies, thin, x, c.edges, sc.triangles, c.inv_mass, self._near_parts(x)
                ),
            ),
            "max_stretch": top,
            "over_strain_limit": over,
            "self_intersections": self_intersections(sc, state.positions),
            "contacts_seconds": self.contact_seconds(state.positions),
        }
