"""Export run datasets for ParaView and Blender.

Per run, into ``<export dir>/<run label>/``:

- ``wind_NNNN.vti`` — each wind snapshot as VTK image data (cell data ``wind`` (m/s) and
  ``speed``; origin at the domain's lower corner, spacing h: the dataset's cell centres are
  the image's cell centres), indexed by ``wind.pvd`` with the snapshot times;
- ``cloth_NNNN.vtp`` — the cloth at each recorded step as VTK polydata (triangles; point data
  ``cloth`` = which cloth a vertex belongs to), indexed by ``cloth.pvd`` with the times;
- ``cloth_NNNN.ply`` — the same frames as PLY meshes for Blender.

Written with pyevtk (VTK XML and the ``.pvd`` collection) and meshio (PLY); coordinates
in metres and velocities in m/s, as in the dataset.
"""

from __future__ import annotations

import re
from pathlib import Path

import meshio
import numpy as np
import xarray as xr
from pyevtk.hl import imageToVTK
from pyevtk.vtk import VtkFile, VtkGroup, VtkPolyData


def run_label(settings: dict, extra: str = "") -> str:
    s = settings
    label = (
        f"{s.get('scene')}_{s.get('wind')}_r{s.get('resolution')}_dt{float(s.get('dt')):.4g}_s{s.get('seed')}"
        + extra
    )
    return re.sub(r"[^A-Za-z0-9_.=-]+", "-", label)


def write_wind(ds: xr.Dataset, folder: Path) -> Path:
    """Wind snapshots -> ``wind_NNNN.vti`` + ``wind.pvd``; returns the .pvd path."""
    h = float(ds.attrs.get("grid_spacing", ds["x"].values[1] - ds["x"].values[0]))
    origin = tuple(float(ds[a].values[0]) - h / 2 for a in "xyz")
    group = VtkGroup(str(folder / "wind"))
    times = ds["snapshot_time"].values
    for k in range(ds.sizes["snapshot"]):
        u = np.asarray(ds["wind"].isel(snapshot=k).values, dtype=np.float64)
        comps = tuple(np.asfortranarray(u[..., c]) for c in range(3))
        path = imageToVTK(
            str(folder / f"wind_{k:04d}"),
            origin=origin,
            spacing=(h, h, h),
            cellData={"wind": comps, "speed": np.asfortranarray(np.linalg.norm(u, axis=-1))},
        )
        group.addFile(path, sim_time=float(times[k]))
    group.save()
    return folder / "wind.pvd"


def write_polydata(path: Path, points: np.ndarray, triangles: np.ndarray, point_data: dict) -> str:
    """One triangle mesh as VTK XML polydata (.vtp) through pyevtk's VtkFile."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    x, y, z = (np.ascontiguousarray(pts[:, c]) for c in range(3))
    conn = np.ascontiguousarray(triangles.reshape(-1), dtype=np.int64)
    offsets = np.arange(3, conn.size + 1, 3, dtype=np.int64)
    w = VtkFile(str(path), VtkPolyData)
    w.openGrid()
    w.openPiece(npoints=len(pts), npolys=len(triangles))
    w.openElement("Points")
    w.addData("points", (x, y, z))
    w.closeElement("Points")
    w.openElement("Polys")
    w.addData("connectivity", conn)
    w.addData("offsets", offsets)
    w.closeElement("Polys")
    w.openData("Point", scalars=next(iter(point_data), None))
    for name, arr in point_data.items():
        w.addData(name, arr)
    w.closeData("Point")
    w.closePiece()
    w.closeGrid()
    w.appendData((x, y, z)).appendData(conn).appendData(offsets)
    for arr in point_data.values():
        w.appendData(arr)
    w.save()
    return w.getFileName()


def write_cloth(ds: xr.Dataset, folder: Path, every: int = 1) -> Path | None:
    """Cloth frames -> ``cloth_NNNN.vtp`` + ``cloth.pvd`` and ``cloth_NNNN.ply``."""
    if ds.sizes.get("vertex", 0) == 0 or ds.sizes.get("time", 0) == 0:
        return None
    tris = np.asarray(ds["cloth_triangles"].values, dtype=np.int64)
    owner = np.ascontiguousarray(ds["vertex_cloth"].values, dtype=np.int64)
    tris32 = tris.astype(np.int32)  # PLY stores 32-bit vertex ids
    times = ds["time"].values
    group = VtkGroup(str(folder / "cloth"))
    for n, i in enumerate(range(0, len(times), max(1, every))):
        pos = np.asarray(ds["cloth_position"].isel(time=i).values, dtype=np.float64)
        vtp = write_polydata(folder / f"cloth_{n:04d}", pos, tris, {"cloth": owner})
        group.addFile(vtp, sim_time=float(times[i]))
        meshio.write_points_cells(
            folder / f"cloth_{n:04d}.ply", pos, [("triangle", tris32)], file_format="ply"
        )
    group.save()
    return folder / "cloth.pvd"


def export_run(path: Path, folder: Path, every: int = 1) -> list[Path]:
    """Everything of one run file into ``folder``; returns the .pvd index files written."""
    folder.mkdir(parents=True, exist_ok=True)
    with xr.open_dataset(path, engine="netcdf4") as ds:
        out = [write_wind(ds, folder)] if ds.sizes.get("snapshot", 0) else []
        cloth = write_cloth(ds, folder, every)
    return out + ([cloth] if cloth else [])
