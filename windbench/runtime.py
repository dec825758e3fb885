"""Where a run's timings come from: its thread budget, the machine's load, its progress.

Thread budget (``runtime.threads``): a run's parallel kernels use ``auto`` = the cores
this process may run on divided by the runs a launcher has in flight at once (at least
one), or the number given. A parallel sweep of two runs on two cores then gives each run
one core instead of two threads each that take turns on both. Set with
``numba.set_num_threads`` before the run's first kernel; the dataset records it. (A
Navier-Stokes grid below ``threads.PARALLEL_CELLS`` cells runs serial kernels whatever
the count: :mod:`windbench.wind.navier_stokes.threads`.)

Honest timing: each step records its process CPU time beside its wall time, and the
dataset the machine's load average when the run starts and ends (:func:`load_average`);
the report flags runs that shared their cores (:mod:`windbench.report.collect`).

Progress: on a terminal a progress bar; in a log (a sweep's job, a batch system) one line
every tenth of the run with the step rate and the time left (:class:`ProgressLog`).
"""

from __future__ import annotations

import logging
import math
import os
import time

from windbench.errors import ConfigError

log = logging.getLogger("windbench")
AUTO = "auto"
PROGRESS_EVERY = 0.1  # of a run's steps between two progress lines in a log
PROGRESS_QUIET = 2.0  # s: no line sooner than this after the previous one (short runs)


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def thread_pool_size() -> int:
    """Threads numba started with (``NUMBA_NUM_THREADS``): the most a run can use."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)


def thread_count(setting, jobs: int = 1, cores: int | None = None) -> int:
    """``runtime.threads`` as a number: ``auto`` is max(1, cores // jobs), ``cores`` the
    cores available (:func:`available_cores`) and ``jobs`` the runs in flight at once;
    a number must lie in [1, numba's pool size]. ConfigError otherwise."""
    limit = thread_pool_size()
    if str(setting) == AUTO:
        cores = available_cores() if cores is None else cores
        return max(1, min(limit, cores // max(1, int(jobs))))
    if isinstance(setting, int) and not isinstance(setting, bool) and 1 <= setting <= limit:
        return setting
    raise ConfigError(
        "runtime.threads",
        f"must be {AUTO!r} or an integer in [1, {limit}] (numba's thread pool, "
        f"NUMBA_NUM_THREADS), got {setting!r}",
    )


def use_threads(count: int) -> int:
    """Let this thread's parallel kernels use ``count`` threads; returns the count."""
    import numba

    numba.set_num_threads(int(count))
    return int(numba.get_num_threads())


def load_average() -> list[float]:
    """The machine's load average over 1, 5 and 15 minutes (runnable processes; NaN where
    the system does not say)."""
    try:
        return [float(x) for x in os.getloadavg()]
    except (AttributeError, OSError):  # pragma: no cover - not POSIX
        return [math.nan] * 3


def _duration(seconds: float) -> str:
    """``1 h 02 min``, ``3 min 05 s`` or ``42 s``."""
    s = int(round(seconds))
    if s >= 3600:
        return f"{s // 3600} h {s % 3600 // 60:02d} min"
    if s >= 60:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s} s"


class ProgressLog:
    """A log line each time another PROGRESS_EVERY of ``total`` steps is done: percent,
    steps, steps per second since the start and the time left at that rate; a mark
    reached within PROGRESS_QUIET s of the last line is passed over."""

    def __init__(self, label: str, total: int, clock=time.perf_counter):
        self.label = label
        self.total = int(total)
        self.clock = clock
        self.start = self.last = clock()
        self.mark = 1

    def update(self, done: int) -> str | None:
        """Called after step ``done`` (1-based); returns the line it logged, if any."""
        if self.total <= 0 or done < self.mark * PROGRESS_EVERY * self.total - 1e-9:
            return None
        while self.mark * PROGRESS_EVERY * self.total <= done + 1e-9:
            self.mark += 1
        now = self.clock()
        if now - self.last < PROGRESS_QUIET:
            return None
        self.last = now
        elapsed = max(now - self.start, 1e-9)
        rate = done / elapsed
        line = (
            f"{self.label}: {100 * done / self.total:3.0f}% ({done}/{self.total} steps), "
            f"{rate:.3g} steps/s, ETA {_duration((self.total - done) / rate)}"
        )
        log.info(line)
        return line
