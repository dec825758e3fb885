"""The Navier-Stokes kernels' two compiled versions: one that splits its ``prange`` loop
over numba's threads, one that runs it as a plain loop; and the choice between them.

Threads cost twice where they cannot pay off. numba's parallel version of a kernel takes
3-5 times the compile time of the serial one (its loop analysis and threaded wrapper; one
process, empty cache: ``subtract_gradient`` 3.0 against 0.64 CPU s, ``residual`` 3.4
against 0.9), and on a small grid waking the other threads for every loop costs more than
the loop (the 20-cell ``smoke`` scene, two threads: projection 8.1 ms per step against
0.75 ms on one). A run uses the parallel versions only when it has more than one thread
and its grid at least ``PARALLEL_CELLS`` cells (:func:`select`); a one-thread run, as
every run of a parallel sweep on a small machine is, never compiles them.

Both versions are compiled from the same source, each with its own cache entry (the
serial one under the kernel's name with ``SERIAL_SUFFIX``), without fast-math flags
(:mod:`.flags`), and every sum is taken in a fixed order: the same bits either way.
"""

from __future__ import annotations

import functools
import types

import numba
from numba import njit

PARALLEL_CELLS = 32768  # cells of the smallest grid whose kernels run on threads
SERIAL_SUFFIX = "_serial"  # name suffix of the serial versions' cache entries


class _Choice:
    """Which version the kernels run (module state: one run per process at a time)."""

    parallel = True


def select(cells: int) -> bool:
    """Run the parallel versions from now on iff this thread has more than one numba
    thread and the grid ``cells`` >= PARALLEL_CELLS; returns that choice."""
    _Choice.parallel = numba.get_num_threads() > 1 and int(cells) >= PARALLEL_CELLS
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
        self.serial = njit(cache=True, **options)(_renamed(fn, SERIAL_SUFFIX))
        functools.update_wrapper(self, fn)

    def __call__(self, *args):
        return (self.parallel if _Choice.parallel else self.serial)(*args)


def threaded(**options):
    """Decorator: a :class:`Kernel` of the function, njit ``options`` for both versions."""
    return lambda fn: Kernel(fn, options)
