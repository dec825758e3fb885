"""XPBD cloth solver with small substeps (``cloth.solver=xpbd``, the default).

The paper's cloth system is a finite-element solver [EKS03]; any stable cloth integrator
serves the wind models, which only need vertex positions and velocities and hand back
per-vertex aerodynamic forces (§3). Of the three stable choices (backward-Euler
mass-spring with CG, projective dynamics with a prefactored matrix, XPBD) we use
**extended position-based dynamics** (Macklin, Mueller, Chentanez 2016) in the
**small-steps** form (Macklin et al. 2019: many substeps, one constraint pass each), because

- it is unconditionally stable at ``sim.dt = 1/60 s`` for any stiffness: stiffness enters
  as a compliance ``alpha = 1/k`` and stiff cloth is the limit ``alpha -> 0``, so stiff
  cloth hangs with little stretch (tested: under 5%) without the heavy artificial damping
  of one backward-Euler step and without rebuilding a factorisation when pins or contacts
  change;
- contacts with the rigid bodies are position projections inside each substep, so a
  vertex never ends a step inside a body (projective dynamics would need contact terms in
  its prefactored matrix, CG a constraint filter);
- the kernels are plain loops over edges and hinges (numba, no sparse algebra, one
  compiled signature); their cost is linear in the mesh size and recorded by
  ``experiments/bench_cloth.py`` (see *Cost* below);
- small substeps make the time integration converge: with zero stiffness work the
  free fall of a cloth is the exact symplectic-Euler parabola, which tends to
  ``1/2 g t^2`` as the substep shrinks (tested).

Per frame of length dt, with ``h = dt / cloth.substeps``, each substep does

1. ``v += h (g + f_ext / m)``; ``p = x + h v`` (pinned vertices: inverse mass 0, p = x);
2. Gauss-Seidel passes over the constraints (stiffness mapping in
   :mod:`windbench.cloth.topology`): ``cloth.edge_iterations`` passes over the stretch edges,
   thread by thread (*Threads* below; the first pass then also over the shear edges, one by
   one), one over the dihedral bending hinges (soft bending: every other substep, see
   *Multi-rate bending* below), each
   ``dlambda = (-C - alpha~ lambda) / (sum_k w_k |grad_k C|^2 + alpha~)``,
   ``p_k += w_k dlambda grad_k C`` with ``alpha~ = 1 / (k h^2)``; then the long-range
   attachments (tethers, Kim et al. 2012): a vertex may not be farther from its nearest pin
   than in the rest shape, which keeps a hanging cloth from sagging through the slow
   propagation of Gauss-Seidel along long threads;
3. contacts: every free vertex is moved out to ``cloth.collision_margin`` from the bodies,
   with Coulomb friction (:mod:`windbench.cloth.collision`); then the strain limit
   (*Strain limiting* below): passes over the threads that shorten every warp/weft edge
   longer than ``(1 + cloth.strain_limit) L``, each followed by the contacts again, until
   no thread needs one (at most ``cloth.limit_passes``);
4. ``v = (p - x) / h``; ``x = p``;

and after the last substep, 5. stiffness-proportional (Rayleigh) damping with time constant
``damping`` (s): each constraint's rate dC/dt is damped implicitly with coefficient
``damping * k`` (:func:`damp_velocities`); it acts on velocities only, so it damps
deformation but not rigid motion, and leaves static equilibria where they are.

Accuracy. One pass per substep reproduces a constraint's stiffness k once the substep
resolves it, ``alpha~ >> w |grad C|^2`` (``h << sqrt(m / k)`` per vertex); stiffer
constraints act as inextensible ones. Real cloth is stiff in stretch (inextensible here:
less than 5% stretch hanging, tested, with the strain limit's help on fine meshes) and
soft in bending (1e-6..1e-4 N m, resolved).
Measured: the static sag of a stiff cantilever strip (B = 0.01 N m, 2 cm cells) lies 4%
above the discrete beam at 512 substeps (a slow test), 8% at 128, 23% at 64. Low bending
modes are damped mainly by the air (aero.py); the per-constraint damping of step 5 is one
Gauss-Seidel pass and reaches mostly the short wavelengths.

Threads. The stretch edges are stiff (alpha~ a hundredth of the vertex weights w), and
edge-by-edge Gauss-Seidel carries a load about one edge per pass: at the default 8
substeps x 4 passes a 40 x 25 flag hanging from its pole in still air had its top edge 11%
long next to the pole, a 64 x 64 one 23%, flags in 6 m/s wind 5 / 7 / 11% (median of the
largest edge strain at 40x25 / 64x64 / 100x60); 16 substeps fixed 40 x 25 at 1.7x the cost,
over-relaxation and alternating sweeps did not fix the finer meshes. So the stretch edges
are decomposed into threads (:func:`~windbench.cloth.topology.thread_chains`: simple paths
of straightest continuation, the warp and weft threads of a flag, the hoops and lines of
the shirt's tubes) and each pass solves every thread's linearised XPBD system exactly
(:func:`solve_chains`, line Gauss-Seidel: a tridiagonal system, Thomas algorithm, O(n);
cf. Deul et al. 2018, direct solver for rods): one pass carries the pull of a pin along the
whole thread. Threads of one direction share no vertex, so a pass is block Gauss-Seidel
with two blocks (warp, weft) instead of one block per edge. ``cloth.threads=false`` makes
every edge a chain of its own (the edge-by-edge sweep, for comparison). A thread's forward
elimination is one chain of dependent divisions, so a pass costs more than the
colour-ordered edge sweep, whose independent edges the processor overlaps; but two passes
over the threads hold the stretch better than four edge passes did, so the default is
``cloth.edge_iterations=2``. Measured (``experiments/bench_cloth.py --stretch``, 4 s runs,
defaults without the strain limit below; the tables are in ``experiments/README.md``):
flags in 6 m/s wind 0.9 / 2.0 /
2.6% median largest edge strain at 40x25 / 64x64 / 100x60 (edge by edge, 4 passes: 5.0 /
7.2 / 11%), the 40 x 25 flag hanging from its pole 1.6% (was 11-12%), at 3.0 / 12.7 /
16.1 ms a frame (edge by edge, 4 passes: 2.8 / 10.1 / 17.4 ms). The threads alone do not
hold the hanging 64 x 64 and 100 x 60 flags (26% and 30% at the end of 4 s): see below.

Strain limiting. On fine meshes the shear resistance saturates at 8 substeps: one
projection of a shear edge per substep exerts no more than its vertices' inertia allows
(``k h^2 (w_i + w_j)`` is about 4 at 40 x 25, 16-23 on the finer flags) and the thread pass
after it undoes most of it (10 frames into the fall the cells next to the pole of the
64 x 64 flag shear by 29 / 15 / 10 / 9.4 degrees for G = 0 / 5 / 50 / 500 N/m; 2.6 degrees
for G = 50 with 32 substeps). A flag hanging from its pole in still air then collapses in
plane near the pole, and at the top corner each substep's shear projection throws the
top-row vertices farther than two thread passes pull back: 26% (64 x 64) and 30%
(100 x 60) stretch at the end of 4 s; ``experiments/hang_cloth.py`` and
``experiments/README.md`` give the diagnosis and the changes tried. Converging it costs
far more than the frame budget (32 substeps: 4.9% and 8.1% at four times the cost). So,
as production cloth solvers do (Provot 1995, deformation constraints; Bridson, Fedkiw and
Anderson 2002; Goldenthal et al. 2007, inextensible cloth), the stretch is limited: after
the contacts, the threads are solved again in limit mode (:func:`solve_chains` with
``limit``): only the edges longer than ``(1 + cloth.strain_limit) L`` are constraints,
rigid, brought to that length, the others free; the contacts follow each pass, so that they
still hold at the end of the substep. A thread is solved only while one of its edges is
longer than ``(1 + 1.1 cloth.strain_limit) L`` (``LIMIT_SLACK``), so the threads of a
hanging flag that sit at the limit are not solved pass after pass; the passes stop when no
thread needs one (at most ``cloth.limit_passes``). Positions move, and step 4 turns the
moves into velocities, as for every constraint. Woven fabric is itself stiff beyond a few
per cent of strain; ``cloth.strain_limit=0`` turns the limit off (an elastic fabric then
stretches as its stiffness says). Measured (``experiments/bench_cloth.py --stretch``,
defaults, 3% limit): largest warp/weft strain of the flag hanging from its pole, end of
4 s (max over 2-4 s), 1.8% (1.8%) / 3.3% (3.3%) / 3.3% (3.8%) at 40 x 25 / 64 x 64 /
100 x 60; in 6 m/s wind median 1.0 / 2.0 / 2.5%, max 3.2 / 3.3 / 3.3% (without the limit
9.4% and 8.2% at single instants on the fine flags). Cost (CPU time of the whole
simulation step, A/B in one process, minimum): in wind 2.09 -> 2.22, 10.2 -> 10.5,
15.2 -> 15.4 ms a frame; hanging in still air, where the limit works in every substep,
10.3 -> 14.7 ms at 64 x 64 and 15.3 -> 24.6 ms at 100 x 60. The active set is a threshold:
two flags whose rounding differs by 1e-12 can take different limit passes (the two flags of
``two_flags_wall`` in the global wind: forces 8e-5 apart).

Multi-rate bending. The hinge pass is about half of a frame, and soft fabric bends far
slower than a substep: a hinge's own oscillation, omega^2 = k_b sum_q w_q |grad_q theta|^2
(:func:`hinge_weights`), has omega h = 0.04 on the 30 x 20 default flag and 0.07 on the
40 x 25 one at 1e-5 N m. When every hinge has omega BEND_EVERY h <= 0.2 (more than 30
bending steps per period of the stiffest hinge) and the substeps divide by BEND_EVERY,
the hinges are projected every BEND_EVERY-th substep with compliance alpha~ / BEND_EVERY,
the impulse of that many substeps (:meth:`XPBDCloth._bend_every`). Tested against the
cantilever statics above with a strip that qualifies (5 x 2 cells, 512 substeps); a
frame of the 40 x 25 flag's solver went from 2.1 to 1.6 ms (one core, CPU time, the
same state stepped 200 times, minimum). Finer meshes (64 x 64: omega 2 h = 0.63) and stiff
strips keep one pass per substep.

The external forces (the aerodynamic forces of ``aero.py``, paper §3) are held constant
over the substeps of one frame: the wind is sampled once per frame. This explicit coupling
is stable while ``dt rho_air C_D |v_rel| / (mass per area) < 2``: 0.94 for the default flag
fabric (0.15 kg/m^2) in 6 m/s wind at dt = 1/60 s; much lighter cloth or stronger wind
needs a shorter ``sim.dt``.

Cost. A frame is one call of :func:`xpbd_frame` (all substeps, contacts, damping, the work
and energy of the divergence check), serial (the meshes are small and the machine's cores
shared), with no allocation per frame: the substep constants alpha~ = alpha / h^2 are
computed once per ``dt`` and the work space is kept by the solver. Measured on the 40 x 25
flag with the edge sweep (8 substeps, 4 edge passes), the hinge pass was about half the
frame (one fast atan2 per hinge), the edge passes a third. Three orderings, fixed with the model, cut it without
changing what is computed: contacts are tested only for vertices inside a body's bounding
box grown by the margin (:func:`~windbench.cloth.collision.near_a_body`: the same contacts,
bit for bit; the pole's cylinder cost a quarter of the frame before); the threads go by
their distance from the pins, shear edges and hinges by colour within each band of equal
distance from the pins (:func:`~windbench.cloth.topology.colour_order`): consecutive constraints then share no
vertex and the processor overlaps them instead of waiting for each result, while the
sweep still runs outwards from the pins band by band (the stretch of hanging and flying
cloth stays within a few per cent of the pin-ordered sweep, measured).

Divergence. The kinetic energy can never exceed the work done on the cloth by gravity and
the external forces (the constraints store or dissipate energy, the bodies do not move). A
step raises :class:`~windbench.errors.SimulationDiverged` when positions or velocities are
not finite or when the kinetic energy exceeds ``cloth.energy_limit`` times the accumulated
positive work ``W = sum_steps max(0, sum_i (f_i + m_i g) . dx_i)`` (plus 1 nJ).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numba import njit

from windbench.cloth.collision import body_boxes, max_penetration, near_a_body, project_vertex
from windbench.cloth.model import ClothModel, ClothState
from windbench.cloth.topology import build_topology, colour_order, tethers, thread_chains
from windbench.errors import ConfigError, SimulationDiverged
from windbench.geometry.bodies import body_table

# Bending hinges whose own oscillation a step of BEND_EVERY substeps resolves,
# omega BEND_EVERY h <= 0.2 (more than 30 bending steps per period of the stiffest hinge),
# are projected every BEND_EVERY-th substep with the impulse of that many substeps
# (compliance alpha~ / BEND_EVERY). The hinge pass is about half of a frame: the default
# fabric (1e-5 N m) qualifies on the 30 x 20 and 40 x 25 flags (omega 2 h = 0.08, 0.14),
# not on finer meshes (64 x 64: 0.63) or stiff strips.
BEND_EVERY = 2
BEND_RESOLVED = 0.04  # (omega BEND_EVERY h)^2
MATERIAL_KEYS = ("density", "stretch_stiffness", "shear_stiffness", "bend_stiffness", "damping")
_POSITIVE = {"density", "stretch_stiffness"}  # the others may be 0


@njit(cache=True, inline="always")
def fast_atan2(y, x):
    """atan2(y, x) from the polynomial of Abramowitz & Stegun 4.4.49 (|error| <= 2e-8 rad).

    atan(a) = a (1 + sum_k c_k a^2k) on [0, 1] with a = min/max of |x|, |y|, then the octant
    symmetries; about three times cheaper than the libm call in the hinge loop. The
    polynomial is evaluated by Estrin's scheme (powers s^2, s^4 computed beside the pairs)
    rather than Horner's: the same terms in a third of the dependent multiply-adds.
    """
    ax, ay = abs(x), abs(y)
    mx = max(ax, ay)
    if mx == 0.0:
        return 0.0
    a = min(ax, ay) / mx
    s = a * a
    s2 = s * s
    s4 = s2 * s2
    q0 = (1.0 - 0.3333314528 * s) + s2 * (0.1999355085 - 0.1420889944 * s)
    q1 = (0.1065626393 - 0.0752896400 * s) + s2 * (0.0429096138 - 0.0161657367 * s)
    r = a * (q0 + s4 * (q1 + s4 * 0.0028662257))
    if ay > ax:
        r = 0.5 * math.pi - r
    if x < 0.0:
        r = math.pi - r
    if y < 0.0:
        r = -r
    return r


@njit(cache=True, inline="always")
def _wrap_angle(a):
    """a mapped to (-pi, pi]."""
    while a > math.pi:
        a -= 2.0 * math.pi
    while a <= -math.pi:
        a += 2.0 * math.pi
    return a


@njit(cache=True, inline="always")
def hinge_gradient(p, i0, i1, i2, i3, grad):
    """Gradient ``grad`` (4, 3) of the dihedral angle of hinge (x0, x1 | x2, x3) = p[i0..i3].

    theta = atan2((nA x nB) . e^, nA . nB), e = x1 - x0, nA = e x (x2 - x0),
    nB = (x0 - x1) x (x3 - x1); d theta/d x2 = -|e| nA/|nA|^2, d theta/d x3 = -|e| nB/|nB|^2,
    the edge vertices share them by the projections of x2, x3 on the edge (Bridson et al.
    2003), so the gradient sums to zero. Returns False (grad untouched) for a degenerate
    hinge.
    """
    ex, ey, ez = p[i1, 0] - p[i0, 0], p[i1, 1] - p[i0, 1], p[i1, 2] - p[i0, 2]
    el2 = ex * ex + ey * ey + ez * ez
    ax, ay, az = p[i2, 0] - p[i0, 0], p[i2, 1] - p[i0, 1], p[i2, 2] - p[i0, 2]
    bx, by, bz = p[i3, 0] - p[i1, 0], p[i3, 1] - p[i1, 1], p[i3, 2] - p[i1, 2]
    # nA = e x a ; nB = (-e) x b
    nax, nay, naz = ey * az - ez * ay, ez * ax - ex * az, ex * ay - ey * ax
    nbx, nby, nbz = -(ey * bz - ez * by), -(ez * bx - ex * bz), -(ex * by - ey * bx)
    na2 = nax * nax + nay * nay + naz * naz
    nb2 = nbx * nbx + nby * nby + nbz * nbz
    if not (el2 > 0.0 and na2 > 1e-30 * el2 * el2 and nb2 > 1e-30 * el2 * el2):
        return False
    el = math.sqrt(el2)
    sa, sb = -el / na2, -el / nb2
    alpha2 = (ax * ex + ay * ey + az * ez) / el2
    alpha3 = ((bx + ex) * ex + (by + ey) * ey + (bz + ez) * ez) / el2
    grad[2, 0], grad[2, 1], grad[2, 2] = sa * nax, sa * nay, sa * naz
    grad[3, 0], grad[3, 1], grad[3, 2] = sb * nbx, sb * nby, sb * nbz
    for k in range(3):
        grad[0, k] = -(1.0 - alpha2) * grad[2, k] - (1.0 - alpha3) * grad[3, k]
        grad[1, k] = -alpha2 * grad[2, k] - alpha3 * grad[3, k]
    return True


@njit(cache=True)
def hinge_weights(x, inv_mass, hinges):
    """S_b = sum_q w_q |grad_q theta_b|^2 of every hinge at positions x (0 if degenerate):
    with alpha~ its compliance over h^2, S / alpha~ = (omega h)^2 of the hinge's own
    oscillation, i.e. how far one substep is from resolving it."""
    out = np.zeros(hinges.shape[0])
    grad = np.empty((4, 3))
    for b in range(hinges.shape[0]):
        if hinge_gradient(x, hinges[b, 0], hinges[b, 1], hinges[b, 2], hinges[b, 3], grad):
            acc = 0.0
            for q in range(4):
                w = inv_mass[hinges[b, q]]
                acc += w * (grad[q, 0] ** 2 + grad[q, 1] ** 2 + grad[q, 2] ** 2)
            out[b] = acc
    return out


@njit(cache=True, inline="always")
def project_hinge(p, inv_mass, i0, i1, i2, i3, rest, alpha):
    """One XPBD projection of the bending hinge (i0, i1 | i2, i3) of rest angle ``rest``.

    C = theta - theta_0 with the gradient of :func:`hinge_gradient` written out in
    scalars: g2 = -|e| nA/|nA|^2, g3 = -|e| nB/|nB|^2, g0 = -(1-a2) g2 - (1-a3) g3,
    g1 = -a2 g2 - a3 g3 (a = projection of the opposite vertex on the edge);
    dlambda = -C / (sum w |g|^2 + alpha~)  (lambda starts at 0: one pass per substep).
    Five divisions (one in the atan2) and one square root per hinge.
    """
    w0, w1, w2, w3 = inv_mass[i0], inv_mass[i1], inv_mass[i2], inv_mass[i3]
    if w0 + w1 + w2 + w3 == 0.0:
        return
    ex, ey, ez = p[i1, 0] - p[i0, 0], p[i1, 1] - p[i0, 1], p[i1, 2] - p[i0, 2]
    el2 = ex * ex + ey * ey + ez * ez
    ax, ay, az = p[i2, 0] - p[i0, 0], p[i2, 1] - p[i0, 1], p[i2, 2] - p[i0, 2]
    bx, by, bz = p[i3, 0] - p[i1, 0], p[i3, 1] - p[i1, 1], p[i3, 2] - p[i1, 2]
    nax, nay, naz = ey * az - ez * ay, ez * ax - ex * az, ex * ay - ey * ax
    nbx, nby, nbz = ez * by - ey * bz, ex * bz - ez * bx, ey * bx - ex * by
    na2 = nax * nax + nay * nay + naz * naz
    nb2 = nbx * nbx + nby * nby + nbz * nbz
    tiny = 1e-30 * el2 * el2
    if el2 == 0.0 or na2 <= tiny or nb2 <= tiny:
        return
    el = math.sqrt(el2)
    cx = nay * nbz - naz * nby
    cy = naz * nbx - nax * nbz
    cz = nax * nby - nay * nbx
    nab = nax * nbx + nay * nby + naz * nbz
    # theta = atan2((nA x nB) . e / |e|, nA . nB) = atan2((nA x nB) . e, |e| nA . nB)
    c = _wrap_angle(fast_atan2(cx * ex + cy * ey + cz * ez, el * nab) - rest)
    inv_el2, inv_na2, inv_nb2 = 1.0 / el2, 1.0 / na2, 1.0 / nb2
    a2 = (ax * ex + ay * ey + az * ez) * inv_el2
    a3 = ((bx + ex) * ex + (by + ey) * ey + (bz + ez) * ez) * inv_el2
    sa, sb = -el * inv_na2, -el * inv_nb2
    # sum_q w_q |g_q|^2 with |g2|^2 = el2/na2, |g3|^2 = el2/nb2, g2.g3 = sa sb nA.nB
    q22, q33, q23 = el2 * inv_na2, el2 * inv_nb2, sa * sb * nab
    b0, b1 = 1.0 - a2, 1.0 - a3
    wsum = (
        w0 * (b0 * b0 * q22 + b1 * b1 * q33 + 2.0 * b0 * b1 * q23)
        + w1 * (a2 * a2 * q22 + a3 * a3 * q33 + 2.0 * a2 * a3 * q23)
        + w2 * q22
        + w3 * q33
    )
    denom = wsum + alpha
    if denom == 0.0 or denom == np.inf:
        return
    dl = -c / denom
    # p_q += w_q dlambda g_q, with g2 = sa nA, g3 = sb nB
    da, db = dl * sa, dl * sb
    f0a, f0b, f1a, f1b = w0 * b0 * da, w0 * b1 * db, w1 * a2 * da, w1 * a3 * db
    f2, f3 = w2 * da, w3 * db
    p[i0, 0] -= f0a * nax + f0b * nbx
    p[i0, 1] -= f0a * nay + f0b * nby
    p[i0, 2] -= f0a * naz + f0b * nbz
    p[i1, 0] -= f1a * nax + f1b * nbx
    p[i1, 1] -= f1a * nay + f1b * nby
    p[i1, 2] -= f1a * naz + f1b * nbz
    p[i2, 0] += f2 * nax
    p[i2, 1] += f2 * nay
    p[i2, 2] += f2 * naz
    p[i3, 0] += f3 * nbx
    p[i3, 1] += f3 * nby
    p[i3, 2] += f3 * nbz


# Strain limiting (module docstring): a thread is solved again only when one of its edges
# is longer than (1 + (1 + LIMIT_SLACK) strain_limit) L, and then its edges longer than
# (1 + strain_limit) L are brought to that length. Without the slack, the threads of a
# hanging flag that sit at the limit were solved pass after pass (100x60 flag hanging from
# its pole: 57 instead of 21 ms a frame with 32 passes, 3.0% against 3.3% largest strain).
LIMIT_SLACK = 0.1


@njit(cache=True)
def solve_chains(p, inv_mass, chain_ptr, chain_vert, rest, alpha, scale, lam, work, limit=0.0):
    """One direct XPBD solve of each chain of distance constraints, in place.

    Chain c (``chain_ptr``, ``chain_vert`` of :func:`~windbench.cloth.topology.thread_chains`)
    is the path v_0 .. v_m of its edges e_k = (v_k, v_k+1), C_k = |p_v(k+1) - p_v(k)| - L_k,
    grad C_k = +-n_k (n_k the unit edge direction). The linearised XPBD system of the chain,
    ``(J W J^T + alpha~) dlambda = -C - alpha~ lambda``, is tridiagonal: diagonal
    ``w_k + w_k+1 + alpha~_k``, off-diagonal ``-w_v(k+1) n_k . n_k+1`` between consecutive
    edges; the Thomas algorithm solves it exactly in O(m) (no pivoting: the matrix is
    diagonally dominant), then ``p_v += w_v sum_k dlambda_k grad_v C_k``. An edge with
    ``scale`` 0 (two pins, zero stiffness) or zero length is an identity row (dlambda 0).
    A chain of one edge is the plain XPBD edge projection. ``work`` (E, 5): n, c', r'.

    With ``limit`` > 0 it is the strain limit instead (module docstring, *Strain
    limiting*): only the edges longer than (1 + limit) L_k are constraints, C_k =
    |p_v(k+1) - p_v(k)| - (1 + limit) L_k with no compliance and no multiplier (``alpha``
    and ``lam`` unread), the others identity rows, and a chain without such an edge is
    skipped. Returns how many chains it solved in that mode (0 otherwise).
    """
    solved = 0
    trigger = 1.0 + (1.0 + LIMIT_SLACK) * limit  # a chain is solved above this stretch
    trigger2 = trigger * trigger
    for c in range(chain_ptr.shape[0] - 1):
        e0, e1 = chain_ptr[c], chain_ptr[c + 1]
        if limit > 0.0:  # strain limit: skip the chains that keep it
            over = False
            for e in range(e0, e1):
                a, b = chain_vert[e + c], chain_vert[e + c + 1]
                dx, dy, dz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
                over |= scale[e] != 0.0 and dx * dx + dy * dy + dz * dz > trigger2 * rest[e] ** 2
            if not over:
                continue
            solved += 1
        inv_den = 0.0  # 1 / pivot of the previous row
        for e in range(e0, e1):  # forward elimination
            a, b = chain_vert[e + c], chain_vert[e + c + 1]
            dx, dy, dz = p[b, 0] - p[a, 0], p[b, 1] - p[a, 1], p[b, 2] - p[a, 2]
            ln = math.sqrt(dx * dx + dy * dy + dz * dz)
            target = rest[e] * (1.0 + limit)
            if scale[e] == 0.0 or ln == 0.0 or (limit > 0.0 and ln <= target):
                work[e, 0] = work[e, 1] = work[e, 2] = 0.0  # an identity row
                diag, rhs = 1.0, 0.0
            else:
                inv_ln = 1.0 / ln
                work[e, 0], work[e, 1], work[e, 2] = dx * inv_ln, dy * inv_ln, dz * inv_ln
                if limit > 0.0:  # -C, rigid
                    diag, rhs = inv_mass[a] + inv_mass[b], target - ln
                else:  # -C - alpha~ lambda
                    diag = inv_mass[a] + inv_mass[b] + alpha[e]
                    rhs = rest[e] - ln - alpha[e] * lam[e]
            if e > e0:  # off-diagonal -w_a n_(k-1) . n_k with the previous edge
                off = -inv_mass[a] * (
                    work[e - 1, 0] * work[e, 0]
                    + work[e - 1, 1] * work[e, 1]
                    + work[e - 1, 2] * work[e, 2]
                )
                cp = off * inv_den  # c'_(k-1)
                work[e - 1, 3] = cp
                diag -= off * cp
                rhs -= off * work[e - 1, 4]
            inv_den = 1.0 / diag
            work[e, 4] = rhs * inv_den  # r'_k
        dl = 0.0
        for e in range(e1 - 1, e0 - 1, -1):  # back substitution and the position update
            dl = work[e, 4] if e == e1 - 1 else work[e, 4] - work[e, 3] * dl
            if limit == 0.0:
                lam[e] += dl
            a, b = chain_vert[e + c], chain_vert[e + c + 1]
            sa, sb = inv_mass[a] * dl, inv_mass[b] * dl
            for k in range(3):
                p[b, k] += sb * work[e, k]
                p[a, k] -= sa * work[e, k]
    return solved


@njit(cache=True)
def damp_velocities(x, v, inv_mass, edges, edge_c, hinges, hinge_c, dt):
    """Stiffness-proportional (Rayleigh) damping of the frame's velocities, in place.

    For each constraint C with damping coefficient c = damping * k, the rate dC/dt = g . v
    (g = grad C) is reduced implicitly over dt, dC/dt' = dC/dt / (1 + dt c S), S = sum w |g|^2,
    by the impulse v_q += w_q g_q (dC/dt' - dC/dt) / S. Rigid motions have dC/dt = 0, so
    they are never damped, and a cloth at rest (v = 0) is left exactly where it is.
    """
    grad = np.empty((4, 3))
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        s_w = inv_mass[i] + inv_mass[j]
        if edge_c[e] == 0.0 or s_w == 0.0:
            continue
        dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        ln = math.sqrt(dx * dx + dy * dy + dz * dz)
        if ln == 0.0:
            continue
        nx, ny, nz = dx / ln, dy / ln, dz / ln
        rate = nx * (v[i, 0] - v[j, 0]) + ny * (v[i, 1] - v[j, 1]) + nz * (v[i, 2] - v[j, 2])
        k = dt * edge_c[e] * s_w
        d = -rate * k / (1.0 + k) / s_w
        v[i, 0] += inv_mass[i] * d * nx
        v[i, 1] += inv_mass[i] * d * ny
        v[i, 2] += inv_mass[i] * d * nz
        v[j, 0] -= inv_mass[j] * d * nx
        v[j, 1] -= inv_mass[j] * d * ny
        v[j, 2] -= inv_mass[j] * d * nz
    for b in range(hinges.shape[0]):
        if hinge_c[b] == 0.0:
            continue
        if not hinge_gradient(x, hinges[b, 0], hinges[b, 1], hinges[b, 2], hinges[b, 3], grad):
            continue
        rate = 0.0
        s_w = 0.0
        for q in range(4):
            w = inv_mass[hinges[b, q]]
            for c in range(3):
                rate += grad[q, c] * v[hinges[b, q], c]
                s_w += w * grad[q, c] * grad[q, c]
        if s_w == 0.0:
            continue
        k = dt * hinge_c[b] * s_w
        d = -rate * k / (1.0 + k) / s_w
        for q in range(4):
            w = inv_mass[hinges[b, q]]
            for c in range(3):
                v[hinges[b, q], c] += w * d * grad[q, c]


@njit(cache=True)
def xpbd_frame(
    x,
    v,
    f_ext,
    mass,
    inv_mass,
    gravity,
    edges,
    edge_rest,
    edge_alpha,
    edge_scale,
    edge_damping,
    n_stretch,
    chain_ptr,
    chain_vert,
    hinges,
    hinge_rest,
    hinge_alpha,
    hinge_damping,
    bend_every,
    tether_anchor,
    tether_length,
    body_kinds,
    body_params,
    body_boxes,
    margin,
    friction,
    dt,
    substeps,
    edge_iterations,
    strain_limit,
    limit_passes,
    x_out,
    v_out,
    scratch_x,
    scratch_lambda,
    scratch_chain,
):
    """One frame of ``substeps`` XPBD substeps (module docstring, steps 1-5), one call.

    Inputs x, v, f_ext (n, 3), mass and inv_mass (n,), gravity (3,); edge_alpha and
    hinge_alpha the compliances over h^2 (alpha~), edge_scale = 1 / (w_i + w_j + alpha~)
    (0: skip the edge) (:meth:`XPBDCloth.substep_constants`); edge_damping and
    hinge_damping the damping coefficients c = damping * k; body_boxes the bodies'
    bounding boxes grown by the margin (:func:`windbench.cloth.collision.body_boxes`).
    Outputs x_out, v_out; scratch_x (n, 3) and scratch_lambda (E,) are work space.
    Returns (W, K, finite): the work ``sum_i (f_i + m_i g) . (x_out_i - x_i)`` (J), the
    kinetic energy ``1/2 sum m v^2`` (J) of v_out, and whether x_out, v_out are finite.
    """
    n = x.shape[0]
    h = dt / substeps
    inv_h = 1.0 / h
    xp = scratch_x
    xp[:] = x
    p = x_out
    vv = v_out
    vv[:] = v
    normal = np.empty(3)
    has_bodies = body_kinds.shape[0] > 0
    n_e = edges.shape[0]
    lam = scratch_lambda  # XPBD multipliers of the substep
    for sub in range(substeps):
        for i in range(n):  # 1. v += h a, a = g + f/m ; p = x + h v
            if inv_mass[i] > 0.0:
                for k in range(3):
                    vv[i, k] += h * (gravity[k] + f_ext[i, k] * inv_mass[i])
                    p[i, k] = xp[i, k] + h * vv[i, k]
            else:
                for k in range(3):
                    vv[i, k] = 0.0
                    p[i, k] = xp[i, k]
        lam[:] = 0.0
        for it in range(edge_iterations):  # 2a. C = |p_i - p_j| - L
            # the stretch edges thread by thread, each thread solved directly
            solve_chains(
                p,
                inv_mass,
                chain_ptr,
                chain_vert,
                edge_rest,
                edge_alpha,
                edge_scale,
                lam,
                scratch_chain,
            )
            if it > 0:
                continue
            for e in range(n_stretch, n_e):  # the first pass also the shear edges, one by one
                if edge_scale[e] == 0.0:
                    continue
                i, j = edges[e, 0], edges[e, 1]
                dx, dy, dz = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
                ln = math.sqrt(dx * dx + dy * dy + dz * dz)
                if ln == 0.0:
                    continue
                inv_ln = 1.0 / ln
                # dlambda = (-C - alpha~ lambda) / (w_i + w_j + alpha~)
                dl = (edge_rest[e] - ln - edge_alpha[e] * lam[e]) * edge_scale[e]
                lam[e] += dl
                si, sj = inv_mass[i] * dl * inv_ln, inv_mass[j] * dl * inv_ln
                p[i, 0] += si * dx
                p[i, 1] += si * dy
                p[i, 2] += si * dz
                p[j, 0] -= sj * dx
                p[j, 1] -= sj * dy
                p[j, 2] -= sj * dz
        bend = (sub + 1) % bend_every == 0  # soft bending: every bend_every-th substep
        for b in range(hinges.shape[0] if bend else 0):  # 2b. C = theta - theta_0
            project_hinge(
                p,
                inv_mass,
                hinges[b, 0],
                hinges[b, 1],
                hinges[b, 2],
                hinges[b, 3],
                hinge_rest[b],
                hinge_alpha[b],
            )
        for i in range(n):  # 2c. long-range attachment: |p_i - x_anchor| <= L_i
            a = tether_anchor[i]
            if a < 0 or inv_mass[i] == 0.0:
                continue
            dx, dy, dz = p[i, 0] - p[a, 0], p[i, 1] - p[a, 1], p[i, 2] - p[a, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > tether_length[i] * tether_length[i]:
                s = tether_length[i] / math.sqrt(d2)
                p[i, 0] = p[a, 0] + s * dx
                p[i, 1] = p[a, 1] + s * dy
                p[i, 2] = p[a, 2] + s * dz
        if has_bodies:  # 3. contacts, for vertices inside a body's grown bounding box
            _contacts(
                p, xp, inv_mass, body_kinds, body_params, body_boxes, margin, friction, normal
            )
        for _ in range(limit_passes if strain_limit > 0.0 else 0):  # 3b. strain limit
            solved = solve_chains(
                p,
                inv_mass,
                chain_ptr,
                chain_vert,
                edge_rest,
                edge_alpha,
                edge_scale,
                lam,
                scratch_chain,
                strain_limit,
            )
            if solved == 0:  # every thread kept it: nothing moved
                break
            if has_bodies:  # the contacts again, so that they hold at the end
                _contacts(
                    p, xp, inv_mass, body_kinds, body_params, body_boxes, margin, friction, normal
                )
        for i in range(n):  # 4. v = (p - x)/h ; x = p
            for k in range(3):
                vv[i, k] = (p[i, k] - xp[i, k]) * inv_h
                xp[i, k] = p[i, k]
    damp_velocities(p, vv, inv_mass, edges, edge_damping, hinges, hinge_damping, dt)  # 5.
    work = 0.0
    energy = 0.0
    finite = True
    for i in range(n):
        for k in range(3):
            work += (f_ext[i, k] + mass[i] * gravity[k]) * (p[i, k] - x[i, k])
            energy += 0.5 * mass[i] * vv[i, k] * vv[i, k]
            finite = finite and math.isfinite(p[i, k]) and math.isfinite(vv[i, k])
    return work, energy, finite


@njit(cache=True, inline="always")
def _contacts(p, xp, inv_mass, body_kinds, body_params, body_boxes, margin, friction, normal):
    """Step 3: every free vertex inside a body's grown bounding box moved out to the margin
    (:func:`~windbench.cloth.collision.project_vertex`, friction against its motion from xp;
    ``normal`` (3,) work space)."""
    for i in range(p.shape[0]):
        if inv_mass[i] > 0.0 and near_a_body(body_boxes, p[i, 0], p[i, 1], p[i, 2]):
            project_vertex(body_kinds, body_params, margin, friction, xp[i], p[i], normal)


@njit(cache=True)
def max_edge_stretch(x, edges, rest):
    """max_e |x_i - x_j| / L_e - 1 over the edges (i, j) of ``edges`` (as many as ``rest``)."""
    top = -np.inf
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        top = max(top, math.sqrt(dx * dx + dy * dy + dz * dz) / rest[e] - 1.0)
    return top


def _param(params, key, default=None):
    if params is None:
        return default
    if isinstance(params, Mapping):
        return params.get(key, default)
    return getattr(params, key, default)


def _count(params, key: str, default: int) -> int:
    """The integer >= 1 at ``cloth.<key>``, or a ConfigError naming the key."""
    value = _param(params, key, default)
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


def cloth_materials(model: ClothModel, params) -> list[dict[str, float]]:
    """Material of each cloth: the mesh's ``material`` dict over ``cloth.material`` defaults.

    Keys (SI): density (kg/m^2), stretch_stiffness (N/m), shear_stiffness (N/m),
    bend_stiffness (N m), damping (s). Raises ConfigError naming the faulty key.
    """
    defaults = _param(params, "material", None)
    base = {}
    for key in MATERIAL_KEYS:
        value = _param(defaults, key, None)
        if value is None:
            raise ConfigError(f"cloth.material.{key}", "is required (SI units)")
        base[key] = _number(value, f"cloth.material.{key}", key in _POSITIVE)
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


class XPBDCloth:
    """The XPBD solver (module docstring). Model: topology, masses, compliances; fixed."""

    stats_units = {
        "kinetic_energy": ("kinetic energy of the cloth", "J"),
        "max_penetration": ("deepest penetration of a cloth vertex into a body", "m"),
        "max_stretch": ("largest relative elongation of a warp/weft edge", "1"),
    }

    def __init__(self, model: ClothModel, bodies, params):
        self.model = model
        self.substeps = _count(params, "substeps", 8)
        self.edge_iterations = _count(params, "edge_iterations", 2)
        self.strain_limit = _number(
            _param(params, "strain_limit", 0.03), "cloth.strain_limit", False
        )
        self.limit_passes = _count(params, "limit_passes", 32)
        threads = _param(params, "threads", True)
        if not isinstance(threads, bool):
            raise ConfigError("cloth.threads", f"must be true or false, got {threads!r}")
        self.threads = threads
        g = _number(_param(params, "gravity", 9.81), "cloth.gravity", False)
        self.gravity = np.array([0.0, 0.0, -g])  # z is up
        self.margin = _number(
            _param(params, "collision_margin", 0.005), "cloth.collision_margin", False
        )
        self.friction = _number(_param(params, "friction", 0.3), "cloth.friction", False)
        self.energy_limit = _number(
            _param(params, "energy_limit", 10.0), "cloth.energy_limit", True
        )
        self.materials = cloth_materials(model, params)
        self.body_kinds, self.body_params = body_table(tuple(bodies))

        topo = build_topology(model.rest_positions, model.triangles)
        self.topology = topo
        mat = {k: np.array([m[k] for m in self.materials] or [0.0]) for k in MATERIAL_KEYS}
        vc = model.vertex_cloth
        self.mass = mat["density"][vc] * topo.vertex_area if vc.size else np.zeros(0)
        inv = np.where(self.mass > 0, 1.0 / np.where(self.mass > 0, self.mass, 1.0), 0.0)
        inv[model.pinned] = 0.0
        self.inv_mass = inv
        ec = model.triangle_cloth[topo.edge_triangle] if topo.edges.size else np.zeros(0, int)
        L, A = topo.edge_length, topo.edge_area
        k_edge = np.where(
            topo.edge_shear,
            mat["shear_stiffness"][ec] * L**2 / A,  # k = G L^2 / A_e
            mat["stretch_stiffness"][ec] * A / L**2,  # k = Y A_e / L^2
        )
        self.edge_compliance = _compliance(k_edge)
        self.edge_damping = mat["damping"][ec] * k_edge  # c = damping * k, N s/m
        hc = model.triangle_cloth[topo.hinge_triangle] if topo.hinges.size else np.zeros(0, int)
        k_hinge = mat["bend_stiffness"][hc] * topo.hinge_length**2 / topo.hinge_area
        self.hinge_compliance = _compliance(k_hinge)
        self.hinge_damping = mat["damping"][hc] * k_hinge  # N m s/rad
        self.stretch_edges = ~topo.edge_shear
        self.tether_anchor, self.tether_length, path = tethers(
            model.rest_positions, topo.edges, model.pinned
        )
        # Gauss-Seidel order: outwards from the pins, so that one pass carries a pin's hold
        # down the cloth (measured: less stretch than mesh order at the same cost); stretch
        # edges first (then put in thread order below). Within a band of equal
        # distance from the pins (one edge length wide) edges and hinges go by colour
        # (colour_order): a third faster edge sweeps, the same stretch (measured: hanging
        # 16x16 cloth 1.41% both, 32x32 6.35% vs 6.40%; flags in wind within +-4%).
        step = topo.edge_length.min() if topo.edges.size else 1.0
        near_e, near_h = path[topo.edges].min(axis=1), path[topo.hinges].min(axis=1)
        band_e, band_h = (
            np.where(np.isfinite(d), np.round(d / step), -1).astype(np.int64)
            for d in (near_e, near_h)
        )
        self.edge_order, _ = colour_order(
            topo.edges, near_e, topo.edge_shear * (band_e.max(initial=0) + 2) + band_e
        )
        self.n_stretch = int(np.count_nonzero(~topo.edge_shear))
        stretch = self.edge_order[: self.n_stretch]
        if self.threads:  # the stretch edges thread by thread (solve_chains), pins first
            order, self.chain_ptr, self.chain_vert = thread_chains(
                model.rest_positions, topo.edges[stretch], near_e[stretch]
            )
            self.edge_order = np.concatenate([stretch[order], self.edge_order[self.n_stretch :]])
        else:  # every stretch edge a chain of its own: edge-by-edge Gauss-Seidel
            self.chain_ptr = np.arange(self.n_stretch + 1, dtype=np.int64)
            self.chain_vert = np.empty(2 * self.n_stretch, dtype=np.int64)
            self.chain_vert[0::2] = topo.edges[stretch, 0]
            self.chain_vert[1::2] = topo.edges[stretch, 1]
        self.hinge_order, _ = colour_order(topo.hinges, near_h, band_h)
        eo, ho = self.edge_order, self.hinge_order
        self._edge_arrays = tuple(
            np.ascontiguousarray(a[eo])
            for a in (topo.edges, topo.edge_length, self.edge_compliance, self.edge_damping)
        )
        self._hinge_arrays = tuple(
            np.ascontiguousarray(a[ho])
            for a in (topo.hinges, topo.hinge_angle, self.hinge_compliance, self.hinge_damping)
        )
        self.body_boxes = body_boxes(tuple(bodies), self.margin)
        self._constants_dt = None  # substep_constants cache
        # soft bending every bend_every-th substep (_bend_every; set per dt)
        self._hinge_weights = hinge_weights(
            np.ascontiguousarray(model.rest_positions, np.float64),
            self.inv_mass,
            self._hinge_arrays[0],
        )
        self.bend_every = 1
        self._scratch_x = np.empty((model.n_vertices, 3))  # work space of xpbd_frame
        self._scratch_lambda = np.empty(topo.edges.shape[0])
        self._scratch_chain = np.empty((self.n_stretch, 5))
        self.steps = 0
        self.work_in = 0.0  # accumulated positive work of gravity and external forces, J

    def _bend_every(self, inv_h: float) -> int:
        """BEND_EVERY when every hinge's own oscillation is resolved by a step of that many
        substeps, (omega N h)^2 = N^2 S / alpha~ <= BEND_RESOLVED (S: :func:`hinge_weights`
        at rest), and the substeps divide into such steps; else 1 (every substep)."""
        n = BEND_EVERY
        compliance = self._hinge_arrays[2]
        weights = self._hinge_weights
        with np.errstate(divide="ignore", invalid="ignore"):  # a rigid hinge: never resolved
            omega_h2 = np.where(
                compliance > 0, weights / (compliance * inv_h**2), np.where(weights > 0, np.inf, 0)
            )
        resolved = omega_h2.size == 0 or n * n * float(np.max(omega_h2)) <= BEND_RESOLVED
        return n if (resolved and self.substeps % n == 0) else 1

    def substep_constants(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(edge alpha~, edge scale, hinge alpha~) for frames of length ``dt``, cached.

        alpha~ = alpha / h^2 with h = dt / substeps; scale = 1 / (w_i + w_j + alpha~), 0 for
        an edge that cannot move (two pins) or has zero stiffness (alpha~ infinite).
        """
        if self._constants_dt != dt:
            inv_h = 1.0 / (dt / self.substeps)
            self.bend_every = self._bend_every(inv_h)
            edges, _, e_compliance, _ = self._edge_arrays
            e_alpha = e_compliance * (inv_h * inv_h)
            den = self.inv_mass[edges[:, 0]] + self.inv_mass[edges[:, 1]] + e_alpha
            ok = (den > 0.0) & (den < np.inf)
            e_scale = np.where(ok, 1.0 / np.where(ok, den, 1.0), 0.0)
            # bending every bend_every-th substep with the impulse of bend_every substeps
            h_alpha = self._hinge_arrays[2] * (inv_h * inv_h) / self.bend_every
            self._constants = (e_alpha, e_scale, h_alpha)
            self._constants_dt = dt
        return self._constants

    def step(self, state: ClothState, external_forces, dt: float) -> ClothState:
        """Advance all cloths by one frame ``dt`` under gravity and ``external_forces`` (N)."""
        self.steps += 1
        x = np.ascontiguousarray(state.positions, dtype=np.float64)
        v = np.ascontiguousarray(state.velocities, dtype=np.float64)
        f = np.ascontiguousarray(external_forces, dtype=np.float64).reshape(x.shape)
        e_alpha, e_scale, h_alpha = self.substep_constants(float(dt))
        edges, edge_rest, _, edge_damping = self._edge_arrays
        hinges, hinge_rest, _, hinge_damping = self._hinge_arrays
        x_new = np.empty_like(x)
        v_new = np.empty_like(v)
        work, energy, finite = xpbd_frame(
            x,
            v,
            f,
            self.mass,
            self.inv_mass,
            self.gravity,
            edges,
            edge_rest,
            e_alpha,
            e_scale,
            edge_damping,
            self.n_stretch,
            self.chain_ptr,
            self.chain_vert,
            hinges,
            hinge_rest,
            h_alpha,
            hinge_damping,
            self.bend_every,
            self.tether_anchor,
            self.tether_length,
            self.body_kinds,
            self.body_params,
            self.body_boxes,
            self.margin,
            self.friction,
            float(dt),
            self.substeps,
            self.edge_iterations,
            self.strain_limit,
            self.limit_passes,
            x_new,
            v_new,
            self._scratch_x,
            self._scratch_lambda,
            self._scratch_chain,
        )
        if not finite:
            raise SimulationDiverged(self.steps, "cloth positions or velocities are not finite")
        self.work_in += max(0.0, work)
        bound = self.energy_limit * self.work_in + 1e-9
        if energy > bound:
            raise SimulationDiverged(
                self.steps,
                f"cloth kinetic energy {energy:.4g} J exceeds {self.energy_limit:g} x the work "
                f"done on it by gravity and wind ({self.work_in:.4g} J)",
            )
        return ClothState(x_new, v_new)

    def kinetic_energy(self, velocities) -> float:
        """1/2 sum m v^2 (J)."""
        return 0.5 * float(np.sum(self.mass * np.einsum("ij,ij->i", velocities, velocities)))

    def max_stretch(self, positions) -> float:
        """Largest relative elongation of a stretch (warp/weft) edge, |x_i - x_j| / L - 1."""
        edges, rest = self._edge_arrays[0][: self.n_stretch], self._edge_arrays[1]
        if edges.shape[0] == 0:
            return 0.0
        return float(max_edge_stretch(np.ascontiguousarray(positions, np.float64), edges, rest))

    def stats(self, state: ClothState) -> dict[str, float]:
        """Figures recorded per step: kinetic energy (J), deepest body penetration (m),
        largest stretch of a warp/weft edge (relative)."""
        return {
            "kinetic_energy": self.kinetic_energy(state.velocities),
            "max_penetration": max_penetration(
                self.body_kinds, self.body_params, self.body_boxes, state.positions
            ),
            "max_stretch": self.max_stretch(state.positions),
        }


def _compliance(k: np.ndarray) -> np.ndarray:
    """alpha = 1/k (m/N); an infinite stiffness is compliance 0, zero stiffness inf."""
    k = np.asarray(k, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), np.inf)
