"""Appending measured rows to a results CSV (``experiments/results/*.csv``)."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path


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
