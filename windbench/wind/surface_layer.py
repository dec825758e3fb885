"""The atmospheric surface layer's eddy diffusivity, shared by the backends that mix
(the Navier-Stokes eddy viscosity ``wind.turbulence=mixing_length`` and the particles'
``wind.lee_model=mixing``): K(z) = l(z)^2 |dU/dz|, U(z) the undisturbed wind of the
scene's sources, Prandtl's mixing length l = kappa z limited aloft as
1/l = 1/(kappa z) + 1/lambda (Blackadar 1962). Over a log-law profile this is the
equilibrium K = kappa u_* z; over uniform sources (no shear) it is zero.
"""

from __future__ import annotations

import numpy as np

from windbench.errors import ConfigError
from windbench.wind.primitives import LOG_PROFILE, superpose

KARMAN = 0.41  # von Karman's constant
MIXING_LENGTH_LIMIT = 40.0  # m, Blackadar's lambda (the wind.mixing_length_limit default)


def blackadar_length(z, limit: float) -> np.ndarray:
    """l = 1 / (1 / (kappa z) + 1 / lambda) (m) at heights ``z`` above the ground."""
    z = np.asarray(z, dtype=float)
    return 1.0 / (1.0 / (KARMAN * z) + 1.0 / limit)


def surface_layer_viscosity(z, shear, limit: float) -> np.ndarray:
    """K(z) = l(z)^2 |dU/dz| (m^2/s) from the undisturbed wind's shear (1/s) at ``z``."""
    return blackadar_length(z, limit) ** 2 * np.abs(shear)


def sources_viscosity(sources, heights, lower, upper, limit: float, eps: float) -> np.ndarray:
    """K = l^2 |dU/dz| (m^2/s) of the sources' undisturbed wind U = sum w_i at the world
    ``heights`` over the middle of the box [lower, upper] (the ground at lower z): the
    shear by central differences +-eps (m) (:func:`surface_layer_viscosity`)."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    column = np.zeros((len(heights), 3))
    column[:, 2] = heights
    column[:, :2] = 0.5 * (lower[:2] + upper[:2])
    up, down = column.copy(), column.copy()
    up[:, 2] += eps
    down[:, 2] -= eps
    shear = np.linalg.norm(superpose(sources, up) - superpose(sources, down), axis=1) / (2 * eps)
    return surface_layer_viscosity(np.asarray(heights) - lower[2], shear, limit)


def ground_roughness(sources) -> tuple[float, float]:
    """(z_0, ground height) (m) of a rough ground (``scene.boundary.z_min: rough``): the
    log profile of the sources, which must agree (ConfigError naming the key otherwise)."""
    found = {(s.profile[1], s.profile[3]) for s in sources if s.profile[0] == LOG_PROFILE}
    if len(found) != 1:
        got = "none has one" if not found else f"they differ: {sorted(found)}"
        raise ConfigError(
            "scene.boundary.z_min",
            "rough takes its roughness length from the sources' log profile (one z_0 and "
            f"ground for all of them); {got}",
        )
    return found.pop()
