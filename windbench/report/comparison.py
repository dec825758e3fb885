"""The measured comparison: accuracy against cost, lee error with the reference's own
uncertainty, the fence wake against shelter measurements, and the steady windows.

Every statistic here comes from a run's steady window (:mod:`windbench.report.collect`);
``lee_error`` is measured against the scene's reference (:mod:`windbench.report.lee`),
whose grid-convergence index is drawn as a band: errors inside it are indistinguishable
from the reference's own error.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from matplotlib.ticker import FormatStrFormatter, NullFormatter

from windbench.report.collect import display_path, record_backend, with_backend
from windbench.report.figures import Drawn, Missing, _color, _figure, timed
from windbench.report.lee import Reference, beyond_noise

COST_X = "seconds_per_simulated_second"
CPU_X = "cpu_seconds_per_simulated_second"
COST_LABEL = "s per simulated s"
RESOLUTION_MARKERS = "v<osD*Ph>"  # by rank of the resolutions in a table, coarsest first
# Relative wind speed behind dense windbreaks (optical porosity < 20 %) at about half
# their height, as summarised by Heisler & DeWalle (1988, Agric. Ecosyst. Environ.
# 22/23: 41-69): an approximate range read from their review, for plausibility only.
SHELTER_RANGE = pd.DataFrame(
    {"distance_H": [2, 5, 10, 15, 20], "low": [0.05, 0.15, 0.45, 0.65, 0.8]}
).assign(high=[0.3, 0.35, 0.65, 0.85, 0.95])
SHELTER_SOURCE = "dense windbreaks, Heisler & DeWalle (1988), approximate range"
SHELTER_HEIGHT = 0.5  # H: the height the range refers to


def compared(df: pd.DataFrame) -> pd.DataFrame:
    """Complete runs with a lee error that are not levels of their scene's reference, with
    their ``backend`` (:func:`with_backend`)."""
    if df.empty or "lee_error" not in df:
        return df.iloc[0:0].assign(backend=pd.Series(dtype=object))
    levels = df.get("reference_level", pd.Series(False, index=df.index)).astype(bool)
    return with_backend(df[~levels & np.isfinite(df["lee_error"].astype(float))])


def pareto_front(cost: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Mask of the points no other point beats in both cost and error (lower is better)."""
    cost, error = np.asarray(cost, float), np.asarray(error, float)
    front = np.ones(len(cost), dtype=bool)
    for i in range(len(cost)):
        better = (cost <= cost[i]) & (error <= error[i]) & ((cost < cost[i]) | (error < error[i]))
        front[i] = not better.any()
    return front


def own_cost(d: pd.DataFrame, contended: bool = False) -> pd.Series:
    """Seconds per simulated second that are the run's own: the wall time of a run that had
    its cores (:func:`~windbench.report.figures.timed`), else the process CPU time of a
    one-thread run (what it takes on an idle core: it computed while it held one), else
    NaN (a multi-thread run that shared its cores measured the sharing)."""
    cost = pd.Series(np.nan, index=d.index)
    kept = timed(d, contended).index
    cost[kept] = d.loc[kept, COST_X]
    if CPU_X in d and "threads" in d:
        single = cost.isna() & (d["threads"] == 1)
        cost[single] = d.loc[single, CPU_X]
    return cost


def accuracy_cost_table(df: pd.DataFrame, contended: bool = False) -> pd.DataFrame:
    """Per scene, backend (the particles' lee model told apart) and resolution: cost per
    simulated second and lee error (seeds and time steps: mean, with the seeds' spread),
    Pareto front marked per scene. The cost is the median of :func:`own_cost` over the
    runs (``contended`` counts the runs that shared their cores and were timed by CPU)."""
    d = compared(df)
    if d.empty or COST_X not in d:
        return pd.DataFrame()
    d = d.assign(timed_cost=own_cost(d, contended))
    keys = [k for k in ("scene", "backend", "resolution", "dt") if k in d]
    g = d.groupby(keys, sort=True)
    out = g.agg(
        runs=("lee_error", "size"),
        contended=("contended", lambda c: int(c.fillna(False).astype(bool).sum())),
        cost=("timed_cost", "median"),
        lee_error=("lee_error", "mean"),
        error_min=("lee_error", "min"),
        error_max=("lee_error", "max"),
    ).reset_index()
    out["pareto"] = False
    for _, idx in out.groupby("scene").groups.items():
        sub = out.loc[idx]
        finite = np.isfinite(sub["cost"].values)
        front = np.zeros(len(sub), dtype=bool)
        front[finite] = pareto_front(sub["cost"].values[finite], sub["lee_error"].values[finite])
        out.loc[idx, "pareto"] = front
    return out.rename(columns={"cost": COST_LABEL})


def reference_table(refs: dict[str, Reference]) -> pd.DataFrame:
    """One row per scene: the reference, its levels and its uncertainty."""
    rows = []
    for scene, ref in sorted(refs.items()):
        rows.append(
            {
                "scene": scene,
                "reference": ref.run.label,
                "file": display_path(ref.path),
                "scheme": ref.run.config.get("wind.advection"),
                "levels": ", ".join(str(r.settings.get("resolution")) for r in ref.levels),
                "e21": ref.difference,
                "e21 sampling noise": ref.noise,
                "e21 beyond noise": beyond_noise(ref.difference, ref.noise),
                "order p": ref.order,
                "p observed": ref.observed,
                "GCI": ref.gci,
                "converged": {True: "yes", False: "NO", None: "unknown"}[ref.converged],
            }
        )
    return pd.DataFrame(rows)


def window_table(records) -> pd.DataFrame:
    """Per scene: flow-through time, spin-up and steady window of its complete runs."""
    rows = []
    for rec in records:
        if rec.status != "complete":
            continue
        rows.append(
            {
                "scene": rec.settings.get("scene"),
                "flow-through (s)": rec.figures.get("flow_through_time", math.nan),
                "spin-up (s)": rec.figures.get("spinup", math.nan),
                "window from (s)": rec.figures.get("analysis_start", math.nan),
                "window to (s)": rec.figures.get("end_time", math.nan),
            }
        )
    if not rows:
        return pd.DataFrame()
    d = pd.DataFrame(rows).groupby("scene", sort=True).agg(["min", "max"])
    d.columns = [f"{name} {stat}" for name, stat in d.columns]  # one header row
    return d.reset_index()


def _scene_panels(scenes):
    """A figure with one panel per scene, three to a row: (figure, axes)."""
    cols = min(len(scenes), 3)
    rows = math.ceil(len(scenes) / cols)
    fig = _figure(4.0 * cols, 3.4 * rows + 0.8)
    return fig, [fig.add_subplot(rows, cols, i + 1) for i in range(len(scenes))]


def _band(ax, ref: Reference | None, errors) -> None:
    """The reference's GCI as a grey band from 0; a band above the panel's errors is cut at
    1.2x the largest and labelled with its value, so that the points stay readable."""
    if ref is None or not np.isfinite(ref.gci):
        return
    top = 1.2 * float(np.nanmax(errors)) if len(errors) else ref.gci
    ax.axhspan(0, min(ref.gci, top), color="0.85", zorder=0)
    if ref.gci > top:
        ax.set_ylim(0, top)
        ax.text(0.02, 0.97, f"GCI = {ref.gci:.3g} (off the scale): not converged",
                transform=ax.transAxes, va="top", fontsize=7)  # fmt: skip


def _legend_below(fig, handles_axes):
    handles, labels = {}, {}
    for ax in handles_axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
            labels[lab] = lab
    fig.legend(handles.values(), labels.values(), loc="outside lower center", ncol=4, fontsize=7)


def spans_a_decade(lo: float, hi: float) -> bool:
    """Whether a log axis from ``lo`` to ``hi`` holds a power of ten: a major tick with a
    label. A panel whose costs lie within one decade (the shirt's) has none; its minor
    ticks are labelled instead."""
    return math.floor(math.log10(hi)) >= math.ceil(math.log10(lo))


def fig_accuracy_cost(table: pd.DataFrame, refs: dict[str, Reference]) -> Drawn | Missing:
    """x: own time per simulated second (:func:`own_cost`), y: lee error, one panel per
    scene; Pareto front."""
    title = "Accuracy against cost"
    if table.empty:
        return Missing("accuracy_vs_cost", title, "runs with a lee error and a reference")
    scenes = sorted(table["scene"].unique())
    fig, axes = _scene_panels(scenes)
    markers = dict(zip(sorted(table["resolution"].unique()), RESOLUTION_MARKERS, strict=False))
    for ax, scene in zip(axes, scenes, strict=True):
        sub = table[table["scene"] == scene]
        _band(ax, refs.get(scene), sub["error_max"].to_numpy())
        for _, r in sub.iterrows():
            ax.errorbar(
                r[COST_LABEL],
                r["lee_error"],
                yerr=[[r["lee_error"] - r["error_min"]], [r["error_max"] - r["lee_error"]]],
                fmt=markers.get(r["resolution"], "o"),
                color=_color(r["backend"]),
                ms=5,
                label=r["backend"],
            )
        front = sub[sub["pareto"]].sort_values(COST_LABEL)
        ax.plot(front[COST_LABEL], front["lee_error"], "k--", lw=0.8)
        ax.set_xscale("log")
        # a power of ten labels the axis, else its minor ticks carry the only labels, short
        short = NullFormatter() if spans_a_decade(*ax.get_xlim()) else FormatStrFormatter("%g")
        ax.xaxis.set_minor_formatter(short)
        ax.set_title(scene, fontsize=9)
        ax.set_xlabel(COST_LABEL)
        ax.set_ylabel("lee error / U")
        ax.grid(True, which="both", alpha=0.3)
    for res, marker in markers.items():
        axes[0].plot([], [], marker, color="0.4", label=f"{res} cells")
    axes[0].plot([], [], "k--", lw=0.8, label="Pareto front")
    _legend_below(fig, axes)
    caption = (
        "Every backend and resolution as a point: its own time per simulated second (median "
        "step over the steady window, divided by dt: wall time, or for a one-thread run that "
        "shared its cores its CPU time, see the table's contended column) against the lee error (RMS wind "
        "difference in the lee box against the scene's reference, over U_ref); error bars "
        "span the seeds; the dashed line joins the Pareto front (no point is both cheaper "
        "and more accurate); the grey band is the reference's own uncertainty (GCI): an "
        "error inside it is not resolved by the reference."
    )
    return Drawn("accuracy_vs_cost", title, caption, fig)


def fig_lee_error(df: pd.DataFrame, refs: dict[str, Reference]) -> Drawn | Missing:
    """Lee error against resolution per scene and backend, with the reference's band."""
    title = "Lee error against resolution"
    d = compared(df)
    if d.empty:
        return Missing("lee_error_vs_resolution", title, "runs with a lee error and a reference")
    scenes = sorted(d["scene"].unique())
    fig, axes = _scene_panels(scenes)
    for ax, scene in zip(axes, scenes, strict=True):
        _band(ax, refs.get(scene), d.loc[d["scene"] == scene, "lee_error"].to_numpy())
        for backend, g in d[d["scene"] == scene].groupby("backend", sort=True):
            s = g.groupby("resolution")["lee_error"].agg(["mean", "min", "max"])
            ax.errorbar(
                s.index,
                s["mean"],
                yerr=[s["mean"] - s["min"], s["max"] - s["mean"]],
                marker="o",
                color=_color(backend),
                label=backend,
                capsize=2,
            )
        ax.set_xscale("log", base=2)
        resolutions = sorted(d.loc[d["scene"] == scene, "resolution"].unique())
        ax.set_xticks(resolutions, [str(r) for r in resolutions])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(scene, fontsize=9)
        ax.set_xlabel("cells along the longest axis")
        ax.set_ylabel("lee error / U")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].fill_between([], [], color="0.85", label="reference uncertainty (GCI)")
    _legend_below(fig, axes)
    caption = (
        "Mean over time steps and seeds, bars from the smallest to the largest; grey: the "
        "reference's grid-convergence index, below which differences are not resolved."
    )
    return Drawn("lee_error_vs_resolution", title, caption, fig)


def wake_frame(records, refs: dict[str, Reference]) -> pd.DataFrame:
    """Window-mean u/u0 behind the obstacle: per scene, backend (finest run of each, and
    the reference) and position; long format."""
    rows = []
    finest: dict[tuple, object] = {}
    ref_paths = {r.path for r in refs.values()}
    for rec in [*records, *(ref.run for ref in refs.values())]:
        if rec.status != "complete" or rec.wake is None:
            continue
        label = "reference" if rec.path in ref_paths else record_backend(rec)
        key = (rec.settings.get("scene"), label)
        best = finest.get(key)
        if best is None or int(rec.settings.get("resolution") or 0) > int(
            best.settings.get("resolution") or 0
        ):
            finest[key] = rec
    for (scene, label), rec in sorted(finest.items()):
        for dist, row in rec.wake.iterrows():
            for height, value in row.items():
                rows.append(
                    {
                        "scene": scene,
                        "backend": label,
                        "resolution": rec.settings.get("resolution"),
                        "distance_H": float(dist),
                        "height_H": float(height),
                        "u_over_u0": float(value),
                    }
                )
    return pd.DataFrame(rows)


def fig_wake(wake: pd.DataFrame) -> Drawn | Missing:
    """u/u0 against distance behind the fence at each height, backends and reference,
    beside the range of shelter measurements."""
    title = "Wake behind the fence: u/u0 at 0.25, 0.5 and 1 H"
    if wake.empty:
        return Missing("fence_wake", title, "fence runs: `windbench -m experiment=paper`")
    heights = sorted(wake["height_H"].unique())
    fig = _figure(4.0 * len(heights), 3.8)
    axes = [fig.add_subplot(1, len(heights), i + 1) for i in range(len(heights))]
    for ax, height in zip(axes, heights, strict=True):
        if height == SHELTER_HEIGHT:  # the measurements are at about half the height
            ax.fill_between(
                SHELTER_RANGE["distance_H"], SHELTER_RANGE["low"], SHELTER_RANGE["high"],
                color="0.88", label=SHELTER_SOURCE,
            )  # fmt: skip
        for backend, g in wake[wake["height_H"] == height].groupby("backend", sort=True):
            g = g.sort_values("distance_H")
            ax.plot(
                g["distance_H"], g["u_over_u0"], "o-",
                color="k" if backend == "reference" else _color(backend),
                label=f"{backend} ({int(g['resolution'].iloc[0])} cells)",
            )  # fmt: skip
        ax.axhline(0, color="0.5", lw=0.6)
        ax.set_title(f"{height:g} H above the ground", fontsize=9)
        ax.set_xlabel("distance behind the fence / H")
        ax.set_ylabel("u / u0 (window mean)")
        ax.grid(True, alpha=0.3)
    _legend_below(fig, axes)
    caption = (
        "Time-mean wind along the flow behind the fence over the undisturbed wind at the "
        "same height, finest run of each backend and the reference; negative values are "
        "flow back toward the fence (recirculation). The grey band is the range of "
        "measurements behind dense windbreaks at about half their height (Heisler & "
        "DeWalle 1988, read approximately; drawn at 0.5 H): a plausibility range, not a data set."
    )
    return Drawn("fence_wake", title, caption, fig)
