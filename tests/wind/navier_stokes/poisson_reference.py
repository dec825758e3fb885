"""The pressure operator written out with numpy: the reference the pressure kernels
(:mod:`windbench.wind.navier_stokes.multigrid`, :mod:`windbench.wind.navier_stokes.coarse_levels`) are tested against."""

from __future__ import annotations

import numpy as np


def operator_numpy(x, w, periodic):
    """A x = sum_f w_f (x_c - x_nb), ghost x = 0 outside a non-periodic axis."""
    out = np.zeros_like(x)
    for a in range(3):
        n = x.shape[a]
        for side in (0, 1):  # the - face (index i) and the + face (index i + 1) of cell i
            wf = np.take(w[a], np.arange(n) + side, axis=a)
            shift = -1 if side == 0 else 1
            nb = np.roll(x, -shift, axis=a)
            if not periodic[a]:
                edge = [slice(None)] * 3
                edge[a] = 0 if side == 0 else n - 1
                nb[tuple(edge)] = 0.0
            out += wf * (x - nb)
    return out
