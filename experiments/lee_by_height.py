"""Where a lee error comes from, height by height: for every run under RUNS against the
finest run under REFERENCE, per probe height of the lee box the run's and the reference's
mean wind along x (m/s) and that height's part of lee_error^2
(:func:`windbench.report.lee.lee_error_by_height`; the parts sum to lee_error^2).

    PYTHONPATH=$PWD python experiments/lee_by_height.py RUNS... --against REFERENCE [--out CSV]

e.g. the two_flags_wall comparison at 80 cells over four flow-through windows
(``sim.window_flow_throughs=4``; particles with ``wind.lee_model=paper`` and ``mixing``,
navier_stokes) against the 160-cell reference with the same window. Appends to
``experiments/results/lee_by_height.csv``: one row per run and height, with the date and
the run's code version.
"""

from __future__ import annotations

import argparse
from datetime import UTC, datetime
from pathlib import Path

from experiments.reference_noise import complete_runs, wind_model
from experiments.rows import append_rows
from windbench.report.lee import lee_error, lee_error_by_height

OUT = Path(__file__).resolve().parent / "results" / "lee_by_height.csv"
COLUMNS = [
    "date", "code", "scene", "resolution", "model", "reference", "lee_error", "z", "u_run",
    "u_reference", "part_of_error_squared", "folder",
]  # fmt: skip


def rows(folder: Path, against: Path) -> list[dict]:
    """The rows of every complete run in ``folder`` against the finest run in ``against``."""
    ref = max(complete_runs(against), key=lambda r: int(r.settings["resolution"]))
    found = []
    for run in complete_runs(folder):
        common = {
            "date": datetime.now(UTC).date().isoformat(),
            "code": run.code,
            "scene": run.settings["scene"],
            "resolution": run.settings["resolution"],
            "model": wind_model(run),
            "reference": ref.settings["resolution"],
            "lee_error": round(lee_error(run, ref), 4),
            "folder": folder.name,
        }
        for z, u_run, u_ref, part in lee_error_by_height(run, ref):
            found.append(
                common
                | {"z": round(z, 3), "u_run": round(u_run, 3), "u_reference": round(u_ref, 3)}
                | {"part_of_error_squared": round(part, 5)}
            )
    return found


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--against", type=Path, required=True, help="the reference sweep")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    found = [row for folder in args.runs for row in rows(folder, args.against)]
    for row in found:
        print(", ".join(f"{k} {row[k]}" for k in COLUMNS[3:-1]))
    append_rows(args.out, found, COLUMNS)
    print(f"appended {len(found)} rows to {args.out}")


if __name__ == "__main__":
    main()
