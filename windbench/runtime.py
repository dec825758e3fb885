"""Where a run's timings come from: its thread budget, the machine's load, its progress.

Thread budget (``runtime.threads``): a run's parallel kernels use ``auto`` = the cores
this process may run on divided by the runs a launcher has in flight at once (at least
one), or the number given. A parallel sweep of two runs on two cores then gives each run
one core instead of two threads each that take turns on both. Set with
``numba.set_num_threads`` before the run's first kernel; the dataset records it. Under
``auto`` the run also keeps to the cores that other processes leave free where that is
faster, re-read as it runs (:class:`ThreadBudget`); the dataset records each step's count.
(A Navier-Stokes grid below ``threads.PARALLEL_CELLS`` cells runs serial kernels whatever
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
from pathlib import Path

from windbench.errors import ConfigError

log = logging.getLogger("windbench")
AUTO = "auto"
RECHECK = 0.25  # s between two readings of the cores that other processes keep busy
PROC_STAT = Path("/proc/stat")  # Linux: CPU time of each core since boot, in clock ticks
PROGRESS_EVERY = 0.1  # of a run's steps between two progress lines in a log
PROGRESS_QUIET = 2.0  # s: no line sooner than this after the previous one (short runs)


def cpu_set() -> list[int]:
    """The CPU numbers this process may run on (its affinity, else all the machine's)."""
    try:
        return sorted(os.sched_getaffinity(0)) or [0]
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return list(range(max(1, os.cpu_count() or 1)))


def available_cores() -> int:
    """Cores this process may run on (:func:`cpu_set`)."""
    return len(cpu_set())


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


def busy_seconds(stat_text: str, cores, tick: float) -> float:
    """CPU seconds the ``cores`` (CPU numbers) have spent busy since boot, from the text of
    /proc/stat: user, nice, system, irq, softirq and steal ticks of each ``cpuN`` line
    (guest time is inside user) times ``tick`` seconds. ValueError if a core has no line
    (a container's /proc/stat may number its cores apart from the affinity's)."""
    wanted = {f"cpu{c}" for c in cores}
    ticks, found = 0, 0
    for line in stat_text.splitlines():
        fields = line.split()
        if fields and fields[0] in wanted:
            user, nice, system, _idle, _iowait, irq, softirq, steal = map(int, fields[1:9])
            ticks += user + nice + system + irq + softirq + steal
            found += 1
    if found < len(wanted):
        raise ValueError(f"/proc/stat has no line for some of the cores {sorted(cores)}")
    return ticks * tick


class BusyElsewhere:
    """How many of this process's cores other processes kept busy between two readings:
    (busy seconds of those cores - this process's CPU seconds) / wall seconds, from
    /proc/stat; None where the system does not say (not Linux).

    ``read()`` gives /proc/stat's text, ``clock`` wall time and ``cpu_clock`` the process's
    CPU time (all its threads; a child process counts as another process)."""

    def __init__(self, cores=None, read=None, clock=time.monotonic, cpu_clock=time.process_time):
        self.cores = cpu_set() if cores is None else list(cores)
        self.read = read or PROC_STAT.read_text
        self.clock, self.cpu_clock = clock, cpu_clock
        self.tick = 1.0 / os.sysconf("SC_CLK_TCK")
        self.last = self._sample()

    def _sample(self) -> tuple[float, float, float] | None:
        try:
            busy = busy_seconds(self.read(), self.cores, self.tick)
        except (OSError, ValueError):  # no /proc/stat, or one this parser does not know
            return None
        return self.clock(), busy, self.cpu_clock()

    def reading(self) -> float | None:
        """Cores busy elsewhere since the last reading (>= 0), or None."""
        now, last = self._sample(), self.last
        self.last = now
        if now is None or last is None or now[0] <= last[0]:
            return None
        elsewhere = (now[1] - last[1]) - (now[2] - last[2])
        return max(0.0, elsewhere / (now[0] - last[0]))


def threads_beside(planned: int, cores: int, busy_elsewhere: float) -> int:
    """The threads for a run that plans ``planned`` of ``cores`` while other processes keep
    ``busy_elsewhere`` cores busy: min(planned, free) with free = cores - round(busy
    elsewhere) when free >= planned / 2, else ``planned``.

    A parallel loop is split evenly among its n threads and ends when the slowest does. A
    thread that shares its core with a busy process runs at half speed, so a loop takes
    2 / n of its one-thread time when some of the n threads share, 1 / n when none does:
    the free cores alone are the faster choice when free >= planned / 2 (on a tie they
    leave the busy process its core)."""
    free = int(cores) - round(busy_elsewhere)
    return max(1, min(int(planned), free)) if 2 * free >= int(planned) else int(planned)


class ThreadBudget:
    """The numba threads of a run's parallel kernels, step by step.

    ``planned`` threads (:func:`thread_count`); when ``adaptive`` (``runtime.threads=auto``)
    only the cores other processes leave free, where that is faster (:func:`threads_beside`),
    re-read every RECHECK s by :meth:`update` (``experiments/bench_contention.py``).
    Kernels sum in a fixed order, so the count changes timings only, never results."""

    def __init__(self, planned: int, adaptive: bool = False, watch=None, clock=time.monotonic):
        self.planned = int(planned)
        self.current = use_threads(self.planned)
        self.watch = (watch or BusyElsewhere()) if adaptive else None
        self.clock = clock
        self.checked = clock()

    @classmethod
    def of(cls, setting, jobs: int = 1) -> ThreadBudget:
        """The budget of ``runtime.threads`` = ``setting`` with ``jobs`` runs in flight:
        :func:`thread_count` planned, adaptive under ``auto``."""
        return cls(thread_count(setting, jobs), adaptive=str(setting) == AUTO)

    @classmethod
    def as_set(cls) -> ThreadBudget:
        """A fixed budget of the threads numba runs with now."""
        import numba

        return cls(numba.get_num_threads())

    def update(self) -> int:
        """The thread count for the next step (set in numba when it changes)."""
        if self.watch is None or self.clock() - self.checked < RECHECK:
            return self.current
        self.checked = self.clock()
        elsewhere = self.watch.reading()
        if elsewhere is not None:
            wanted = threads_beside(self.planned, len(self.watch.cores), elsewhere)
            if wanted != self.current:
                log.debug("%.2f cores busy elsewhere: %d threads", elsewhere, wanted)
                self.current = use_threads(wanted)
        return self.current

    def note(self) -> str:
        """What a progress line says of the budget: nothing while it runs as planned."""
        if self.current == self.planned:
            return ""
        return f"{self.current} of {self.planned} threads (cores busy elsewhere)"

    def restart(self):
        """Read the load afresh from now on: the time before (a first step that compiled,
        beside the process that compiled the cloth's kernels) says nothing of the steps."""
        if self.watch is not None:
            self.watch.reading()
            self.checked = self.clock()

    def restore(self) -> int:
        """Back to the planned count (what the dataset records as the run's threads)."""
        self.current = use_threads(self.planned)
        return self.current


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

    def update(self, done: int, note: str = "") -> str | None:
        """Called after step ``done`` (1-based); returns the line it logged, if any, with
        ``note`` at its end."""
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
        ) + (f"; {note}" if note else "")
        log.info(line)
        return line
