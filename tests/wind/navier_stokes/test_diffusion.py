"""The diffusion kernels against a discrete eigenmode (:mod:`windbench.wind.navier_stokes.diffusion`).

On a periodic lattice the product of cosines q0 = prod_b cos(theta_b i_b) is an
eigenvector of the neighbour sum: sum_nb q0 = (sum_b 2 cos theta_b) q0 over the active
axes. One Jacobi sweep of (1 + 2 alpha d) q - alpha sum_nb q = q0 from q0 therefore gives
q1 = q0 (1 + alpha sum_b 2 cos theta_b) / (1 + 2 alpha d), and the exact implicit solution
is q0 / (1 + alpha sum_b (2 - 2 cos theta_b)).
"""

from __future__ import annotations

import numpy as np
import pytest

from windbench.wind.navier_stokes import diffusion

SHAPE = (8, 6, 5)
ALPHA = 0.3


def _mode(shape, axes):
    """(padded q0 with periodic ghosts, sum_b 2 cos theta_b over the active axes)."""
    theta = [2 * np.pi / n if axes[b] else 0.0 for b, n in enumerate(shape)]
    idx = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    q0 = np.prod([np.cos(t * i) for t, i in zip(theta, idx, strict=True)], axis=0)
    return np.pad(q0, 1, mode="wrap"), sum(2 * np.cos(t) for b, t in enumerate(theta) if axes[b])


@pytest.mark.parametrize(
    "shape, axes", [(SHAPE, (1, 1, 1)), ((8, 6, 1), (1, 1, 0))], ids=["3d", "2d"]
)
def test_jacobi_first_sweep_on_an_eigenmode(shape, axes):
    q0, cos_sum = _mode(shape, axes)
    axes = np.array(axes, dtype=np.int64)
    free = np.ones(q0.shape, dtype=np.uint8)
    free[3, 2, 1] = 0  # a prescribed face keeps its value
    out = np.full_like(q0, np.nan)
    changes, peaks = np.zeros(q0.shape[0]), np.zeros(q0.shape[0])
    diffusion.jacobi_first_sweep(q0, out, ALPHA, axes, free, changes, peaks)
    d = int(axes.sum())
    expected = q0 * (1 + ALPHA * cos_sum) / (1 + 2 * ALPHA * d)
    expected[3, 2, 1] = q0[3, 2, 1]
    inner = (slice(1, -1),) * 3
    np.testing.assert_allclose(out[inner], expected[inner], rtol=0, atol=1e-14)
    # ghosts copied (the caller refills them), peaks and changes per padded plane
    ghost = np.ones(q0.shape, dtype=bool)
    ghost[inner] = False
    assert np.array_equal(out[ghost], q0[ghost])
    np.testing.assert_allclose(peaks, np.abs(q0).max(axis=(1, 2)), rtol=0, atol=0)
    change = np.abs(expected - q0)
    change[ghost] = 0.0
    np.testing.assert_allclose(changes, change.max(axis=(1, 2)), rtol=0, atol=1e-14)


def test_sweeps_converge_to_the_implicit_solution():
    """Jacobi then red-black Gauss-Seidel sweeps (ghosts refilled periodically between
    half sweeps) reach q0 / (1 + alpha sum_b (2 - 2 cos theta_b))."""
    q0, cos_sum = _mode(SHAPE, (1, 1, 1))
    axes = np.ones(3, dtype=np.int64)
    free = np.ones(q0.shape, dtype=np.uint8)
    changes, peaks = np.zeros(q0.shape[0]), np.zeros(q0.shape[0])
    q = np.empty_like(q0)
    diffusion.jacobi_first_sweep(q0, q, ALPHA, axes, free, changes, peaks)
    inner = (slice(1, -1),) * 3
    for _ in range(60):
        for colour in (0, 1):
            q[...] = np.pad(q[inner], 1, mode="wrap")
            diffusion.gauss_seidel_half(q, q0, colour, ALPHA, axes, free, changes)
    exact = q0 / (1 + ALPHA * (6 - cos_sum))
    np.testing.assert_allclose(q[inner], exact[inner], rtol=0, atol=1e-12)
