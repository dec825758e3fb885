"""Run folders -> run records -> one combined dataset with the swept settings as dimensions.

Every ``windbench.nc`` under the given folders is opened lazily (xarray + netCDF4): only
the per-step figures and the probe values are read. Each file becomes one
:class:`RunRecord` with a status:

- ``complete``: ``status = complete``, every planned step recorded and a steady window;
- ``unsettled``: complete, but no recorded step after the steady window's start
  (:func:`windbench.metrics.unsettled_reason`);
- ``failed``: the run stopped (``status = failed``), with its ``failure``;
- ``partial``: readable but incomplete (fewer steps than planned, unknown status, or a
  required variable missing);
- ``unreadable``: netCDF cannot open it or a checksum does not match
  (:func:`windbench.dataset.verify`; the reason then starts with ``checksum``);
- ``invalid``: no dataset, the run's ``run_status.yaml`` says the config was refused.

Only ``complete`` runs are combined; the others are listed with the reason. Each record
keeps the code version that made it (:func:`code_versions`; the report warns when a sweep
mixes several).

Figures per run, all over the steady window t >= ``analysis_start`` (two flow-through
times, :func:`windbench.simulate.analysis_window`; older datasets: the second half):
window means of ``lee_speed_ratio``, ``lee_force_ratio``, ``divergence_rms`` and every other
per-step variable (a backend's ``stats()``), ``*_final`` at the last step,
``divergence_max`` the window's maximum; ``seconds_per_step`` (mean wall time, first step
excluded: it holds numba's compile or cache load), ``seconds_per_step_median`` and
``wind_seconds_median`` (medians over the window, robust to other processes),
``seconds_per_simulated_second`` (median step / dt); the lee probe wind averaged over the
window (``probe_wind_mean``, for :mod:`windbench.report.lee`) and over each block of it
(``probe_wind_block_mean``, for the time mean's sampling error), the window-mean wake
profile u/u0 (``wake_speed_ratio``). A run whose timings were taken while it shared its
cores is ``contended`` (:func:`contention`); the cost fits leave it out.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from omegaconf import OmegaConf

from windbench.config import schema_fields
from windbench.dataset import CONVENTIONS, VARIABLES, code_version, verify
from windbench.errors import ConfigError, DatasetUnreadable
from windbench.metrics import unsettled_reason
from windbench.wind.registry import get_backend

RUN_FILE = "windbench.nc"
STATUS_FILE = "run_status.yaml"  # windbench.sweep.STATUS_FILE
AVERAGE_FROM = 0.5  # datasets without analysis_start: time averages over t >= this x t_end
# canonical setting -> dotted config key; always dimensions of the combined dataset
SETTINGS = {
    "wind": "wind.name",
    "scene": "scene.name",
    "resolution": "grid.resolution",
    "dt": "sim.dt",
    "seed": "seed",
}
# The setting that picks a backend's model where it has more than one: the particles' lee
# (paper §4.2.2, or the ``mixing`` lee) and the Navier-Stokes wind's cloth coupling (paper
# §4.1.2, or ``projection`` and ``none``). PAPER_MODEL is the value that names the paper's.
MODEL_KEYS = {"particles": "wind.lee_model", "navier_stokes": "wind.coupling"}
PAPER_MODEL = "paper"
# config keys that never count as swept settings (scene contents follow from scene.name)
IGNORED = ("scene.", "output.", "hydra.", "sim.progress", "resume", "experiment")
REQUIRED = ("wind", "step_seconds", "cloth_position", "divergence_rms")
AVERAGED = ("lee_speed_ratio", "lee_force_ratio", "divergence_rms")
# cloth figures whose largest value over the steady window is kept too (``<name>_peak``):
# a crossing or a penetration in one step is a defect that a time mean would dilute
PEAKS = ("self_intersections", "max_penetration", "max_stretch")
# Contention: a step whose wall time exceeds its process's CPU time by this factor waited
# for a core; a load average above the machine's cores by this margin had more runnable
# threads than cores (the run's own threads are at most the cores).
WALL_CPU_LIMIT = 1.2
LOAD_MARGIN = 0.5
# long_name and units of what combine() writes besides the run variables' time means (a
# run variable's own long_name and units come from the run datasets); units None: a label
FIGURES: dict[str, tuple[str, str | None]] = {
    "seconds_per_step": ("mean wall time per step (first step excluded)", "s"),
    "seconds_per_step_median": ("median wall time per step over the steady window", "s"),
    "wind_seconds_median": ("median wall time of the wind phase per step, steady window", "s"),
    "seconds_per_simulated_second": ("median wall time per step / dt", "1"),
    "wall_cpu_ratio": ("median over the steps of wall time / process CPU time", "1"),
    "cpu_seconds_per_simulated_second": ("median process CPU time per step / dt", "1"),
    "threads": ("numba threads of the run", "1"),
    "load_average_peak": ("larger 1-minute load average of the run's start and end", "1"),
    "contended": ("the run shared its cores: its timings are not its own cost", "1"),
    "analysis_start": ("start of the steady window", "s"),
    "flow_through_time": ("domain length along the wind / reference speed", "s"),
    "spinup": ("simulated time before recording", "s"),
    "end_time": ("last recorded time", "s"),
    "is_reference": ("the run is its scene's lee reference", "1"),
    "reference_level": ("the run is a level of its scene's reference", "1"),
    "step_seconds": ("mean wall time per step and phase (first step excluded)", "s"),
    "grid_cells": ("number of grid cells", "1"),
    "grid_spacing": ("grid cell edge h", "m"),
    "steps_completed": ("steps recorded", "1"),
    "steps_planned": ("steps planned (sim.duration / sim.dt)", "1"),
    "lee_error": ("RMS wind error in the lee box against the reference / U_ref", "1"),
    "lee_noise": ("sampling noise of lee_error from the finite steady windows / U_ref", "1"),
    "experiment": ("experiment of the run", None),
    "path": ("run dataset file", None),
    "code": ("code version that made the run", None),
    "phase": VARIABLES["phase"],
    "wind": ("wind backend", None),
    "scene": ("scene", None),
    "resolution": ("grid cells along the longest domain axis", "1"),
    "dt": ("time step", "s"),
    "seed": ("random seed", "1"),
}


@dataclass
class RunRecord:
    """What the report knows about one run file (small: no fields, no cloth frames)."""

    path: Path
    status: str  # complete | unsettled | failed | partial | unreadable | invalid
    reason: str = ""
    settings: dict = field(default_factory=dict)  # canonical settings (wind, scene, ...)
    config: dict = field(default_factory=dict)  # flattened resolved config (dotted keys)
    figures: dict = field(default_factory=dict)  # scalar figures
    phases: dict = field(default_factory=dict)  # phase -> mean seconds per step
    lee_points: np.ndarray | None = None  # (n, 3) lee probe points
    lee_wind: np.ndarray | None = None  # (n, 3) wind there: window mean (:func:`_probes`)
    lee_block_wind: np.ndarray | None = None  # (blocks, n, 3) its means over window blocks
    free_stream_speed: float = math.nan  # mean |u| at the free-stream probes (as lee_wind)
    reference_speed: float = math.nan
    experiment: str = ""
    wake: pd.DataFrame | None = None  # window-mean u/u0: index distance (H), columns height (H)
    code: str = ""  # code_version() of the code that made it
    meta: dict = field(default_factory=dict)  # figure -> (long_name, units) for results.nc

    @property
    def label(self) -> str:
        s = self.settings
        if not s.get("wind"):
            return self.path.parent.name
        return (
            f"{s.get('scene')}/{s.get('wind')} r={s.get('resolution')} "
            f"dt={_fmt(s.get('dt'))} seed={s.get('seed')}"
        )


def _fmt(x) -> str:
    return f"{x:.4g}" if isinstance(x, float) else str(x)


def clean_reason(text: str) -> str:
    """A failure reason on one line: terminal colour codes removed, whitespace collapsed."""
    return " ".join(re.sub(r"\x1b\[[0-9;]*m", "", str(text)).split())


def find_invalid(inputs: Iterable, filename: str = RUN_FILE) -> list[RunRecord]:
    """Runs a sweep refused (``run_status.yaml`` says invalid, no dataset beside it)."""
    import yaml

    out = []
    for item in inputs:
        p = Path(item)
        if not p.is_dir():
            continue
        for status in sorted(p.rglob(STATUS_FILE)):
            if (status.parent / filename).exists():
                continue
            try:
                info = yaml.safe_load(status.read_text()) or {}
            except (OSError, yaml.YAMLError):
                continue
            if info.get("status") != "invalid":
                continue
            flat = _config_beside(status.parent / filename)
            out.append(
                RunRecord(
                    (status.parent / filename).resolve(),
                    "invalid",
                    clean_reason(info.get("reason", "config refused")),
                    settings=_settings_from_config(flat),
                    config=flat,
                )
            )
    return out


def find_runs(inputs: Iterable, filename: str = RUN_FILE) -> list[Path]:
    """Every run file under the given folders (a file given directly is taken as is)."""
    found: dict[Path, None] = {}
    for item in inputs:
        p = Path(item)
        if p.is_file():
            found[p.resolve()] = None
        elif p.is_dir():
            for f in sorted(p.rglob(filename)):
                found[f.resolve()] = None
        else:
            raise FileNotFoundError(f"no such run or sweep folder: {p}")
    return list(found)


def flatten(tree, prefix: str = "") -> dict:
    """Nested dicts -> {dotted.key: value}; a list of dicts (the scene's cloths, bodies)
    -> one key per entry and field (``scene.cloths.0.resolution``); other lists become
    tuples (hashable)."""
    out = {}
    if isinstance(tree, dict):
        for k, v in tree.items():
            out.update(flatten(v, f"{prefix}{k}."))
    elif isinstance(tree, list) and tree and all(isinstance(v, dict) for v in tree):
        for n, v in enumerate(tree):
            out.update(flatten(v, f"{prefix}{n}."))
    elif isinstance(tree, list):
        out[prefix[:-1]] = tuple(
            tuple(v) if isinstance(v, list) else (str(v) if isinstance(v, dict) else v)
            for v in tree
        )
    else:
        out[prefix[:-1]] = tree
    return out


def _settings_from_config(flat: dict) -> dict:
    return {name: flat.get(key) for name, key in SETTINGS.items()}


def _config_beside(path: Path) -> dict:
    """The flattened Hydra config saved beside a run file, or {}."""
    hydra_cfg = path.parent / ".hydra" / "config.yaml"
    if not hydra_cfg.is_file():
        return {}
    try:
        return flatten(OmegaConf.to_container(OmegaConf.load(hydra_cfg), resolve=False))
    except Exception:  # noqa: BLE001 - best effort: settings of an unreadable run
        return {}


def window_mask(ds: xr.Dataset) -> np.ndarray:
    """Recorded steps inside the run's steady window (t >= ``analysis_start``)."""
    times = np.asarray(ds["time"].values, dtype=float)
    start = float(ds.attrs.get("analysis_start", math.nan))
    if not np.isfinite(start):
        start = AVERAGE_FROM * times[-1] if times.size else 0.0
    return times >= start - 1e-9


def _window_mean(values: np.ndarray, window: np.ndarray) -> float:
    if values.size == 0 or not np.isfinite(values).any():
        return math.nan
    chosen = values[window] if window.any() else values
    return float(np.nanmean(chosen)) if np.isfinite(chosen).any() else math.nan


def _window_max(ds: xr.Dataset, name: str, window: np.ndarray) -> float:
    """The largest value of run variable ``name`` over the steady window (over every step
    when the window is empty; NaN when the run has no such variable or no finite value)."""
    if name not in ds or not ds.sizes.get("time", 0):
        return math.nan
    vals = np.asarray(ds[name].values, dtype=float)
    chosen = vals[window] if window.any() else vals
    return float(np.nanmax(chosen)) if np.isfinite(chosen).any() else math.nan


def _figures(ds: xr.Dataset) -> tuple[dict, dict]:
    window = window_mask(ds) if ds.sizes.get("time", 0) else np.zeros(0, bool)
    figs: dict[str, float] = {}
    for name in AVERAGED:
        if name in ds and ds.sizes.get("time", 0):
            vals = np.asarray(ds[name].values, dtype=float)
            figs[name] = _window_mean(vals, window)
            figs[f"{name}_final"] = float(vals[-1])
        else:
            figs[name] = figs[f"{name}_final"] = math.nan
    known = {*AVERAGED, "divergence_max"}
    for name, var in ds.data_vars.items():  # backend figures (stats()): window means
        if var.dims == ("time",) and name not in known and var.dtype.kind in "fiu":
            figs[str(name)] = _window_mean(np.asarray(var.values, dtype=float), window)
    figs["divergence_max"] = _window_max(ds, "divergence_max", window)
    for name in PEAKS:
        figs[f"{name}_peak"] = _window_max(ds, name, window)
    phases = {}
    n_times = ds.sizes.get("time", 0)
    later = np.arange(n_times) >= 1 if n_times > 1 else np.ones(n_times, bool)
    if "step_seconds" in ds and n_times:
        sec = np.asarray(ds["step_seconds"].values, dtype=float)
        steady = sec[later]
        in_window = sec[later & window] if (later & window).any() else steady
        for j, ph in enumerate(ds["phase"].values):
            phases[str(ph)] = float(steady[:, j].mean())
    figs["seconds_per_step"] = phases.get("total", math.nan)
    figs["seconds_per_step_median"] = figs["wind_seconds_median"] = math.nan
    names = [str(p) for p in ds["phase"].values] if phases else []
    for phase, key in (("total", "seconds_per_step_median"), ("wind", "wind_seconds_median")):
        if phase in names:
            figs[key] = float(np.median(in_window[:, names.index(phase)]))
    figs["seconds_per_simulated_second"] = figs["seconds_per_step_median"] / float(
        ds.attrs.get("dt", math.nan)
    )
    figs["cpu_seconds_per_simulated_second"] = _cpu_per_simulated_second(ds, later & window)
    figs["threads"] = int(ds.attrs.get("numba_threads", 0))
    figs.update(contention(ds))
    shape = ds.attrs.get("grid_shape")
    shape = (
        [int(v) for v in np.atleast_1d(shape)] if shape is not None else list(ds["wind"].shape[1:4])
    )
    for key in ("analysis_start", "flow_through_time", "spinup"):
        figs[key] = float(ds.attrs.get(key, math.nan))
    times = np.asarray(ds["time"].values, dtype=float)
    figs["end_time"] = float(times[-1]) if times.size else math.nan
    figs["grid_cells"] = int(np.prod(shape))
    figs["grid_spacing"] = float(ds.attrs.get("grid_spacing", math.nan))
    figs["steps_completed"] = int(ds.attrs.get("steps_completed", ds.sizes.get("time", 0)))
    figs["steps_planned"] = int(ds.attrs.get("steps_planned", -1))
    return figs, phases


def _cpu_per_simulated_second(ds: xr.Dataset, steps) -> float:
    """Median process CPU time per step over ``steps`` (the steady window after the first
    step) / dt: a one-thread run's own cost even when it shared its cores."""
    if "step_cpu_seconds" not in ds or not ds.sizes.get("time", 0):
        return math.nan
    cpu = np.asarray(ds["step_cpu_seconds"].values, dtype=float)
    chosen = cpu[steps] if np.any(steps) else cpu
    return float(np.median(chosen)) / float(ds.attrs.get("dt", math.nan))


def contention(ds: xr.Dataset) -> dict:
    """``wall_cpu_ratio`` (median over the steps after the first of wall / CPU time),
    ``load_average_peak`` (the larger 1-minute load average at start and end) and
    ``contended``: the ratio above WALL_CPU_LIMIT (the process waited for a core), the
    load above the machine's cores + LOAD_MARGIN (more runnable threads than cores) or a
    step after the first run on fewer threads than the run's own (``step_threads``: the
    run gave cores up to other processes). Datasets without these (older ones) are not
    flagged."""
    ratio = math.nan
    if "step_cpu_seconds" in ds and "step_seconds" in ds and ds.sizes.get("time", 0) > 1:
        wall = np.asarray(ds["step_seconds"].sel(phase="total").values, dtype=float)[1:]
        cpu = np.asarray(ds["step_cpu_seconds"].values, dtype=float)[1:]
        ok = cpu > 0
        ratio = float(np.median(wall[ok] / cpu[ok])) if ok.any() else math.nan
    loads = [np.atleast_1d(ds.attrs[k])[0] for k in ds.attrs if k.startswith("load_average_")]
    peak = float(max(loads)) if loads else math.nan
    cores = float(ds.attrs.get("cpu_count", math.nan))
    gave_up = "step_threads" in ds and bool(
        (ds["step_threads"].values[1:] < int(ds.attrs.get("numba_threads", 0))).any()
    )
    contended = bool(ratio > WALL_CPU_LIMIT or peak > cores + LOAD_MARGIN or gave_up)
    return {"wall_cpu_ratio": ratio, "load_average_peak": peak, "contended": contended}


def _probes(ds: xr.Dataset, rec: RunRecord):
    """The lee probe wind: the steady-window mean (``probe_wind_mean``), or the last
    snapshot in datasets without it."""
    if "probe_wind_mean" in ds:
        last = np.asarray(ds["probe_wind_mean"].values, dtype=float)
    elif "probe_wind" in ds and ds.sizes.get("snapshot", 0):
        last = np.asarray(ds["probe_wind"].isel(snapshot=-1).values, dtype=float)
    else:
        return
    box = np.asarray(ds["probe_box"].values).astype(str)
    pts = np.asarray(ds["probe_points"].values, dtype=float)
    lee, free = box == "lee", box == "free_stream"
    rec.lee_points, rec.lee_wind = pts[lee], last[lee]
    if "probe_wind_block_mean" in ds:
        rec.lee_block_wind = np.asarray(ds["probe_wind_block_mean"].values, dtype=float)[:, lee]
    if free.any():
        rec.free_stream_speed = float(np.linalg.norm(last[free], axis=1).mean())


def _figure_meta(ds: xr.Dataset) -> dict:
    """(long_name, units) of each figure _figures takes from a per-step run variable."""
    meta = {}
    late = "the steady window (t >= analysis_start)"
    for name, var in ds.data_vars.items():
        if var.dims != ("time",):
            continue
        long_name, units = var.attrs.get("long_name", name), var.attrs.get("units")
        if name == "divergence_max":
            meta[name] = (f"{long_name}: maximum over the steady window", units)
            continue
        if name in PEAKS:
            meta[f"{name}_peak"] = (f"{long_name}: maximum over the steady window", units)
        meta[str(name)] = (f"{long_name}: time mean over {late}", units)
        if name in AVERAGED:
            meta[f"{name}_final"] = (f"{long_name}: value at the last step", units)
    return meta


def _unreadable(path: Path, reason: str) -> RunRecord:
    flat = _config_beside(path)
    return RunRecord(
        path,
        "unreadable",
        clean_reason(reason),
        settings=_settings_from_config(flat),
        config=flat,
    )


def read_run(path: Path) -> RunRecord:
    """One run file -> RunRecord (never raises for a bad file: it becomes a status)."""
    path = Path(path)
    try:
        verify(path)
    except DatasetUnreadable as err:
        return _unreadable(path, str(err))
    try:
        ds = xr.open_dataset(path, engine="netcdf4")
    except Exception as err:  # noqa: BLE001 - any reason to be unreadable is reported
        return _unreadable(path, f"cannot open: {type(err).__name__}: {err}")
    with ds:
        attrs = dict(ds.attrs)
        try:
            flat = flatten(OmegaConf.to_container(OmegaConf.create(attrs.get("config", "{}"))))
        except Exception:  # noqa: BLE001
            flat = _config_beside(path)
        settings = _settings_from_config(flat)
        for name in SETTINGS:  # the dataset's own attributes win over the config text
            if name in attrs:
                v = attrs[name]
                settings[name] = v.item() if isinstance(v, np.generic) else v
        rec = RunRecord(
            path,
            "complete",
            settings=settings,
            config=flat,
            experiment=str(attrs.get("experiment", "") or ""),
            reference_speed=float(attrs.get("reference_speed", math.nan)),
            code=code_version(attrs),
            meta=_figure_meta(ds),
        )
        status = attrs.get("status")
        missing = [v for v in REQUIRED if v not in ds.variables]
        try:
            rec.figures, rec.phases = _figures(ds)
            _probes(ds, rec)
            rec.wake = _wake(ds)
            unsettled = _unsettled(ds)
        except Exception as err:  # noqa: BLE001 - a damaged variable makes the run partial
            rec.status, rec.reason = "partial", f"cannot read figures: {type(err).__name__}: {err}"
            return rec
    done, planned = rec.figures["steps_completed"], rec.figures["steps_planned"]
    if status == "failed":
        rec.status, rec.reason = "failed", clean_reason(attrs.get("failure", "")) or "status failed"
    elif status != "complete":
        rec.status, rec.reason = "partial", f"status attribute is {status!r}, not 'complete'"
    elif missing:
        rec.status, rec.reason = "partial", f"missing variables {missing}"
    elif planned >= 0 and done < planned:
        rec.status, rec.reason = "partial", f"{done} of {planned} steps recorded"
    elif unsettled:
        rec.status, rec.reason = "unsettled", unsettled
    return rec


def _unsettled(ds: xr.Dataset) -> str:
    """The reason a run has no steady window ('' if it has one or predates the attribute)."""
    if "analysis_start" not in ds.attrs or not ds.sizes.get("time", 0):
        return ""
    return unsettled_reason(ds["time"].values, float(ds.attrs["analysis_start"]))


def _wake(ds: xr.Dataset) -> pd.DataFrame | None:
    """Window mean of ``wake_speed_ratio``: rows distance / H, columns height / H."""
    if "wake_speed_ratio" not in ds or not ds.sizes.get("time", 0):
        return None
    window = window_mask(ds)
    mean = ds["wake_speed_ratio"].isel(time=np.flatnonzero(window)).mean("time")
    return pd.DataFrame(
        mean.values,
        index=pd.Index(mean["wake_distance"].values, name="distance_H"),
        columns=pd.Index(mean["wake_height"].values, name="height_H"),
    )


READ_PER_WORKER = 20  # run files per reading process (one file reads in about 0.1 s)


def read_runs(paths: Sequence[Path], progress: bool = True, jobs: int = 1) -> list[RunRecord]:
    """:func:`read_run` of every path, sorted; over up to ``jobs`` processes."""
    from windbench.report.parallel import pmap

    records = pmap(read_run, list(paths), jobs, READ_PER_WORKER, "reading runs", progress)
    return sorted(records, key=sort_key)


def sort_key(rec: RunRecord) -> tuple:
    """Runs ordered by scene, backend, resolution, dt, seed, then file."""
    s = rec.settings

    def num(v):
        try:
            return float(v)
        except (TypeError, ValueError):
            return math.inf

    return (
        str(s.get("scene") or ""),
        str(s.get("wind") or ""),
        num(s.get("resolution")),
        num(s.get("dt")),
        num(s.get("seed")),
        str(rec.path),
    )


def mark_duplicates(records: list[RunRecord]) -> None:
    """Complete runs with the same settings as an earlier one are skipped (one cell each)."""
    seen: dict[tuple, RunRecord] = {}
    dims = swept_keys(records)
    for rec in records:
        if rec.status != "complete":
            continue
        key = tuple(_setting(rec, d) for d in dims)
        if key in seen:
            rec.status = "duplicate"
            rec.reason = f"same settings as {seen[key].path}"
        else:
            seen[key] = rec


def display_path(path: Path) -> str:
    """Relative to the working folder when below it (a committed report names no home dirs)."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _setting(rec: RunRecord, name: str):
    if name in SETTINGS:
        return rec.settings.get(name)
    return rec.config.get(name)


def swept_keys(records: Sequence[RunRecord]) -> list[str]:
    """The dimensions: :data:`SETTINGS`, then every other config key that all complete runs
    have and that takes more than one value among them (e.g. ``aero.lift_coefficient``).
    A ``wind.*`` key of one backend (e.g. the particles' ``wind.lee_model``) counts when it
    takes more than one value among the runs that read it (:func:`_reads`: a mixing-lee
    key is no dimension of paper-lee runs made before its default changed). A ``scene.*`` key counts only
    if it varies among runs of one scene (e.g. a swept ``scene.cloths.0.resolution``):
    otherwise it follows from the scene's name. A ``cloth.*`` key counts only if it varies
    among the runs whose scene has cloth: a scene without cloth has no use for it."""
    complete = [r for r in records if r.status in ("complete", "duplicate")]
    extra = []
    if complete:
        common = set(complete[0].config)
        for r in complete[1:]:
            common &= set(r.config)
        backend_keys = {k for r in complete for k in r.config if k.startswith("wind.")} - common
        for key in sorted(backend_keys):
            if len({repr(r.config[key]) for r in complete if _reads(r, key)}) > 1:
                extra.append(key)
        for key in sorted(common):
            if key in SETTINGS.values() or key in IGNORED:
                continue
            if key.startswith("scene."):
                if _varies_within_a_scene(complete, key):
                    extra.append(key)
                continue
            if key.startswith(IGNORED):
                continue
            runs = [r for r in complete if _has_cloth(r)] if key.startswith("cloth.") else complete
            if len({repr(r.config[key]) for r in runs}) > 1:
                extra.append(key)
    return list(SETTINGS) + extra


def _reads(record: RunRecord, key: str) -> bool:
    """Whether the run has the ``wind.*`` key and its backend reads it: not where the key's
    schema field is read only when a sibling key has a value (``when`` of
    :func:`windbench.config.setting`) that the run's has not."""
    if key not in record.config:
        return False
    when = _read_when(str(record.settings.get("wind")), key.removeprefix("wind."))
    return when is None or record.config.get(f"wind.{when[0]}") == when[1]


@functools.cache
def _read_when(backend: str, name: str) -> tuple[str, str] | None:
    """The ``when`` of field ``name`` in ``backend``'s config schema (None: always read)."""
    try:
        schema = get_backend(backend).config
    except ConfigError:  # a backend not installed here: every key counts
        return None
    fields = {f.name: f for f in dataclasses.fields(schema)}
    return fields[name].metadata.get("when") if name in fields else None


def _has_cloth(record: RunRecord) -> bool:
    """Whether the run's scene has a cloth (a ``scene.cloths.<n>.*`` key in its config)."""
    return any(k.startswith("scene.cloths.") for k in record.config)


def _varies_within_a_scene(records: Sequence[RunRecord], key: str) -> bool:
    values: dict[str, set[str]] = {}
    for r in records:
        values.setdefault(str(r.settings.get("scene")), set()).add(repr(r.config[key]))
    return any(len(v) > 1 for v in values.values())


def summary_frame(records: Sequence[RunRecord]) -> pd.DataFrame:
    """One row per run file: settings, figures, seconds per phase, status and reason."""
    dims = swept_keys(records)
    rows = []
    for rec in records:
        row = {d: _setting(rec, d) for d in dims}
        row.update(rec.figures)
        for ph, sec in rec.phases.items():
            row[f"step_seconds_{ph}"] = sec
        row.update(status=rec.status, failure=rec.reason, experiment=rec.experiment, code=rec.code)
        row["path"] = display_path(rec.path)
        rows.append(row)
    df = pd.DataFrame(rows)
    front = [*dims, "status", "failure"]
    return df[[c for c in front if c in df] + [c for c in df if c not in front]]


def _netcdf_dims(df: pd.DataFrame, dims: Sequence[str]) -> None:
    """Dimension columns as netCDF can hold them, in place: tuples (list-valued settings)
    as text, and a backend's key that other backends' runs lack (None, NaN) as "" when its
    values are text (e.g. ``wind.lee_model`` of a navier_stokes run)."""
    for c in dims:
        if df[c].map(lambda v: isinstance(v, tuple)).any():
            df[c] = df[c].map(str)
        if df[c].map(lambda v: isinstance(v, str)).any():
            df[c] = df[c].where(df[c].notna(), "")


def combine(records: Sequence[RunRecord]) -> xr.Dataset:
    """Complete runs -> one dataset whose dimensions are the swept settings.

    Runs at different resolutions have different grids, so the combination holds the
    per-run figures (scalars, and ``step_seconds`` per ``phase``); a settings combination that
    was not run is NaN. The path of each run file is kept in ``path``.
    """
    dims = swept_keys(records)
    good = [r for r in records if r.status == "complete"]
    if not good:
        return xr.Dataset(attrs={"runs": 0})
    df = summary_frame(good)
    df = df.drop(columns=[c for c in df if c.startswith("step_seconds_")] + ["status", "failure"])
    _netcdf_dims(df, dims)
    for c in df:  # flags as 0/1 so that a missing combination can be NaN
        if df[c].map(lambda v: isinstance(v, bool | np.bool_)).all():
            df[c] = df[c].astype(float)
    ds = xr.Dataset.from_dataframe(df.set_index(dims))
    phase_rows = [
        {**{d: _setting(r, d) for d in dims}, "phase": ph, "step_seconds": sec}
        for r in good
        for ph, sec in r.phases.items()
    ]
    if phase_rows:
        pf = pd.DataFrame(phase_rows)
        _netcdf_dims(pf, dims)
        ds = ds.merge(xr.Dataset.from_dataframe(pf.set_index([*dims, "phase"])))
        ds["step_seconds"].attrs.update(
            long_name="mean wall time per step (first step excluded)", units="s"
        )
    for name in ds.data_vars:
        if ds[name].dtype == object:
            ds[name] = ds[name].fillna("").astype(str)
    _annotate_results(ds, good)
    ds.attrs.update(
        Conventions=CONVENTIONS,
        runs=len(good),
        averaging=(
            "means over each run's steady window (t >= analysis_start: two flow-through "
            "times); step times exclude the first step"
        ),
        code_versions="; ".join(code_versions(good)),
    )
    return ds


def _annotate_results(ds: xr.Dataset, records: Sequence[RunRecord]) -> None:
    """long_name and units on every variable and coordinate of the combined dataset: the
    run variables' own (:func:`_figure_meta`), :data:`FIGURES`, the schema's settings."""
    table = {key: (f.metadata["doc"], f.metadata["units"] or None) for key, f in schema_fields()}
    for rec in records:
        table.update({k: v for k, v in rec.meta.items() if k not in table})
    table.update(FIGURES)
    for name in ds.variables:
        long_name, units = table.get(str(name), (f"config key {name}", None))
        ds[name].attrs["long_name"] = long_name
        if units is not None and ds[name].dtype.kind in "fiub":
            ds[name].attrs["units"] = units


def code_versions(records: Sequence[RunRecord]) -> list[str]:
    """The code versions that made the readable runs among ``records``, sorted."""
    return sorted({r.code for r in records if r.code})


def backend_label(wind, model) -> str:
    """The model a run stands for: the backend's name for the paper's model, else
    ``backend/model`` (``particles/mixing``, ``navier_stokes/projection``); ``model`` is
    the value of the backend's :data:`MODEL_KEYS` setting (None or NaN for a run made
    before that setting existed: the paper's)."""
    if wind in MODEL_KEYS and isinstance(model, str) and model not in ("", PAPER_MODEL):
        return f"{wind}/{model}"
    return str(wind)


def with_backend(df: pd.DataFrame) -> pd.DataFrame:
    """df with a ``backend`` column (:func:`backend_label`) beside ``wind``."""
    winds = df["wind"].tolist()
    keys = {key: df[key].tolist() for key in MODEL_KEYS.values() if key in df}
    models = [
        keys[MODEL_KEYS[w]][n] if MODEL_KEYS.get(w) in keys else None for n, w in enumerate(winds)
    ]
    return df.assign(backend=[backend_label(w, m) for w, m in zip(winds, models, strict=True)])


def record_backend(record: RunRecord) -> str:
    """:func:`backend_label` of a run record."""
    wind = record.settings.get("wind")
    return backend_label(wind, record.config.get(MODEL_KEYS.get(wind, "")))


def is_paper_model(record: RunRecord) -> bool:
    """Whether the run is of its backend's paper model (:func:`backend_label`)."""
    return record_backend(record) == str(record.settings.get("wind"))
