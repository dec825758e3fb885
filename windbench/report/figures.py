"""Figures of the report: the paper's Figs. 3-6 from run datasets, and §4.3 measured.

Drawn with matplotlib's object API (``matplotlib.figure.Figure`` + Agg canvas: no pyplot
state, no display). Every figure function returns a :class:`Drawn` (written as PNG and SVG)
or a :class:`Missing` that says which runs would produce it.

Paper figures (§5): Fig. 3 the flag in particle-traced wind at a few times; Figs. 4/5 two
flags and a wall, Navier-Stokes beside particle tracing, over a horizontal slice of wind
speed that shows the lee; Fig. 6 the shirt with lee (particles) beside without (global);
§4.2.2's opposing sources: the per-source particle field beside the field that tagging
cells with the superposed ``w = sum w_i`` would give.

§4.3 measured: cost per step against grid cells (log-log, fitted exponent), lee error and
divergence against resolution, lee force ratio against time step and resolution, and the
§3 force law as flat-plate coefficients beside Hoerner's measurements (Fluid-Dynamic Lift,
1985). These group runs by model (``backend``: :func:`~windbench.report.collect.backend_label`),
so that the particles' two lee models and the Navier-Stokes wind's cloth couplings stay
apart; the paper's figures show each backend's paper model.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: F401 - registers "3d"
from omegaconf import OmegaConf

from windbench.aero import AeroParams, plate_coefficients
from windbench.report.collect import AVERAGE_FROM, RunRecord, is_paper_model, with_backend
from windbench.report.frames import (
    FRONT_BAND,
    RunFrames,
    front_passes,
    gust_front,
    open_frames,
    read_frames,
    side_pressure,
    wind_direction,
)
from windbench.scenes import Scene, build_scene
from windbench.wind.primitives import superpose

BACKEND_COLORS = {
    "global": "tab:blue",
    "particles": "tab:orange",
    "particles/mixing": "tab:red",
    "navier_stokes": "tab:green",
    "navier_stokes/projection": "tab:purple",
    "navier_stokes/none": "tab:brown",
}
MARKERS = "osD^v<>ph*"
LINESTYLES = ("-", "--", ":", "-.")
SNAPSHOT_FRAMES = 4  # cloth frames in Fig. 3
COST = "seconds_per_step_median"  # robust to other processes on a shared machine
WIND_COST = "wind_seconds_median"  # the backend's own share of a step


@dataclass
class Drawn:
    name: str
    title: str
    caption: str
    figure: Figure


@dataclass
class Missing:
    name: str
    title: str
    needs: str  # which runs would produce it, with the command
    error: str = ""  # set when the runs were there but drawing failed


TITLES = {
    "fig3_flag": "Fig. 3 — flag in the wind",
    "fig45_two_flags_wall": "Figs. 4 and 5 — two flags and a wall",
    "fig6_shirt": "Fig. 6 — shirt with lee (particles) and without (global), front and back",
    "opposing_sources": "§4.2.2 — opposing sources: per-source particles vs. tagging with w = Σ wᵢ",
    "lee_in_time": "Lee speed ratio in time",
}


def attempt(name: str, records) -> Drawn | Missing:
    """Draw the run figure ``name`` (see :data:`RUN_FIGURES`), or a :class:`Missing` with the
    error if drawing fails: a report with one figure missing beats no report."""
    try:
        return RUN_FIGURES[name](records)
    except Exception as err:  # noqa: BLE001 - reported in the page
        return Missing(name, TITLES[name], "", error=f"{type(err).__name__}: {err}")


def _color(wind: str) -> str:
    return BACKEND_COLORS.get(wind, "tab:gray")


def save(fig: Figure, folder: Path, name: str) -> list[Path]:
    """Write ``fig`` as PNG and SVG. The figures lay themselves out (constrained layout,
    :func:`_figure`), so they are saved at their own size: a tight bounding box would draw
    each one once more to measure it. The layout is solved while the PNG is drawn and then
    kept (the layout engine is removed), so the SVG, the same figure at the same size,
    does not solve it again."""
    import matplotlib

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    with matplotlib.rc_context({"svg.hashsalt": "windbench"}):  # stable SVG ids
        for ext in ("png", "svg"):
            path = folder / f"{name}.{ext}"
            fig.savefig(path, dpi=110, metadata=_metadata(ext))
            fig.set_layout_engine("none")  # the axes keep the positions just solved
            out.append(path)
    return out


def _metadata(ext: str) -> dict:
    # no creation dates: the same runs give the same files
    return {"Date": None} if ext == "svg" else {"Software": "windbench/matplotlib"}


# ---------------------------------------------------------------------------- helpers


def pick(records: Sequence[RunRecord], scene: str, wind: str) -> RunRecord | None:
    """The finest complete run of (scene, wind): the paper's model of the backend where
    there is one (:func:`~windbench.report.collect.is_paper_model`), highest resolution,
    smallest dt, lowest seed."""
    runs = _runs_of(records, scene, wind)
    return runs[0] if runs else None


def _runs_of(records: Sequence[RunRecord], scene: str, wind: str) -> list[RunRecord]:
    """The complete runs of (scene, wind), in the order :func:`pick` prefers them."""
    runs = [
        r
        for r in records
        if r.status == "complete"
        and r.settings.get("scene") == scene
        and r.settings.get("wind") == wind
    ]
    return sorted(runs, key=_finest_first)


def _finest_first(rec: RunRecord) -> tuple:
    s = rec.settings
    paper = is_paper_model(rec)
    return (not paper, -int(s["resolution"]), float(s["dt"]), int(s["seed"]), str(rec.path))


def pick_with_frames(records: Sequence[RunRecord], scene: str, wind: str):
    """(record, frames) of the run :func:`pick` would choose among those that kept frames,
    or None."""
    for rec in _runs_of(records, scene, wind):
        frames = open_frames(rec.path)
        if frames is not None:
            return rec, frames
    return None


def scene_of(ds: xr.Dataset) -> Scene:
    """The run's scene, rebuilt from the resolved config stored in the dataset."""
    cfg = OmegaConf.create(ds.attrs["config"])
    return build_scene(cfg.scene)


def _cloth_polys(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    return positions[triangles]


def _clip_segment(a, b, lower, upper):
    """The part of segment ab inside the box [lower, upper] (Liang-Barsky), or None."""
    t0, t1, d = 0.0, 1.0, b - a
    for k in range(3):
        if d[k] == 0:
            if not lower[k] <= a[k] <= upper[k]:
                return None
            continue
        lo, hi = sorted(((lower[k] - a[k]) / d[k], (upper[k] - a[k]) / d[k]))
        t0, t1 = max(t0, lo), min(t1, hi)
    return (a + t0 * d, a + t1 * d) if t0 <= t1 else None


def _draw_bodies_3d(ax, scene: Scene, lower=None, upper=None):
    """Boxes as faces, capsules and cylinders as thick lines, cut to the view box if given."""
    lower = scene.lower if lower is None else np.asarray(lower)
    upper = scene.upper if upper is None else np.asarray(upper)
    for body in scene.bodies:
        p = np.asarray(body.params)
        if body.kind == "box":
            lo, hi = np.maximum(p[0:3], lower), np.minimum(p[3:6], upper)
            if np.any(lo >= hi):
                continue
            faces = []
            for axis in range(3):
                for side in (lo[axis], hi[axis]):
                    others = [a for a in range(3) if a != axis]
                    corners = []
                    for u, v in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        c = np.empty(3)
                        c[axis] = side
                        c[others[0]] = (lo, hi)[u][others[0]]
                        c[others[1]] = (lo, hi)[v][others[1]]
                        corners.append(c)
                    faces.append(corners)
            ax.add_collection3d(
                Poly3DCollection(faces, facecolor="0.6", edgecolor="0.3", alpha=0.35, lw=0.5)
            )
        elif body.kind in ("cylinder", "capsule"):
            seg = _clip_segment(p[0:3], p[3:6], lower, upper)
            if seg is not None:
                ax.plot(*zip(*seg, strict=True), color="0.45", lw=2.0 + 50.0 * p[6], alpha=0.8)


def _draw_cloth_3d(ax, positions, triangles, color="tab:red"):
    ax.add_collection3d(
        Poly3DCollection(
            _cloth_polys(positions, triangles),
            facecolor=color,
            edgecolor="k",
            linewidths=0.1,
            alpha=0.85,
            rasterized=True,  # SVG: the mesh as one bitmap, not a path per triangle
        )
    )


def _frame_3d(ax, lower, upper, zoom: float = 1.0):
    ax.set_xlim(lower[0], upper[0])
    ax.set_ylim(lower[1], upper[1])
    ax.set_zlim(lower[2], upper[2])
    ax.set_box_aspect(tuple(np.asarray(upper) - np.asarray(lower)), zoom=zoom)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.view_init(elev=18, azim=-60)
    ax.locator_params(nbins=4)
    ax.tick_params(labelsize=7)


def _cloth_bounds(ds: xr.Dataset, scene: Scene, margin: float = 0.4):
    """A view box around every frame of the cloth (at least 1 m per axis), inside the domain."""
    pos = np.asarray(ds["cloth_position"].values)
    mid = 0.5 * (pos.min(axis=(0, 1)) + pos.max(axis=(0, 1)))
    half = np.maximum(0.5 * (pos.max(axis=(0, 1)) - pos.min(axis=(0, 1))) + margin, 0.5)
    lo = np.minimum(mid - half, scene.upper)
    hi = np.maximum(mid + half, scene.lower)
    lo = np.maximum(lo, scene.lower)
    hi = np.minimum(hi, scene.upper)
    lo[2] = scene.lower[2]
    return lo, hi


def _lee_height(ds: xr.Dataset) -> float:
    """z of the horizontal wind slice: the centre of the lee probe box, else mid-domain."""
    if "probe_points" in ds:
        box = np.asarray(ds["probe_box"].values).astype(str)
        pts = np.asarray(ds["probe_points"].values)
        if (box == "lee").any():
            return float(pts[box == "lee", 2].mean())
    z = ds["z"].values
    return float(0.5 * (z[0] + z[-1]))


def _slice(ds: xr.Dataset, z: float, component: int | None = None) -> np.ndarray:
    """(nx, ny) wind speed (or one component) at the cell layer nearest to height z."""
    layer = ds["wind"].isel(snapshot=-1).sel(z=z, method="nearest").values
    return np.linalg.norm(layer, axis=-1) if component is None else layer[..., component]


def _extent(ds: xr.Dataset):
    h = float(ds.attrs.get("grid_spacing", ds["x"].values[1] - ds["x"].values[0]))
    x, y = ds["x"].values, ds["y"].values
    return [x[0] - h / 2, x[-1] + h / 2, y[0] - h / 2, y[-1] + h / 2]


def _draw_bodies_xy(ax, scene: Scene, z: float):
    from matplotlib.patches import Circle, Rectangle

    for body in scene.bodies:
        lo, hi = body.bounds()
        if body.kind == "plane" or not (lo[2] <= z <= hi[2]):
            continue
        if body.kind == "box":
            ax.add_patch(
                Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fc="0.5", ec="k", lw=0.6)
            )
        elif body.kind == "mesh":
            _mesh_section_xy(ax, body, lo, hi, z)
        else:  # capsule or cylinder: its axis where it crosses the height z
            p = np.asarray(body.params)
            a, b = p[0:3], p[3:6]
            f = np.clip((z - a[2]) / (b[2] - a[2]), 0.0, 1.0) if b[2] != a[2] else 0.0
            c = a + f * (b - a)
            ax.add_patch(Circle((c[0], c[1]), max(p[6], 0.04), fc="0.3", ec="k", lw=0.6))


SECTION_POINTS = 160  # samples per side of a mesh body's section


def _mesh_section_xy(ax, body, lo, hi, z: float) -> None:
    """A mesh body's cross-section at height z: where its signed distance is negative."""
    x = np.linspace(lo[0], hi[0], SECTION_POINTS)
    y = np.linspace(lo[1], hi[1], SECTION_POINTS)
    xx, yy = np.meshgrid(x, y)
    points = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)])
    d = body.distance(points)[0].reshape(xx.shape)
    if d.min() >= 0.0:
        return
    ax.contourf(xx, yy, d, levels=[d.min() - 1.0, 0.0], colors=["0.3"])
    ax.contour(xx, yy, d, levels=[0.0], colors="k", linewidths=0.6)


def _view_box(scene: Scene, positions: Sequence[np.ndarray], margin: float = 0.4):
    """A 3D view box around the cloth (every frame given) and the bodies the wind grid
    resolves (walls, a torso), inside the domain; thin bodies (poles, limbs) are cut to it."""
    solid = [b for b in scene.bodies if b.kind != "plane" and b.resolve]
    lows = [np.asarray(b.bounds()[0]) for b in solid]
    highs = [np.asarray(b.bounds()[1]) for b in solid]
    for pos in positions:
        if pos.size:
            lows.append(pos.reshape(-1, 3).min(axis=0) - margin)
            highs.append(pos.reshape(-1, 3).max(axis=0) + margin)
    if not lows:
        return np.asarray(scene.lower, float), np.asarray(scene.upper, float)
    lo = np.maximum(np.min(lows, axis=0), scene.lower)
    hi = np.minimum(np.max(highs, axis=0), scene.upper)
    return lo, hi


PRESSURE_CMAP = "plasma"
SPEED_CMAP = "viridis"
NOT_ARRIVED_RGBA = (0.93, 0.93, 0.93, 0.95)  # particle tracing: no gust particle yet
NOT_ARRIVED_LABEL = "no gust particle has arrived yet (not lee)"
ARRIVAL = (
    "Particle tracing has wind only where its gust particles have arrived: pale grey cells "
    f"lie beyond its gust front or within {FRONT_BAND:g} cells behind it (the front is "
    "ragged) and have not been reached yet, which is not lee; unreached cells farther behind "
    "the front are its lee."
)


def _shared_max(arrays, q: float = 99.0) -> float:
    """One colour-scale top for several panels: the q-th percentile of all their values."""
    values = np.concatenate([np.ravel(a) for a in arrays if np.size(a)] or [np.zeros(1)])
    values = values[np.isfinite(values)]
    top = float(np.percentile(values, q)) if values.size else 0.0
    return top if top > 0 else 1.0


def _pressure_cloth_3d(ax, positions, triangles, pressure, norm):
    """The cloth with each triangle coloured by its |F| / A on the shared scale ``norm``."""
    import matplotlib

    poly = Poly3DCollection(
        _cloth_polys(positions, triangles),
        facecolors=matplotlib.colormaps[PRESSURE_CMAP](norm(pressure)),
        edgecolor="none",
        rasterized=True,  # SVG: the mesh as one bitmap, not a path per triangle
    )
    ax.add_collection3d(poly)
    return poly


def _not_arrived(frames: RunFrames, k: int, direction) -> np.ndarray:
    """(ny, nx, 4) RGBA overlay of the slice cells no gust particle has reached by frame k."""
    rgba = np.zeros((*frames.speed.shape[1:][::-1], 4))
    _, later = frames.unreached(k, direction)
    rgba[later.T] = NOT_ARRIVED_RGBA
    return rgba


def regenerate(records: Sequence[RunRecord], inputs: Sequence, out, reference=None) -> str:
    """The one-line command that remakes a report's figures (ends every caption): the runs'
    experiment, when they share one, then ``windbench-report`` on the same inputs."""
    from windbench.report.collect import display_path

    experiments = {r.experiment for r in records if r.experiment}
    args = " ".join(display_path(Path(i)) for i in inputs)
    if reference:
        folders = reference if isinstance(reference, list | tuple) else [reference]
        args += " --reference " + " ".join(display_path(Path(f)) for f in folders)
    report = f"windbench-report {args} --out {display_path(Path(out))}"
    if not experiments:
        return f"Regenerate: `{report}`."
    sweeps = " && ".join(f"windbench -m experiment={e}" for e in sorted(experiments))
    if reference:  # the references' sweeps: listed beside the experiments'
        return f"Regenerate: `{sweeps}`, the reference sweeps (`conf/experiment/reference.yaml`), then `{report}`."
    return f"Regenerate: `{sweeps} && {report}`."


def _figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def _run_note(rec: RunRecord) -> str:
    s = rec.settings
    return f"{s['wind']}, resolution {s['resolution']}, dt = {float(s['dt']):.3g} s"


# ---------------------------------------------------------------------------- paper figures


def fig3_flag(records: Sequence[RunRecord]) -> Drawn | Missing:
    """Fig. 3: the flag in the wind (particle tracing), a few frames in time."""
    title = TITLES["fig3_flag"]
    rec = pick(records, "flag", "particles")
    fallback = rec is None
    if fallback:
        rec = next(
            (
                pick(records, "flag", w)
                for w in ("navier_stokes", "global")
                if pick(records, "flag", w)
            ),
            None,
        )
    if rec is None:
        return Missing(
            "fig3_flag",
            title,
            "a `flag` run with `wind=particles`: `windbench scene=flag wind=particles`",
        )
    with xr.open_dataset(rec.path) as ds:
        scene = scene_of(ds)
        times = ds["time"].values
        idx = np.unique(np.linspace(0, len(times) - 1, SNAPSHOT_FRAMES).round().astype(int))
        tris = ds["cloth_triangles"].values
        lo, hi = _cloth_bounds(ds, scene)
        fig = _figure(3.2 * len(idx), 3.4)
        for n, i in enumerate(idx):
            ax = fig.add_subplot(1, len(idx), n + 1, projection="3d")
            _draw_bodies_3d(ax, scene, lo, hi)
            _draw_cloth_3d(ax, ds["cloth_position"].isel(time=int(i)).values, tris)
            _frame_3d(ax, lo, hi)
            ax.set_title(f"t = {times[i]:.2f} s", fontsize=9)
    note = " (no particles run in the inputs: shown with the backend that is)" if fallback else ""
    caption = f"The flag of Fig. 3 at {len(idx)} times; {_run_note(rec)}{note}."
    return Drawn("fig3_flag", title, caption, fig)


def _slice_height(ds: xr.Dataset) -> float:
    """The height of the recorded frames' slice (``slice_z``), else :func:`_lee_height`."""
    return float(ds["slice_wind"].attrs["slice_z"]) if "slice_wind" in ds else _lee_height(ds)


def _arrival(ds: xr.Dataset, path) -> tuple[RunFrames | None, str]:
    """The run's frames and a sentence on where its particles have arrived at the end."""
    frames = read_frames(ds, path)
    if frames is None or frames.reached is None:
        if ds.attrs.get("wind") == "particles":
            return frames, (
                "Where its particles had not arrived is not recorded (a run with "
                "`output.frames.interval` > 0 keeps it), so its zero-wind cells may be lee or "
                "wind not yet arrived."
            )
        return frames, ""
    direction = wind_direction(scene_of(ds))
    t = float(frames.times[-1])
    if direction is None:
        return frames, f"Pale grey: cells no gust particle had reached by t = {t:.2f} s."
    front = gust_front(frames.reach[-1], direction)
    where = ", ".join(
        f"{a} = {v:.3g} m" for a, v in zip("xyz", direction * front, strict=True) if abs(v) > 0
    )
    return frames, f"At t = {t:.2f} s the particles' gust front stands at {where}. {ARRIVAL}"


def _wake_span(scene: Scene, lo, hi) -> tuple[float, float]:
    """x range of a lee slice: from the domain's inflow end to twice the view box's length
    beyond it (the near wake, where the lee box lies), inside the domain."""
    return float(scene.lower[0]), float(min(scene.upper[0], hi[0] + 2.0 * (hi[0] - lo[0])))


def _lee_panels(records, scene_name, winds):
    present = [(w, pick(records, scene_name, w)) for w in winds]
    present = [(w, r) for w, r in present if r is not None]
    if not present:
        return None, [], [], []
    datasets = [xr.open_dataset(r.path) for _, r in present]
    notes = []
    try:
        z = _slice_height(datasets[0])
        speeds = [_slice(ds, z) for ds in datasets]
        vmax = max(float(s.max()) for s in speeds) or 1.0
        n = len(present)
        fig = _figure(4.2 * n, 6.0)
        grid = fig.add_gridspec(2, n, height_ratios=[1.25, 1.0])
        axes_slice = []
        for c, ((wind, rec), ds, speed) in enumerate(zip(present, datasets, speeds, strict=True)):
            scene = scene_of(ds)
            ax = fig.add_subplot(grid[0, c], projection="3d")
            lo, hi = _view_box(scene, [ds["cloth_position"].values])  # the flags, the wall
            _draw_bodies_3d(ax, scene, lo, hi)
            tris = ds["cloth_triangles"].values
            if tris.size:
                _draw_cloth_3d(ax, ds["cloth_position"].isel(time=-1).values, tris)
            _frame_3d(ax, lo, hi)
            ax.set_title(f"{wind}  (t = {float(ds['time'].values[-1]):.2f} s)", fontsize=10)
            ax2 = fig.add_subplot(grid[1, c])
            im = ax2.imshow(
                speed.T, origin="lower", extent=_extent(ds), vmin=0, vmax=vmax, cmap="viridis"
            )
            frames, note = _arrival(ds, rec.path)
            if frames is not None and frames.reached is not None:
                ax2.imshow(
                    _not_arrived(frames, -1, wind_direction(scene)),
                    origin="lower",
                    extent=_extent(ds),
                    interpolation="nearest",
                )
            if note:
                notes.append(f"{wind}: {note}")
            _draw_bodies_xy(ax2, scene, z)
            if tris.size:
                pos = ds["cloth_position"].isel(time=-1).values
                ax2.plot(pos[:, 0], pos[:, 1], ".", color="tab:red", ms=0.8)
            ax2.set_aspect("equal")
            ax2.set_xlim(*_wake_span(scene, lo, hi))
            ax2.set_xlabel("x (m)")
            ax2.set_ylabel("y (m)")
            lsr = rec.figures.get("lee_speed_ratio", math.nan)
            lfr = rec.figures.get("lee_force_ratio", math.nan)
            label = f"|u| at z = {z:.3g} m; lee speed ratio " + (
                f"{lsr:.3g}" if np.isfinite(lsr) else "–"
            )
            if np.isfinite(lfr):
                label += f", force ratio {lfr:.3g}"
            ax2.set_title(label, fontsize=8)
            axes_slice.append(ax2)
        fig.colorbar(im, ax=axes_slice, label="wind speed (m/s)", shrink=0.8)
    finally:
        for ds in datasets:
            ds.close()
    return fig, present, [w for w in winds if w not in dict(present)], notes


def fig45_two_flags_wall(records: Sequence[RunRecord]) -> Drawn | Missing:
    """Figs. 4/5: two flags and a wall; Navier-Stokes beside particle tracing (and global)."""
    title = TITLES["fig45_two_flags_wall"]
    winds = ("navier_stokes", "particles", "global")
    fig, present, absent, notes = _lee_panels(records, "two_flags_wall", winds)
    if fig is None:
        return Missing(
            "fig45_two_flags_wall",
            title,
            "`two_flags_wall` runs with `wind=navier_stokes` and `wind=particles`: "
            "`windbench -m scene=two_flags_wall wind=navier_stokes,particles`",
        )
    caption = (
        "Final frame of each backend around the flags and the wall (top) and the wind speed "
        "in a horizontal slice through the lee box, over the near wake (bottom; dark grey: "
        "the wall, red dots: cloth vertices). The wall stands "
        "upwind of the second flag (y > 2 m); the global field ignores it by design (no "
        "lee); each slice's title gives the measured lee speed ratio and the force on the "
        "sheltered flag over that on the exposed one. "
        + "".join(f"{n} " for n in notes)
        + "Runs: "
        + "; ".join(_run_note(r) for _, r in present)
        + "."
    )
    if absent:
        caption += " Not in the inputs: " + ", ".join(f"`wind={w}`" for w in absent) + "."
    return Drawn("fig45_two_flags_wall", title, caption, fig)


SHIRT_WINDS = ("particles", "global", "navier_stokes")  # Fig. 6: lee, no lee, reference
SIDE_VIEWS = (("front (upwind side)", 180.0), ("back (lee side)", 0.0))  # camera azimuths


def shirt_pressure(frames: RunFrames, direction: np.ndarray) -> tuple[float, float]:
    """(front, back) mean pressure of the cloth, time mean over the frames of the second
    half of the run (t >= AVERAGE_FROM t_end), each frame's ``sum |F| / sum A``."""
    late = frames.times >= AVERAGE_FROM * frames.times[-1]
    sides = [
        side_pressure(frames.force[k], frames.positions[k], frames.triangles, direction)
        for k in np.flatnonzero(late)
    ]
    front, back = np.asarray(sides).mean(axis=0)
    return float(front), float(back)


def fig6_shirt(records: Sequence[RunRecord]) -> Drawn | Missing:
    """Fig. 6: the shirt's front and back coloured by |F| / A, with lee (particles), without
    (global) and the Navier-Stokes reference, over a horizontal wind slice through the chest."""
    title = TITLES["fig6_shirt"]
    present = []
    for wind in SHIRT_WINDS:
        found = pick_with_frames(records, "shirt", wind)
        if found is not None:
            present.append((wind, *found))
    if not present:
        return Missing(
            "fig6_shirt",
            title,
            "`shirt` runs that record frames (per-triangle forces): "
            f"`windbench -m scene=shirt wind={','.join(SHIRT_WINDS)} output.frames.interval=0.02`",
        )
    with xr.open_dataset(present[0][1].path) as ds:
        scene = scene_of(ds)
    direction = wind_direction(scene)
    if direction is None:
        direction = np.array([1.0, 0.0, 0.0])
    norm = Normalize(0.0, _shared_max([f.pressure[-1] for _, _, f in present]))
    u_max = _shared_max([f.speed[-1] for _, _, f in present], 100.0)
    lo, hi = _view_box(scene, [f.positions[-1] for _, _, f in present], margin=0.05)
    lo[2] = min(f.positions[-1][:, 2].min() for _, _, f in present) - 0.05
    n = len(present)
    fig = _figure(3.3 * n + 1.0, 9.6)
    grid = fig.add_gridspec(3, n, height_ratios=[1.0, 1.0, 0.9])
    cloth_axes, slice_axes, sides = [], [], []
    for c, (wind, _rec, fr) in enumerate(present):
        for row, (label, azim) in enumerate(SIDE_VIEWS):
            ax = fig.add_subplot(grid[row, c], projection="3d")
            ax.set_proj_type("ortho")
            _pressure_cloth_3d(ax, fr.positions[-1], fr.triangles, fr.pressure[-1], norm)
            _frame_3d(ax, lo, hi)
            ax.view_init(elev=8, azim=azim)
            ax.set_xticks([])  # along the line of sight
            ax.set_xlabel("")
            ax.set_title(f"{wind}: {label}", fontsize=9)
            cloth_axes.append(ax)
        ax = fig.add_subplot(grid[2, c])
        im = _chest_slice(ax, wind, fr, scene, direction, (lo, hi), u_max)
        slice_axes.append(ax)
        sides.append((wind, *shirt_pressure(fr, direction)))
    fig.colorbar(
        _mappable(norm, PRESSURE_CMAP),
        ax=cloth_axes,
        label="|F| / A (Pa)",
        shrink=0.6,
        pad=0.08,  # clear of the 3D axes' z labels
        extend="max",
    )
    fig.colorbar(im, ax=slice_axes, label="wind speed (m/s)", shrink=0.8)
    t = float(present[0][2].times[-1])
    measured = "; ".join(
        f"{w} {front:.3g} / {back:.3g} Pa (back/front {back / front:.3g})"
        for w, front, back in sides
    )
    caption = (
        f"The shirt at t = {t:.2f} s seen from upwind (top row) and from downwind (middle "
        "row), every triangle coloured by its aerodynamic pressure |F| / A on one scale; "
        f"bottom: wind speed in the horizontal slice through the chest (z = "
        f"{present[0][2].slice_z:.3g} m; red: shirt vertices within half a cell of it, dark "
        "grey: the body). The global field has no lee: every triangle sees the same wind, "
        "so front and back differ only by their angle to it; a back/front ratio below that "
        "of the global field is the shelter of the body. Measured mean pressure front / back "
        "(area-weighted, time mean over the second half of the run; front = triangles upwind "
        f"of the shirt's centre): {measured}. Runs: "
        + "; ".join(_run_note(r) for _, r, _ in present)
    )
    missing = set(SHIRT_WINDS) - {w for w, _, _ in present}
    if missing:
        caption += ". Not in the inputs (or without frames): " + ", ".join(
            f"`wind={w}`" for w in sorted(missing)
        )
    return Drawn("fig6_shirt", title, caption + ".", fig)


def _chest_slice(ax, wind, fr, scene, direction, box, u_max):
    """Fig. 6's bottom row: wind speed in the slice through the chest, the body, the shirt
    vertices near the slice and where the wind has not arrived; returns the image."""
    lo, hi = box
    im = ax.imshow(
        fr.speed[-1].T,
        origin="lower",
        extent=fr.extent,
        vmin=0,
        vmax=u_max,
        cmap=SPEED_CMAP,
        interpolation="nearest",
    )
    ax.imshow(_not_arrived(fr, -1, direction), origin="lower", extent=fr.extent)
    _draw_bodies_xy(ax, scene, fr.slice_z)
    ring = np.abs(fr.positions[-1][:, 2] - fr.slice_z) < 0.5 * fr.h
    ax.plot(fr.positions[-1][ring, 0], fr.positions[-1][ring, 1], ".", color="tab:red", ms=1)
    ax.set_xlim(lo[0] - 0.4, hi[0] + 0.6)
    ax.set_ylim(lo[1] - 0.3, hi[1] + 0.3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{wind}: |u| at z = {fr.slice_z:.3g} m", fontsize=9)
    ax.annotate(
        "wind",
        (0.26, 0.93),
        xytext=(0.04, 0.93),
        xycoords="axes fraction",
        arrowprops={"arrowstyle": "->", "color": "w"},
        color="w",
        va="center",
        fontsize=8,
    )
    return im


def _mappable(norm, cmap):
    from matplotlib.cm import ScalarMappable

    return ScalarMappable(norm=norm, cmap=cmap)


def tagging_field(ds: xr.Dataset) -> np.ndarray:
    """The wind that tagging cells with the superposed field would give (paper §4.2.2).

    Cells the per-source particles reached (non-zero wind in the run) are tagged "wind" and
    get ``w = sum_i w_i`` at their centre; untagged cells get zero.
    """
    scene = scene_of(ds)
    x, y, z = ds["x"].values, ds["y"].values, ds["z"].values
    centres = np.stack(np.meshgrid(x, y, z, indexing="ij"), axis=-1)
    w = superpose(scene.sources, centres)
    reached = np.linalg.norm(ds["wind"].isel(snapshot=-1).values, axis=-1) > 0
    return w * reached[..., None]


def fig_opposing_sources(records: Sequence[RunRecord]) -> Drawn | Missing:
    """§4.2.2: per-source particles beside cell tagging with the superposed field."""
    title = TITLES["opposing_sources"]
    rec = pick(records, "opposing_sources", "particles")
    if rec is None:
        return Missing(
            "opposing_sources",
            title,
            "an `opposing_sources` run with `wind=particles`: "
            "`windbench scene=opposing_sources wind=particles`",
        )
    with xr.open_dataset(rec.path) as ds:
        scene = scene_of(ds)
        z = float(0.5 * (scene.lower[2] + scene.upper[2]))
        iz = int(np.abs(ds["z"].values - z).argmin())
        particles = ds["wind"].isel(snapshot=-1).values[:, :, iz, 0]
        tagged = tagging_field(ds)[:, :, iz, 0]
        u = scene.reference_speed
        fig = _figure(9.0, 3.6)
        axes = []
        for c, (field, label) in enumerate(
            ((particles, "particle tracing (per-source w_i)"), (tagged, "tagging with w = Σ w_i"))
        ):
            ax = fig.add_subplot(1, 2, c + 1)
            im = ax.imshow(
                field.T, origin="lower", extent=_extent(ds), vmin=-u, vmax=u, cmap="RdBu_r"
            )
            _draw_bodies_xy(ax, scene, float(ds["z"].values[iz]))
            ax.set_title(f"{label}\nRMS |u_x| = {np.sqrt(np.mean(field**2)):.3g} m/s", fontsize=9)
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
            ax.set_aspect("equal")
            axes.append(ax)
        fig.colorbar(im, ax=axes, label="u_x (m/s)", shrink=0.8)
    caption = (
        "Wind u_x in the mid-height slice. Each source's particles carry its own velocity, "
        "so each side of the wall keeps its own wind; tagging the reached cells with the "
        f"superposed field would cancel it to zero. Run: {_run_note(rec)}."
    )
    return Drawn("opposing_sources", title, caption, fig)


# ---------------------------------------------------------------------------- §4.3 measured


MIN_FIT_SECONDS = 1e-3  # steps faster than this measure overheads, not the solver's cost


def fit_exponent(cells, seconds) -> float:
    """p of seconds ~ cells^p by least squares in log-log over the sizes whose step takes
    at least MIN_FIT_SECONDS (nan with < 2 such sizes)."""
    cells, seconds = np.asarray(cells, float), np.asarray(seconds, float)
    ok = (cells > 0) & np.isfinite(seconds) & (seconds >= MIN_FIT_SECONDS)
    if len(np.unique(cells[ok])) < 2:
        return math.nan
    return float(np.polyfit(np.log(cells[ok]), np.log(seconds[ok]), 1)[0])


def _series(df: pd.DataFrame, x: str, y: str, by=("backend", "scene")):
    """Mean of y at each x within each group (other settings averaged)."""
    d = df[np.isfinite(df[y].astype(float))]
    for key, g in d.groupby(list(by), sort=True):
        s = g.groupby(x)[y].mean().sort_index()
        yield key, s


def timed(df: pd.DataFrame, contended: bool = False) -> pd.DataFrame:
    """The runs whose timings are their own cost: without those flagged ``contended``
    (they shared their cores, :func:`windbench.report.collect.contention`) unless
    ``contended`` keeps them."""
    if contended or "contended" not in df:
        return df
    return df[~df["contended"].fillna(False).astype(bool)]


def cost_exponents(df: pd.DataFrame, contended: bool = False) -> pd.DataFrame:
    """Fitted p of wind-phase time ~ cells^p per model (``backend``, :func:`with_backend`;
    all scenes) and per scene, over the runs :func:`timed` keeps; ``left out
    (contended)`` counts the others."""
    rows = []
    d = df[np.isfinite(df[WIND_COST].astype(float))] if WIND_COST in df else df.iloc[0:0]
    for model, g in with_backend(d).groupby("backend", sort=True):
        k = timed(g, contended)
        row = _exponent_row(model, "all scenes", k["grid_cells"], k[WIND_COST])
        rows.append({**row, "left out (contended)": len(g) - len(k)})
        for scene, gs in g.groupby("scene", sort=True):
            ks = timed(gs, contended)
            s = ks.groupby("grid_cells")[WIND_COST].mean().sort_index()
            row = _exponent_row(model, scene, s.index.values, s.values)
            rows.append({**row, "left out (contended)": len(gs) - len(ks)})
    return pd.DataFrame(rows)


def _exponent_row(model, scene, cells, seconds) -> dict:
    cells = np.asarray(cells, dtype=float)
    return {
        "backend": model,
        "scene": scene,
        "runs": len(cells),
        "cells": f"{int(cells.min())}..{int(cells.max())}" if len(cells) else "",
        "fitted (step >= 1 ms)": int((np.asarray(seconds, float) >= MIN_FIT_SECONDS).sum()),
        "exponent p": fit_exponent(cells, seconds),
    }


def fig_cost(df: pd.DataFrame) -> Drawn | Missing:
    """Wind-phase time per step against grid cells, per backend, with the fitted exponent."""
    title = "Cost per step against grid cells"
    if df.empty or WIND_COST not in df or not np.isfinite(df[WIND_COST]).any():
        return Missing("cost_vs_cells", title, "complete runs: `windbench -m experiment=paper`")
    d = df[np.isfinite(df[WIND_COST]) & (df[WIND_COST] > 0)]
    left_out = len(d) - len(d := timed(d))
    fig = _figure(6.4, 4.4)
    ax = fig.add_subplot()
    scenes = sorted(d["scene"].unique())
    for model, g in with_backend(d).groupby("backend", sort=True):
        for scene, gs in g.groupby("scene", sort=True):
            ax.loglog(
                gs["grid_cells"],
                gs[WIND_COST] * 1e3,
                MARKERS[scenes.index(scene) % len(MARKERS)],
                color=_color(model),
                alpha=0.6,
                ms=4,
            )
        p = fit_exponent(g["grid_cells"], g[WIND_COST])
        if np.isfinite(p):
            c = np.geomspace(g["grid_cells"].min(), g["grid_cells"].max(), 20)
            lc, ls = np.log(g["grid_cells"]), np.log(g[WIND_COST])
            ax.loglog(c, np.exp(ls.mean() + p * (np.log(c) - lc.mean())) * 1e3, color=_color(model))
        ax.plot(
            [],
            [],
            color=_color(model),
            label=f"{model}" + (f": p = {p:.3g}" if np.isfinite(p) else ""),
        )
    for scene in scenes:
        ax.plot([], [], MARKERS[scenes.index(scene) % len(MARKERS)], color="0.4", label=scene)
    caption = (
        "Median wall time of the wind phase (the backend's own step; cloth and aerodynamics "
        "excluded) per step, first step excluded, against the number of grid cells; lines are "
        "least-squares fits of time ~ cells^p over all scenes of a model, using only steps "
        f"of at least 1 ms. Runs that shared their cores (contended) are left out: {left_out}."
    )
    return _cost_drawn(ax, "grid cells", Drawn("cost_vs_cells", title, caption, fig))


def _cost_drawn(ax, xlabel: str, drawn: Drawn) -> Drawn:
    ax.set_xlabel(xlabel)
    ax.set_ylabel("wall time per step (ms)")
    ax.grid(True, which="both", alpha=0.3)
    _legend_outside(drawn.figure, ax.get_legend_handles_labels()[0])
    return drawn


def _legend_outside(fig: Figure, handles, where: str = "outside right upper", **kw) -> None:
    """The figure's key beside the axes (never over the data)."""
    if handles:
        fig.legend(handles=handles, loc=where, fontsize=7, frameon=False, **kw)


def _shared_key(winds, scenes, third_name: str = "", third=()) -> list:
    """Proxies for a key that is shared by all lines: colour = backend, marker = scene,
    line style = a third setting (e.g. resolution), instead of one entry per line."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=_color(w), lw=2, label=w) for w in winds]
    handles += [
        Line2D([], [], color="0.4", ls="", marker=MARKERS[i % len(MARKERS)], label=sc)
        for i, sc in enumerate(scenes)
    ]
    handles += [
        Line2D([], [], color="k", ls=LINESTYLES[i % len(LINESTYLES)], label=f"{third_name} {v}")
        for i, v in enumerate(third)
    ]
    return handles


def fig_cost_particles(df: pd.DataFrame) -> Drawn | Missing:
    """Particle tracing's cost against the number of live particles (scaling study)."""
    title = "Particle tracing: cost per step against live particles"
    d = df[(df["wind"] == "particles")] if "live_particles" in df else df.iloc[0:0]
    d = d[
        np.isfinite(d.get("live_particles", pd.Series(dtype=float)))
        & (d.get("live_particles", 0) > 0)
    ]
    left_out = len(d) - len(d := timed(d))
    if d.empty:
        return Missing(
            "cost_vs_particles",
            title,
            "`particles` runs that record `live_particles`: `windbench -m experiment=scaling`",
        )
    fig = _figure(6.4, 4.4)
    ax = fig.add_subplot()
    for i, (scene, g) in enumerate(d.groupby("scene", sort=True)):
        p = fit_exponent(g["live_particles"], g[COST])
        label = scene + (f": p = {p:.3g}" if np.isfinite(p) else "")
        ax.loglog(g["live_particles"], g[COST] * 1e3, MARKERS[i % len(MARKERS)], label=label)
    caption = (
        "Median wall time per step of the particle backend against its mean number of live "
        "particles; p is the fitted exponent of time ~ particles^p. Runs that shared their "
        f"cores (contended) are left out: {left_out}."
    )
    drawn = Drawn("cost_vs_particles", title, caption, fig)
    return _cost_drawn(ax, "live particles (time mean)", drawn)


def _against(df: pd.DataFrame, spec: Against) -> Drawn | Missing:
    """y against x, one line per group of ``by`` (means over the other settings)."""
    x, y, by = spec.x, spec.y, spec.by
    d = df[np.isfinite(df[y].astype(float))] if y in df else df.iloc[0:0]
    if d.empty:
        return Missing(spec.name, spec.title, spec.needs)
    d = with_backend(d)
    fig = _figure(6.4, 4.4)
    ax = fig.add_subplot()
    scenes = sorted(d["scene"].unique())
    third = sorted(d[by[2]].unique()) if len(by) > 2 else []
    styles = {v: LINESTYLES[i % len(LINESTYLES)] for i, v in enumerate(third)}
    for key, s in _series(d, x, y, by):
        model, scene = key[0], key[1]
        ax.plot(
            s.index.values,
            s.values,
            marker=MARKERS[scenes.index(scene) % len(MARKERS)],
            linestyle=styles.get(key[2], "-") if len(key) > 2 else "-",
            color=_color(model),
        )
    if spec.logy and (d[y] > 0).all():
        ax.set_yscale("log")
    elif not spec.logy:
        ax.set_ylim(bottom=0, top=max(1.1, float(d[y].max()) * 1.1))
    if spec.logx:  # the swept values as the ticks, in plain numbers
        ax.set_xscale("log")
        values = sorted(d[x].unique())
        ax.set_xticks(values, [f"{v:g}" for v in values])
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(spec.xlabel)
    ax.set_ylabel(spec.ylabel)
    ax.grid(True, which="both", alpha=0.3)
    models = sorted(d["backend"].unique(), key=_backend_order)
    _legend_outside(fig, _shared_key(models, scenes, by[2] if third else "", third))
    return Drawn(spec.name, spec.title, spec.caption, fig)


def _backend_order(wind: str):
    order = list(BACKEND_COLORS)
    return (order.index(wind) if wind in order else len(order), wind)


@dataclass(frozen=True)
class Against:
    """One §4.3 plot of a run figure against a setting (see :func:`_against`)."""

    name: str
    x: str
    y: str
    title: str
    xlabel: str
    ylabel: str
    caption: str
    needs: str
    logx: bool = False
    logy: bool = True
    by: tuple[str, ...] = ("backend", "scene")


ALL_RUNS = "complete runs: `windbench -m experiment=paper`"
MEASURED = {
    "divergence": Against(
        "divergence_vs_resolution",
        "resolution",
        "divergence_rms",
        "Divergence against resolution",
        "grid.resolution (cells along the longest axis)",
        "RMS |div u| h / U_ref",
        "Steady-window mean of the RMS of |div u| h / U_ref over interior air cells "
        "(eq. 4.1 asks for 0).",
        ALL_RUNS,
    ),
    "force_ratio": Against(
        "lee_force_ratio_vs_dt",
        "dt",
        "lee_force_ratio",
        "Lee force ratio against time step",
        "sim.dt (s)",
        "|F sheltered| / |F exposed|",
        "Steady-window mean of the force on the sheltered flag over the force on the "
        "exposed one; 1 means no lee, 0 a perfect shelter.",
        "`two_flags_wall` runs at several `sim.dt`: `windbench -m experiment=paper`",
        logx=True,
        by=("backend", "scene", "resolution"),
    ),
    "force_ratio_resolution": Against(
        "lee_force_ratio_vs_resolution",
        "resolution",
        "lee_force_ratio",
        "Lee force ratio against resolution, per model",
        "grid.resolution (cells along the longest axis)",
        "|F sheltered| / |F exposed|",
        "Steady-window mean of the force on the sheltered flag over the force on the "
        "exposed one, per model (seeds averaged). `navier_stokes` is the paper's cloth "
        "coupling (§4.1.2): before each step the air's velocity normal to the cloth is set "
        "to the cloth's in the cells the cloth cuts, and the §3 law reads that air, so the "
        "finer the grid, the nearer the cloth the air it reads. "
        "`navier_stokes/projection`: the cloth closes the grid faces it crosses in the "
        "pressure solve and feels the pressure jump across it. `navier_stokes/none`: "
        "one-way, the §3 law in the wake the wall alone makes. `particles/mixing`: the "
        "particles' mixing lee. The couplings on finer grids: "
        "`experiments/results/projection_coupling*.csv`.",
        "`two_flags_wall` runs at several resolutions: `windbench -m experiment=paper` and "
        "`windbench -m experiment=paper_coupling`",
        logx=True,
        by=("backend", "scene", "dt"),
    ),
}


def fig_divergence(df: pd.DataFrame) -> Drawn | Missing:
    return _against(df, MEASURED["divergence"])


def fig_force_ratio_dt(df: pd.DataFrame) -> Drawn | Missing:
    return _against(df, MEASURED["force_ratio"])


def fig_force_ratio_resolution(df: pd.DataFrame) -> Drawn | Missing:
    return _against(df, MEASURED["force_ratio_resolution"])


def hoerner_long_plate(alpha):
    """Hoerner (1985): normal-force coefficient of a long flat plate, C_N = 1/(0.222 + 0.283/sin a);
    returns (C_D, C_L) = (C_N sin a, C_N cos a)."""
    alpha = np.asarray(alpha, dtype=float)
    s = np.sin(alpha)
    with np.errstate(divide="ignore"):
        cn = np.where(s > 0, 1.0 / (0.222 + 0.283 / np.where(s > 0, s, 1.0)), 0.0)
    return cn * s, cn * np.cos(alpha)


HOERNER_SQUARE_CD = 1.17  # square plate normal to the flow (Hoerner 1985)


def plate_table(params: AeroParams, degrees=(10, 20, 30, 45, 60, 75, 90)) -> pd.DataFrame:
    a = np.radians(np.asarray(degrees, dtype=float))
    cd, cl = plate_coefficients(a, params)
    hd, hl = hoerner_long_plate(a)
    return pd.DataFrame(
        {
            "alpha_deg": list(degrees),
            "C_D model": cd,
            "C_L model": cl,
            "C_D Hoerner": hd,
            "C_L Hoerner": hl,
        }
    )


def fig_plate(params: AeroParams) -> Drawn:
    title = "The §3 force law on a flat plate beside Hoerner's measurements"
    a = np.radians(np.linspace(0.0, 90.0, 181))
    cd, cl = plate_coefficients(a, params)
    hd, hl = hoerner_long_plate(a)
    deg = np.degrees(a)
    fig = _figure(6.4, 4.4)
    ax = fig.add_subplot()
    ax.plot(
        deg, cd, color="tab:red", label=f"model drag C_D sin α (C_D = {params.drag_coefficient:g})"
    )
    ax.plot(
        deg,
        cl,
        color="tab:blue",
        label=f"model lift C_L sin α cos α (C_L = {params.lift_coefficient:g})",
    )
    ax.plot(deg, hd, "--", color="tab:red", label="Hoerner long plate C_N sin α")
    ax.plot(deg, hl, "--", color="tab:blue", label="Hoerner long plate C_N cos α")
    ax.plot([90], [HOERNER_SQUARE_CD], "ks", label="Hoerner square plate normal, C_D = 1.17")
    ax.set_xlabel("angle of attack α (degrees)")
    ax.set_ylabel("force coefficient")
    ax.set_xlim(0, 92)
    ax.grid(True, alpha=0.3)
    _legend_outside(fig, ax.get_legend_handles_labels()[0], "outside lower center", ncol=2)
    caption = (
        "Drag and lift coefficients (force / (½ ρ v² A)) of the paper's §3 law for a flat plate "
        "at angle of attack α, with Hoerner's (Fluid-Dynamic Lift, 1985) long-plate normal-force "
        "fit C_N = 1/(0.222 + 0.283/sin α) split into drag C_N sin α and lift C_N cos α."
    )
    return Drawn("plate_coefficients", title, caption, fig)


def fig_lee_in_time(records: Sequence[RunRecord]) -> Drawn | Missing:
    """lee_speed_ratio against time, the finest run of each backend, one panel per scene;
    for particle tracing, the time its gust front has passed the whole lee box."""
    from matplotlib.lines import Line2D

    title = TITLES["lee_in_time"]
    good = [r for r in records if r.status == "complete"]
    scenes = sorted(
        {r.settings["scene"] for r in good if np.isfinite(r.figures.get("lee_speed_ratio", np.nan))}
    )
    if not scenes:
        return Missing("lee_in_time", title, "runs of a scene with lee and free-stream probes")
    fig = _figure(min(3.6 * len(scenes), 16.0), 3.6)
    winds_shown, passed = set(), []
    for c, scene in enumerate(scenes):
        ax = fig.add_subplot(1, len(scenes), c + 1)
        for wind in sorted({r.settings["wind"] for r in good if r.settings["scene"] == scene}):
            rec = pick(good, scene, wind)
            with xr.open_dataset(rec.path) as ds:
                if "lee_speed_ratio" not in ds:
                    continue
                ax.plot(ds["time"].values, ds["lee_speed_ratio"].values, color=_color(wind))
                winds_shown.add(wind)
                t_pass = _front_past_lee(ds, rec.path)
            if np.isfinite(t_pass):
                ax.axvline(t_pass, color=_color(wind), ls=":", lw=1.2)
                passed.append(f"{scene} {t_pass:.2f} s")
        ax.set_title(scene, fontsize=9)
        ax.set_xlabel("t (s)")
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        if c == 0:
            ax.set_ylabel("mean |u| lee / free stream")
    handles = _shared_key(sorted(winds_shown, key=_backend_order), [])
    if passed:
        handles.append(
            Line2D([], [], color=_color("particles"), ls=":", label="particle front past lee box")
        )
    _legend_outside(fig, handles, "outside lower center", ncol=len(handles))
    caption = (
        "Mean wind speed in each scene's lee box over that in its free-stream box, finest run "
        "of each backend; 1 means no lee, 0 a perfect wind shadow. The particle backend has "
        "wind only where its gust particles have arrived: until its front has passed the "
        "whole lee box (dotted line, from the recorded frames"
        + (": " + ", ".join(passed) if passed else "; none recorded")
        + ") a ratio below 1 is partly wind not yet arrived, not lee."
    )
    return Drawn("lee_in_time", title, caption, fig)


def _front_past_lee(ds: xr.Dataset, path) -> float:
    """When the particles' gust front had passed the scene's whole lee box (nan: unknown)."""
    frames = read_frames(ds, path)
    scene = scene_of(ds)
    direction = wind_direction(scene)
    box = scene.probes.get("lee")
    if frames is None or direction is None or box is None:
        return math.nan
    return front_passes(frames, box.lower, box.upper, direction)


RUN_FIGURES = {  # figures drawn from run datasets, in the order of the report
    "fig3_flag": fig3_flag,
    "fig45_two_flags_wall": fig45_two_flags_wall,
    "fig6_shirt": fig6_shirt,
    "opposing_sources": fig_opposing_sources,
    "lee_in_time": fig_lee_in_time,
}
