"""The WindField interface: the only thing the step loop knows about a wind backend.

- ``WindField(scene, grid, params)`` — built by :func:`windbench.wind.make_wind` from the
  ``wind`` config group.
- ``step(dt, obstacles)`` — advance the air by ``dt``; ``obstacles`` carries the rigid
  bodies and the current cloth triangles (positions, velocities).
- ``sample(points) -> (n, 3)`` — wind velocity (m/s) at world points.
- ``velocity() -> (nx, ny, nz, 3)`` — cell-centred wind on the grid.
- ``stats() -> dict`` — scalar figures of the last step (recorded per time step); the class
  table ``stats_units`` gives each figure's long_name and units for the dataset.
- ``solid_mask() -> (nx, ny, nz) bool`` — cells that are not air (inside rigid bodies).
- ``cloth_pressure_loads() -> (m, 3) | None`` — pressure force over rho per cloth triangle,
  where the backend couples through pressure.

Model (scene, grid, params: fixed) is kept apart from state (arrays that change).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from windbench.geometry.bodies import Body, inside
from windbench.grid import Grid


@dataclass(frozen=True)
class Obstacles:
    """What the air must react to this step: rigid bodies and the current cloth.

    Cloth arrays are all cloths concatenated: ``cloth_positions``/``cloth_velocities``
    ``(n, 3)``, ``cloth_triangles`` ``(m, 3)`` indexing them; ``cloth_mobility`` ``(n,)``
    (1/m, None: all 0) is the air density over each vertex's mass per area, 0 where the
    cloth cannot move (pinned, or a static cloth): how far the air's pressure moves it.
    """

    bodies: tuple[Body, ...]
    cloth_positions: np.ndarray
    cloth_velocities: np.ndarray
    cloth_triangles: np.ndarray
    cloth_mobility: np.ndarray | None = None

    @classmethod
    def rigid_only(cls, bodies) -> Obstacles:
        return cls(tuple(bodies), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), np.int64))


class WindField(ABC):
    """Base class of the wind backends (see module docstring)."""

    name: ClassVar[str] = ""
    max_cfl: ClassVar[float] = float("inf")  # above it the run warns (see simulate.prepare)
    # numba kernels of its own, many: on an empty cache a second process compiles the
    # cloth's while the run compiles these (windbench.compile_ahead)
    compiles_kernels: ClassVar[bool] = False
    stats_units: ClassVar[dict[str, tuple[str, str]]] = {}  # stats() key -> (long_name, units)

    @classmethod
    def check(cls, scene, grid: Grid, params: Any) -> None:
        """Raise ConfigError for bad ``wind.*`` values before any work (default: none)."""
        return None

    @classmethod
    def memory(cls, scene, grid: Grid, params: Any, dt: float) -> dict[str, tuple[float, str]]:
        """Bytes the backend holds beyond the per-cell budget of simulate.BYTES_PER_CELL, by
        the config key they scale with: ``{key: (bytes, what)}`` (default: nothing)."""
        return {}

    def __init__(self, scene, grid: Grid, params: Any):
        self.scene = scene
        self.grid = grid
        self.params = params
        self._solid = inside(scene.bodies, grid.cell_centres().reshape(-1, 3)).reshape(grid.shape)
        self.moving = any(b.motion is not None for b in scene.bodies)

    def pose_solid(self, time: float) -> None:
        """The cells whose centre lies inside a body posed at ``time`` (s): for a scene whose
        bodies move (:mod:`windbench.geometry.motion`); :meth:`solid_mask` follows."""
        centres = self.grid.cell_centres().reshape(-1, 3)
        self._solid = inside(self.scene.bodies, centres, time).reshape(self.grid.shape)

    @abstractmethod
    def step(self, dt: float, obstacles: Obstacles) -> None:
        """Advance the air by ``dt`` seconds."""

    @abstractmethod
    def velocity(self) -> np.ndarray:
        """Cell-centred wind, ``(nx, ny, nz, 3)`` in m/s."""

    def sample(self, points) -> np.ndarray:
        """Wind at world points ``(n, 3)``: trilinear in the cell-centred field."""
        return self.grid.sample(self.velocity(), points)

    def stats(self) -> dict[str, float]:
        """Backend figures of the last step (e.g. pressure iterations)."""
        return {}

    def divergence(self) -> np.ndarray | None:
        """The backend's own discrete div u per cell (NaN outside the air), or None.

        None (the default) lets the loop take central differences of ``velocity()``;
        a solver on a staggered grid returns the divergence its projection controls.
        """
        return None

    def cloth_pressure_loads(self) -> np.ndarray | None:
        """Force over the air density on each cloth triangle from the air's own pressure
        (m^4 s^-2), for a backend whose solve closes the cloth (two-way coupling through
        pressure); None (the default): the cloth feels the paper's §3 law."""
        return None

    def solid_mask(self) -> np.ndarray:
        """Cells whose centre lies inside a rigid body."""
        return self._solid
