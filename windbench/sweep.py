"""Sweeps that survive faults: per-run status files, folder locks, resume, the closing count.

Every run leaves ``run_status.yaml`` beside its dataset (written atomically) saying
``complete``, ``failed``, ``invalid`` (bad input, nothing run) or ``skipped`` (resumed:
a complete dataset with the same resolved config and code was already there). At the end
of a multirun, :class:`SweepSummary` (a Hydra callback, see ``conf/config.yaml``) counts
them, prints one line, whatever launcher ran the jobs (basic, joblib, submitit), and sets
the exit status (:func:`exit_status`); after each run it prints how many of the sweep's
runs are done and how many failed (:func:`progress_line`).

One writer per run folder: a run (and a whole sweep, on its sweep folder) holds
:class:`FolderLock`, a lock file created atomically with the writer's PID and host. A
second writer finding it held by a live process refuses; a lock whose process is gone
(same host) is taken over with a message, and the dead writer's temporary files with it.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections import Counter
from pathlib import Path
from typing import Any

import yaml
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from windbench.dataset import CODE_ATTRS, code_version, current_code, owner_tag, read, verify
from windbench.dataset import temporary_name as _temporary_name
from windbench.errors import DatasetUnreadable, FolderBusy

log = logging.getLogger("windbench")
STATUS_FILE = "run_status.yaml"
SWEEP_FILE = ".windbench_sweep.yaml"  # the sweep's planned run count and start time
FAILURES = ("failed", "invalid", "unreadable")
LOCK_FILE = ".windbench.lock"
STATUSES = ("complete", "failed", "invalid", "skipped")
# keys that do not change a run's numbers: ignored when deciding whether to resume
NON_SEMANTIC = ("resume", "runtime", "sim.progress", "sim.max_steps")
exit_code = 0  # of the last multirun in this process (set by SweepSummary)


def write_status(out_dir: Path, status: str, **info: Any) -> None:
    """Atomically write ``run_status.yaml`` in ``out_dir`` (mode from the user's umask)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = _temporary_name(out_dir / STATUS_FILE)
    try:
        with open(tmp, "x") as fh:
            yaml.safe_dump({"status": status, **info}, fh)
        os.replace(tmp, out_dir / STATUS_FILE)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


# ------------------------------------------------------------------------ resume
def semantic_config(cfg) -> dict:
    """The resolved config as a plain dict without the keys that do not change results."""
    if isinstance(cfg, str):
        data = yaml.safe_load(cfg)
    else:
        data = OmegaConf.to_container(cfg, resolve=True)
    for dotted in NON_SEMANTIC:
        node = data
        *parents, leaf = dotted.split(".")
        for p in parents:
            node = node.get(p, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict):
            node.pop(leaf, None)
    return data


def resume_decision(cfg: DictConfig, path: Path) -> tuple[bool, str]:
    """(skip, why) for a run whose dataset would be ``path``: skip only a dataset that is
    whole (checksums verified), complete, of the same config and, unless
    ``resume.code=any``, made by the same code (:data:`windbench.dataset.CODE_ATTRS`)."""
    path = Path(path)
    if not path.exists():
        return False, "no dataset yet"
    try:
        verify(path)
    except DatasetUnreadable as err:
        return False, f"the dataset is unreadable ({err})"
    with read(path) as ds:
        attrs = dict(ds.attrs)
    if attrs.get("status") != "complete":
        return False, f"the dataset's status is {attrs.get('status')!r}"
    if semantic_config(attrs.get("config", "")) != semantic_config(cfg):
        return False, "the config changed"
    now = current_code()
    if cfg.resume.code != "any" and any(str(attrs.get(k)) != now[k] for k in CODE_ATTRS):
        return False, (
            f"it was made by {code_version(attrs)}, this is {code_version(now)} "
            "(resume.code=any keeps it)"
        )
    return True, "complete with the same config and code"


# ------------------------------------------------------------------------ lock
def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


class FolderLock:
    """``with FolderLock(folder):`` — this process is the folder's only writer.

    The lock file (:data:`LOCK_FILE`) is created with ``O_EXCL`` and holds ``pid host
    time``. Re-entrant within a process (a single run locks its folder before Hydra starts
    and again in the task). ``where`` names the folder in the refusal (e.g.
    ``hydra.run.dir``).
    """

    def __init__(self, folder: Path, where: str = "run folder"):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_FILE
        self.where = where
        self.owned = False

    def __enter__(self) -> FolderLock:
        self.folder.mkdir(parents=True, exist_ok=True)
        for _ in range(3):  # create, or take over a stale lock and create
            try:
                self._create()
            except FileExistsError:
                if self._held_by_us():
                    return self
                self._take_over()  # FolderBusy if a live run holds it
                continue
            self.owned = True
            return self
        raise FolderBusy(f"{self.where}: could not take the lock {self.path}")

    def _create(self) -> None:
        """Create the lock file whole or not at all (FileExistsError if it exists): its
        text goes to a temporary first, which is then hard-linked to the lock's name, so
        that another process never reads a lock file that is still empty."""
        host, pid = socket.gethostname(), os.getpid()
        tmp = self.folder / f"{LOCK_FILE}.{owner_tag(host, pid)}.new.tmp"
        text = f"{pid} {host} {time.time():.0f}\n"
        tmp.write_text(text)
        try:
            os.link(tmp, self.path)
        except FileExistsError:
            raise
        except OSError:  # a file system without hard links: exclusive create, then write
            with os.fdopen(
                os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666), "w"
            ) as fh:
                fh.write(text)
        finally:
            tmp.unlink(missing_ok=True)

    def __exit__(self, *exc) -> None:
        if self.owned:
            self.path.unlink(missing_ok=True)
            self.owned = False

    def _holder(self) -> tuple[int, str]:
        try:
            pid, host, *_ = self.path.read_text().split()
            return int(pid), host
        except (OSError, ValueError):
            return -1, ""  # vanished or half written: try again

    def _held_by_us(self) -> bool:
        pid, host = self._holder()
        return pid == os.getpid() and host == socket.gethostname()

    def _take_over(self) -> None:
        """Remove a stale lock (its run is gone) with that run's temporaries; FolderBusy if
        a live run holds it."""
        pid, host = self._holder()
        if pid < 0:
            return
        if host != socket.gethostname():
            raise FolderBusy(
                f"{self.where}: {self.folder} is in use by process {pid} on host {host} "
                f"(lock file {self.path}; delete it if that run is gone)"
            )
        if _alive(pid):
            raise FolderBusy(
                f"{self.where}: {self.folder} is in use by run {pid} on this host; "
                "wait for it to finish or choose another folder"
            )
        stale = self.path.with_name(f"{LOCK_FILE}.stale.{os.getpid()}")
        try:
            os.rename(self.path, stale)  # atomic: one of two racing takers wins
        except FileNotFoundError:
            return
        removed = remove_temporaries(self.folder, owner_tag(host, pid))
        stale.unlink(missing_ok=True)
        log.warning(
            "%s: took over the lock of run %d, which is no longer running (%d temporary "
            "files of it removed)",
            self.folder,
            pid,
            removed,
        )


def remove_temporaries(folder: Path, owner: str) -> int:
    """Delete the temporary files of writer ``owner`` (``host.pid``) in ``folder``."""
    n = 0
    for tmp in Path(folder).glob(f".*.{owner}.*.tmp"):
        tmp.unlink(missing_ok=True)
        n += 1
    return n


# ------------------------------------------------------------------------ summary
def count_statuses(sweep_dir: Path, since: float | None = None) -> Counter:
    """Runs per status under ``sweep_dir``; with ``since`` (a time.time()), only the
    status files written since then (the runs of this sweep, not of an earlier one)."""
    counts: Counter = Counter()
    for status_file in Path(sweep_dir).rglob(STATUS_FILE):
        if since is not None and status_file.stat().st_mtime < since:
            continue
        try:
            counts[yaml.safe_load(status_file.read_text())["status"]] += 1
        except (OSError, yaml.YAMLError, KeyError, TypeError):
            counts["unreadable"] += 1
    return counts


def exit_status(counts: Counter) -> int:
    """0 when every run is complete or skipped; 2 when any was invalid (bad input: fix
    it first); else 1 (a run failed, or its status file is unreadable)."""
    if counts.get("invalid", 0):
        return 2
    return 0 if set(counts) <= {"complete", "skipped"} else 1


def summary_line(counts: Counter, sweep_dir) -> str:
    parts = [f"{counts.get(s, 0)} {s}" for s in STATUSES]
    parts += [f"{n} {s}" for s, n in counts.items() if s not in STATUSES]
    return f"windbench sweep: {', '.join(parts)} ({sweep_dir})"


def planned_runs(config: DictConfig) -> int | None:
    """How many runs the sweep of ``config`` launches, as Hydra's basic sweeper (which the
    basic and joblib launchers use) expands its ``params`` and the command line's sweeps;
    None where it cannot be told (another sweeper, a glob)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = OmegaConf.select(config, "hydra.sweeper.params", default=None) or {}
    args = [f"{k}={v}" for k, v in params.items()]
    args += list(OmegaConf.select(config, "hydra.overrides.task", default=None) or [])
    try:
        overrides = OverridesParser.create().parse_overrides(args)
        return sum(len(batch) for batch in BasicSweeper.split_arguments(overrides, None))
    except Exception:  # noqa: BLE001 - a sweep this count does not know: no total
        return None


def progress_line(sweep_dir: Path) -> str:
    """``windbench sweep: 3/12 runs done (1 failed)``: the runs of the sweep in progress
    in ``sweep_dir`` (started as :data:`SWEEP_FILE` says) that have a status."""
    try:
        plan = yaml.safe_load((Path(sweep_dir) / SWEEP_FILE).read_text()) or {}
    except (OSError, yaml.YAMLError):
        plan = {}
    counts = count_statuses(sweep_dir, since=plan.get("started"))
    total = plan.get("runs")
    failed = sum(counts.get(s, 0) for s in FAILURES)
    done = f"{sum(counts.values())}/{total if total is not None else '?'}"
    return f"windbench sweep: {done} runs done ({failed} failed)"


class SweepSummary(Callback):
    """After each run of a multirun, the count of its runs done and failed (on every
    launcher: the count is read from the status files); when it ends, the one-line count
    of its outcomes, and the process's exit status (``windbench.sweep.exit_code``, read by
    ``windbench.cli``)."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        plan = {"runs": planned_runs(config), "started": time.time()}
        tmp = _temporary_name(sweep_dir / SWEEP_FILE)
        tmp.write_text(yaml.safe_dump(plan))
        os.replace(tmp, sweep_dir / SWEEP_FILE)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        from hydra.types import RunMode

        if OmegaConf.select(config, "hydra.mode", default=None) != RunMode.MULTIRUN:
            return
        line = progress_line(Path(config.hydra.sweep.dir))
        log.info(line)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        global exit_code
        sweep_dir = Path(config.hydra.sweep.dir)
        counts = count_statuses(sweep_dir)
        exit_code = exit_status(counts)
        print(summary_line(counts, sweep_dir), flush=True)
