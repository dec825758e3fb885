"""Synthetic turbulence: a seeded, divergence-free random field of velocity fluctuations
carried by the mean wind (Taylor's frozen turbulence), for turbulent inflow.

Random Fourier modes after Kraichnan (1970) and Smirnov, Shi & Celik (2001):

    u'(x, t) = sigma sqrt(6 / N) sum_n a_n cos(k_n . (x - U t) + phi_n),   a_n . k_n = 0,

with N modes, unit amplitude directions a_n normal to the wave vectors (each mode, and so
the sum, is divergence free), uniform phases phi_n, wave-vector directions uniform on
the sphere and magnitudes drawn from the von Karman spectrum

    E(k) ~ (k L_e)^4 / (1 + (k L_e)^2)^(17/6),   L_e = L / 0.747,

whose integral length scale is L (``length_scale``). Each component then has standard
deviation sigma = I |U| (``intensity`` I of the mean wind U). The field is a function of
position and time only, so the same seed gives the same inflow at any resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MODES = 64
VON_KARMAN_SCALE = 0.747  # L = 0.747 L_e for the von Karman spectrum


@dataclass(frozen=True)
class Fluctuation:
    """One source's turbulent fluctuation: modes fixed at construction (model)."""

    sigma: float  # m/s, standard deviation of each component
    velocity: np.ndarray  # (3,) mean wind that carries the field
    wave_vectors: np.ndarray  # (N, 3), 1/m
    directions: np.ndarray  # (N, 3), unit, normal to the wave vectors
    phases: np.ndarray  # (N,)

    @classmethod
    def build(cls, intensity, length_scale, velocity, seed, modes=MODES) -> Fluctuation:
        rng = np.random.default_rng(seed)
        velocity = np.asarray(velocity, dtype=float)
        k = _von_karman_wavenumbers(rng, modes, length_scale / VON_KARMAN_SCALE)
        d = _unit_vectors(rng, modes)
        a = np.cross(d, _unit_vectors(rng, modes))
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        return cls(
            sigma=float(intensity * np.linalg.norm(velocity)),
            velocity=velocity,
            wave_vectors=k[:, None] * d,
            directions=a,
            phases=rng.uniform(0.0, 2.0 * np.pi, modes),
        )

    def __call__(self, points, t: float) -> np.ndarray:
        """u'(points, t), ``(n, 3)`` m/s."""
        x = np.asarray(points, dtype=float) - self.velocity * t
        arg = x @ self.wave_vectors.T + self.phases
        amp = self.sigma * np.sqrt(6.0 / len(self.phases))
        return amp * np.cos(arg) @ self.directions


def _unit_vectors(rng, n) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _von_karman_wavenumbers(rng, n, length) -> np.ndarray:
    """n wavenumbers (1/m) drawn from E(k) ~ (kL)^4 / (1 + (kL)^2)^(17/6) by inverting its
    cumulative distribution on a logarithmic lattice."""
    kl = np.logspace(-3, 3, 4001)
    e = kl**4 / (1.0 + kl**2) ** (17.0 / 6.0)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (e[1:] + e[:-1]) * np.diff(kl))])
    cdf /= cdf[-1]
    return np.interp(rng.uniform(0.0, 1.0, n), cdf, kl) / length
