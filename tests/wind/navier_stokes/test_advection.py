"""The semi-Lagrangian kernel against backtraces known in closed form.

Trilinear interpolation is exact for fields that are linear along each axis, so with the
velocity (u, v, w) = (alpha_0 x, alpha_1 y, alpha_2 z) (cell coordinates, cells per unit
time) every interpolation the kernel does is exact, and its RK2 backtrace must land where
the midpoint rule puts it, axis by axis:

    x_mid = x - dt/2 alpha x,   x_back = x - dt alpha x_mid.

The backtrace is done once per cell centre (the cell's velocity the mean of its two faces,
exact here) and a face takes the mean of its two cells' displacements, which is exact too,
since the displacement dt alpha (x - dt/2 alpha x) is linear in x. The advected field
q = x y + 2 z + 1 (multilinear) is then read exactly at x_back. This checks the staggered
offsets of every component (face along its own axis, cell centre across) and the pairing
of faces with cells, ghost cells included (their velocity extends the linear field).
"""

from __future__ import annotations

import numpy as np
import pytest

from windbench.wind.navier_stokes import advection
from windbench.wind.navier_stokes.boundaries import padded_shape

CELLS = (6, 7, 8)
ALPHA = np.array([0.3, -0.2, 0.25])


def _coordinates(a):
    """Cell coordinates (x, y, z) of every element of component a's padded lattice."""
    shape = padded_shape(CELLS, a)
    start = [-1.0 if b == a else -0.5 for b in range(3)]
    return np.meshgrid(
        *[s + np.arange(n) for s, n in zip(start, shape, strict=True)], indexing="ij"
    )


def _advect(q, a, velocity, cells, periodic, dt, out, chunks=2):
    """out = q (component a) carried over dt by the velocity components (cells per unit
    time); the other two components carry fields of NaN (they must not leak into a)."""
    src = [np.full(padded_shape(CELLS, b), np.nan) for b in range(3)]
    dst = [np.full(padded_shape(CELLS, b), np.nan) for b in range(3)]
    src[a], dst[a] = q, out
    advection.advect(
        *velocity,
        cells,
        periodic,
        dt,
        chunks,
        tuple(src),
        tuple(dst),
        tuple(dst),
        tuple(dst),
        False,
    )


def _q(x, y, z):
    return x * y + 2.0 * z + 1.0


@pytest.mark.parametrize("chunks", [1, 3])
@pytest.mark.parametrize("a", [0, 1, 2])
@pytest.mark.parametrize("dt", [0.5, -0.4])
def test_rk2_backtrace_of_a_linear_flow_is_exact(a, dt, chunks):
    """Exact for every face, however the planes are split into runs (``chunks``: each run
    restarts the ring of displacement planes)."""
    velocity = [ALPHA[b] * _coordinates(b)[b] for b in range(3)]
    x, y, z = _coordinates(a)
    q = _q(x, y, z)
    out = np.full_like(q, np.nan)
    cells = np.array(CELLS, dtype=np.int64)
    periodic = np.zeros(3, dtype=np.bool_)
    _advect(q, a, velocity, cells, periodic, dt, out, chunks)
    back = []
    for b, c in enumerate((x, y, z)):
        mid = c - 0.5 * dt * ALPHA[b] * c
        back.append(c - dt * ALPHA[b] * mid)
    expected = _q(*back)
    inner = (slice(1, -1),) * 3
    # only faces whose backtrace stays in the domain [0, n] (outside it is clamped)
    inside = np.ones(q.shape, dtype=bool)
    for b, c in enumerate(back):
        inside &= (c >= 0.0) & (c <= CELLS[b])
    mask = inside[inner]
    assert mask.sum() > 0.5 * mask.size
    np.testing.assert_allclose(out[inner][mask], expected[inner][mask], rtol=0, atol=1e-12)


def test_points_leaving_a_periodic_axis_wrap_around():
    """A uniform flow of 2.5 cells per step along a periodic x carries a field periodic in x
    by 2.5 cells, wrapping at the domain ends, exactly where it is linear between samples."""
    a = 1  # a component staggered across x: samples at cell centres along x
    x, y, z = _coordinates(a)
    n = CELLS[0]
    q = np.cos(2 * np.pi * x / n) + y
    zero = [np.zeros(padded_shape(CELLS, b)) for b in range(3)]
    zero[0][...] = 2.5
    out = np.full_like(q, np.nan)
    cells = np.array(CELLS, dtype=np.int64)
    periodic = np.array([True, False, False])
    # the ghost cells along x hold the periodic copies, as boundaries.fill_boundary does
    _advect(q, a, zero, cells, periodic, 1.0, out)
    shifted = (x - 2.5) % n
    lo = np.floor(shifted - 0.5) + 0.5  # neighbouring cell centres
    f = shifted - lo
    expected = (1 - f) * np.cos(2 * np.pi * lo / n) + f * np.cos(2 * np.pi * (lo + 1) / n) + y
    inner = (slice(1, -1),) * 3
    np.testing.assert_allclose(out[inner], expected[inner], rtol=0, atol=1e-12)
