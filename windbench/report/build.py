"""Run or sweep folders -> ``results.nc``, ``summary.csv``, figures, ``report.md``, ``index.html``.

:func:`build_report` is what ``windbench-report`` runs; see :mod:`windbench.report` for the
layout of the output folder.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from windbench.aero import AeroParams
from windbench.config import AeroConfig
from windbench.dataset import write_atomic
from windbench.report import animation, validation
from windbench.report import figures as F
from windbench.report.collect import (
    AVERAGE_FROM,
    RunRecord,
    combine,
    display_path,
    find_invalid,
    find_runs,
    mark_duplicates,
    read_runs,
    sort_key,
    summary_frame,
    swept_keys,
)
from windbench.report.document import FigureRef, Note, Section, Table, Text, to_html, to_markdown
from windbench.report.lee import assign_lee_errors, choose_references

PAPER_COMMAND = "windbench -m experiment=paper"
MAX_ROWS = 300  # runs listed in report.md / index.html; summary.csv has them all


@dataclass
class Report:
    out: Path
    records: list[RunRecord]
    summary: pd.DataFrame
    references: dict[str, RunRecord]
    drawn: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    exported: list[Path] = field(default_factory=list)

    @property
    def skipped(self) -> list[RunRecord]:
        return [r for r in self.records if r.status != "complete"]


def sweep_name(records: Sequence[RunRecord], inputs: Sequence) -> str:
    """The runs' common ``experiment`` attribute, else the first input folder's name."""
    names = {r.experiment for r in records if r.experiment}
    if len(names) == 1:
        return names.pop()
    return Path(inputs[0]).resolve().name or "report"


def _aero_params(records: Sequence[RunRecord]) -> tuple[AeroParams, str]:
    for r in records:
        if r.status == "complete" and "aero.drag_coefficient" in r.config:
            p = AeroParams(
                drag_coefficient=float(r.config["aero.drag_coefficient"]),
                lift_coefficient=float(r.config["aero.lift_coefficient"]),
                air_density=float(r.config.get("aero.air_density", 1.2)),
            )
            return p, f"as in run {r.label}"
    d = AeroConfig()
    return AeroParams(d.drag_coefficient, d.lift_coefficient, d.air_density), "windbench defaults"


def _reference_note(refs: dict[str, RunRecord], reference_dir) -> str:
    if not refs:
        return (
            "No reference: no `navier_stokes` run among the inputs"
            + (f" and none readable under `{reference_dir}`" if reference_dir else "")
            + ", so `lee_error` is empty."
        )
    src = "the finest `navier_stokes` run of the scene among the inputs"
    if reference_dir:
        src = f"the finest run of the scene under `--reference {reference_dir}`, else " + src
    return f"Reference for `lee_error`: {src}."


def comparison_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per scene, backend and resolution: runtime, lee error, divergence, force ratio."""
    if df.empty:
        return df
    cols = {
        "seconds_per_step_median": "ms/step (median)",
        "wind_seconds_median": "wind ms/step",
        "lee_error": "lee error",
        "divergence_rms": "divergence rms",
        "lee_force_ratio": "lee force ratio",
        "lee_speed_ratio": "lee speed ratio",
    }
    d = df.copy()
    d["seconds_per_step_median"] = d["seconds_per_step_median"] * 1e3
    d["wind_seconds_median"] = d["wind_seconds_median"] * 1e3
    if "is_reference" in d:  # the reference's own error (0) would dilute the mean
        d.loc[d["is_reference"].astype(bool), "lee_error"] = np.nan
    g = d.groupby(["scene", "wind", "resolution"], sort=True)
    out = g[list(cols)].mean().rename(columns=cols)
    out.insert(0, "runs", g.size())
    out.insert(1, "cells", g["grid_cells"].first())
    return out.reset_index()


def lee_at_a_glance(df: pd.DataFrame) -> pd.DataFrame:
    """Per scene and backend, the finest run's lee speed ratio (and force ratio, if any)."""
    if df.empty:
        return df
    d = df.sort_values(["resolution", "dt"], ascending=[False, True])
    finest = d.groupby(["scene", "wind"], sort=True).head(1)
    rows = []
    for scene, g in finest.groupby("scene", sort=True):
        row = {"scene": scene}
        for _, r in g.iterrows():
            row[f"{r['wind']} speed"] = r["lee_speed_ratio"]
            if np.isfinite(r.get("lee_force_ratio", np.nan)):
                row[f"{r['wind']} force"] = r["lee_force_ratio"]
        rows.append(row)
    out = pd.DataFrame(rows)
    order = {w: i for i, w in enumerate(F.BACKEND_COLORS)}
    cols = sorted(
        (c for c in out if c != "scene"),
        key=lambda c: (order.get(c.rsplit(" ", 1)[0], 9), c.rsplit(" ", 1)[0], c.endswith("force")),
    )
    return out[["scene", *cols]]


def _short(text, limit: int = 240) -> str:
    text = "" if not isinstance(text, str) else text
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _run_table(df: pd.DataFrame, dims: list[str]) -> pd.DataFrame:
    cols = [
        *dims,
        "status",
        "seconds_per_step",
        "lee_speed_ratio",
        "lee_force_ratio",
        "lee_error",
        "divergence_rms",
        "failure",
    ]
    out = df[[c for c in cols if c in df]].copy()
    if "failure" in out:
        out["failure"] = out["failure"].map(_short)
    return out


def build_report(
    inputs: Sequence,
    out: Path | None = None,
    reference: Path | None = None,
    export: Path | None = None,
    export_every: int = 1,
    progress: bool = True,
) -> Report:
    """Read every run under ``inputs``, write the report folder, return what was done."""
    records = read_runs(find_runs(inputs), progress=progress) + find_invalid(inputs)
    records.sort(key=sort_key)
    if not records:
        raise FileNotFoundError(f"no windbench.nc under {[str(i) for i in inputs]}")
    mark_duplicates(records)
    ref_records = read_runs(find_runs([reference]), progress=progress) if reference else None
    refs = choose_references(records, ref_records)
    assign_lee_errors(records, refs)

    name = sweep_name(records, inputs)
    out = Path(out) if out else Path("reports") / name
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)

    summary = summary_frame(records)
    summary.to_csv(out / "summary.csv", index=False)
    combined = combine(records)
    combined.attrs.update(
        sweep=name,
        lee_reference="; ".join(f"{s}: {r.path}" for s, r in sorted(refs.items())) or "none",
    )
    write_atomic(combined, out / "results.nc")

    report = Report(out, records, summary, refs)
    complete = summary[summary["status"] == "complete"].copy()
    dims = swept_keys(records)
    ref_note = _reference_note(refs, reference)
    aero, aero_src = _aero_params(records)
    regenerate = F.regenerate(records, inputs, out, reference)

    def place(result) -> FigureRef | Note:
        if isinstance(result, F.Missing):
            report.missing.append(result.name)
            return Note(result.title, result.needs, result.error)
        F.save(result.figure, fig_dir, result.name)
        report.drawn.append(result.name)
        return FigureRef(result.name, result.title, f"{result.caption} {regenerate}")

    counts = summary["status"].value_counts().to_dict()
    overview = Section(
        "Overview",
        [
            Text(
                f"**{len(records)}** run files under "
                + ", ".join(f"`{i}`" for i in inputs)
                + ": "
                + ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
                + ". Swept settings (dimensions of `results.nc`): "
                + ", ".join(f"`{d}`" for d in dims)
                + "."
            ),
            Text(
                f"Figures per run: lee and divergence figures are time means over the second "
                f"half of each run (t >= {AVERAGE_FROM:g} t_end); time per step is the mean "
                "(`seconds_per_step`) and the median (`seconds_per_step_median`, used in the "
                "cost figures and tables: robust to other processes) of the wall time over "
                "every step but the first (which includes numba's compile or cache load). "
                "Files: `results.nc` (combined), `summary.csv` (one row per run), `figures/` "
                "(PNG and SVG)."
            ),
            Text(ref_note),
        ],
    )
    if refs:
        overview.blocks.append(
            Table(
                pd.DataFrame(
                    [
                        {"scene": s, "reference run": r.label, "file": display_path(r.path)}
                        for s, r in sorted(refs.items())
                    ]
                ),
                "Lee-error references",
            )
        )
    overview.blocks.append(
        Table(
            lee_at_a_glance(complete),
            "Lee at a glance: mean |u| in the lee box / in the free stream (speed) and |F| on "
            "the sheltered / exposed cloth (force), finest run of each backend; 1 = no lee, "
            "0 = full shelter",
        )
    )
    records_ok = [r for r in records if r.status == "complete"]
    paper = Section(
        "The paper's figures (§5)",
        [
            Text(
                "Drawn from the run datasets; each needs particular runs, and says which when "
                f"they are missing (`{PAPER_COMMAND}` makes them all)."
            ),
            *(place(F.attempt(name, records_ok)) for name in F.RUN_FIGURES),
        ],
    )
    exps = F.cost_exponents(complete) if len(complete) else pd.DataFrame()
    measured = Section(
        "§4.3 measured: cost, lee accuracy, divergence, time step",
        [
            Text(
                "The paper compares the models in words (§4.3): Navier-Stokes is accurate and "
                "expensive, the global field cheap and without lee, particle tracing cheap with "
                "lee. Here the same comparison is measured on the runs above."
            ),
            place(F.fig_cost(complete)),
            Table(exps, "Fitted cost exponents p (wind-phase time per step ~ cells^p)"),
            place(F.fig_cost_particles(complete)),
            place(F.fig_lee_error(complete, ref_note)),
            place(F.fig_divergence(complete)),
            place(F.fig_force_ratio_dt(complete)),
            Table(
                comparison_table(complete),
                "Per scene, backend and resolution (mean over the other settings; the lee "
                "error leaves out the reference run itself)",
            ),
        ],
    )
    plate = plate_section(aero, aero_src, place)
    shown = _run_table(summary, dims)
    caption = "Every run file found (full table: `summary.csv`)"
    if len(shown) > MAX_ROWS:
        caption = f"The first {MAX_ROWS} of {len(shown)} run files (all of them: `summary.csv`)"
        shown = shown.head(MAX_ROWS)
    runs = Section("Runs", [Table(shown, caption)])
    skipped = report.skipped
    if skipped:
        runs.blocks.append(
            Table(
                pd.DataFrame(
                    [
                        {
                            "file": display_path(r.path),
                            "status": r.status,
                            "reason": _short(r.reason),
                        }
                        for r in skipped
                    ]
                ),
                "Skipped (not combined)",
            )
        )
    moving = animation.section(records_ok, fig_dir, place, regenerate, progress)
    checks = validation.section(records_ok, inputs, place)
    sections = [overview, paper, moving, measured, plate, *([checks] if checks else []), runs]
    title = f"windbench report: {name}"
    (out / "report.md").write_text(to_markdown(title, sections), encoding="utf-8")
    (out / "index.html").write_text(to_html(title, sections, fig_dir), encoding="utf-8")

    if export:
        from windbench.report.export import export_run, run_label

        labels: set[str] = set()
        for rec in records:
            if rec.status in ("unreadable",):
                continue
            label = run_label(rec.settings)
            n = 1
            while label in labels:
                n += 1
                label = run_label(rec.settings, f"_{n}")
            labels.add(label)
            report.exported += export_run(rec.path, Path(export) / label, export_every)
    return report


def plate_section(aero: AeroParams, source: str, place) -> Section:
    table = F.plate_table(aero)
    a = np.radians(np.linspace(1.0, 90.0, 90))
    from windbench.aero import plate_coefficients

    cd, cl = plate_coefficients(a, aero)
    hd, hl = F.hoerner_long_plate(a)
    rms_d = math.sqrt(float(np.mean((cd - hd) ** 2)))
    rms_l = math.sqrt(float(np.mean((cl - hl) ** 2)))
    return Section(
        "The aerodynamic model (§3) against flat-plate data",
        [
            Text(
                f"Coefficients C_D = {aero.drag_coefficient:g}, C_L = {aero.lift_coefficient:g} "
                f"({source}). Against Hoerner's long plate over 1°..90° the model's drag differs "
                f"by {rms_d:.3g} (RMS) and its lift by {rms_l:.3g}; at 90° the model's drag "
                f"{aero.drag_coefficient:g} is Hoerner's square plate ({F.HOERNER_SQUARE_CD})."
            ),
            place(F.fig_plate(aero)),
            Table(table, "Force coefficients against angle of attack"),
        ],
    )
