"""Sweeps that survive faults: per-run status files, resume, and the closing count.

Every run leaves ``run_status.yaml`` beside its dataset (written atomically) saying
``complete``, ``failed``, ``invalid`` (bad input, nothing run) or ``skipped`` (resumed:
a complete dataset with the same resolved config was already there). At the end of a
multirun, :class:`SweepSummary` (a Hydra callback, see ``conf/config.yaml``) counts them
and prints one line, whatever launcher ran the jobs (basic, joblib, submitit).
"""

from __future__ import annotations

import os
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

import yaml
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from windbench.dataset import is_complete, read

STATUS_FILE = "run_status.yaml"
STATUSES = ("complete", "failed", "invalid", "skipped")
# keys that do not change a run's numbers: ignored when deciding whether to resume
NON_SEMANTIC = ("resume", "sim.progress")


def write_status(out_dir: Path, status: str, **info: Any) -> None:
    """Atomically write ``run_status.yaml`` in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{STATUS_FILE}.", dir=out_dir)
    with os.fdopen(fd, "w") as fh:
        yaml.safe_dump({"status": status, **info}, fh)
    os.replace(tmp, out_dir / STATUS_FILE)


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


def already_done(cfg: DictConfig, path: Path) -> bool:
    """True if ``path`` holds a complete dataset of the same (semantic) config."""
    if not is_complete(path):
        return False
    with read(path) as ds:
        return semantic_config(ds.attrs.get("config", "")) == semantic_config(cfg)


def remove_stale_temporaries(out_dir: Path) -> None:
    """Delete temporary files a killed run left behind (never the final dataset)."""
    for tmp in Path(out_dir).glob(".*.tmp"):
        tmp.unlink(missing_ok=True)


def count_statuses(sweep_dir: Path) -> Counter:
    counts: Counter = Counter()
    for status_file in Path(sweep_dir).rglob(STATUS_FILE):
        try:
            counts[yaml.safe_load(status_file.read_text())["status"]] += 1
        except (OSError, yaml.YAMLError, KeyError, TypeError):
            counts["unreadable"] += 1
    return counts


def summary_line(counts: Counter, sweep_dir) -> str:
    parts = [f"{counts.get(s, 0)} {s}" for s in STATUSES]
    parts += [f"{n} {s}" for s, n in counts.items() if s not in STATUSES]
    return f"windbench sweep: {', '.join(parts)} ({sweep_dir})"


class SweepSummary(Callback):
    """Prints the one-line count of a sweep's outcomes when the multirun ends."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        print(summary_line(count_statuses(sweep_dir), sweep_dir), flush=True)
