"""The particles' two lee models against the Navier-Stokes reference: lee error, flux, wake
and cost (windbench/wind/particles/mixing.py).

    PYTHONPATH=$PWD python experiments/lee_mixing.py RUNS... --reference REF... [--out CSV]
        [--vary KEY]
    PYTHONPATH=$PWD python experiments/lee_mixing.py --cost [--steps N]

The first form reads the particle runs under RUNS (e.g. multirun/fence,
multirun/fence_mixing, multirun/paper, multirun/paper_mixing) and writes one row per run
to ``lee_mixing.csv``: scene, lee model, resolution, dt, seed, the command that repeats
it; ``lee_error`` against the scene's reference (the report's choice,
:mod:`windbench.report.lee`) and its ratio to the paper lee's at the same settings, and the floor no lee without reverse flow can go
below (:func:`reverse_flow_floor`); the smallest volume-flux ratio through the planes
behind the scene's bodies (``metrics.plane_flux_ratio`` of the mean of the run's wind
snapshots); the fence's u/u0 at half its height 2, 5, 10 and 15 H behind it (steady
window) and ``wake_error``, the RMS difference of u/u0 from the reference's over the whole
wake lattice (2-15 H behind, 0.25-1 H high: the lee box of ``lee_error`` lies within the
first 5 H, in the reference's recirculation); the median wind time per step and its ratio
to the paper lee's. Each scene's reference gets a row of its own (lee model
``reference``) with its wake, its levels (resolutions), the lee difference of its two
finest levels, the order used and its GCI (:mod:`windbench.report.lee`). ``--vary KEY``
(e.g. ``wind.recirculation_backflow``) adds a column with each run's value of a key its
sweep varied, and that override to the command.

The second form times both lee models in one process, alternating them over the same
steps (the fence at 64 cells, dt 0.05 s; two_flags_wall at 40 cells, dt 0.02 s, with the
wall alone and with its two flags held still at their rest shape), after the spin-up, and
writes the median step time of each and their ratio to ``lee_mixing_cost.csv`` (wall and
CPU seconds; the 1-minute load average beside them).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from windbench.cli import compose_config
from windbench.cloth.model import ClothModel
from windbench.grid import Grid
from windbench.metrics import plane_flux_ratio
from windbench.report.collect import display_path, find_runs, read_runs
from windbench.report.lee import assign_lee_errors, choose_references
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.particles import ParticleWind
from windbench.wind.primitives import superpose

RESULTS = Path(__file__).resolve().parent / "results"
SETTINGS = ["scene", "resolution", "dt", "seed"]
COST_CASES = [("fence", 64, 0.05, False), ("two_flags_wall", 40, 0.02, False)]
COST_CASES.append(("two_flags_wall", 40, 0.02, True))  # (scene, cells, dt, with its cloth)


def behind_flux(rec) -> float:
    """Smallest flux ratio through the planes behind the scene's resolved bodies."""
    cfg = compose_config([f"scene={rec.settings['scene']}"])
    scene = build_scene(cfg.scene)
    grid = Grid.from_domain(scene.lower, scene.upper, int(rec.settings["resolution"]))
    with xr.open_dataset(rec.path) as ds:
        wind = ds["wind"].values
    undisturbed = superpose(scene.sources, grid.cell_centres().reshape(-1, 3))
    solid = np.linalg.norm(wind, axis=-1).max(axis=0) == 0.0
    ratio = plane_flux_ratio(wind.mean(axis=0), undisturbed.reshape(wind.shape[1:]), solid)
    rears = [b.bounds()[1][0] for b in scene.bodies if b.resolve]
    return float(ratio[grid.axes()[0] > max(rears)].min()) if rears else np.nan


def run_command(rec, lee_model: str, vary: str | None = None) -> str:
    """The single-run command that repeats ``rec`` (its experiment and settings, and the
    varied key's value)."""
    s = rec.settings
    extra = f" {vary}={rec.config.get(vary)}" if vary else ""
    return (
        f"windbench experiment={rec.experiment} wind=particles wind.lee_model={lee_model} "
        f"scene={s['scene']} grid.resolution={s['resolution']} sim.dt={s['dt']} seed={s['seed']}"
        + extra
    )


def reverse_flow_floor(ref) -> float:
    """The smallest lee error a lee without reverse flow (u_x >= 0 everywhere) can have
    against ``ref``: the RMS of the reference's negative u_x over its lee probes / U_ref,
    all else matched exactly."""
    return float(np.sqrt(np.mean(np.minimum(ref.lee_wind[:, 0], 0.0) ** 2)) / ref.reference_speed)


def wake_error(wake, ref_wake) -> float:
    """RMS over the wake lattice of u/u0 - the reference's u/u0 (NaN without both)."""
    if wake is None or ref_wake is None:
        return np.nan
    return float(np.sqrt(np.nanmean((wake - ref_wake.reindex_like(wake)).to_numpy() ** 2)))


def wake_columns(wake) -> dict:
    """u/u0 at half the fence height at each wake distance, one column each."""
    if wake is None:
        return {}
    return {f"u_over_u0_{dist:g}H": value for dist, value in wake[0.5].items()}


def reference_rows(refs) -> list[dict]:
    """One row per scene reference: its settings and its wake."""
    return [
        {
            **{k: ref.run.settings[k] for k in SETTINGS},
            "lee_model": "reference",
            "wind_seconds_median": ref.run.figures.get("wind_seconds_median"),
            **wake_columns(ref.run.wake),
            "reference_levels": "/".join(str(lv.settings["resolution"]) for lv in ref.levels),
            "reference_difference": ref.difference,
            "reference_order": ref.order,
            "reference_gci": ref.gci,
            "reference": display_path(ref.path),
            "code": ref.run.code,
        }
        for ref in refs.values()
    ]


def run_rows(runs, references, vary: str | None = None) -> pd.DataFrame:
    """One row per complete particle run (module docstring)."""
    records = read_runs(find_runs(runs), progress=False)
    refs = choose_references(records, read_runs(find_runs(references), progress=False))
    assign_lee_errors(records, refs)
    rows = []
    for rec in records:
        if rec.status != "complete" or rec.settings.get("wind") != "particles":
            continue
        row = {k: rec.settings[k] for k in SETTINGS}
        row["lee_model"] = rec.config.get("wind.lee_model") or "paper"
        if vary:
            row[vary] = rec.config.get(vary)
        row["command"] = run_command(rec, row["lee_model"], vary)
        row["lee_error"] = rec.figures.get("lee_error")
        row["flux_behind_min"] = behind_flux(rec)
        row["wind_seconds_median"] = rec.figures.get("wind_seconds_median")
        row.update(wake_columns(rec.wake))
        ref = refs.get(rec.settings["scene"])
        row["wake_error"] = wake_error(rec.wake, ref.run.wake) if ref else np.nan
        row["reverse_flow_floor"] = reverse_flow_floor(ref.run) if ref else np.nan
        row["reference"] = display_path(ref.path) if ref else ""
        row["code"] = rec.code
        rows.append(row)
    rows += reference_rows(refs)
    df = pd.DataFrame(rows).sort_values([*SETTINGS, "lee_model", *([vary] if vary else [])])
    paper = df[df["lee_model"] == "paper"].set_index(SETTINGS)
    for col in ("lee_error", "wake_error", "wind_seconds_median"):
        base = paper[col].reindex(df.set_index(SETTINGS).index).to_numpy()
        df[f"{col}_over_paper"] = df[col].to_numpy() / base
    return df


def _wind(scene, resolution, lee_model):
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    params = compose_config(["wind=particles", f"wind.lee_model={lee_model}"]).wind
    return ParticleWind(scene, grid, params)


def still_obstacles(scene, with_cloth: bool) -> Obstacles:
    """The scene's rigid bodies, and its cloth at rest if ``with_cloth``."""
    if not with_cloth:
        return Obstacles.rigid_only(scene.bodies)
    cloth = ClothModel.from_meshes(scene.cloths)
    still = np.zeros_like(cloth.rest_positions)
    return Obstacles(tuple(scene.bodies), cloth.rest_positions, still, cloth.triangles)


def cost_rows(steps: int) -> pd.DataFrame:
    """Median wall and CPU time per step of both lee models, alternated step by step."""
    rows = []
    for name, resolution, dt, with_cloth in COST_CASES:
        scene = build_scene(compose_config([f"scene={name}"]).scene)
        obstacles = still_obstacles(scene, with_cloth)
        winds = {m: _wind(scene, resolution, m) for m in ("paper", "mixing")}
        spinup = int(round(2 * (scene.upper - scene.lower)[0] / scene.reference_speed / dt))
        for wind in winds.values():
            for _ in range(spinup):
                wind.step(dt, obstacles)
        times = {m: ([], []) for m in winds}
        for _ in range(steps):
            for m, wind in winds.items():
                w0, c0 = time.perf_counter(), time.process_time()
                wind.step(dt, obstacles)
                times[m][0].append(time.perf_counter() - w0)
                times[m][1].append(time.process_time() - c0)
        row = {"scene": name, "cloth": with_cloth, "resolution": resolution, "dt": dt}
        row["steps"] = steps
        for m, (wall, cpu) in times.items():
            row[f"{m}_wall_s"], row[f"{m}_cpu_s"] = np.median(wall), np.median(cpu)
            row[f"{m}_particles"] = winds[m].stats()["live_particles"]
        row["mixing_over_paper_wall"] = row["mixing_wall_s"] / row["paper_wall_s"]
        row["mixing_over_paper_cpu"] = row["mixing_cpu_s"] / row["paper_cpu_s"]
        row["load1"] = os.getloadavg()[0]
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", type=Path)
    ap.add_argument("--reference", nargs="*", type=Path, default=[])
    ap.add_argument("--cost", action="store_true")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--out", type=Path, help="the table to write (default: by the form)")
    ap.add_argument("--vary", help="a key the runs' sweep varied: a column of its values")
    args = ap.parse_args(argv)
    RESULTS.mkdir(exist_ok=True)
    if args.cost:
        df, out = cost_rows(args.steps), RESULTS / "lee_mixing_cost.csv"
    else:
        df, out = run_rows(args.runs, args.reference, args.vary), RESULTS / "lee_mixing.csv"
    out = args.out or out
    df.to_csv(out, index=False, float_format="%.6g")
    print(df.to_string(index=False))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
