"""The small coarse levels of the pressure multigrid (:mod:`.multigrid`), run as one compiled
call per visit.

On the levels below ``multigrid.SERIAL_CELLS`` cells a thread start, a kernel call per
level and smoothing pass, and the per-row set-up of the row kernels cost more than the
arithmetic. Here those levels
share flat float32 arrays in natural (C) order, one block per level, and every cell
carries the global indices of its six neighbours (wrapped on periodic axes; beyond a
non-periodic face the *zero slot*, the last element, which stays 0: the ghost x = 0 of
:mod:`.multigrid`), its six face weights (coarse weights with their (h/H)^2 factor), its
diagonal and 1/diagonal. One call (:func:`run_cycle`) then runs the whole cycle below a
level from a schedule written once (:func:`schedule`).

The arithmetic is that of :mod:`.multigrid` (McAdams et al. 2010 as used there): red-black
Gauss-Seidel x_c <- x_c + OMEGA ((b_c + sum_f w_f x_nb) / diag_c - x_c) on cells with an
open face (cells without one are left alone), the residual b - A x restricted to the parent
cell as the sum over its children / a full block's count, the coarse correction prolonged
by injection; the
coarsest level gets many symmetric sweeps. Sums are taken in another order than there, so
the preconditioner changes in the last bits of float32 (tested against the operator
written out with numpy).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

PRE, POST, COARSEST = 0, 1, 2  # schedule operations (on one level each)
FACES = 6  # -x, +x, -y, +y, -z, +z
# :func:`_smooth`'s order as numpy bools: a literal True or False would compile it twice
RED_FIRST, BLACK_FIRST = np.bool_(False), np.bool_(True)


@njit(cache=True, inline="always")
def _neighbour_sum(x, nb, w, c):
    """sum_f w_f x_nb(f) for cell c."""
    return (
        w[c, 0] * x[nb[c, 0]]
        + w[c, 1] * x[nb[c, 1]]
        + w[c, 2] * x[nb[c, 2]]
        + w[c, 3] * x[nb[c, 3]]
        + w[c, 4] * x[nb[c, 4]]
        + w[c, 5] * x[nb[c, 5]]
    )


@njit(cache=True)
def half_sweep(x, b, nb, w, inv, cells, omega):
    """One colour of red-black SOR: x_c += omega ((b_c + sum_f w_f x_nb) / diag - x_c) for
    the cells listed (one colour, open cells only; their neighbours are of the other
    colour, so the order within the list does not matter)."""
    for m in range(cells.shape[0]):
        c = cells[m]
        target = (b[c] + _neighbour_sum(x, nb, w, c)) * inv[c]
        if omega == 1.0:
            x[c] = target
        else:
            x[c] += omega * (target - x[c])


@njit(cache=True)
def _smooth(x, b, nb, w, inv, order, ranges, level, sweeps, reverse, omega):
    """``sweeps`` red-black sweeps on ``level``, black first if ``reverse``."""
    start, split, stop = ranges[level, 0], ranges[level, 1], ranges[level, 2]
    for half in range(2 * sweeps):
        colour = (half + (1 if reverse else 0)) % 2
        if colour == 0:
            half_sweep(x, b, nb, w, inv, order[start:split], omega)
        else:
            half_sweep(x, b, nb, w, inv, order[split:stop], omega)


@njit(cache=True)
def residual_restrict(x, b, nb, w, diag, parent, first, count, coarse_first, coarse_count, mean):
    """b of the next level = the residual b - A x of the cells first .. first + count - 1
    summed over each parent's children, times ``mean`` (1 / a full block's count); also
    zeroes the next level's x (its cycle starts from 0)."""
    for c in range(coarse_first, coarse_first + coarse_count):
        b[c] = 0.0
        x[c] = 0.0
    for c in range(first, first + count):
        b[parent[c]] += b[c] - (diag[c] * x[c] - _neighbour_sum(x, nb, w, c))
    for c in range(coarse_first, coarse_first + coarse_count):
        b[c] *= mean


@njit(cache=True)
def prolong(x, parent, first, count):
    """x += the parent's x (injection) on the cells first .. first + count - 1."""
    for c in range(first, first + count):
        x[c] += x[parent[c]]


@njit(cache=True)
def run_cycle(ops, x, b, tables, sweeps, omega):
    """Run the schedule ``ops`` (rows (operation, level)): PRE = ``sweeps[0]`` sweeps, the
    residual restricted to the next level; POST = the correction prolonged from the next
    level, ``sweeps[0]`` sweeps in reverse order; COARSEST = ``sweeps[1]`` sweeps each way.
    ``tables`` are the levels' :class:`CellTables`; ``blocks[l]`` = (first cell, cell count)
    of level l."""
    nb, w, diag, inv, parent, order, ranges, blocks, mean = tables
    for n in range(ops.shape[0]):
        op, lev = ops[n, 0], ops[n, 1]
        if op == PRE:
            _smooth(x, b, nb, w, inv, order, ranges, lev, sweeps[0], RED_FIRST, omega)
            residual_restrict(
                x, b, nb, w, diag, parent, blocks[lev, 0], blocks[lev, 1],
                blocks[lev + 1, 0], blocks[lev + 1, 1], mean[lev],
            )  # fmt: skip
        elif op == POST:
            prolong(x, parent, blocks[lev, 0], blocks[lev, 1])
            _smooth(x, b, nb, w, inv, order, ranges, lev, sweeps[0], BLACK_FIRST, omega)
        else:
            _smooth(x, b, nb, w, inv, order, ranges, lev, sweeps[1], RED_FIRST, omega)
            _smooth(x, b, nb, w, inv, order, ranges, lev, sweeps[1], BLACK_FIRST, omega)


class CellTables(NamedTuple):
    """The flat per-cell tables of the small levels (see module docstring): neighbour
    indices, face weights, diagonal and its inverse, parent cell, the cells of each colour
    in order and their ranges, each level's block of cells and its mean flag."""

    nb: np.ndarray
    w: np.ndarray
    diag: np.ndarray
    inv: np.ndarray
    parent: np.ndarray
    order: np.ndarray
    ranges: np.ndarray
    blocks: np.ndarray
    mean: np.ndarray


def schedule(first: int, last: int, w_levels) -> np.ndarray:
    """The operations of one cycle from level ``first`` down to the coarsest ``last``
    (absolute level numbers, rows (operation, level - first)): a W on the levels in
    ``w_levels`` (two corrections from the next level), a V on the others."""
    ops = []

    def visit(n):
        if n == last:
            ops.append((COARSEST, n - first))
            return
        ops.append((PRE, n - first))
        for _ in range(2 if n in w_levels else 1):
            visit(n + 1)
        ops.append((POST, n - first))

    visit(first)
    return np.array(ops, dtype=np.int64).reshape(-1, 2)


def neighbour_table(shape, periodic, first: int, zero: int) -> np.ndarray:
    """Global indices (cells numbered from ``first`` in C order) of the six neighbours of
    every cell of a level: wrapped on periodic axes, ``zero`` beyond a non-periodic face."""
    index = first + np.arange(int(np.prod(shape)), dtype=np.int32).reshape(shape)
    table = np.empty((index.size, FACES), dtype=np.int32)
    for a in range(3):
        for side, shift in ((0, 1), (1, -1)):  # the -a neighbour is the array rolled by +1
            nb = np.roll(index, shift, axis=a)
            if not periodic[a]:
                edge = [slice(None)] * 3
                edge[a] = 0 if side == 0 else -1
                nb[tuple(edge)] = zero
            table[:, 2 * a + side] = nb.reshape(-1)
    return table


def face_weight_table(w) -> np.ndarray:
    """The six face weights of every cell (C order) from a level's face-weight arrays."""
    shape = (w[0].shape[0] - 1, w[0].shape[1], w[0].shape[2])
    table = np.empty((int(np.prod(shape)), FACES), dtype=w[0].dtype)
    for a in range(3):
        n = shape[a]
        for side in (0, 1):  # the - face (index i) and the + face (index i + 1) of cell i
            table[:, 2 * a + side] = np.take(w[a], np.arange(n) + side, axis=a).reshape(-1)
    return table


class CoarseLevels:
    """The levels ``levels`` (consecutive, the last the coarsest) in flat arrays; their
    ``x`` and ``b`` become views of those arrays, so the level above restricts into and
    prolongs from them as before."""

    def __init__(self, levels, periodic, first: int, w_levels, pre_sweeps, coarse_sweeps, omega):
        self.levels = levels
        sizes = [int(np.prod(lev.shape)) for lev in levels]
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        total = int(sum(sizes))
        dtype = levels[0].x.dtype
        self.blocks = np.stack([starts, np.array(sizes, dtype=np.int64)], axis=1)
        self.x = np.zeros(total + 1, dtype)  # + the zero slot
        self.b = np.zeros(total + 1, dtype)
        self.nb = np.concatenate(
            [
                neighbour_table(lev.shape, periodic, s, total)
                for lev, s in zip(levels, starts, strict=True)
            ]
        )
        self.parent = np.full(total, total, dtype=np.int32)  # the coarsest: no parent
        self.mean = np.ones(len(levels), dtype)
        for n, (lev, nxt) in enumerate(zip(levels[:-1], levels[1:], strict=True)):
            idx = np.indices(lev.shape).reshape(3, -1) // lev.ratio[:, None]
            coarse = np.ravel_multi_index(tuple(idx), nxt.shape)
            self.parent[starts[n] : starts[n] + sizes[n]] = starts[n + 1] + coarse
            self.mean[n] = 1.0 / np.prod(lev.ratio)
        for lev, s, size in zip(levels, starts, sizes, strict=True):
            lev.x = self.x[s : s + size].reshape(lev.shape)
            lev.b = self.b[s : s + size].reshape(lev.shape)
        self.w = np.zeros((total, FACES), dtype)
        self.diag = np.zeros(total, dtype)
        self.inv = np.zeros(total, dtype)
        self.order = np.zeros(total, dtype=np.int32)
        self.ranges = np.zeros((len(levels), 3), dtype=np.int64)
        self.colour = np.concatenate(  # (i + j + k) % 2 of every cell
            [(np.indices(lev.shape).sum(axis=0).reshape(-1) % 2).astype(np.int8) for lev in levels]
        )
        self.ops = schedule(first, first + len(levels) - 1, w_levels)
        self.sweeps = np.array([pre_sweeps, coarse_sweeps], dtype=np.int64)
        self.omega = float(omega)

    def set_weights(self):
        """Read the levels' face weights (after :meth:`MultigridPoisson.set_weights` has
        coarsened and scaled them) into the cell tables and list each colour's open cells."""
        filled = 0
        for n, lev in enumerate(self.levels):
            s, size = self.blocks[n]
            table = face_weight_table(lev.w)
            self.w[s : s + size] = table
            diag = table.sum(axis=1, dtype=table.dtype)
            self.diag[s : s + size] = diag
            self.inv[s : s + size] = np.where(diag > 0, 1.0 / np.where(diag > 0, diag, 1), 0)
            colour = self.colour[s : s + size]
            red = s + np.flatnonzero((diag > 0) & (colour == 0))
            black = s + np.flatnonzero((diag > 0) & (colour == 1))
            self.order[filled : filled + red.size] = red
            self.order[filled + red.size : filled + red.size + black.size] = black
            self.ranges[n] = filled, filled + red.size, filled + red.size + black.size
            filled += red.size + black.size

    def cycle(self):
        """One cycle from the first of these levels, from its current x."""
        tables = CellTables(
            self.nb, self.w, self.diag, self.inv, self.parent, self.order, self.ranges,
            self.blocks, self.mean,
        )  # fmt: skip
        run_cycle(self.ops, self.x, self.b, tables, self.sweeps, self.omega)
