"""The report's Navier-Stokes validation section (paper §4.1 against known answers).

- **Plane Poiseuille flow through the run loop** (``windbench -m experiment=validation_ns``,
  scene ``poiseuille``): a channel of height H between no-slip walls, driven from rest by
  the body force f (``wind.body_force``) with viscosity nu (``wind.viscosity``), has the
  steady profile ``u_s(y) = f / (2 nu) y (H - y)``, ``u_max = f H^2 / (8 nu)``, and on the
  way there (the sine series of the start-up problem)

      u(y, t) = u_s(y) - sum_{n odd} 32 u_max / (n pi)^3 sin(n pi y / H) exp(-(n pi)^2 nu t / H^2).

  The last wind snapshot of each run is compared with ``u(y, t)`` at the cell centres; the
  no-slip ghost value (ghost = -interior) makes the steady error ``f h^2 / (8 nu) =
  (h / H)^2 u_max`` (experiments/validation_ns/README.md), second order in h. The
  slowest transient mode still left, ``32 / pi^3 exp(-pi^2 nu t / H^2)`` of u_max, says how
  far from steady a run ended.
- **Taylor-Green vortex and free stream** (``experiments/validation_ns/``, which start
  from initial fields a scene config cannot express): drawn from the CSVs its ``run.py``
  writes to ``results/``, when that folder is among the report's inputs (or, with
  Poiseuille runs among them, found in this source tree).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from matplotlib.ticker import NullFormatter
from omegaconf import OmegaConf

from windbench.report import figures as F
from windbench.report.collect import RunRecord
from windbench.report.document import Section, Table, Text

VALIDATION_SCENE = "poiseuille"  # conf/experiment/validation_ns.yaml
RESULTS_FILE = "taylor_green.csv"  # marks experiments/validation_ns/results
TREE_RESULTS = Path(__file__).resolve().parents[2] / "experiments" / "validation_ns" / "results"
COMMAND = "windbench -m experiment=validation_ns"
STUDY_COMMAND = (
    "PYTHONPATH=. python experiments/validation_ns/run.py && "
    "PYTHONPATH=. python experiments/validation_ns/plot.py"
)


SERIES_TERMS = 200  # odd terms of the start-up series (each below 32 / (n pi)^3)


def poiseuille_start_up(s, t: float, height: float, f: float, nu: float) -> np.ndarray:
    """u(s, t) of the channel flow started from rest (module docstring); s = y - wall."""
    u_max = f * height**2 / (8 * nu)
    n = np.arange(1, 2 * SERIES_TERMS, 2)[:, None]
    k = n * np.pi / height
    modes = 32 * u_max / (n * np.pi) ** 3 * np.sin(k * s) * np.exp(-(k**2) * nu * t)
    return f / (2 * nu) * s * (height - s) - modes.sum(axis=0)


def transient_left(t: float, height: float, nu: float) -> float:
    """The slowest start-up mode's amplitude over u_max at time t."""
    return 32 / np.pi**3 * math.exp(-(np.pi**2) * nu * t / height**2)


def _channel(ds: xr.Dataset):
    """(y, h, wall, H, f, nu, t) of a Poiseuille run dataset."""
    cfg = OmegaConf.create(ds.attrs["config"])
    y = np.asarray(ds["y"].values, dtype=float)
    h = float(ds.attrs.get("grid_spacing", y[1] - y[0]))
    t = float(ds["snapshot_time"].values[-1])
    return (
        y,
        h,
        y[0] - h / 2,
        h * len(y),
        float(cfg.wind.body_force[0]),
        float(cfg.wind.viscosity),
        t,
    )


def poiseuille_profile(ds: xr.Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(y, u_x, u_exact) at the cell centres across the channel at the last wind snapshot;
    u_x is averaged over x and z (one periodic cell each in the validation scene)."""
    y, _, wall, height, f, nu, t = _channel(ds)
    u = np.asarray(ds["wind"].isel(snapshot=-1).values[..., 0], dtype=float).mean(axis=(0, 2))
    return y, u, poiseuille_start_up(y - wall, t, height, f, nu)


def poiseuille_runs(records: Sequence[RunRecord]) -> list[RunRecord]:
    """Complete runs of the validation scene, coarsest first (one per resolution)."""
    runs = [
        r for r in records if r.status == "complete" and r.settings.get("scene") == VALIDATION_SCENE
    ]
    best: dict[int, RunRecord] = {}
    for r in sorted(runs, key=lambda r: (float(r.settings["dt"]), str(r.path))):
        best.setdefault(int(r.settings["resolution"]), r)
    return [best[k] for k in sorted(best)]


def poiseuille_table(records: Sequence[RunRecord]) -> pd.DataFrame:
    """Per resolution: cells across, dt, time of the snapshot, the transient left, max and
    RMS error against u(y, t) over u_max, the known steady error (h / H)^2 and the observed
    order log(e_coarse / e_fine) / log(n_fine / n_coarse)."""
    rows = []
    for rec in poiseuille_runs(records):
        with xr.open_dataset(rec.path) as ds:
            y, u, exact = poiseuille_profile(ds)
            _, h, _, height, f, nu, t = _channel(ds)
        err = np.abs(u - exact) / (f * height**2 / (8 * nu))
        rows.append(
            {
                "resolution": int(rec.settings["resolution"]),
                "cells across": len(y),
                "dt (s)": float(rec.settings["dt"]),
                "t (s)": t,
                "transient left": transient_left(t, height, nu),
                "max error / u_max": float(err.max()),
                "RMS error / u_max": float(np.sqrt(np.mean(err**2))),
                "(h/H)^2": (h / height) ** 2,
            }
        )
    df = pd.DataFrame(rows)
    if len(df):
        e, n = df["max error / u_max"].to_numpy(), df["cells across"].to_numpy()
        order = [math.nan] + [
            math.log(e[i - 1] / e[i]) / math.log(n[i] / n[i - 1]) for i in range(1, len(df))
        ]
        df["order"] = order
    return df


def fig_poiseuille(records: Sequence[RunRecord]) -> F.Drawn | F.Missing:
    """The profiles against the parabola, and the error against h."""
    title = "Plane Poiseuille flow through the run loop (Navier-Stokes)"
    runs = poiseuille_runs(records)
    if not runs:
        return F.Missing("validation_poiseuille", title, f"`{VALIDATION_SCENE}` runs: `{COMMAND}`")
    table = poiseuille_table(runs)
    fig = F._figure(9.0, 3.8)
    ax, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for rec in runs:
        with xr.open_dataset(rec.path) as ds:
            y, u, exact = poiseuille_profile(ds)
        ax.plot(u, y, ".-", label=f"{len(y)} cells")
    ax.plot(exact, y, "k-", lw=0.8, label="u(y, t), analytic")
    ax.set_xlabel("u_x (m/s)")
    ax.set_ylabel("y (m)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5), frameon=False)
    h = 1.0 / table["cells across"]
    ax2.loglog(h, table["max error / u_max"], "o-", label="max |u − u_exact| / u_max")
    ax2.loglog(h, table["(h/H)^2"], "k--", lw=0.8, label="(h/H)²: the known steady error")
    ax2.set_xlabel("h / H")
    ax2.set_ylabel("relative error")
    ax2.grid(True, which="both", alpha=0.3)
    F._legend_outside(fig, ax2.get_legend_handles_labels()[0], "outside lower center", ncol=2)
    caption = (
        "Left: u_x across the channel at the last snapshot of each run against the analytic "
        "start-up flow u(y, t) (the steady parabola less its decaying sine modes); right: the "
        "largest error over u_max against the cell size, beside the known error of the "
        "no-slip ghost value, (h/H)² (second order). Runs: "
        + "; ".join(F._run_note(r) for r in runs)
        + "."
    )
    return F.Drawn("validation_poiseuille", title, caption, fig)


def results_folder(inputs: Sequence, records: Sequence[RunRecord]) -> Path | None:
    """The validation study's results: an input folder holding its CSVs, else (when the
    inputs hold Poiseuille runs) this tree's ``experiments/validation_ns/results``."""
    for item in inputs:
        p = Path(item)
        if (p / RESULTS_FILE).is_file():
            return p
    if poiseuille_runs(records) and (TREE_RESULTS / RESULTS_FILE).is_file():
        return TREE_RESULTS
    return None


def fig_taylor_green(folder: Path) -> F.Drawn:
    """Decay-rate and velocity errors of the Taylor-Green vortex against h (CFL 0.5) and
    against dt at 64 cells, per advection scheme."""
    tg = pd.read_csv(folder / RESULTS_FILE)
    fig = F._figure(9.0, 3.8)
    ax, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for i, (scheme, g) in enumerate(tg.groupby("scheme", sort=True)):
        colour = f"C{i}"
        hd = g[g["study"] == "h_and_dt"].sort_values("cells")
        h = 2 * np.pi / hd["cells"]
        ax.loglog(h, hd["rate_rel_error"].abs(), "o-", color=colour, label=f"{scheme}: decay rate")
        ax.loglog(
            h, hd["linf_rel_error"], "s--", color=colour, label=f"{scheme}: max |u − u_exact|"
        )
        dd = g[g["study"] == "dt_at_64"].sort_values("dt")
        ax2.loglog(dd["dt"], dd["rate_rel_error"].abs(), "o-", color=colour)
    ax.set_xlabel("h (m), dt = 0.5 h / U")
    ax.set_ylabel("relative error")
    ax.set_title("h and dt refined together", fontsize=9)
    ax2.set_xlabel("dt (s)")
    ax2.set_ylabel("|decay-rate error| (relative)")
    ax2.set_title("dt refined alone, 64 cells", fontsize=9)
    for a in (ax, ax2):
        a.grid(True, which="both", alpha=0.3)
        a.xaxis.set_minor_formatter(NullFormatter())  # decade labels only: no overlaps
    F._legend_outside(fig, ax.get_legend_handles_labels()[0], "outside lower center", ncol=2)
    caption = (
        "Taylor-Green vortex (2D periodic, L = 2π, U = 1, ν = 0.05, t = 1 s; analytic decay "
        "rate 0.1 1/s): relative error of the measured decay rate and largest velocity error "
        f"over the amplitude, from `{folder / RESULTS_FILE}` (made by `{STUDY_COMMAND}`)."
    )
    return F.Drawn("validation_taylor_green", "Taylor-Green vortex (Navier-Stokes)", caption, fig)


def free_stream_table(folder: Path) -> pd.DataFrame:
    df = pd.read_csv(folder / "free_stream.csv")
    return df.pivot(index="cells", columns="scheme", values="max_rel_deviation").reset_index()


def orders_table(folder: Path) -> pd.DataFrame:
    path = folder / "orders.csv"
    if not path.is_file():
        return pd.DataFrame()
    df = pd.read_csv(path)
    return df.groupby(["study", "scheme", "metric"], sort=True)["order"].agg(list).reset_index()


def section(records: Sequence[RunRecord], inputs: Sequence, place) -> Section | None:
    """The validation section, or None when the inputs hold neither Poiseuille runs nor
    the validation study's results. ``place`` turns a Drawn/Missing into a report block."""
    folder = results_folder(inputs, records)
    runs = poiseuille_runs(records)
    if folder is None and not runs:
        return None
    blocks = [
        Text(
            "The Navier-Stokes backend against problems whose answer is known without the "
            "code (see `experiments/validation_ns/README.md`)."
        ),
        place(fig_poiseuille(records)),
    ]
    if runs:
        blocks.append(
            Table(
                poiseuille_table(records),
                "Poiseuille through the run loop: error against the analytic u(y, t) at the "
                "last snapshot over u_max, the slowest start-up mode still left (how far from "
                "steady), the known steady error (h/H)², observed order per halving of h",
            )
        )
    if folder is None:
        blocks.append(
            Text(
                "Taylor-Green and free stream: not drawn; pass the study's results folder "
                f"(`experiments/validation_ns/results`, made by `{STUDY_COMMAND}`) as an input."
            )
        )
        return Section("Validation of the Navier-Stokes wind", blocks)
    blocks.append(place(fig_taylor_green(folder)))
    orders = orders_table(folder)
    if len(orders):
        orders["order"] = orders["order"].map(lambda v: ", ".join(f"{x:.3g}" for x in v))
        blocks.append(
            Table(orders, "Observed orders p = log(e_coarse / e_fine) / log 2, successive pairs")
        )
    blocks.append(
        Table(
            free_stream_table(folder),
            "Free stream: a uniform oblique wind (2, 0.5, -0.3) m/s through inflow/outflow "
            "faces, 20 steps; max |u − U| / |U| per advection scheme (the uniform field is kept to round-off)",
        )
    )
    return Section("Validation of the Navier-Stokes wind", blocks)
