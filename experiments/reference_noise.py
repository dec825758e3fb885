"""What a reference's e21 is made of: grid, window or geometry. For the Navier-Stokes runs
of one scene at several resolutions (a reference sweep), every pair of levels gives its
lee difference e (``lee_error`` of the coarser against the finer, fraction of U_ref), its
sampling noise (``sampling_noise``: batch means over the window's blocks) and the part
the noise leaves, sqrt(e^2 - noise^2) (:mod:`windbench.report.lee`). ``noise_by_blocks``
gives the noise again with the recorded blocks merged pairwise (16, 8, 4 blocks from
``output.window_blocks=16``): batch means is too small while a block is shorter than the
flow's correlation time, so a noise that still grows as the blocks get longer is a lower
bound (Flyvbjerg and Petersen 1989).

    PYTHONPATH=$PWD python experiments/reference_noise.py SWEEP... [--out CSV]
    PYTHONPATH=$PWD python experiments/reference_noise.py RUNS... --against REFERENCE

The second form gives the same for every run under RUNS against the finest run under
REFERENCE: what a compared run's lee error is made of.

e.g. ``experiment=reference scene=two_flags_wall grid.resolution=80,40`` once with the
default window and once with ``sim.window_flow_throughs=4``, and the fence at the
comparison's reference levels (64, 128, 256) beside levels whose cell size divides the
fence's height, thickness and position (47, 94, 188 cells along its 47 m: h = 1, 0.5,
0.25 m). Each run's row also gives the window (flow-through times), the lee box's mean
wind along x and the top of the run's highest solid cell (a body fills the cells whose
centres it holds, so a 2 m fence is 2.20 m tall at h = 0.73 m, 1.84 m at 0.37 m). Appends to
``experiments/results/reference_noise.csv``: one row per pair, with the date and the
runs' code version.

With ``--by-height`` (and ``--against``) it gives instead, per probe height of the lee
box, each run's and the reference's mean wind along x (m/s) and that height's part of
lee_error^2 (the parts sum to it), appended to ``experiments/results/lee_by_height.csv``:
where in the lee box a lee error comes from.

    PYTHONPATH=$PWD python experiments/reference_noise.py RUNS... --against REF --by-height
"""

from __future__ import annotations

import argparse
import itertools
import math
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import xarray as xr

from experiments.rows import show_and_append
from windbench.report.collect import read_run
from windbench.report.lee import beyond_noise, lee_error, lee_error_by_height, sampling_noise

OUT = Path(__file__).resolve().parent / "results" / "reference_noise.csv"
HEIGHT_OUT = OUT.with_name("lee_by_height.csv")
COLUMNS = [
    "date", "code", "scene", "fine", "coarse", "coarse_model", "window_flow_throughs", "e", "noise",
    "beyond_noise", "noise_by_blocks", "fine_lee_u", "coarse_lee_u", "fine_body_height", "coarse_body_height",
    "folder",
]  # fmt: skip

HEIGHT_COLUMNS = [
    "date", "code", "scene", "resolution", "model", "reference", "lee_error", "z", "u_run",
    "u_reference", "part_of_error_squared", "folder",
]  # fmt: skip


def run_facts(path: Path) -> dict:
    """Window (flow-through times), mean lee wind along x (m/s), solid height (m)."""
    with xr.open_dataset(path) as ds:
        lee = (ds["probe_box"] == "lee").values
        window = float(ds.attrs["duration"]) / float(ds.attrs["flow_through_time"])
        lee_u = float(ds["probe_wind_mean"].values[lee, 0].mean())
    return {"window": window, "lee_u": lee_u, "height": solid_height(path)}


def solid_height(path: Path) -> float:
    """Top of the highest solid cell of the run's grid (m), from its config."""
    from windbench.cli import compose_config
    from windbench.simulate import prepare
    from windbench.wind import make_wind

    with xr.open_dataset(path) as ds:
        scene, res = ds.attrs["scene"], int(ds.attrs["resolution"])
    cfg = compose_config([f"scene={scene}", "wind=global", f"grid.resolution={res}"])
    setup = prepare(cfg)
    solid = make_wind(cfg.wind, setup.scene, setup.grid).solid_mask()
    layers = np.flatnonzero(solid.any(axis=(0, 1)))
    return float(setup.grid.lower[2] + (layers.max() + 1) * setup.grid.h) if len(layers) else 0.0


def noise_by_blocks(coarse, fine) -> str:
    """'B: noise; ...' for the recorded blocks merged pairwise while at least 4 remain."""
    parts, a, b = [], coarse.lee_block_wind, fine.lee_block_wind
    while a is not None and b is not None and len(a) == len(b) and len(a) >= 4:
        merged = [replace(coarse, lee_block_wind=a), replace(fine, lee_block_wind=b)]
        parts.append(f"{len(a)}: {sampling_noise(*merged):.4f}")
        if len(a) % 2:
            break
        a, b = _pairs(a), _pairs(b)
    return "; ".join(parts)


def _pairs(blocks: np.ndarray) -> np.ndarray:
    """Means of consecutive pairs of block means (the blocks hold equal step counts to
    within one step)."""
    return 0.5 * (blocks[0::2] + blocks[1::2])


def complete_runs(folder: Path) -> list:
    records = [read_run(p) for p in sorted(folder.glob("*/windbench.nc"))]
    return [r for r in records if r.status == "complete"]


def finest_run(folder: Path):
    """The complete run of the highest resolution in ``folder`` (the reference)."""
    return max(complete_runs(folder), key=lambda r: int(r.settings["resolution"]))


def wind_model(rec) -> str:
    """The run's wind model: backend and its lee model or advection scheme."""
    c = rec.config
    return " ".join(
        str(x)
        for x in (c.get("wind.name"), c.get("wind.lee_model") or c.get("wind.advection"))
        if x
    )


def pair_row(fine, coarse, facts: dict, folder: Path) -> dict:
    """The row of ``coarse`` against ``fine`` (module docstring)."""
    e, noise = lee_error(coarse, fine), sampling_noise(coarse, fine)
    a, b = facts[fine.path], facts[coarse.path]
    return {
        "date": datetime.now(UTC).date().isoformat(),
        "code": coarse.code,
        "scene": fine.settings["scene"],
        "fine": fine.settings["resolution"],
        "coarse": coarse.settings["resolution"],
        "coarse_model": wind_model(coarse),
        "window_flow_throughs": round(b["window"], 3),
        "e": round(e, 4),
        "noise": round(noise, 4),
        "beyond_noise": round(beyond_noise(e, noise), 4) if math.isfinite(noise) else "",
        "noise_by_blocks": noise_by_blocks(coarse, fine),
        "fine_lee_u": round(a["lee_u"], 3),
        "coarse_lee_u": round(b["lee_u"], 3),
        "fine_body_height": round(a["height"], 3),
        "coarse_body_height": round(b["height"], 3),
        "folder": folder.name,
    }


def rows(folder: Path, against: Path | None = None) -> list[dict]:
    """Every pair of levels in ``folder``; with ``against``, every run in ``folder``
    against the finest run there (the reference)."""
    records = complete_runs(folder)
    if against is None:
        records.sort(key=lambda r: -int(r.settings["resolution"]))
        pairs = list(itertools.combinations(records, 2))
    else:
        ref = finest_run(against)
        pairs = [(ref, r) for r in records]
    facts = {r.path: run_facts(r.path) for pair in pairs for r in pair}
    return [pair_row(fine, coarse, facts, folder) for fine, coarse in pairs]


def height_rows(folder: Path, against: Path) -> list[dict]:
    """``--by-height``: per probe height, every complete run in ``folder`` against the
    finest run in ``against`` (:func:`windbench.report.lee.lee_error_by_height`)."""
    ref = finest_run(against)
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
    parser.add_argument("sweeps", nargs="+", type=Path)
    parser.add_argument("--against", type=Path, help="a reference sweep: each run against it")
    parser.add_argument("--by-height", action="store_true", help="lee error by probe height")
    parser.add_argument("--out", type=Path, default=None, help="default: by the form")
    args = parser.parse_args(argv)
    if args.by_height:
        if args.against is None:
            parser.error("--by-height needs --against REFERENCE")
        found = [row for folder in args.sweeps for row in height_rows(folder, args.against)]
        show_and_append(args.out or HEIGHT_OUT, found, HEIGHT_COLUMNS, HEIGHT_COLUMNS[3:-1])
        return
    found = [row for folder in args.sweeps for row in rows(folder, args.against)]
    show_and_append(args.out or OUT, found, COLUMNS, COLUMNS[2:-1])


if __name__ == "__main__":
    main()
