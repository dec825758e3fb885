"""Figures a run records: divergence, lee-zone speed ratio, force ratio, energies.

- ``divergence``: ``|div u| h / U_ref`` by central differences of the cell-centred wind,
  over cells whose six neighbours are all air (so walls and bodies do not count).
  A divergence-free field (eq. 4.1) gives 0; a linear field gives its exact divergence.
- ``lee_speed_ratio``: mean |u| at the ``lee`` probe lattice / mean |u| at the
  ``free_stream`` lattice; 1 with no lee, 0 in a perfect wind shadow.
- ``lee_force_ratio``: |F| on the sheltered cloth / |F| on the exposed cloth.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def central_divergence(u, solid, h, out):
    """out[i,j,k] = div u by central differences where all six neighbours are air, else NaN.
    Serial: a per-record figure on the cell-centred field, where a parallel loop's
    compilation costs more than it saves."""
    nx, ny, nz, _ = u.shape
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                out[i, j, k] = np.nan
                if i == 0 or j == 0 or k == 0 or i == nx - 1 or j == ny - 1 or k == nz - 1:
                    continue
                if (
                    solid[i, j, k]
                    or solid[i - 1, j, k]
                    or solid[i + 1, j, k]
                    or solid[i, j - 1, k]
                    or solid[i, j + 1, k]
                    or solid[i, j, k - 1]
                    or solid[i, j, k + 1]
                ):
                    continue
                out[i, j, k] = (
                    u[i + 1, j, k, 0]
                    - u[i - 1, j, k, 0]
                    + u[i, j + 1, k, 1]
                    - u[i, j - 1, k, 1]
                    + u[i, j, k + 1, 2]
                    - u[i, j, k - 1, 2]
                ) / (2.0 * h)


def central_divergence_field(u, solid, h) -> np.ndarray:
    """div u per cell by central differences (NaN where a neighbour is not air).

    Axes one cell thick (2D problems) are replicated so their derivative is zero.
    """
    u = np.ascontiguousarray(u, dtype=np.float64)
    solid = np.ascontiguousarray(solid)
    thin = [n == 1 for n in u.shape[:3]]
    if any(thin):
        pad = [(1, 1) if t else (0, 0) for t in thin]
        u = np.pad(u, [*pad, (0, 0)], mode="edge")
        solid = np.pad(solid, pad, mode="edge")
    div = np.empty(u.shape[:3])
    central_divergence(u, solid, h, div)
    return div[tuple(slice(1, 2) if t else slice(None) for t in thin)]


def divergence_figures(div, h, reference_speed) -> tuple[float, float]:
    """(rms, max) of |div u| h / U_ref over the finite entries of ``div``; nan if none."""
    vals = np.abs(div[np.isfinite(div)]) * h / reference_speed
    if vals.size == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(vals**2))), float(vals.max())


def mean_speed(wind_at_points: np.ndarray) -> float:
    return float(np.linalg.norm(wind_at_points, axis=-1).mean())


def speed_ratio(lee_wind: np.ndarray, free_wind: np.ndarray) -> float:
    """mean |u| in the lee box / mean |u| in the free-stream box (nan if the latter is 0)."""
    free = mean_speed(free_wind)
    return mean_speed(lee_wind) / free if free > 0 else float("nan")


def force_ratio(sheltered_force: np.ndarray, exposed_force: np.ndarray) -> float:
    exposed = float(np.linalg.norm(exposed_force))
    return float(np.linalg.norm(sheltered_force)) / exposed if exposed > 0 else float("nan")


def plane_flux_ratio(u, undisturbed, solid, axis: int = 0) -> np.ndarray:
    """Volume flux through each plane of cells across ``axis`` over the undisturbed wind's:
    sum of u_axis over the plane's air cells / sum of the sources' wind over all its cells
    (the cell areas cancel). 1 where no air is lost; the paper's lee, whose particles stop
    at bodies, loses the flux of what they blocked."""
    u, undisturbed = (
        np.moveaxis(u[..., axis], axis, 0),
        np.moveaxis(undisturbed[..., axis], axis, 0),
    )
    air = ~np.moveaxis(np.asarray(solid, bool), axis, 0)
    return (u * air).reshape(len(u), -1).sum(axis=1) / undisturbed.reshape(len(u), -1).sum(axis=1)


def unsettled_reason(times, analysis_start: float) -> str:
    """Why a run's recorded ``times`` hold no steady window (no step at or after
    ``analysis_start``); empty when they hold one."""
    times = np.asarray(times, dtype=float)
    if times.size and times[-1] >= analysis_start - 1e-9:
        return ""
    end = float(times[-1]) if times.size else 0.0
    return (
        f"no steady window: recorded until t = {end:.3g} s, statistics start at "
        f"{analysis_start:.3g} s (two flow-through times; use sim.spinup=auto or a longer "
        "sim.duration)"
    )
