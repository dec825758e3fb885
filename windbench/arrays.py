"""Array copies, the cross product and the largest row distance for compiled kernels,
written as loops.

numba compiles three common array operations with an error path that formats its
message at run time, and the string machinery behind it is compiled once per process on
first use: an array-to-array assignment (``a[:] = b``, ``a[i] = row``; its message
names both shapes), ``np.cross`` and ``ndarray.transpose(axes)``. In a fresh process
each costs seconds of compile time on first use, many times the loop that does the same
(``experiments/compile_first_use.py``). Every cold process that compiles a
kernel paid them, so the kernels use these instead: the same numbers, since each element
is computed by the same operations in the same order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def copy_head(dst, src, n):
    """dst[:n] = src[:n] for 1-D arrays."""
    for i in range(n):
        dst[i] = src[i]


@njit(cache=True)
def copy_rows(dst, src, n):
    """dst[:n] = src[:n] for 2-D arrays of equal width."""
    for i in range(n):
        for k in range(src.shape[1]):
            dst[i, k] = src[i, k]


@njit(cache=True)
def cross(a, b):
    """a x b of two 3-vectors, as ``np.cross``: (a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0)."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(cache=True)
def largest_move(p, q):
    """max_i |p_i - q_i| (m) of two (n, 3) arrays."""
    d2 = 0.0
    for i in range(p.shape[0]):
        dx, dy, dz = p[i, 0] - q[i, 0], p[i, 1] - q[i, 1], p[i, 2] - q[i, 2]
        d2 = max(d2, dx * dx + dy * dy + dz * dz)
    return math.sqrt(d2)
