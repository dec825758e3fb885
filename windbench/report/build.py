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
from windbench.report import comparison as C
from windbench.report import figures as F
from windbench.report.collect import (
    RunRecord,
    code_versions,
    combine,
    display_path,
    find_invalid,
    find_runs,
    mark_duplicates,
    read_runs,
    sort_key,
    summary_frame,
    swept_keys,
    with_backend,
)
from windbench.report.document import FigureRef, Note, Section, Table, Text, to_html, to_markdown
from windbench.report.lee import Reference, assign_lee_errors, choose_references

PAPER_COMMAND = "windbench -m experiment=paper"
MAX_ROWS = 300  # runs listed in report.md / index.html; summary.csv has them all


@dataclass
class Report:
    out: Path
    records: list[RunRecord]
    summary: pd.DataFrame
    references: dict[str, Reference]
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


def _reference_note(refs: dict[str, Reference], reference_dir) -> str:
    if not refs:
        return (
            "No reference: no `navier_stokes` run among the inputs"
            + (f" and none readable under `{reference_dir}`" if reference_dir else "")
            + ", so `lee_error` is empty."
        )
    src = (
        "the finest `navier_stokes` run of the scene with the second-order scheme "
        "(`wind.advection=second_order`; another scheme where there is none) among the inputs"
    )
    if reference_dir:
        given = " ".join(str(d) for d in _folders(reference_dir))
        src = f"the finest such run under `--reference {given}`, else " + src
    unconverged = sorted(s for s, r in refs.items() if r.converged is False)
    flag = (
        f" **Not converged** (uncertainty larger than the smallest error it ranks): "
        f"{', '.join(unconverged)}."
        if unconverged
        else ""
    )
    return f"Reference for `lee_error`: {src}.{flag}"


def comparison_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per scene, backend and resolution: runtime, lee error, divergence, force ratio."""
    if df.empty:
        return df
    cols = {
        "seconds_per_step_median": "ms/step (median)",
        "wind_seconds_median": "wind ms/step",
        "lee_error": "lee error",
        "lee_noise": "lee error's sampling noise",
        "divergence_rms": "divergence rms",
        "lee_force_ratio": "lee force ratio",
        "lee_speed_ratio": "lee speed ratio",
    }
    d = with_backend(df)  # the models of one backend apart
    d["seconds_per_step_median"] = d["seconds_per_step_median"] * 1e3
    d["wind_seconds_median"] = d["wind_seconds_median"] * 1e3
    if "is_reference" in d:  # the reference's own error (0) would dilute the mean
        d.loc[d["is_reference"].astype(bool), ["lee_error", "lee_noise"]] = np.nan
    g = d.groupby(["scene", "backend", "resolution"], sort=True)
    out = g[list(cols)].mean().rename(columns=cols)
    out.insert(0, "runs", g.size())
    out.insert(1, "cells", g["grid_cells"].first())
    return out.reset_index()


def cloth_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per scene with cloth and backend: the runs and the largest intersecting triangle
    pairs, body penetration (mm) and edge strain over every run's steady window."""
    cols = {
        "self_intersections_peak": "intersecting triangle pairs",
        "max_penetration_peak": "deepest body penetration (mm)",
        "max_stretch_peak": "largest edge strain",
    }
    if df.empty or not set(cols) <= set(df):
        return pd.DataFrame()
    d = with_backend(df)
    d["max_penetration_peak"] = d["max_penetration_peak"] * 1e3
    g = d.groupby(["scene", "backend"], sort=True)
    out = g[list(cols)].max()
    out = out[out["max_stretch_peak"] > 0.0].rename(columns=cols)  # scenes with cloth
    out.insert(0, "runs", g.size())
    return out.reset_index()


def lee_at_a_glance(df: pd.DataFrame) -> pd.DataFrame:
    """Per scene and backend, the finest run's lee speed ratio (and force ratio, if any)."""
    if df.empty:
        return df
    d = with_backend(df).sort_values(["resolution", "dt"], ascending=[False, True])
    finest = d.groupby(["scene", "backend"], sort=True).head(1)
    rows = []
    for scene, g in finest.groupby("scene", sort=True):
        row = {"scene": scene}
        for _, r in g.iterrows():
            row[f"{r['backend']} speed"] = r["lee_speed_ratio"]
            if np.isfinite(r.get("lee_force_ratio", np.nan)):
                row[f"{r['backend']} force"] = r["lee_force_ratio"]
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
    jobs: int = 1,
) -> Report:
    """Read every run under ``inputs``, write the report folder, return what was done:
    read and rank the runs, write the data files, draw and write the documents, export.
    Reading and the animations use up to ``jobs`` processes (windbench-report: the cores)."""
    records, refs = _read(inputs, reference, progress, jobs)
    name = sweep_name(records, inputs)
    out = Path(out) if out else Path("reports") / name
    summary = _write_data(records, refs, out, name)
    C.reference_table(refs).to_csv(out / "references.csv", index=False)
    report = Report(out, records, summary, refs)
    regenerate = F.regenerate(records, inputs, out, reference)
    place = _placer(report, out / "figures", regenerate)
    complete = summary[summary["status"] == "complete"].copy()
    records_ok = [r for r in records if r.status == "complete"]
    animations = animation.start(records_ok, out / "figures", jobs)  # drawn meanwhile
    try:
        before = [
            _overview(report, inputs, reference),
            _comparison_section(records, complete, refs, place),
            _paper_section(records, place),
        ]
        checks = validation.section(records_ok, inputs, place)
        after = [
            _measured_section(complete, place),
            plate_section(*_aero_params(records), place),
            *([checks] if checks else []),
            _cloth_section(complete),
            _runs_section(report, swept_keys(records)),
        ]
        anim = animation.section(animations, place, regenerate, progress)
    finally:
        animations.close()  # a figure that failed stops the animations too
    sections = [*before, anim, *after]
    title = f"windbench report: {name}"
    (out / "report.md").write_text(to_markdown(title, sections), encoding="utf-8")
    (out / "index.html").write_text(to_html(title, sections, out / "figures"), encoding="utf-8")
    if export:
        report.exported += _export(records, Path(export), export_every)
    return report


def _read(inputs: Sequence, reference, progress: bool, jobs: int):
    """The runs (sorted, duplicates marked) and each scene's reference, lee errors set."""
    records = read_runs(find_runs(inputs), progress, jobs) + find_invalid(inputs)
    records.sort(key=sort_key)
    if not records:
        raise FileNotFoundError(f"no windbench.nc under {[str(i) for i in inputs]}")
    mark_duplicates(records)
    ref_records = read_runs(find_runs(_folders(reference)), progress, jobs) if reference else None
    refs = choose_references(records, ref_records)
    assign_lee_errors([*records, *(ref_records or [])], refs)
    return records, refs


def _folders(reference) -> list:
    """``--reference`` as a list of folders (one folder or several)."""
    return list(reference) if isinstance(reference, list | tuple) else [reference]


def _write_data(records, refs: dict[str, Reference], out: Path, name: str) -> pd.DataFrame:
    """``summary.csv`` (every run) and ``results.nc`` (the complete runs combined)."""
    (out / "figures").mkdir(parents=True, exist_ok=True)
    summary = summary_frame(records)
    summary.to_csv(out / "summary.csv", index=False)
    combined = combine(records)
    combined.attrs.update(
        sweep=name,
        lee_reference="; ".join(f"{s}: {r.path}" for s, r in sorted(refs.items())) or "none",
    )
    write_atomic(combined, out / "results.nc")
    return summary


def _placer(report: Report, fig_dir: Path, regenerate: str):
    """place(result) -> the document block of a drawn (saved) or missing figure, its
    caption ending with the command that regenerates it."""

    def place(result) -> FigureRef | Note:
        if isinstance(result, F.Missing):
            report.missing.append(result.name)
            return Note(result.title, result.needs, result.error)
        F.save(result.figure, fig_dir, result.name)
        report.drawn.append(result.name)
        return FigureRef(result.name, result.title, f"{result.caption} {regenerate}")

    return place


def _versions_note(records) -> str:
    """Which code made the runs (every run file records its version)."""
    versions = code_versions(records) or ["an unknown code version"]
    if len(versions) == 1:
        return f"Made by {versions[0]}."
    return (
        f"Made by {len(versions)} code versions (`summary.csv` column `code`): "
        + "; ".join(versions)
        + "."
    )


def _overview(report: Report, inputs, reference) -> Section:
    counts = report.summary["status"].value_counts().to_dict()
    dims = swept_keys(report.records)
    complete = report.summary[report.summary["status"] == "complete"]
    return Section(
        "Overview",
        [
            Text(
                f"**{len(report.records)}** run files under "
                + ", ".join(f"`{i}`" for i in inputs)
                + ": "
                + ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
                + ". Swept settings (dimensions of `results.nc`): "
                + ", ".join(f"`{d}`" for d in dims)
                + ". "
                + _versions_note(report.records)
            ),
            Text(
                "Every statistic is taken over a run's steady window: from two flow-through "
                "times of the domain (L / U_ref) after the wind starts, when the start-up "
                "transient has left the domain and the particle front has crossed it; runs "
                "spin up for that long before recording (`sim.spinup=auto`). A run too short "
                "to have a window is `unsettled`: listed below with the reason and left out "
                "of every figure. Time per step: the median wall time over the window "
                "(robust to other processes), the first step (numba's compile or cache "
                "load) excluded. Files: `results.nc` (combined), `summary.csv` (one row per "
                "run), `figures/` (PNG and SVG)."
            ),
            Text(_reference_note(report.references, reference)),
            Table(
                lee_at_a_glance(complete),
                "Lee at a glance: mean |u| in the lee box / in the free stream (speed) and "
                "|F| on the sheltered / exposed cloth (force), finest run of each backend, "
                "steady-window means; 1 = no lee, 0 = full shelter",
            ),
        ],
    )


def _paper_section(records, place) -> Section:
    records_ok = [r for r in records if r.status == "complete"]
    return Section(
        "The paper's figures (§5)",
        [
            Text(
                "Drawn from the run datasets; each needs particular runs, and says which when "
                f"they are missing (`{PAPER_COMMAND}` makes them all)."
            ),
            *(place(F.attempt(name, records_ok)) for name in F.RUN_FIGURES),
        ],
    )


def _comparison_section(records, complete, refs: dict[str, Reference], place) -> Section:
    table = C.accuracy_cost_table(complete)
    blocks = [
        Text(
            "The paper compares the wind models in words (§4.3). Here every backend and "
            "resolution is measured against a converged reference: per scene a "
            "Navier-Stokes run with the second-order scheme, finer than every compared run, "
            "whose own uncertainty (the grid-convergence index of its two or three finest "
            "levels) is stated and drawn. A reference whose uncertainty exceeds the errors "
            "it ranks is marked as not converged. Every time mean comes from a finite "
            "window: the sampling noise beside e21 and each lee error is what two runs "
            "with the same true mean would differ by from their windows alone (batch means "
            "over the window's blocks); a difference not well above it is sampling, and a "
            "longer window lowers it as 1/sqrt(window)."
        ),
        Table(C.reference_table(refs), "References and their uncertainty (fractions of U_ref)"),
        place(C.fig_accuracy_cost(table, refs)),
        Table(table, "Accuracy against cost (Pareto front marked)"),
        place(C.fig_lee_error(complete, refs)),
        place(C.fig_wake(C.wake_frame(records, refs))),
        Table(C.window_table(records), "Steady windows per scene (s of simulated time)"),
    ]
    return Section("Accuracy against cost: the comparison, measured", blocks)


def _measured_section(complete, place) -> Section:
    exps = F.cost_exponents(complete) if len(complete) else pd.DataFrame()
    return Section(
        "§4.3 measured: cost, divergence, time step",
        [
            place(F.fig_cost(complete)),
            Table(exps, "Fitted cost exponents p (wind-phase time per step ~ cells^p)"),
            place(F.fig_cost_particles(complete)),
            place(F.fig_divergence(complete)),
            place(F.fig_force_ratio_dt(complete)),
            place(F.fig_force_ratio_resolution(complete)),
            Table(
                comparison_table(complete),
                "Per scene, backend and resolution (mean over the other settings; the lee "
                "error leaves out the reference run itself)",
            ),
        ],
    )


def _cloth_section(complete) -> Section:
    return Section(
        "Cloth: contacts and stretch",
        [
            Text(
                "The cloth's own figures, largest over the steady window of every complete "
                "run: triangle pairs of the cloths that cross each other (0 where the cloth "
                "never passes through itself or another cloth, `cloth.self_collision`), "
                "how deep a cloth vertex, edge or triangle lies inside a body, and the "
                "largest relative stretch of a cloth edge (`cloth.strain_limit` bounds the "
                "lattice threads)."
            ),
            Table(cloth_table(complete), "Cloth figures per scene and backend"),
        ],
    )


def _runs_section(report: Report, dims) -> Section:
    shown = _run_table(report.summary, dims)
    caption = "Every run file found (full table: `summary.csv`)"
    if len(shown) > MAX_ROWS:
        caption = f"The first {MAX_ROWS} of {len(shown)} run files (all of them: `summary.csv`)"
        shown = shown.head(MAX_ROWS)
    runs = Section("Runs", [Table(shown, caption)])
    if report.skipped:
        skipped = pd.DataFrame(
            [
                {"file": display_path(r.path), "status": r.status, "reason": _short(r.reason)}
                for r in report.skipped
            ]
        )
        runs.blocks.append(Table(skipped, "Skipped (not combined)"))
    return runs


def _export(records, folder: Path, every: int) -> list[Path]:
    """Each readable run's wind and cloth as VTK/PLY under ``folder/<label>/``."""
    from windbench.report.export import export_run, run_label

    written, labels = [], set()
    for rec in records:
        if rec.status == "unreadable":
            continue
        label = run_label(rec.settings)
        n = 1
        while label in labels:
            n += 1
            label = run_label(rec.settings, f"_{n}")
        labels.add(label)
        written += export_run(rec.path, folder / label, every)
    return written


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
