"""Backend ``global``: the superposition w = sum_i w_i of the flow primitives (paper §4.2.1).

The paper's baseline: an analytic wind that ignores every object, so it has no lee
("tissues in the lee of other objects will be affected by the wind flow as well"); it is
the "no lee" shirt on the right of Fig. 6. ``sample`` evaluates the primitives exactly at
the query points (no interpolation). Without gusts or turbulence the field does not change
and is evaluated once on the cell centres; with them it is w(x, t) of
:mod:`windbench.wind.envelope`, evaluated at the time of the last step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from windbench.wind.base import Obstacles, WindField
from windbench.wind.envelope import SourceTimes
from windbench.wind.primitives import parameter_table, superpose
from windbench.wind.registry import WindConfig, register_backend


@dataclass
class GlobalConfig(WindConfig):
    """``wind.*`` keys of the global field: none but the name."""

    name: str = "global"
    seed: int = 0  # turbulent fluctuations (conf/wind/global.yaml sets ${seed})


@register_backend("global", config=GlobalConfig)
class GlobalWind(WindField):
    """w = sum_i w_i everywhere, whatever the obstacles (module docstring)."""

    def __init__(self, scene, grid, params):
        super().__init__(scene, grid, params)
        self._table = parameter_table(scene.sources)  # model: built once, read every step
        self._times = SourceTimes.build(scene, params.seed)
        self.time = 0.0
        self._field = self._evaluate(grid.cell_centres())
        self._field.setflags(write=False)
        self._field_time = 0.0

    def _evaluate(self, points) -> np.ndarray:
        """w at ``points`` (..., 3) at the current time."""
        pts = np.asarray(points, dtype=np.float64)
        if not self._times.varies:
            return superpose(self.scene.sources, pts, self._table)
        return self._times.wind(pts.reshape(-1, 3), self.time).reshape(pts.shape)

    def step(self, dt: float, obstacles: Obstacles) -> None:
        """Advance the time of the sources' envelopes; w does not depend on the objects."""
        self.time += dt

    def velocity(self) -> np.ndarray:
        if self._times.varies and self._field_time != self.time:
            self._field = self._evaluate(self.grid.cell_centres())
            self._field.setflags(write=False)
            self._field_time = self.time
        return self._field

    def sample(self, points) -> np.ndarray:
        return self._evaluate(np.atleast_2d(points))
