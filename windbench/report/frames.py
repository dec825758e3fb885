"""Animation frames of a run dataset (``output.frames``): pressure on the cloth, arrival, lee.

A run with ``output.frames.interval > 0`` keeps, every few steps, a horizontal wind slice
(``slice_wind`` at height ``slice_z``), the §3 aerodynamic force on every cloth triangle
(``triangle_force``) and, for particle tracing, the cells of the slice that a gust particle
has marked since the start (``slice_reached``). This module turns them into what the
figures and animations show:

- **aerodynamic pressure** of a triangle, ``p = |F| / A`` (Pa), with ``A`` its area in the
  cloth of that step;
- **front and back** of a cloth: triangles whose centre lies upwind (``c . d`` below the
  cloth's mean vertex ``. d``, ``d`` the unit wind direction) are its front, the rest its
  back; a side's mean pressure is ``sum |F| / sum A`` (the area-weighted mean of ``p``);
- **lee or not yet arrived.** With particle tracing a cell holds wind only once a gust
  particle has marked it, so a cell of zero wind is either *lee* (the gust passed it by:
  it is sheltered) or the gust has *not arrived yet*. The run keeps, per frame, the box
  around every cell marked so far (``reached_box``, in 3D: a wall that blocks the whole
  slice does not stop the front above it); the gust front is its farthest corner along
  ``d``, ``s_front = max c . d``. The front is ragged: particles are emitted a few at a
  time and jittered, so the cells just behind the foremost one may still wait for theirs.
  An unmarked cell of the slice with ``c . d <= s_front - FRONT_BAND h`` is lee; any other
  unmarked cell has not been reached yet. Where the sources set no single direction (e.g.
  ``opposing_sources``) unmarked cells are not called lee.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import xarray as xr

from windbench.scenes import Scene

NEEDED = ("slice_wind", "triangle_force")  # what every run that kept frames has
FRONT_BAND = 2.0  # cells behind the gust front still counted as not yet reached


def has_frames(ds: xr.Dataset) -> bool:
    return all(v in ds for v in NEEDED) and ds.sizes.get("frame", 0) > 0


def triangle_areas(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """A = |(b - a) x (c - a)| / 2 per triangle; positions ``(..., n, 3)``."""
    a, b, c = (positions[..., triangles[:, k], :] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=-1)


def triangle_pressure(force: np.ndarray, positions: np.ndarray, triangles: np.ndarray):
    """p = |F| / A (Pa) per triangle; ``force (..., m, 3)``, ``positions (..., n, 3)``."""
    area = triangle_areas(positions, triangles)
    return np.linalg.norm(force, axis=-1) / np.where(area > 0, area, np.inf)


def wind_direction(scene: Scene) -> np.ndarray | None:
    """Unit direction of the summed uniform sources, or None when they set none."""
    total = sum(
        (np.asarray(s.velocity, float) for s in scene.sources if s.kind == "uniform"),
        np.zeros(3),
    )
    norm = float(np.linalg.norm(total))
    return total / norm if norm > 0 else None


def _corners(lower, upper) -> np.ndarray:
    """(8, 3) corners of the box [lower, upper]."""
    grid = np.meshgrid(*zip(lower, upper, strict=True), indexing="ij")
    return np.stack(grid, axis=-1).reshape(-1, 3)


def gust_front(box: np.ndarray, direction: np.ndarray) -> float:
    """``max c . d`` over the corners of the reached box ``(2, 3)`` (``-inf``: none reached)."""
    if not np.isfinite(box).all():
        return -np.inf
    return float((_corners(box[0], box[1]) @ direction).max())


def unreached_kinds(reached: np.ndarray, centres: np.ndarray, front: float | None):
    """(lee, not_arrived) boolean masks of the unmarked cells (module docstring); ``centres
    (..., 3)`` hold ``c . d`` through ``front`` = ``(direction, s_front)`` or None.

    Without a front every unmarked cell counts as not arrived: nothing is called lee.
    """
    unmarked = ~reached
    if front is None:
        return np.zeros_like(unmarked), unmarked
    direction, s_front = front
    behind = centres @ direction <= s_front
    return unmarked & behind, unmarked & ~behind


def front_passes(frames: RunFrames, lower, upper, direction: np.ndarray) -> float:
    """First frame time at which the gust front lies at or beyond every corner of the box
    ``[lower, upper]`` (nan if it never does or the run kept no arrival)."""
    if frames.reach is None:
        return np.nan
    far = float((_corners(lower, upper) @ direction).max())
    for t, box in zip(frames.times, frames.reach, strict=True):
        if gust_front(box, direction) >= far:
            return float(t)
    return np.nan


def side_pressure(
    force: np.ndarray, positions: np.ndarray, triangles: np.ndarray, direction: np.ndarray
) -> tuple[float, float]:
    """(front, back) area-weighted mean pressure ``sum |F| / sum A`` (Pa) of one cloth."""
    area = triangle_areas(positions, triangles)
    centre = positions[triangles].mean(axis=1) @ direction
    front = centre < positions.mean(axis=0) @ direction
    magnitude = np.linalg.norm(force, axis=-1)
    return tuple(
        float(magnitude[side].sum() / area[side].sum()) if area[side].sum() > 0 else np.nan
        for side in (front, ~front)
    )


@dataclass
class RunFrames:
    """The frames of one run, read into memory (small: a slice and the cloth per frame)."""

    path: Path
    times: np.ndarray  # (k,) s
    speed: np.ndarray  # (k, nx, ny) |u| in the slice
    reached: np.ndarray | None  # (k, nx, ny) bool, particle tracing only
    reach: np.ndarray | None  # (k, 2, 3) box around every marked cell, particle tracing only
    force: np.ndarray  # (k, m, 3) N per triangle
    positions: np.ndarray  # (k, n, 3) cloth at the frame times
    triangles: np.ndarray  # (m, 3)
    vertex_cloth: np.ndarray  # (n,) cloth id of each vertex
    slice_z: float
    x: np.ndarray
    y: np.ndarray
    h: float

    @cached_property
    def pressure(self) -> np.ndarray:
        """(k, m) |F| / A per triangle and frame (computed once: every frame drawn reads it)."""
        return triangle_pressure(self.force, self.positions, self.triangles)

    @property
    def extent(self) -> list[float]:
        h = self.h
        return [self.x[0] - h / 2, self.x[-1] + h / 2, self.y[0] - h / 2, self.y[-1] + h / 2]

    def centres(self) -> np.ndarray:
        """(nx, ny, 3) centres of the slice's cells."""
        x, y = np.meshgrid(self.x, self.y, indexing="ij")
        return np.stack([x, y, np.full_like(x, self.slice_z)], axis=-1)

    def nearest(self, t: float) -> int:
        return int(np.abs(self.times - t).argmin())

    def unreached(self, k: int, direction: np.ndarray | None):
        """(lee, not_arrived) masks of the slice at frame k (all False without arrival)."""
        if self.reached is None:
            empty = np.zeros(self.speed.shape[1:], dtype=bool)
            return empty, empty
        if direction is None:
            return unreached_kinds(self.reached[k], self.centres(), None)
        s_front = gust_front(self.reach[k], direction) - FRONT_BAND * self.h
        return unreached_kinds(self.reached[k], self.centres(), (direction, s_front))


def read_frames(ds: xr.Dataset, path: Path) -> RunFrames | None:
    """The frames of an open run dataset, or None when it recorded none."""
    if not has_frames(ds):
        return None
    times = np.asarray(ds["frame_time"].values, dtype=float)
    steps = np.asarray(ds["time"].values, dtype=float)
    index = np.abs(steps[None, :] - times[:, None]).argmin(axis=1)
    x = np.asarray(ds["x"].values, dtype=float)
    h = float(ds.attrs.get("grid_spacing", x[1] - x[0] if len(x) > 1 else 1.0))
    reached = ds["slice_reached"].values.astype(bool) if "slice_reached" in ds else None
    reach = np.asarray(ds["reached_box"].values, float) if "reached_box" in ds else None
    return RunFrames(
        path=Path(path),
        times=times,
        speed=np.linalg.norm(np.asarray(ds["slice_wind"].values, dtype=float), axis=-1),
        reached=reached if reach is not None else None,
        reach=reach,
        force=np.asarray(ds["triangle_force"].values, dtype=float),
        positions=np.asarray(ds["cloth_position"].values[index], dtype=float),
        triangles=np.asarray(ds["cloth_triangles"].values, dtype=np.int64),
        vertex_cloth=np.asarray(ds["vertex_cloth"].values, dtype=np.int64),
        slice_z=float(ds["slice_wind"].attrs["slice_z"]),
        x=x,
        y=np.asarray(ds["y"].values, dtype=float),
        h=h,
    )


def open_frames(path: Path) -> RunFrames | None:
    with xr.open_dataset(path) as ds:
        return read_frames(ds, path)
