"""Flow primitives w_i(x) and their superposition w = sum_i w_i (paper §4.2.1).

After Wejchert & Haumann (1991): potential flows that solve the Laplace equation (4.3),
so each is divergence- and curl-free away from its singular set, and any sum of them is
again a potential flow.

=========== ======================================================================
primitive   velocity w_i(x)
=========== ======================================================================
uniform     w = U (the paper's "directional" wind source; exactly constant), or
            w = U f(z) with an atmospheric ``profile`` over the ground (below)
source      w = m / (4 pi r^2) r_hat * g(r),  m = ``strength`` (m^3/s of air emitted)
sink        the same with -m: air drawn in
vortex      w = Gamma / (2 pi d) theta_hat * g_v(d),  d = distance from the axis line,
            Gamma = ``strength`` (circulation, m^2/s), theta_hat = axis_hat x d_hat
=========== ======================================================================

The point singularities are kept finite by a core radius ``rc`` (``core_radius``; 0 means
the bare singular law, with w = 0 exactly on the singular set):

- source/sink: ``g(r) = 1 - exp(-(r/rc)^3)`` — the field of a smooth ball of emission,
  exactly ``m/(4 pi r^2)`` to within ``exp(-(r/rc)^3)`` outside the core;
- vortex: ``g_v(d) = 1 - exp(-(d/rc)^2)`` — the Lamb-Oseen vortex, whose vorticity
  ``Gamma/(pi rc^2) exp(-(d/rc)^2)`` vanishes exponentially outside the core.

A uniform source may carry an atmospheric boundary-layer ``profile`` over the ground at
height z_g (U is then the wind at ``reference_height`` z_r above it, s = z - z_g):

- ``log``: f = ln(s / z_0) / ln(z_r / z_0) for s > z_0, else 0 — the neutral surface layer,
  u(z) = (u_* / kappa) ln(z / z_0), with roughness length z_0 = ``roughness`` (m);
- ``power``: f = (s / z_r)^alpha for s > 0, else 0, alpha = ``exponent``.

Such a wind is still divergence free (u depends on z only), but no longer irrotational.

Each primitive is one row of a parameter table (``kind`` + 15 floats) so that the same
numba kernel serves the vectorised field here, the superposed ``global`` backend and the
per-source particle tracing of §4.2.2, where a particle follows only its own w_i.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from windbench.errors import ConfigError

UNIFORM, SOURCE, SINK, VORTEX = 0, 1, 2, 3
KINDS = {"uniform": UNIFORM, "source": SOURCE, "sink": SINK, "vortex": VORTEX}
NO_PROFILE, LOG_PROFILE, POWER_PROFILE = 0, 1, 2
PROFILES = {"log": LOG_PROFILE, "power": POWER_PROFILE}
# centre(3), axis(3), velocity(3), strength, core_radius,
# profile kind, roughness or exponent, reference height, ground height
N_PARAMS = 15


@dataclass(frozen=True)
class Primitive:
    """One flow primitive: its kind and parameter row (see module docstring)."""

    kind: str
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    strength: float = 0.0
    core_radius: float = 0.0
    profile: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 0.0)  # kind, z0|alpha, z_r, z_g
    turbulence: tuple[float, float] | None = None  # (intensity, length scale m) at the inflow

    @property
    def kind_id(self) -> int:
        return KINDS[self.kind]

    def row(self) -> np.ndarray:
        axis = np.asarray(self.axis, dtype=float)
        return np.concatenate(
            [
                self.center,
                axis / np.linalg.norm(axis),
                self.velocity,
                [self.strength, self.core_radius],
                self.profile,
            ]
        ).astype(np.float64)

    def speed_scale(self) -> float:
        """A characteristic speed (m/s): |U| for uniform, else the speed at one core radius."""
        if self.kind == "uniform":
            return float(np.linalg.norm(self.velocity))
        r = max(self.core_radius, 1e-3)
        if self.kind == "vortex":
            return abs(self.strength) / (2 * np.pi * r)
        return abs(self.strength) / (4 * np.pi * r * r)

    def __call__(self, points) -> np.ndarray:
        """w_i at world points ``(n, 3)``."""
        return superpose([self], points)


_ALLOWED = {
    "uniform": {"type", "velocity", "profile", "turbulence", "emit", "gusts", "name"},
    "source": {"type", "center", "strength", "core_radius", "emit", "gusts", "name"},
    "sink": {"type", "center", "strength", "core_radius", "emit", "gusts", "name"},
    "vortex": {"type", "center", "axis", "strength", "core_radius", "emit", "gusts", "name"},
}


def _vec3(spec: Mapping, name: str, key: str, default=None):
    value = spec.get(name, default)
    if value is None:
        raise ConfigError(f"{key}.{name}", "is required: a list of 3 numbers")
    arr = np.asarray(list(value), dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{key}.{name}", f"must be 3 finite numbers, got {list(value)}")
    return tuple(float(v) for v in arr)


def _positive_number(spec: Mapping, name: str, key: str) -> float:
    value = spec.get(name)
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}.{name}", f"must be a number > 0, got {value!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise ConfigError(f"{key}.{name}", f"must be a finite number > 0, got {value}")
    return value


def _profile(spec: Mapping | None, key: str) -> tuple[float, float, float, float]:
    """The (kind, z0 | alpha, z_r, z_g) row entries of a uniform source's ``profile``."""
    if spec is None:
        return (float(NO_PROFILE), 0.0, 1.0, 0.0)
    kind = spec.get("type")
    if kind not in PROFILES:
        raise ConfigError(f"{key}.type", f"must be one of {sorted(PROFILES)}, got {kind!r}")
    shape = "roughness" if kind == "log" else "exponent"
    allowed = {"type", shape, "reference_height", "ground"}
    unknown = set(spec) - allowed
    if unknown:
        raise ConfigError(key, f"unknown key(s) {sorted(unknown)}; allowed {sorted(allowed)}")
    parameter = _positive_number(spec, shape, key)
    height = _positive_number(spec, "reference_height", key)
    if kind == "log" and height <= parameter:
        raise ConfigError(
            f"{key}.reference_height", f"must exceed the roughness {parameter} m, got {height}"
        )
    ground = float(spec.get("ground", 0.0))
    if not np.isfinite(ground):
        raise ConfigError(f"{key}.ground", f"must be a finite height (m), got {ground}")
    return (float(PROFILES[kind]), parameter, height, ground)


def _turbulence(spec: Mapping | None, key: str) -> tuple[float, float] | None:
    """(intensity, length scale) of a uniform source's inflow ``turbulence``
    (:mod:`windbench.wind.fluctuation`)."""
    if spec is None:
        return None
    unknown = set(spec) - {"intensity", "length_scale"}
    if unknown:
        raise ConfigError(key, f"unknown key(s) {sorted(unknown)}; allowed intensity, length_scale")
    intensity = _positive_number(spec, "intensity", key)
    if intensity >= 1:
        raise ConfigError(f"{key}.intensity", f"must lie in (0, 1), got {intensity}")
    return intensity, _positive_number(spec, "length_scale", key)


def primitive_from_config(spec: Mapping, key: str) -> Primitive:
    """Build and check one primitive from a scene's ``sources`` entry."""
    kind = spec.get("type")
    if kind not in KINDS:
        raise ConfigError(f"{key}.type", f"must be one of {sorted(KINDS)}, got {kind!r}")
    unknown = set(spec) - _ALLOWED[kind]
    if unknown:
        raise ConfigError(
            f"{key}",
            f"unknown key(s) {sorted(unknown)} for a {kind}; allowed {sorted(_ALLOWED[kind])}",
        )
    if kind == "uniform":
        return Primitive(
            "uniform",
            velocity=_vec3(spec, "velocity", key),
            profile=_profile(spec.get("profile"), f"{key}.profile"),
            turbulence=_turbulence(spec.get("turbulence"), f"{key}.turbulence"),
        )
    strength = float(spec.get("strength", Primitive.strength))
    core = float(spec.get("core_radius", Primitive.core_radius))
    if core < 0:
        raise ConfigError(f"{key}.core_radius", f"must be >= 0, got {core}")
    axis = _vec3(spec, "axis", key, Primitive.axis)
    if np.linalg.norm(axis) == 0:
        raise ConfigError(f"{key}.axis", "must be a non-zero vector")
    return Primitive(
        kind, center=_vec3(spec, "center", key), axis=axis, strength=strength, core_radius=core
    )


def profile_scale(primitive: Primitive, points) -> np.ndarray:
    """f(z) of a uniform source's profile at world points ``(n, 3)`` (1 without one)."""
    row = primitive.row()
    return np.array([profile_factor(row, z) for z in np.asarray(points)[:, 2]])


def parameter_table(primitives: Sequence[Primitive]) -> tuple[np.ndarray, np.ndarray]:
    """(kinds ``(m,)`` int64, params ``(m, N_PARAMS)`` float64) for the numba kernels."""
    kinds = np.array([p.kind_id for p in primitives], dtype=np.int64)
    params = np.zeros((len(primitives), N_PARAMS), dtype=np.float64)
    for i, p in enumerate(primitives):
        params[i] = p.row()
    return kinds, params


def superpose(primitives: Sequence[Primitive], points, table=None) -> np.ndarray:
    """w(x) = sum_i w_i(x) at world points ``(n, 3)`` (or a grid ``(..., 3)``).

    ``table``: the primitives' :func:`parameter_table`, when the caller keeps it.
    """
    pts = np.asarray(points, dtype=np.float64)
    flat = np.ascontiguousarray(pts.reshape(-1, 3))
    out = np.zeros_like(flat)
    kinds, params = parameter_table(primitives) if table is None else table
    superposed_velocity(kinds, params, flat, out)
    return out.reshape(pts.shape)


@njit(cache=True, inline="always")
def profile_factor(prm, pz):
    """f(z) of a uniform source's profile (module docstring); 1 without one."""
    shape = prm[11]
    if shape == NO_PROFILE:
        return 1.0
    s = pz - prm[14]
    if shape == LOG_PROFILE:
        z0 = prm[12]
        return np.log(s / z0) / np.log(prm[13] / z0) if s > z0 else 0.0
    return (s / prm[13]) ** prm[12] if s > 0.0 else 0.0


@njit(cache=True)
def primitive_velocity(kind, prm, px, py, pz, out):
    """out = w_i(p) for one primitive (kind, parameter row prm); see module table."""
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    if kind == UNIFORM:
        f = profile_factor(prm, pz)
        out[0] = f * prm[6]
        out[1] = f * prm[7]
        out[2] = f * prm[8]
        return
    rx = px - prm[0]
    ry = py - prm[1]
    rz = pz - prm[2]
    strength = prm[9]
    rc = prm[10]
    if kind == SOURCE or kind == SINK:
        # w = +-m/(4 pi r^2) r_hat (1 - exp(-(r/rc)^3))
        r2 = rx * rx + ry * ry + rz * rz
        if r2 == 0.0:
            return
        r = np.sqrt(r2)
        g = 1.0 - np.exp(-((r / rc) ** 3)) if rc > 0.0 else 1.0
        sign = 1.0 if kind == SOURCE else -1.0
        s = sign * strength * g / (4.0 * np.pi * r2 * r)
        out[0] = s * rx
        out[1] = s * ry
        out[2] = s * rz
    elif kind == VORTEX:
        # w = Gamma/(2 pi d) (a x d_hat) (1 - exp(-(d/rc)^2)), d = distance from the axis
        ax, ay, az = prm[3], prm[4], prm[5]
        along = rx * ax + ry * ay + rz * az
        dx = rx - along * ax
        dy = ry - along * ay
        dz = rz - along * az
        d2 = dx * dx + dy * dy + dz * dz
        if d2 == 0.0:
            return
        g = 1.0 - np.exp(-d2 / (rc * rc)) if rc > 0.0 else 1.0
        s = strength * g / (2.0 * np.pi * d2)
        out[0] = s * (ay * dz - az * dy)
        out[1] = s * (az * dx - ax * dz)
        out[2] = s * (ax * dy - ay * dx)


@njit(cache=True)
def superposed_velocity(kinds, params, points, out):
    """out[p] = sum_i w_i(points[p]) (paper §4.2.1, w = sum w_i)."""
    for p in range(points.shape[0]):
        w = np.empty(3)
        acc0 = 0.0
        acc1 = 0.0
        acc2 = 0.0
        for i in range(kinds.shape[0]):
            primitive_velocity(kinds[i], params[i], points[p, 0], points[p, 1], points[p, 2], w)
            acc0 += w[0]
            acc1 += w[1]
            acc2 += w[2]
        out[p, 0] = acc0
        out[p, 1] = acc1
        out[p, 2] = acc2
