"""``windbench-report DIR... [--out PATH] [--reference DIR...] [--export DIR] [--jobs N]``.

Exit status 0 when the report was written (skipped runs are listed, not fatal: a damaged
dataset is listed as ``unreadable: checksum ...`` and never combined), 2 on bad arguments
or when no run file is found. The code versions that made the runs are listed, with a
warning when a sweep mixes several.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="windbench-report",
        description="Turn windbench run or sweep folders into a report (results.nc, "
        "summary.csv, figures, report.md, index.html).",
    )
    p.add_argument("inputs", nargs="+", type=Path, metavar="DIR", help="run or sweep folders")
    p.add_argument("--out", type=Path, help="output folder (default reports/<sweep name>/)")
    p.add_argument(
        "--reference",
        type=Path,
        nargs="+",
        metavar="DIR",
        help="folders with the reference runs for lee_error: per scene the finest "
        "second-order navier_stokes run and its coarser levels (default: those among the "
        "inputs)",
    )
    p.add_argument(
        "--export",
        type=Path,
        metavar="DIR",
        help="also write each run's wind (VTK image data) and cloth (VTK polydata + .pvd, PLY)",
    )
    p.add_argument(
        "--export-every", type=int, default=1, metavar="N", help="export every N-th cloth frame"
    )
    p.add_argument(
        "--jobs",
        type=int,
        metavar="N",
        help="processes for reading runs and drawing animations (default: the cores "
        "available; the report is the same for any N)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.export_every < 1:
        parser().error("--export-every: must be >= 1")
    if args.jobs is not None and args.jobs < 1:
        parser().error(f"--jobs: must be >= 1, got {args.jobs}")
    import matplotlib

    matplotlib.use("Agg")
    from windbench.report.build import build_report
    from windbench.runtime import available_cores

    try:
        report = build_report(
            args.inputs,
            out=args.out,
            reference=args.reference,
            export=args.export,
            export_every=args.export_every,
            progress=not args.quiet,
            jobs=args.jobs or available_cores(),
        )
    except FileNotFoundError as err:
        print(f"windbench-report: error: {err}", file=sys.stderr)
        return 2
    from windbench.report.collect import code_versions

    n_ok = sum(r.status == "complete" for r in report.records)
    print(f"windbench-report: {n_ok} of {len(report.records)} runs combined -> {report.out}")
    versions = code_versions(report.records)
    print(f"  code: {'; '.join(versions) or 'unknown'}")
    if len(versions) > 1:
        print(
            f"windbench-report: warning: the runs were made by {len(versions)} code versions "
            "(summary.csv column 'code'); rerun with resume=true for one",
            file=sys.stderr,
        )
    for rec in report.skipped:
        reason = rec.reason if len(rec.reason) <= 200 else rec.reason[:199] + "…"
        print(f"  skipped {rec.path}: {rec.status}: {reason}")
    if report.missing:
        print(f"  figures not drawn (runs missing, see report.md): {', '.join(report.missing)}")
    if args.export:
        print(f"  exported {len(report.exported)} ParaView series to {args.export}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
