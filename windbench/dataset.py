"""The run dataset (DESIGN.md "Run dataset"): schema, atomic netCDF write, read.

Every variable carries ``long_name`` and ``units``; global attributes carry the provenance
(resolved config, versions, git commit) and the outcome (``status``, ``failure``).
A file named ``windbench.nc`` is always whole: it is written under a temporary name in the
same folder and renamed (``os.replace`` is atomic on POSIX).
"""

from __future__ import annotations

import os
import platform
import subprocess
import tempfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import xarray as xr

import windbench

VARIABLES = {
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
    "probe_wind": ("wind at the probe lattice points", "m s-1"),
    "probe_wind_mean": ("wind at the probe lattice points, mean over the steady window", "m s-1"),
    "probe_points": ("probe lattice point positions", "m"),
    "cloth_triangles": ("cloth triangle vertex ids", "1"),
}
PACKAGES = ("numpy", "scipy", "numba", "xarray", "netCDF4", "pandas", "hydra-core")


def package_versions() -> dict[str, str]:
    out = {"windbench_version": windbench.__version__}
    for pkg in PACKAGES:
        try:
            out[f"version_{pkg.replace('-', '_')}"] = version(pkg)
        except PackageNotFoundError:  # pragma: no cover
            out[f"version_{pkg.replace('-', '_')}"] = "not installed"
    return out


def runtime_info() -> dict[str, object]:
    """Where the timings (``step_seconds``) were taken: numba's thread count for the
    parallel kernels, the machine's cores and platform."""
    import numba

    return {
        "numba_threads": int(numba.get_num_threads()),
        "cpu_count": int(os.cpu_count() or 0),
        "platform": platform.platform(),
    }


def git_commit() -> str:
    """The source tree's commit (with ``+dirty`` if modified), or ``unknown``."""
    root = Path(windbench.__file__).resolve().parent.parent
    try:
        sha = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5
        )
        if sha.returncode != 0:
            return "unknown"
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        )
        return sha.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def annotate(ds: xr.Dataset, extra_units: dict[str, tuple[str, str]] | None = None) -> xr.Dataset:
    """Attach long_name and units to every known variable."""
    table = {**VARIABLES, **(extra_units or {})}
    for name, (long_name, units) in table.items():
        if name in ds.variables:
            ds[name].attrs.update(long_name=long_name, units=units)
    return ds


def write_atomic(ds: xr.Dataset, path: Path) -> Path:
    """Write ``ds`` to ``path`` so that a file with that name is always whole."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        ds.to_netcdf(tmp, engine="netcdf4")
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read(path) -> xr.Dataset:
    """Open a run dataset (lazily)."""
    return xr.open_dataset(path, engine="netcdf4")


def is_complete(path) -> bool:
    """True if ``path`` is a readable dataset whose status is ``complete``."""
    try:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            return ds.attrs.get("status") == "complete"
    except (OSError, ValueError, KeyError):
        return False
