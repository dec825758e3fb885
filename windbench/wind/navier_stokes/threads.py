"""The Navier-Stokes kernels' two compiled versions: one that splits its ``prange`` loop
over numba's threads, one that runs it as a plain loop; and the choice between them.

Threads cost twice on a small grid. numba's parallel version of a kernel takes several
times the compile time of the serial one (its loop analysis and threaded wrapper,
``experiments/compile_times.py``), and waking the other threads (a passive wait,
:mod:`windbench.runtime`) for each of the step's few hundred loops costs more than the
second thread gains. A grid below ``PARALLEL_CELLS`` cells runs the serial versions
(:func:`select`), so the small runs of a first try, a test suite or a parallel sweep never
compile the parallel ones; larger grids run the parallel versions on the run's threads.
The threshold is where the parallel versions overtake the serial ones on two threads
(``experiments/bench_kernel_versions.py`` steps both in one process,
``experiments/results/bench_kernel_versions.csv``). The serial versions are that fast
only where their loops keep no array views or array-taking helpers in branchy code: there
numba's reference counting stays in a plain loop (:func:`.projection.face_cells`).

Both versions are compiled from the same source, each with its own cache entry (the
serial one under the kernel's name with ``SERIAL_SUFFIX``), with the error model numba
gives a parallel loop's body and without fast-math flags (:mod:`.flags`), and every sum
is taken in a fixed order: the same bits either way.
"""

from __future__ import annotations

import functools
import types

from numba import njit

PARALLEL_CELLS = 1 << 18  # cells of the smallest grid whose kernels run their parallel versions
SERIAL_SUFFIX = "_serial"  # name suffix of the serial versions' cache entries


class _Choice:
    """Which version the kernels run (module state: one run per process at a time)."""

    parallel = True


def select(cells: int) -> bool:
    """Run the parallel versions from now on iff the grid has ``cells`` >= PARALLEL_CELLS
    cells; returns that choice."""
    _Choice.parallel = int(cells) >= PARALLEL_CELLS
    return _Choice.parallel


def _renamed(fn, suffix: str):
    """A copy of function ``fn`` whose qualified name ends in ``suffix`` (numba names a
    function's cache files after it)."""
    copy = types.FunctionType(
        fn.__code__, fn.__globals__, fn.__name__ + suffix, fn.__defaults__, fn.__closure__
    )
    copy.__qualname__ = fn.__qualname__ + suffix
    copy.__module__, copy.__doc__ = fn.__module__, fn.__doc__
    return copy


class Kernel:
    """A kernel with a parallel and a serial version, compiled on first use; calling it
    runs the version :func:`select` chose."""

    def __init__(self, fn, options):
        self.parallel = njit(cache=True, parallel=True, **options)(fn)
        self.serial = njit(cache=True, error_model="numpy", **options)(_renamed(fn, SERIAL_SUFFIX))
        functools.update_wrapper(self, fn)

    def __call__(self, *args):
        return (self.parallel if _Choice.parallel else self.serial)(*args)

    def on(self, cells: int):
        """The version for a field of ``cells`` cells within the run's choice: serial on
        one below PARALLEL_CELLS even where the run's grid is larger (a coarse multigrid
        level)."""
        return self.parallel if _Choice.parallel and cells >= PARALLEL_CELLS else self.serial


def threaded(**options):
    """Decorator: a :class:`Kernel` of the function, njit ``options`` for both versions."""
    return lambda fn: Kernel(fn, options)
