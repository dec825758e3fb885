"""The near wake of the mixing lee: the separation bubble behind a ground-mounted box and
the turbulence its shear layer makes, both tied to the obstacle.

Particles of a source carry its wind and cannot turn back, so alone they fill the space
behind a wall with forward air where the flow separates and recirculates. As in the
diagnostic urban wind models after Röckle (1990; QUIC-URB, Brown et al. 2013), each box of
height H, depth L and width W standing on the floor gets a cavity behind its lee face, the
quarter ellipse (s / L_R)^2 + (z / H)^2 < 1 (s along the wind from the lee face, z up),
its length after Fackrell (1984, J. Wind Eng. Ind. Aerodyn. 16, 97),

    L_R / H = 1.8 (W / H) / ((L / H)^0.3 (1 + 0.24 W / H))   (2-D limit: 7.5 (L/H)^-0.3),

W taken twice across a wall or periodic face it touches, unbounded if it touches both; the
cavity is kappa H tall (``wind.recirculation_height``, Röckle's kappa = 1 by default). The
outer flow goes around the cavity as around a body (a particle that ends a step in it is
mirrored out across its nearest edge, top or side, never along the wind, so its flux
passes around) and the cells add the closed eddy of the stream function (xi = s / L_R,
h(xi) = kappa H sqrt(1 - xi^2), U_H the sources' undisturbed speed at the obstacle's top,
beta its backflow ratio, m ``wind.recirculation_exponent``)

    psi = -beta U_H z P(xi) (1 - (z/h)^m)^2,   P = (27/4) xi (1 - xi)^2,
    u_s = d psi/dz = -beta U_H P (1 - (z/h)^m)(1 - (2m + 1)(z/h)^m),   w = -d psi/ds:

divergence-free, no net flux through any plane across the wind (psi = 0 on the floor, the
lee face and the cavity's edge), backflow beta U_H at the floor a third of the way along,
up to z = (2m + 1)^(-1/m) h (m = 2: h / sqrt(5)), a forward return flow above it. Behind
fences backflows reach 0.2-0.3 of the outer speed (Castro and Fackrell 1978, J. Ind.
Aerodyn. 3, 1), in the second-order Navier-Stokes references here 0.44 (wall) and 0.53
(fence) at 0.3 m. beta = 0.4 (``wind.recirculation_backflow``) is fitted to them, the least
lee error against each of 0.2-0.5 (``experiments/results/lee_mixing_backflow.csv``).

The shear layer that leaves the obstacle's top mixes the wake: a free shear flow has an
eddy viscosity of about c U_s delta, c ~ 0.01-0.07 (Pope 2000, Turbulent Flows, §5.4-5.5),
with U_s ~ U_H and delta ~ H here, so the walk's K gains

    K_w = c U_H H G(s / L_R) Z(z) Y(n),   G(x) = x e^(1 - x) (x > 0),

largest at reattachment, decaying downstream; Z = 1 below H and exp(-((z - H)/H)^2) above;
Y = 1 across the obstacle's width (n across the wind), exp(-(d/H)^2) at a distance d beyond
it. The walk's drift takes grad K_w, so the well-mixed condition still holds.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from windbench.geometry.bodies import BOX
from windbench.wind.primitives import profile_factor

GROUND_SLACK = 1e-9  # m: a box this close to the domain's floor stands on it
CLOSED_SIDES = ("slip", "no_slip", "periodic")  # side faces that mirror or repeat a wake
CX, CY, DX, DY, HALF_DEPTH, N_LO, N_HI, TOP, SPEED, LENGTH = range(10)
BACKFLOW, MIXING, EXPONENT, CAVITY = range(10, 14)
N_WAKE = 14  # columns of a wake row
P_PEAK = 27.0 / 4.0  # P(1/3) = 1


class Eddy(NamedTuple):
    """The near wake's settings (module docstring), the same for every box."""

    backflow: float  # beta: backflow at the floor over U_H
    mixing: float  # c of the shear layer's K_w = c U_H H
    exponent: float  # m of the eddy's profile (1 - (z/h)^m)^2
    height: float  # kappa: the cavity's height over the box's


def fackrell_length(height: float, depth: float, width: float) -> float:
    """L_R (m): Fackrell's (1984) cavity length behind a block (module docstring)."""
    shape = (depth / height) ** 0.3
    if not np.isfinite(width):
        return height * 1.8 / (0.24 * shape)
    ratio = width / height
    return height * 1.8 * ratio / (shape * (1.0 + 0.24 * ratio))


def wind_direction(sources) -> np.ndarray | None:
    """Unit horizontal direction of the sum of the sources' winds (None if it is calm)."""
    total = np.sum([np.asarray(s.velocity, float) for s in sources], axis=0)
    horizontal = np.array([total[0], total[1], 0.0])
    norm = float(np.linalg.norm(horizontal))
    return horizontal / norm if norm > 0 else None


def speed_at(sources, height: float) -> float:
    """U_H (m/s): the undisturbed horizontal speed of the sources' sum at ``height``."""
    total = np.zeros(3)
    for s in sources:
        total += np.asarray(s.velocity, float) * float(profile_factor(s.row(), height))
    return float(np.hypot(total[0], total[1]))


def lateral_span(lo, hi, d, scene) -> tuple[float, float, float]:
    """(n_lo, n_hi, W) of a box [lo, hi] across the wind d (n = p . (-d_y, d_x)): a side
    it shares with a wall or periodic face reaches on (infinite), W doubles per such side."""
    across = np.array([-d[1], d[0]])
    corners = [np.dot(across, (x, y)) for x in (lo[0], hi[0]) for y in (lo[1], hi[1])]
    n_lo, n_hi = min(corners), max(corners)
    width = n_hi - n_lo
    axis = 1 if abs(d[0]) == 1.0 else 0 if abs(d[1]) == 1.0 else -1
    if axis < 0:
        return n_lo, n_hi, width
    name, sign = "xy"[axis], across[axis]
    at_min = lo[axis] <= scene.lower[axis] + GROUND_SLACK and scene.boundary[f"{name}_min"]
    at_max = hi[axis] >= scene.upper[axis] - GROUND_SLACK and scene.boundary[f"{name}_max"]
    closed_lo = (at_min if sign > 0 else at_max) in CLOSED_SIDES
    closed_hi = (at_max if sign > 0 else at_min) in CLOSED_SIDES
    if closed_lo and closed_hi:
        return -np.inf, np.inf, np.inf
    if closed_lo or closed_hi:
        width *= 2.0
    return (-np.inf if closed_lo else n_lo), (np.inf if closed_hi else n_hi), width


def wake_rows(scene, lower, eddy: Eddy):
    """(n_wakes, N_WAKE) rows of the boxes standing on the floor (module docstring): lee
    face centre, wind direction, half depth, lateral span, H, U_H, L_R, beta, c, m and
    the cavity's height kappa H."""
    d = wind_direction(scene.sources)
    rows = []
    for body in scene.bodies if d is not None else ():
        lo, hi = body.bounds()
        if body.kind_id != BOX or not body.resolve or lo[2] > lower[2] + GROUND_SLACK:
            continue
        top = float(hi[2] - lower[2])
        centre = 0.5 * (lo + hi)
        half_depth = 0.5 * (abs(d[0]) * (hi[0] - lo[0]) + abs(d[1]) * (hi[1] - lo[1]))
        n_lo, n_hi, width = lateral_span(lo, hi, d, scene)
        length = fackrell_length(top, 2.0 * half_depth, width)
        speed = speed_at(scene.sources, float(hi[2]))
        rows.append(
            (centre[0], centre[1], d[0], d[1], half_depth, n_lo, n_hi, top, speed, length)
            + (eddy.backflow, eddy.mixing, eddy.exponent, eddy.height * top)
        )
    return np.array(rows, dtype=np.float64).reshape(len(rows), N_WAKE)


@njit(cache=True, inline="always")
def _frame(row, p, lower_z):
    """(s, z, n) of p in a wake's frame: along the wind from the lee face, up from the
    floor, across the wind (n = p . (-d_y, d_x), as the span's bounds)."""
    s = (p[0] - row[CX]) * row[DX] + (p[1] - row[CY]) * row[DY] - row[HALF_DEPTH]
    return s, p[2] - lower_z, -p[0] * row[DY] + p[1] * row[DX]


@njit(cache=True, inline="always")
def _across(row, n):
    """(Y, dY/dn): 1 across the obstacle, a Gaussian of width H beyond its sides."""
    beyond = max(row[N_LO] - n, n - row[N_HI], 0.0)
    if beyond == 0.0:
        return 1.0, 0.0
    h = row[TOP]
    y = np.exp(-((beyond / h) ** 2))
    sign = -1.0 if n < row[N_LO] else 1.0
    return y, sign * (-2.0 * beyond / (h * h)) * y


@njit(cache=True)
def wake_diffusivity(wakes, p, lower_z):
    """(K_w, dK_w/dx, dK_w/dy, dK_w/dz) (m^2/s, m/s) at p: the sum over the wakes."""
    k, gx, gy, gz = 0.0, 0.0, 0.0, 0.0
    for w in range(wakes.shape[0]):
        row = wakes[w]
        s, z, n = _frame(row, p, lower_z)
        if s <= 0.0 or row[MIXING] == 0.0:
            continue
        x = s / row[LENGTH]
        g, dg = x * np.exp(1.0 - x), (1.0 - x) * np.exp(1.0 - x) / row[LENGTH]
        h = row[TOP]
        vz, dvz = 1.0, 0.0
        if z > h:
            vz = np.exp(-(((z - h) / h) ** 2))
            dvz = -2.0 * (z - h) / (h * h) * vz
        y, dy = _across(row, n)
        scale = row[MIXING] * row[SPEED] * h
        ds, dn = scale * dg * vz * y, scale * g * vz * dy
        k += scale * g * vz * y
        gx += ds * row[DX] - dn * row[DY]
        gy += ds * row[DY] + dn * row[DX]
        gz += scale * g * dvz * y
    return k, gx, gy, gz


@njit(cache=True, inline="always")
def _in_cavity(row, s, z, n):
    """(xi, (z / h(xi))^2) if (s, z, n) lies in the wake's cavity, else (-1, 0)."""
    if n < row[N_LO] or n > row[N_HI] or s <= 0.0 or z <= 0.0:
        return -1.0, 0.0
    xi = s / row[LENGTH]
    if xi >= 1.0:
        return -1.0, 0.0
    t = z * z / (row[CAVITY] * row[CAVITY] * (1.0 - xi * xi))
    return (xi, t) if t < 1.0 else (-1.0, 0.0)


@njit(cache=True)
def in_cavity(wakes, p, lower_z):
    """Whether p lies in some wake's cavity."""
    for k in range(wakes.shape[0]):
        s, z, n = _frame(wakes[k], p, lower_z)
        if _in_cavity(wakes[k], s, z, n)[0] >= 0.0:
            return True
    return False


@njit(cache=True, inline="always")
def _cavity_point(row, p, lower_z):
    """(s, z, n) of p in the wake's frame (:func:`_frame`) and where it lies in the
    cavity, (xi, t) of :func:`_in_cavity` (xi < 0: outside)."""
    s, z, n = _frame(row, p, lower_z)
    xi, t = _in_cavity(row, s, z, n)
    return s, z, n, xi, t


@njit(cache=True)
def leave_cavity(wakes, p, lower_z):
    """p mirrored out of the cavity it lies in across its nearest edge, the top (z <- 2 h(xi)
    - z) or a side of the span (n <- 2 n_side - n): a reflecting edge that moves no
    particle along the wind, so the flux it carries is kept; p if it lies in none."""
    for k in range(wakes.shape[0]):
        row = wakes[k]
        s, z, n, xi, t = _cavity_point(row, p, lower_z)
        if xi < 0.0:
            continue
        up = row[CAVITY] * np.sqrt(1.0 - xi * xi) - z
        side = min(n - row[N_LO], row[N_HI] - n)
        if up <= side:
            return (p[0], p[1], p[2] + 2.0 * up)
        shift = -2.0 * side if n - row[N_LO] < row[N_HI] - n else 2.0 * side
        return (p[0] - shift * row[DY], p[1] + shift * row[DX], p[2])
    return p


@njit(cache=True)
def eddy_wind(wakes, p, lower_z):
    """(u, v, w) (m/s) of the wakes' recirculating eddies at p (module docstring)."""
    u, v, w = 0.0, 0.0, 0.0
    for k in range(wakes.shape[0]):
        row = wakes[k]
        s, z, n, xi, t = _cavity_point(row, p, lower_z)
        if xi < 0.0:
            continue
        amp = -row[BACKFLOW] * row[SPEED]
        m = row[EXPONENT]
        tm = t ** (0.5 * m)  # (z / h)^m
        shape = P_PEAK * xi * (1.0 - xi) ** 2
        slope = P_PEAK * (1.0 - xi) * (1.0 - 3.0 * xi)  # dP/dxi
        # d/dxi of psi / (amp z) = P (1 - tm)^2, d tm/dxi = m tm xi / (1 - xi^2)
        growth = P_PEAK * xi * (1.0 - xi) / (1.0 + xi) * m * tm * xi  # P dtm/dxi
        along = amp * shape * (1.0 - tm) * (1.0 - (2.0 * m + 1.0) * tm)
        up = -amp * z * (1.0 - tm) * (slope * (1.0 - tm) - 2.0 * growth) / row[LENGTH]
        u += along * row[DX]
        v += along * row[DY]
        w += up
    return u, v, w


@njit(cache=True)
def eddy_field(wakes, lower, h, shape):
    """(n_cells, 3) eddy wind at the cell centres, cells in (i, j, k) C order."""
    out = np.zeros((shape[0] * shape[1] * shape[2], 3))
    for i in range(shape[0]):
        for j in range(shape[1]):
            for k in range(shape[2]):
                c = (i * shape[1] + j) * shape[2] + k
                p = (lower[0] + (i + 0.5) * h, lower[1] + (j + 0.5) * h, lower[2] + (k + 0.5) * h)
                out[c, 0], out[c, 1], out[c, 2] = eddy_wind(wakes, p, lower[2])
    return out
