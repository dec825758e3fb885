"""``wind.lee_model=paper`` (the default) stays bit for bit what it was before the ``mixing``
lee model existed: SHA-256 digests of the cell wind and the live particles after a few
seconds, recorded with the code as it stood then, on a fence in a log-law wind and on an
oblique wind with a vortex around three kinds of body and a cloth sheet."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from tests.wind.particles.test_backend import BODIES, FACES
from windbench.cli import compose_config
from windbench.cloth.mesh import rectangle_triangles
from windbench.grid import Grid
from windbench.scenes import build_scene
from windbench.wind.base import Obstacles
from windbench.wind.particles import ParticleWind

SHEET_N = 9


def _sheet() -> tuple[np.ndarray, np.ndarray]:
    s = np.linspace(0.4, 1.4, SHEET_N)
    yy, zz = np.meshgrid(s, s, indexing="ij")
    verts = np.stack([np.full(SHEET_N * SHEET_N, 3.6), yy.ravel(), zz.ravel()], axis=1)
    return verts, rectangle_triangles(SHEET_N, SHEET_N)


def _fence():
    scene = build_scene(compose_config(["scene=fence"]).scene)
    return scene, 24, 0.05, 60, Obstacles.rigid_only(scene.bodies)


def _bodies_and_cloth():
    scene = build_scene(
        {
            "name": "t",
            "domain": {"min": [0, 0, 0], "max": [4, 2, 2]},
            "boundary": dict.fromkeys(FACES, "slip"),
            "sources": [
                {"type": "uniform", "velocity": [5.0, 1.0, -0.7]},
                {
                    "type": "vortex",
                    "center": [2.0, 1.0, 1.0],
                    "axis": [0.2, 0.1, 1.0],
                    "strength": 4.0,
                },
            ],
            "bodies": BODIES,
        }
    )
    verts, tris = _sheet()
    return scene, 24, 1.0 / 60.0, 40, Obstacles(scene.bodies, verts, np.zeros_like(verts), tris)


def fingerprint(make, *overrides) -> str:
    """SHA-256 of u and the live particles after the scene's steps."""
    scene, resolution, dt, steps, obstacles = make()
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    wind = ParticleWind(scene, grid, compose_config(["wind=particles", *overrides]).wind)
    for _ in range(steps):
        wind.step(dt, obstacles)
    digest = hashlib.sha256(np.ascontiguousarray(wind.velocity()).tobytes())
    for array in wind.particles:
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


PAPER = {
    "fence": (_fence, "a1d71a73ed1406a993eb646335f8955fc6979525c556b01a2c92bab6f9f1b585"),
    "bodies_and_cloth": (
        _bodies_and_cloth,
        "3427c9322ad48a3f2d875e6c8381372c54e750a381e30ce2c94a3dcd90562888",
    ),
}


@pytest.mark.parametrize("case", sorted(PAPER))
def test_paper_lee_is_unchanged_bit_for_bit(case):
    make, expected = PAPER[case]
    assert fingerprint(make) == expected
