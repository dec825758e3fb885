"""Measured rows for a results CSV (``experiments/results/*.csv``): when and with which
code they were measured, and appending them to the file."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path


def measured_at() -> str:
    """The time now, UTC, to the second (ISO 8601): a row's ``date``."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def stamp() -> dict[str, str]:
    """A row's provenance: ``date`` (:func:`measured_at`) and ``code``, the version and
    git commit of the code measured (:func:`windbench.dataset.code_version`). windbench is
    imported here, not with this module: importing it sets numba's environment
    (:mod:`windbench`), which a script that times other settings must not inherit."""
    from windbench.dataset import code_version, current_code

    return {"date": measured_at(), "code": code_version(current_code())}


def append_rows(path: Path, rows: Sequence[dict], fields: Sequence[str]) -> None:
    """Append ``rows`` (dicts keyed by ``fields``) to the CSV at ``path``, with the header
    first when the file is new; one line ending, so the file diffs cleanly."""
    new = not path.exists()
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(fields), lineterminator="\n")
        if new:
            writer.writeheader()
        writer.writerows(rows)


def show_and_append(path: Path, rows: Sequence[dict], fields: Sequence[str], shown) -> None:
    """Print each row's ``shown`` fields on one line, then :func:`append_rows`."""
    for row in rows:
        print(", ".join(f"{k} {row[k]}" for k in shown))
    append_rows(path, rows, fields)
    print(f"appended {len(rows)} rows to {path}")
