"""Export to ParaView (VTK XML + .pvd) and Blender (PLY): read back what was written."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest
import xarray as xr

from windbench.cli import compose_config
from windbench.report.export import export_run, run_label
from windbench.simulate import run


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    cfg = compose_config(
        [
            "scene=flag",
            "grid.resolution=12",
            "sim.dt=0.05",
            "sim.duration=0.15",
            "output.snapshots=2",
            "sim.progress=false",
        ]
    )
    result = run(cfg, root / "run")
    folder = root / "vtk"
    written = export_run(result.path, folder)
    return result.path, folder, written


def _appended_arrays(path) -> tuple[ET.Element, dict[str, np.ndarray]]:
    """Decode a VTK XML file with raw appended data (pyevtk's layout: UInt64 size headers)."""
    raw = path.read_bytes()
    start = raw.index(b"<AppendedData")
    head = raw[:start].decode() + "</VTKFile>"
    data = raw[raw.index(b"_", start) + 1 :]
    tree = ET.fromstring(head)
    arrays = {}
    for arr in tree.iter("DataArray"):
        off = int(arr.get("Offset") or arr.get("offset"))
        size = int(np.frombuffer(data[off : off + 8], dtype="<u8")[0])
        dtype = {"Float64": "<f8", "Int64": "<i8", "Int32": "<i4", "UInt8": "u1"}[arr.get("type")]
        values = np.frombuffer(data[off + 8 : off + 8 + size], dtype=dtype)
        ncomp = int(arr.get("NumberOfComponents", 1))
        arrays[arr.get("Name")] = values.reshape(-1, ncomp) if ncomp > 1 else values
    return tree, arrays


def _series(folder, name, written, times):
    """The .pvd index's entries, checked against the dataset's times."""
    assert folder / f"{name}.pvd" in written
    entries = ET.parse(folder / f"{name}.pvd").getroot().findall("./Collection/DataSet")
    np.testing.assert_allclose([float(e.get("timestep")) for e in entries], times)
    return entries


def test_wind_snapshots_as_vtk_image_data(exported):
    path, folder, written = exported
    with xr.open_dataset(path) as ds:
        entries = _series(folder, "wind", written, ds["snapshot_time"])
        h = float(ds.attrs["grid_spacing"])
        for k, entry in enumerate(entries):
            tree, arrays = _appended_arrays(folder / entry.get("file"))
            image = tree.find("ImageData")
            nx, ny, nz = (ds.sizes[a] for a in "xyz")
            assert image.get("WholeExtent").split() == ["0", str(nx), "0", str(ny), "0", str(nz)]
            np.testing.assert_allclose([float(v) for v in image.get("Spacing").split()], [h] * 3)
            lower = [float(ds[a][0]) - h / 2 for a in "xyz"]
            np.testing.assert_allclose([float(v) for v in image.get("Origin").split()], lower)
            u = ds["wind"].isel(snapshot=k).values
            # VTK image order: x fastest
            expected = u.transpose(2, 1, 0, 3).reshape(-1, 3)
            np.testing.assert_array_equal(arrays["wind"], expected)
            np.testing.assert_allclose(arrays["speed"], np.linalg.norm(expected, axis=1))


def test_cloth_as_polydata_series_and_ply(exported):
    path, folder, written = exported
    with xr.open_dataset(path) as ds:
        entries = _series(folder, "cloth", written, ds["time"])
        tris = ds["cloth_triangles"].values
        for i, entry in enumerate(entries):
            pos = ds["cloth_position"].isel(time=i).values
            tree, arrays = _appended_arrays(folder / entry.get("file"))
            piece = tree.find("PolyData/Piece")
            assert int(piece.get("NumberOfPolys")) == len(tris)
            np.testing.assert_array_equal(arrays["points"], pos)
            np.testing.assert_array_equal(arrays["connectivity"].reshape(-1, 3), tris)
            mesh = meshio.read(folder / entry.get("file").replace(".vtp", ".ply"))
            np.testing.assert_array_equal(mesh.points, pos)
            np.testing.assert_array_equal(mesh.cells_dict["triangle"], tris)


def test_run_label_is_a_safe_folder_name():
    label = run_label(
        {"scene": "flag", "wind": "global", "resolution": 16, "dt": 1 / 60, "seed": 0}
    )
    assert label == "flag_global_r16_dt0.01667_s0"
