"""The run dataset (DESIGN.md "Run dataset"): names, units, assembly, checked write and read.

Every variable and coordinate carries ``long_name``, every numeric one ``units`` (UDUNITS;
``1`` for counts and ratios; labels such as ``component`` have none, as CF says), x/y/z
carry ``axis``, and the file says ``Conventions = "CF-1.10"``. Global attributes carry the
provenance (resolved config, versions, git commit) and the outcome (``status``, ``failure``).

Integrity: every variable is written with a Fletcher-32 checksum per chunk (HDF5
``fletcher32``; strings as character arrays, so that the checksum covers their text) and
:func:`verify` reads every chunk back, so a damaged file is found instead of combined.
A file named ``windbench.nc`` is always whole: it is written under a temporary name unique
to its writer (:func:`temporary_name`) in the same folder and renamed (``os.replace`` is
atomic on POSIX); netCDF creates the file, so it gets the user's umask.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import platform
import secrets
import socket
import subprocess
from collections.abc import Mapping
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr
from omegaconf import OmegaConf

import windbench
from windbench.errors import DatasetUnreadable

if TYPE_CHECKING:  # pragma: no cover
    from windbench.simulate import Recorder, RunSetup

log = logging.getLogger("windbench")
CONVENTIONS = "CF-1.10"
# name -> (long_name, units); units None: a label (strings), which CF gives no units
VARIABLES: dict[str, tuple[str, str | None]] = {
    "time": ("simulated time at the end of the step", "s"),
    "snapshot_time": ("simulated time of the wind snapshot", "s"),
    "x": ("cell-centre x coordinate", "m"),
    "y": ("cell-centre y coordinate", "m"),
    "z": ("cell-centre z coordinate (up)", "m"),
    "component": ("vector component", None),
    "cloth": ("cloth name", None),
    "phase": ("phase of the step", None),
    "probe_box": ("probe box of the lattice point", None),
    "wake_distance": ("distance behind the obstacle's lee face / its height H", "1"),
    "frame_time": ("simulated time of the animation frame", "s"),
    "wake_height": ("height above the ground / the obstacle's height H", "1"),
    "wind": ("cell-centred wind velocity", "m s-1"),
    "cloth_position": ("cloth vertex position", "m"),
    "aero_force": ("total aerodynamic force on each cloth (paper section 3)", "N"),
    "divergence_rms": ("RMS of |div u| h / U_ref over interior air cells", "1"),
    "divergence_max": ("max of |div u| h / U_ref over interior air cells", "1"),
    "lee_speed_ratio": ("mean |u| in the lee box / mean |u| in the free-stream box", "1"),
    "wake_speed_ratio": (
        "u / u0 along the wind behind the scene's obstacle (u0: the undisturbed wind there)",
        "1",
    ),
    "lee_force_ratio": ("|F| on the sheltered cloth / |F| on the exposed cloth", "1"),
    "step_seconds": ("wall time per step and phase", "s"),
    "step_cpu_seconds": ("CPU time of the process per step (all its threads)", "s"),
    "step_threads": (
        "numba threads of the step's parallel kernels (fewer than numba_threads: cores were "
        "busy with other processes)",
        "1",
    ),
    "probe_wind": ("wind at the probe lattice points", "m s-1"),
    "probe_wind_mean": ("wind at the probe lattice points, mean over the steady window", "m s-1"),
    "probe_wind_block_mean": (
        "wind at the probe lattice points, mean over each of equal blocks of the steady window",
        "m s-1",
    ),
    "probe_points": ("probe lattice point positions", "m"),
    "cloth_triangles": ("cloth triangle vertex ids", "1"),
    "vertex_cloth": ("index of the cloth each vertex belongs to", "1"),
}
# how the machine ran the steps (its speed, its load), not the run's numbers: the only
# variables in which two runs of one config and seed may differ
MACHINE_VARIABLES = ("step_seconds", "step_cpu_seconds", "step_threads")
AXES = {"x": "X", "y": "Y", "z": "Z"}
PHASES = ("wind", "aero", "cloth", "total")  # step_seconds columns the loop records
PACKAGES = ("numpy", "scipy", "numba", "xarray", "netCDF4", "pandas", "hydra-core")
CODE_ATTRS = ("windbench_version", "git_commit")  # what makes two runs' code the same
VERIFY_BLOCK_BYTES = 64 * 2**20  # verify reads at most this much of a variable at once


def package_versions() -> dict[str, str]:
    out = {"windbench_version": windbench.__version__}
    for pkg in PACKAGES:
        try:
            out[f"version_{pkg.replace('-', '_')}"] = version(pkg)
        except PackageNotFoundError:  # pragma: no cover
            out[f"version_{pkg.replace('-', '_')}"] = "not installed"
    return out


def runtime_info(load_average: Mapping[str, list[float]] | None = None) -> dict[str, object]:
    """Where the timings (``step_seconds``) were taken: numba's thread count for the
    parallel kernels, the machine's cores (and those the process could use), its platform
    and its load average (1, 5, 15 min) when the run started and ended."""
    import numba

    from windbench.runtime import available_cores

    loads = {f"load_average_{k}": [float(x) for x in v] for k, v in (load_average or {}).items()}
    return {
        "numba_threads": int(numba.get_num_threads()),
        "cpu_count": int(os.cpu_count() or 0),
        "cores_available": available_cores(),
        "platform": platform.platform(),
        **loads,
    }


@functools.lru_cache(maxsize=1)
def git_commit() -> str:
    """The source tree's commit, or ``unknown`` (an installed wheel has no tree).

    A tree with uncommitted changes to tracked files is ``<commit>+dirty.<hash>``, the
    hash (12 hex digits of SHA-256) taken over ``git diff HEAD``, so that two different
    edits of one commit are two code versions. Taken once per process: the code that runs
    is the code that was loaded.
    """
    root = Path(windbench.__file__).resolve().parent.parent

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, timeout=10, check=False
        )

    try:
        sha = git("rev-parse", "HEAD")
        if sha.returncode != 0:
            return "unknown"
        commit = sha.stdout.decode().strip()
        diff = git("diff", "HEAD", "--no-ext-diff", "--binary")
        if diff.returncode == 0 and diff.stdout:
            return f"{commit}+dirty.{hashlib.sha256(diff.stdout).hexdigest()[:12]}"
        return commit
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def code_version(attrs: Mapping) -> str:
    """``windbench <version> (<git commit>)`` of a dataset's attributes (or of this code,
    :func:`current_code`): two runs with different strings ran different code."""
    return (
        f"windbench {attrs.get('windbench_version', 'unknown')} "
        f"({attrs.get('git_commit', 'unknown')})"
    )


def current_code() -> dict[str, str]:
    """The :data:`CODE_ATTRS` of the code running now."""
    return {"windbench_version": windbench.__version__, "git_commit": git_commit()}


# ------------------------------------------------------------------------ assembly
def run_dataset(setup: RunSetup, rec: Recorder, status: str, failure: str = "") -> xr.Dataset:
    """The run dataset of what ``rec`` recorded for ``setup``, annotated (see module)."""
    n = len(rec.times)
    x, y, z = setup.grid.axes()
    ds = xr.Dataset(
        coords={
            "time": ("time", np.asarray(rec.times, dtype=float)),
            "component": ("component", ["x", "y", "z"]),
            "x": ("x", x),
            "y": ("y", y),
            "z": ("z", z),
            "cloth": ("cloth", setup.cloth.names),
            "snapshot_time": ("snapshot", np.asarray(rec.snap_times, dtype=float)),
        }
    )
    shape_w = (len(rec.snap_wind), *setup.grid.shape, 3)
    ds["wind"] = (
        ("snapshot", "x", "y", "z", "component"),
        np.asarray(rec.snap_wind).reshape(shape_w),
    )
    _step_seconds(ds, rec, n)
    ds["aero_force"] = (
        ("time", "cloth", "component"),
        np.asarray(rec.rows.get("aero_force", []), dtype=float).reshape(n, setup.cloth.n_cloths, 3),
    )
    ds["cloth_position"] = (
        ("time", "vertex", "component"),
        np.asarray(rec.rows.get("cloth_position", []), dtype=float).reshape(
            n, setup.cloth.n_vertices, 3
        ),
    )
    ds["cloth_triangles"] = (("triangle", "corner"), setup.cloth.triangles)
    ds["vertex_cloth"] = (("vertex",), setup.cloth.vertex_cloth)
    for key, values in rec.rows.items():
        if key not in ("step_seconds", "aero_force", "cloth_position", "wake_speed_ratio"):
            ds[key] = (("time",), np.asarray(values, dtype=float))
    ds = _wake(ds, setup, rec)
    ds = _probes(ds, setup, rec)
    ds = _frames(ds, setup, rec)
    ds.attrs.update(_run_attrs(setup, status, failure, n))
    ds.attrs.update(runtime_info(rec.load_average))
    return annotate(ds, rec.units)


FRAME_VARIABLES = {  # output.frames: name -> (dims after "frame", long_name, units)
    "slice_wind": (
        ("x", "y", "component"),
        "wind in the horizontal slice at height slice_z (attribute, m)",
        "m s-1",
    ),
    "triangle_force": (
        ("triangle", "component"),
        "aerodynamic force on each cloth triangle (paper section 3)",
        "N",
    ),
    "slice_reached": (("x", "y"), "1 where a gust particle has marked the cell since t = 0", "1"),
    "reached_box": (
        ("bound", "component"),
        "lower and upper cell centre of the box around every cell a gust particle has marked",
        "m",
    ),
}


def _frames(ds: xr.Dataset, setup: RunSetup, rec: Recorder) -> xr.Dataset:
    """The animation frames (``output.frames``) along ``frame`` (coordinate ``frame_time``)."""
    if not rec.frame_times:
        return ds
    ds = ds.assign_coords(frame_time=("frame", np.asarray(rec.frame_times)))
    for name, values in rec.frame_data.items():
        ds[name] = (("frame", *FRAME_VARIABLES[name][0]), np.asarray(values))
    # the slice's height (m) as an attribute: a scalar variable cannot carry a checksum
    ds["slice_wind"].attrs["slice_z"] = float(setup.frames.height)
    return ds


def _step_seconds(ds: xr.Dataset, rec: Recorder, n: int) -> None:
    """``step_seconds`` (time, phase): the loop's phases, then the backend's own."""
    extra = sorted(rec.phases)
    seconds = np.asarray(rec.rows.get("step_seconds", []), dtype=float).reshape(n, len(PHASES))
    columns = [np.asarray(rec.phases[p][:n], dtype=float) for p in extra]
    ds.coords["phase"] = ("phase", [*PHASES, *extra])
    ds["step_seconds"] = (
        ("time", "phase"),
        np.column_stack([seconds, *columns]) if columns else seconds,
    )


def _wake(ds: xr.Dataset, setup: RunSetup, rec: Recorder) -> xr.Dataset:
    """``wake_speed_ratio`` (time, wake_distance, wake_height), if the scene has a probe."""
    wake = setup.scene.wake
    if wake is None or "wake_speed_ratio" not in rec.rows:
        return ds
    ds = ds.assign_coords(
        wake_distance=("wake_distance", list(wake.distances)),
        wake_height=("wake_height", list(wake.heights)),
    )
    ds["wake_speed_ratio"] = (
        ("time", "wake_distance", "wake_height"),
        np.asarray(rec.rows["wake_speed_ratio"], dtype=float),
    )
    return ds


def _probes(ds: xr.Dataset, setup: RunSetup, rec: Recorder) -> xr.Dataset:
    if not setup.probe_points:
        return ds
    names = sorted(setup.probe_points)
    pts = np.concatenate([setup.probe_points[k] for k in names])
    box = np.concatenate([[k] * len(setup.probe_points[k]) for k in names])
    ds = ds.assign_coords(probe_box=("probe_point", box))
    ds["probe_points"] = (("probe_point", "component"), pts)
    ds["probe_wind"] = (
        ("snapshot", "probe_point", "component"),
        np.asarray(rec.snap_probe).reshape(len(rec.snap_probe), len(pts), 3),
    )
    count = rec.probe_count
    mean = rec.probe_sum / count if count else np.full((len(pts), 3), np.nan)
    ds["probe_wind_mean"] = (("probe_point", "component"), mean)
    blocks = rec.block_count
    if rec.block_sum is not None and blocks.all():  # every block of the window reached
        ds["probe_wind_block_mean"] = (
            ("window_block", "probe_point", "component"),
            rec.block_sum / blocks[:, None, None],
        )
    return ds


def _run_attrs(setup: RunSetup, status: str, failure: str, n: int) -> dict:
    cfg = setup.cfg
    return dict(
        wind=str(cfg.wind.name),
        scene=setup.scene.name,
        resolution=int(cfg.grid.resolution),
        dt=setup.dt,
        duration=setup.n_steps * setup.dt,
        spinup=setup.start_time,
        flow_through_time=setup.flow_through_time,
        analysis_start=setup.analysis_start,
        seed=int(cfg.seed),
        experiment=str(cfg.get("experiment") or ""),
        grid_shape=list(setup.grid.shape),
        grid_spacing=setup.grid.h,
        reference_speed=setup.scene.reference_speed,
        cfl=setup.cfl,
        config=OmegaConf.to_yaml(cfg, resolve=True),
        status=status,
        failure=failure,
        steps_completed=n,
        steps_planned=setup.n_steps,
        git_commit=git_commit(),
        **package_versions(),
    )


def annotate(ds: xr.Dataset, extra_units: Mapping[str, tuple[str, str]] | None = None):
    """Attach long_name and units (:data:`VARIABLES` and ``extra_units``, e.g. a backend's
    ``stats_units``), axis to x/y/z and ``Conventions``; warn about a variable neither
    table knows (its figures would have no units)."""
    frames = {name: (long_name, units) for name, (_, long_name, units) in FRAME_VARIABLES.items()}
    table = {**VARIABLES, **frames, **(extra_units or {})}
    for name in ds.variables:
        if name not in table:
            log.warning(
                "dataset variable %r has no long_name and units: add it to the "
                "stats_units of the backend or cloth solver that records it",
                name,
            )
            continue
        long_name, units = table[name]
        ds[name].attrs["long_name"] = long_name
        if units is not None:
            ds[name].attrs["units"] = units
        if name in AXES:
            ds[name].attrs["axis"] = AXES[name]
    ds.attrs["Conventions"] = CONVENTIONS
    return ds


# ------------------------------------------------------------------------ files
def owner_tag(host: str | None = None, pid: int | None = None) -> str:
    """``<host>.<pid>``: who wrote a temporary file (see :func:`temporary_name`)."""
    host = (host or socket.gethostname()).replace("/", "_")
    return f"{host}.{pid if pid is not None else os.getpid()}"


def temporary_name(path: Path) -> Path:
    """``.<name>.<host>.<pid>.<random>.tmp`` beside ``path``: unique to one writer, so that
    a writer removes only its own temporaries (and a stale-lock takeover those of the dead
    writer, :mod:`windbench.sweep`)."""
    path = Path(path)
    return path.parent / f".{path.name}.{owner_tag()}.{secrets.token_hex(4)}.tmp"


def _checksummed(ds: xr.Dataset) -> dict:
    """netCDF encoding: a Fletcher-32 checksum on every variable, strings as characters."""
    encoding = {}
    for name, var in ds.variables.items():
        enc = {k: v for k, v in var.encoding.items() if k in ("dtype", "chunksizes", "zlib")}
        enc["fletcher32"] = True
        if var.dtype.kind in "OUS":
            enc["dtype"] = "S1"
        encoding[name] = enc
    return encoding


def write_atomic(ds: xr.Dataset, path: Path) -> Path:
    """Write ``ds`` to ``path``, checksummed, so that a file with that name is always whole."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(path)
    try:
        ds.to_netcdf(tmp, engine="netcdf4", encoding=_checksummed(ds))
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def verify(path) -> None:
    """Read every chunk of every variable of ``path`` (HDF5 checks each chunk's Fletcher-32
    checksum as it reads); raise :class:`DatasetUnreadable` on the first fault."""
    import netCDF4

    try:
        nc = netCDF4.Dataset(path)
    except OSError as err:
        raise DatasetUnreadable(f"cannot open: {err}") from err
    with nc:
        for name, var in nc.variables.items():
            if not var.filters().get("fletcher32"):
                raise DatasetUnreadable(
                    f"no checksum on variable {name!r} (written before checksums)"
                )
            var.set_auto_maskandscale(False)
            try:
                for block in _blocks(var.shape, var.dtype.itemsize if var.dtype != str else 8):
                    var[block]
            except (RuntimeError, OSError, IndexError) as err:
                raise DatasetUnreadable(f"checksum: variable {name!r} is damaged ({err})") from err


def _blocks(shape: tuple[int, ...], itemsize: int):
    """Index tuples covering an array of ``shape``, at most VERIFY_BLOCK_BYTES each (in
    slabs along the first axis)."""
    if not shape:
        yield ()
        return
    row = itemsize * int(np.prod(shape[1:], dtype=np.int64))
    step = max(1, VERIFY_BLOCK_BYTES // max(row, 1))
    for start in range(0, max(shape[0], 1), step):
        yield (slice(start, start + step),)


def read(path) -> xr.Dataset:
    """Open a run dataset (lazily; :func:`verify` checks it whole)."""
    return xr.open_dataset(path, engine="netcdf4")
