"""The wind grid: a box of cubic cells, cell centres and trilinear sampling.

Paper §4.2.2: "This model divides the scene into parallelepiped cells ... values between the
defining points of the grid are interpolated using trilinear functions." Both wind models
share this grid; here the cells are cubes of edge ``h = longest side / resolution``.

Choice: an axis of length ``L`` gets ``max(1, round(L / h))`` cells, so the grid's upper
corner is ``lower + h * shape``; it equals the domain's upper corner whenever the side
lengths are multiples of ``h`` (all shipped scenes) and differs by less than ``h / 2``
otherwise. :class:`Grid` checks ``upper - lower == h * shape`` itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from windbench.errors import ConfigError

MIN_RESOLUTION = 4


@dataclass(frozen=True)
class Grid:
    """A frozen, self-checking box of ``shape`` cubic cells of edge ``h`` from ``lower``."""

    lower: tuple[float, float, float]
    shape: tuple[int, int, int]
    h: float

    def __post_init__(self):
        if len(self.lower) != 3 or len(self.shape) != 3:
            raise ValueError(f"Grid needs 3 axes, got lower={self.lower}, shape={self.shape}")
        if self.h <= 0 or not np.isfinite(self.h):
            raise ValueError(f"Grid spacing must be positive, got h={self.h}")
        if min(self.shape) < 1:
            raise ValueError(f"Grid needs at least one cell per axis, got shape={self.shape}")

    @classmethod
    def from_domain(cls, lower, upper, resolution: int) -> Grid:
        """Cubic cells, ``resolution`` of them along the longest axis of ``[lower, upper]``."""
        lower = np.asarray(lower, dtype=float)
        upper = np.asarray(upper, dtype=float)
        if resolution < MIN_RESOLUTION:
            raise ConfigError(
                "grid.resolution", f"must be at least {MIN_RESOLUTION}, got {resolution}"
            )
        extent = upper - lower
        if np.any(extent <= 0):
            raise ConfigError("scene.domain", f"max must exceed min on every axis, got {extent}")
        h = float(extent.max() / resolution)
        shape = tuple(int(max(1, round(e / h))) for e in extent)
        grid = cls(tuple(float(v) for v in lower), shape, h)
        grid.check_consistency()
        return grid

    def check_consistency(self):
        """``upper - lower == h * shape`` by construction; raise with both sides if not."""
        lhs = self.upper - np.asarray(self.lower)
        rhs = self.h * np.asarray(self.shape)
        if not np.allclose(lhs, rhs, rtol=1e-12, atol=0.0):
            raise ValueError(f"Grid inconsistent: upper - lower = {lhs} but h * shape = {rhs}")

    @property
    def upper(self) -> np.ndarray:
        return np.asarray(self.lower) + self.h * np.asarray(self.shape)

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    @property
    def centre_origin(self) -> np.ndarray:
        """World position of the centre of cell (0, 0, 0)."""
        return np.asarray(self.lower) + 0.5 * self.h

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell-centre coordinates along x, y and z."""
        o = self.centre_origin
        return tuple(o[a] + self.h * np.arange(self.shape[a]) for a in range(3))

    def cell_centres(self) -> np.ndarray:
        """All cell centres, shape ``(nx, ny, nz, 3)``."""
        x, y, z = self.axes()
        return np.stack(np.meshgrid(x, y, z, indexing="ij"), axis=-1)

    def cell_index(self, points) -> np.ndarray:
        """Integer cell index of each point, clamped into the grid, shape ``(n, 3)``."""
        p = np.atleast_2d(np.asarray(points, dtype=float))
        idx = np.floor((p - np.asarray(self.lower)) / self.h).astype(np.int64)
        return np.clip(idx, 0, np.asarray(self.shape) - 1)

    def contains(self, points, tol: float = 1e-9) -> np.ndarray:
        p = np.atleast_2d(np.asarray(points, dtype=float))
        lo = np.asarray(self.lower) - tol
        hi = self.upper + tol
        return np.all((p >= lo) & (p <= hi), axis=-1)

    def sample(self, field: np.ndarray, points) -> np.ndarray:
        """Trilinear sample of a cell-centred field ``(nx, ny, nz, c)`` at world points."""
        pts = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
        out = np.empty((pts.shape[0], field.shape[-1]), dtype=np.float64)
        trilinear_sample(_read_only(field), self.centre_origin, self.h, pts, out)
        return out


def _read_only(field: np.ndarray) -> np.ndarray:
    """A C-contiguous read-only view of ``field`` (no copy when it is C-contiguous already):
    numba types read-only and writable arrays apart, so the kernels that only read a field
    get one type whichever backend produced it, and compile once."""
    view = np.ascontiguousarray(field).view()
    view.flags.writeable = False
    return view


@njit(cache=True, inline="always")
def _axis_weight(coord, n):
    """Lower index and weight along one axis, clamped to the outermost sample points."""
    if n == 1:
        return 0, 0, 0.0
    if coord <= 0.0:
        return 0, 1, 0.0
    if coord >= n - 1:
        return n - 2, n - 1, 1.0
    i0 = int(np.floor(coord))
    return i0, i0 + 1, coord - i0


@njit(cache=True, inline="always")
def trilinear_point(field, origin, h, px, py, pz, out):
    """out[c] = trilinear interpolation of field[..., c] at (px, py, pz).

    ``field[i, j, k]`` sits at ``origin + h * (i, j, k)``; points outside the sample
    lattice take the value on its boundary (clamped).
    """
    nx, ny, nz, nc = field.shape
    i0, i1, fx = _axis_weight((px - origin[0]) / h, nx)
    j0, j1, fy = _axis_weight((py - origin[1]) / h, ny)
    k0, k1, fz = _axis_weight((pz - origin[2]) / h, nz)
    for c in range(nc):
        c00 = field[i0, j0, k0, c] * (1 - fx) + field[i1, j0, k0, c] * fx
        c10 = field[i0, j1, k0, c] * (1 - fx) + field[i1, j1, k0, c] * fx
        c01 = field[i0, j0, k1, c] * (1 - fx) + field[i1, j0, k1, c] * fx
        c11 = field[i0, j1, k1, c] * (1 - fx) + field[i1, j1, k1, c] * fx
        c0 = c00 * (1 - fy) + c10 * fy
        c1 = c01 * (1 - fy) + c11 * fy
        out[c] = c0 * (1 - fz) + c1 * fz


@njit(cache=True)
def trilinear_sample(field, origin, h, points, out):
    """out[p, :] = field interpolated trilinearly at points[p] (lattice origin, spacing h).

    Serial on purpose, like the other point-set kernels (aero, collisions): the point sets
    are cloth-sized (1e3-1e4), where starting threads costs more than it saves, and far
    more on a loaded machine or in a parallel sweep.
    """
    for p in range(points.shape[0]):
        trilinear_point(field, origin, h, points[p, 0], points[p, 1], points[p, 2], out[p])
