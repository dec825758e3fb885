"""Kinematic bodies: a rigid body's prescribed pose over time and the velocity of its points.

The paper's bodies are rigid and still (§4.1.2); a body may instead follow a prescribed
rigid motion (``motion`` under a body of ``scene.bodies``). A pose maps a point x0 of the
body as configured (its rest placement) to the world,

    x = R(t) (x0 - P) + c(t),        R(t) a rotation, c(t) the current place of the pivot P,

so that the body's points move with the rigid velocity

    v(x, t) = c'(t) + omega(t) x (x - c(t)),

and its signed distance is the rest body's at the point carried back to the rest frame,
d(x, t) = d0(R^T (x - c) + P), with the normal rotated forward, n = R n0
(:func:`windbench.geometry.bodies.table_distance`). Time is the simulation's time (s),
spin-up included, as the run records it. Two motions:

``keyframes``: ``times`` (s, increasing), ``positions`` (the pivot's displacement from P at
each time, m; default none), ``rotations`` (angle about ``axis`` through the pivot at each
time, degrees; default none), ``axis`` (default z, up), ``pivot`` (P, default the centre of
the body's bounding box; a plane must give it). Between keyframes the displacement and the
angle are linear in time, so R(t) turns about the fixed axis at a constant rate (the
slerp of two rotations about one axis); before the first and after the last keyframe the
pose is held.

``rotation``: ``axis``, ``point`` (on the axis, the pivot), ``angular_speed`` (rad/s,
right-handed about ``axis``), ``start`` and ``stop`` (s, defaults 0 and never): the angle
is ``angular_speed (clamp(t, start, stop) - start)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from windbench.errors import ConfigError

UP = (0.0, 0.0, 1.0)  # z is up
POSE_WIDTH = 12  # a pose row: R row-major (9), translation T = c - R P (3)
_KEYS = {
    "keyframes": ("times", "positions", "rotations", "axis", "pivot"),
    "rotation": ("axis", "point", "angular_speed", "start", "stop"),
}


class Pose(NamedTuple):
    """A body's pose at one time: rotation R (3, 3), pivot place c (3,), its velocity c'
    (3,) and the angular velocity omega (3,) (rad/s); ``pivot`` P (3,) in the rest frame."""

    rotation: np.ndarray
    centre: np.ndarray
    velocity: np.ndarray
    omega: np.ndarray
    pivot: np.ndarray

    def row(self) -> np.ndarray:
        """The :data:`POSE_WIDTH` floats the kernels read: R row-major, T = c - R P."""
        return np.concatenate([self.rotation.reshape(9), self.centre - self.rotation @ self.pivot])

    def point_velocity(self, points) -> np.ndarray:
        """v(x) = c' + omega x (x - c) at world points (n, 3)."""
        x = np.atleast_2d(np.asarray(points, dtype=np.float64))
        return self.velocity + np.cross(self.omega, x - self.centre)

    def to_world(self, points) -> np.ndarray:
        """x = R (x0 - P) + c of rest-frame points (n, 3)."""
        x0 = np.atleast_2d(np.asarray(points, dtype=np.float64))
        return (x0 - self.pivot) @ self.rotation.T + self.centre


def axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: R = I + sin(a) K + (1 - cos(a)) K^2, K the cross-product matrix of the
    unit ``axis``."""
    kx, ky, kz = axis
    k = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


@dataclass(frozen=True)
class Keyframes:
    """Piecewise-linear displacement and angle about a fixed axis (module docstring)."""

    times: tuple[float, ...]
    positions: tuple[tuple[float, float, float], ...]  # m, the pivot's displacement
    angles: tuple[float, ...]  # rad
    axis: tuple[float, float, float]  # unit
    pivot: tuple[float, float, float]

    def pose(self, t: float) -> Pose:
        times = np.asarray(self.times)
        k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1))
        u = np.asarray(self.positions)
        a = np.asarray(self.angles)
        if k + 1 < len(times) and t >= times[0]:  # inside segment k: linear, rates constant
            span = times[k + 1] - times[k]
            s = (t - times[k]) / span
            du, da = (u[k + 1] - u[k]) / span, (a[k + 1] - a[k]) / span
            disp, angle = u[k] + s * (u[k + 1] - u[k]), a[k] + s * (a[k + 1] - a[k])
        else:  # held before the first and after the last keyframe
            du, da = np.zeros(3), 0.0
            disp, angle = u[k], a[k]
        axis, pivot = np.asarray(self.axis), np.asarray(self.pivot)
        return Pose(axis_rotation(axis, angle), pivot + disp, du, da * axis, pivot)


@dataclass(frozen=True)
class Rotation:
    """A turn about a fixed axis at a constant angular speed from ``start`` to ``stop``."""

    axis: tuple[float, float, float]  # unit
    point: tuple[float, float, float]
    angular_speed: float  # rad/s
    start: float  # s
    stop: float  # s

    def pose(self, t: float) -> Pose:
        axis, point = np.asarray(self.axis), np.asarray(self.point)
        angle = self.angular_speed * (min(max(t, self.start), self.stop) - self.start)
        turning = self.start <= t < self.stop
        omega = self.angular_speed * axis if turning else np.zeros(3)
        return Pose(axis_rotation(axis, angle), point.copy(), np.zeros(3), omega, point)


Motion = Keyframes | Rotation


def _vector(value, key: str) -> np.ndarray:
    """3 finite numbers, else ConfigError naming ``key``."""
    try:
        v = np.asarray(list(value), dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(key, f"must be 3 finite numbers, got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(key, f"must be 3 finite numbers, got {value!r}")
    return v


def _unit(value, key: str) -> tuple[float, float, float]:
    v = _vector(value, key)
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        raise ConfigError(key, "must be a non-zero vector")
    return tuple(float(x) for x in v / norm)


def _number(value, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ConfigError(key, f"must be a finite number, got {value!r}")
    return float(value)


def _keyframes(spec: Mapping, key: str, centre) -> Keyframes:
    times = spec.get("times")
    if not isinstance(times, list | tuple) or len(times) == 0:
        raise ConfigError(f"{key}.times", f"must be a list of >= 1 times (s), got {times!r}")
    t = [_number(x, f"{key}.times[{i}]") for i, x in enumerate(times)]
    if np.any(np.diff(t) <= 0):
        raise ConfigError(f"{key}.times", f"must increase strictly, got {t}")
    n = len(t)
    positions = spec.get("positions") or [[0.0, 0.0, 0.0]] * n
    rotations = spec.get("rotations") or [0.0] * n
    for name, values in (("positions", positions), ("rotations", rotations)):
        if len(values) != n:
            raise ConfigError(
                f"{key}.{name}", f"must have one entry per time ({n}), got {len(values)}"
            )
    if "pivot" not in spec and centre is None:
        raise ConfigError(f"{key}.pivot", "is required: the body has no finite centre")
    pivot = _vector(spec["pivot"], f"{key}.pivot") if "pivot" in spec else centre
    return Keyframes(
        times=tuple(t),
        positions=tuple(
            tuple(float(x) for x in _vector(p, f"{key}.positions[{i}]"))
            for i, p in enumerate(positions)
        ),
        angles=tuple(
            np.radians(_number(a, f"{key}.rotations[{i}]")) for i, a in enumerate(rotations)
        ),
        axis=_unit(spec.get("axis") or UP, f"{key}.axis"),
        pivot=tuple(float(x) for x in pivot),
    )


def _rotation(spec: Mapping, key: str) -> Rotation:
    for name in ("axis", "point", "angular_speed"):
        if name not in spec:
            raise ConfigError(f"{key}.{name}", "is required for a rotation")
    start = _number(spec["start"], f"{key}.start") if "start" in spec else 0.0
    stop = spec["stop"] if "stop" in spec else np.inf
    if isinstance(stop, bool) or not isinstance(stop, int | float) or not stop > start:
        raise ConfigError(f"{key}.stop", f"must be a time after start ({start} s), got {stop!r}")
    return Rotation(
        axis=_unit(spec["axis"], f"{key}.axis"),
        point=tuple(float(x) for x in _vector(spec["point"], f"{key}.point")),
        angular_speed=_number(spec["angular_speed"], f"{key}.angular_speed"),
        start=start,
        stop=stop,
    )


def motion_from_config(spec, key: str, centre=None) -> Motion:
    """The checked ``motion`` of a body (module docstring); ``centre`` the body's default
    pivot (None: it has none). Raises ConfigError naming the first bad key."""
    if not isinstance(spec, Mapping):
        raise ConfigError(key, f"must be a mapping with a type, got {spec!r}")
    kind = spec.get("type")
    if kind not in _KEYS:
        raise ConfigError(f"{key}.type", f"must be one of {sorted(_KEYS)}, got {kind!r}")
    allowed = {"type", *_KEYS[kind]}
    unknown = set(spec) - allowed
    if unknown:
        raise ConfigError(
            key, f"unknown key(s) {sorted(unknown)} for a {kind} motion; allowed {sorted(allowed)}"
        )
    return _keyframes(spec, key, centre) if kind == "keyframes" else _rotation(spec, key)
