"""All cloths of a scene as one model (concatenated arrays) and their changing state.

Model: rest vertices, triangles with global vertex ids, pinned vertices, and the vertex and
triangle ranges of each cloth. State: positions and velocities. Solvers read the model and
turn one state into the next; nothing here changes in place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from windbench.cloth.mesh import ClothMesh


@dataclass(frozen=True)
class ClothModel:
    meshes: tuple[ClothMesh, ...]
    rest_positions: np.ndarray  # (n, 3)
    triangles: np.ndarray  # (m, 3) global vertex ids
    pinned: np.ndarray  # global vertex ids
    vertex_cloth: np.ndarray  # (n,) index of the cloth each vertex belongs to
    triangle_cloth: np.ndarray  # (m,)

    @classmethod
    def from_meshes(cls, meshes) -> ClothModel:
        meshes = tuple(meshes)
        verts, tris, pins, vc, tc = [], [], [], [], []
        offset = 0
        for c, mesh in enumerate(meshes):
            verts.append(mesh.vertices)
            tris.append(mesh.triangles + offset)
            pins.append(mesh.pinned + offset)
            vc.append(np.full(mesh.n_vertices, c))
            tc.append(np.full(mesh.triangles.shape[0], c))
            offset += mesh.n_vertices

        def cat(parts, shape, dtype):
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)

        return cls(
            meshes=meshes,
            rest_positions=cat(verts, (0, 3), np.float64),
            triangles=cat(tris, (0, 3), np.int64),
            pinned=cat(pins, (0,), np.int64),
            vertex_cloth=cat(vc, (0,), np.int64),
            triangle_cloth=cat(tc, (0,), np.int64),
        )

    @property
    def n_cloths(self) -> int:
        return len(self.meshes)

    @property
    def n_vertices(self) -> int:
        return int(self.rest_positions.shape[0])

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.meshes]

    def per_cloth_sum(self, triangle_values: np.ndarray) -> np.ndarray:
        """Sum a per-triangle ``(m, 3)`` quantity over each cloth -> ``(n_cloths, 3)``."""
        values = np.asarray(triangle_values, dtype=np.float64)
        return np.stack(
            [
                np.bincount(self.triangle_cloth, weights=values[:, k], minlength=self.n_cloths)
                for k in range(values.shape[1])
            ],
            axis=1,
        ).reshape(self.n_cloths, values.shape[1])

    def initial_state(self) -> ClothState:
        return ClothState(self.rest_positions.copy(), np.zeros_like(self.rest_positions))


@dataclass(frozen=True)
class ClothState:
    """What a solver's step takes and returns: vertex positions and velocities ``(n, 3)``,
    the frames advanced so far and the positive work done on the cloth by gravity and the
    external forces (J), which bounds its kinetic energy."""

    positions: np.ndarray
    velocities: np.ndarray
    frames: int = 0
    work_in: float = 0.0


class StaticCloth:
    """Cloth held in its rest shape: forces are computed on it but it does not move.

    ``cloth.solver=static``: for runs that want the wind alone with a fixed cloth obstacle
    (the default solver is ``xpbd``, :mod:`windbench.cloth.solver`).
    """

    @classmethod
    def check(cls, model: ClothModel, params) -> None:
        """Nothing to check: the static cloth reads no ``cloth.*`` value."""

    def __init__(self, model: ClothModel, bodies, params):
        self.model = model

    def step(self, state: ClothState, external_forces: np.ndarray, dt: float) -> ClothState:
        return state

    def mobility(self) -> np.ndarray:
        """A static cloth does not yield to the air: 0 per vertex."""
        return np.zeros(self.model.n_vertices)

    def stats(self, state: ClothState) -> dict[str, float]:
        return {}
