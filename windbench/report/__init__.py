"""Reports: run or sweep folders -> combined dataset -> figures -> report.

``windbench-report DIR... [--out PATH] [--reference DIR] [--export DIR]`` writes into the
output folder (default ``reports/<sweep name>/``):

- ``results.nc``   — the complete runs combined, the swept settings as dimensions;
- ``summary.csv``  — one row per run file: settings, lee figures, divergence, time per step,
  status and failure reason;
- ``figures/``     — PNG and SVG of the paper's Figs. 3-6 and of §4.3 measured;
- ``report.md`` and ``index.html`` (self-contained: images embedded, no network).

Modules: :mod:`.collect` (find, read, combine), :mod:`.lee` (lee-zone error),
:mod:`.figures`, :mod:`.document` (markdown/HTML), :mod:`.export` (VTK/PLY), :mod:`.build`.
"""

from windbench.report.build import Report, build_report

__all__ = ["Report", "build_report"]
