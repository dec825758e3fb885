"""Backend ``global``: the superposition w = sum_i w_i of the flow primitives (paper §4.2.1).

The paper's baseline: a fixed, analytic wind that ignores every object, so it has no lee
("tissues in the lee of other objects will be affected by the wind flow as well"); it is
the "no lee" shirt on the right of Fig. 6. The field is evaluated once on the cell centres
and ``sample`` evaluates the primitives exactly at the query points (no interpolation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from windbench.wind.base import Obstacles, WindField
from windbench.wind.primitives import parameter_table, superpose
from windbench.wind.registry import WindConfig, register_backend


@dataclass
class GlobalConfig(WindConfig):
    """``wind.*`` keys of the global field: none but the name."""

    name: str = "global"


@register_backend("global", config=GlobalConfig)
class GlobalWind(WindField):
    """w = sum_i w_i everywhere, whatever the obstacles (module docstring)."""

    def __init__(self, scene, grid, params):
        super().__init__(scene, grid, params)
        self._table = parameter_table(scene.sources)  # model: built once, read every step
        self._field = superpose(scene.sources, grid.cell_centres(), self._table)
        self._field.setflags(write=False)

    def step(self, dt: float, obstacles: Obstacles) -> None:
        """Nothing to advance: w does not depend on time or on the objects."""

    def velocity(self) -> np.ndarray:
        return self._field

    def sample(self, points) -> np.ndarray:
        return superpose(self.scene.sources, np.atleast_2d(points), self._table)
