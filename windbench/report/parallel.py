"""Independent pieces of a report (run files to read, animations to encode) spread over
worker processes.

Each piece is a pure function of its arguments (a file, a scene's runs), so the result is
the same whatever the number of workers; ``map`` keeps the input order. Workers are
started with ``spawn`` (a clean interpreter: no inherited matplotlib or thread state) and
cost seconds of imports each, so small batches stay in this process: a caller says how
many of its pieces make one worker worth starting. Functions of the library default to one
process (a script calling them needs no ``if __name__ == "__main__"`` guard, which
``spawn`` requires); ``windbench-report`` asks for the cores.
"""

from __future__ import annotations

import multiprocessing
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor

from tqdm.auto import tqdm


def worker_count(jobs: int, pieces: int, per_worker: int) -> int:
    """Processes for ``pieces`` independent pieces: ``jobs`` at most, and at most one per
    ``per_worker`` pieces, at least one."""
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    return max(1, min(jobs, pieces // per_worker))


class Batch:
    """``fn`` over ``items`` started in :func:`worker_count` processes at once, collected by
    :meth:`results`, so that this process can do other work meanwhile (with one process
    the work is done in :meth:`results`)."""

    def __init__(self, fn: Callable, items: Sequence, jobs: int, per_worker: int):
        self.fn, self.items = fn, list(items)
        n = worker_count(jobs, len(self.items), per_worker)
        self.pool = None
        if n > 1:
            context = multiprocessing.get_context("spawn")
            self.pool = ProcessPoolExecutor(n, mp_context=context)
            self.futures = [self.pool.submit(fn, x) for x in self.items]

    def results(self, desc: str = "", progress: bool = False) -> list:
        """``[fn(x) for x in items]`` in order; a tqdm bar on a terminal when ``progress``."""
        bar = tqdm(total=len(self.items), desc=desc, disable=not (progress and sys.stderr.isatty()))
        with bar:
            if self.pool is None:
                return [_tick(bar, self.fn(x)) for x in self.items]
            try:
                return [_tick(bar, f.result()) for f in self.futures]
            finally:
                self.close()

    def close(self) -> None:
        """Stop the workers (what has not started is cancelled); safe to call again."""
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)


def pmap(
    fn: Callable,
    items: Sequence,
    jobs: int,
    per_worker: int,
    desc: str = "",
    progress: bool = False,
) -> list:
    """``[fn(x) for x in items]`` over :func:`worker_count` processes (``fn`` must be a
    module-level function); a tqdm bar on a terminal when ``progress``."""
    return Batch(fn, items, jobs, per_worker).results(desc, progress)


def _tick(bar, result):
    bar.update()
    return result
