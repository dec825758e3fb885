"""The rough ground's wall law (:mod:`windbench.wind.navier_stokes.wall_law`) against the
log law it stands for: at the log-law wind of the first cell centre its stress is u_*^2 at
any grid spacing; its step is the implicit drag in closed form; over a flat rough ground
the log-law inflow keeps its profile down the domain, which a no-slip floor does not."""

from __future__ import annotations

import math

import numpy as np
import pytest
from omegaconf import OmegaConf

from windbench.cli import compose_config
from windbench.errors import ConfigError
from windbench.grid import Grid
from windbench.scenes import build_scene
from windbench.wind import make_wind
from windbench.wind.base import Obstacles
from windbench.wind.navier_stokes import wall_law
from windbench.wind.navier_stokes.boundaries import padded_shape
from windbench.wind.primitives import superpose
from windbench.wind.surface_layer import KARMAN

Z0, Z_REF, U_REF = 0.1, 10.0, 6.0  # the fence scene's log profile (conf/scene/fence.yaml)
USTAR = KARMAN * U_REF / math.log(Z_REF / Z0)


def _flat_scene(ground: str, domain=(24.0, 0.25, 10.0)):
    """The fence scene without its fence, probes and wake lattice, on ``ground``."""
    spec = OmegaConf.to_container(compose_config(["scene=fence"]).scene, resolve=True)
    spec.update(domain={"min": [0, 0, 0], "max": list(domain)}, bodies=[], probes={}, wake=None)
    spec["boundary"]["z_min"] = ground
    return build_scene(spec)


@pytest.mark.parametrize("h", [1.0, 0.5, 0.25, 0.21])
def test_at_the_log_law_wind_the_stress_is_ustar_squared_at_any_spacing(h):
    scene = _flat_scene("rough")
    z1 = 0.5 * h
    u1 = superpose(scene.sources, np.array([[1.0, 0.1, z1]]))[0, 0]
    assert u1 == pytest.approx(USTAR / KARMAN * math.log(z1 / Z0), rel=1e-12)
    assert wall_law.drag_coefficient(scene, 0.0, h) * u1 * u1 == pytest.approx(USTAR**2, rel=1e-12)


def test_a_first_cell_centre_within_the_roughness_is_refused():
    with pytest.raises(ConfigError, match="grid.resolution.*coarser"):
        wall_law.drag_coefficient(_flat_scene("rough"), 0.0, 2 * Z0)


@pytest.mark.parametrize(
    ("face", "sources", "match"),
    [
        ("x_max", None, "scene.boundary.x_max: rough is the ground's kind"),
        ("z_min", [{"type": "uniform", "velocity": [6.0, 0.0, 0.0]}], "none has one"),
    ],
)
def test_a_rough_face_needs_the_ground_and_a_log_profile(face, sources, match):
    spec = OmegaConf.to_container(compose_config(["scene=fence"]).scene, resolve=True)
    spec["boundary"][face] = "rough"
    if sources is not None:
        spec["sources"] = sources
    with pytest.raises(ConfigError, match=match):
        build_scene(spec)


def test_the_step_is_the_implicit_drag_of_the_first_layer():
    """u_1 <- u_1 / (1 + rate |U_1|) on free faces of the first layer, from the old values
    of both components; every other face as it was."""
    cells = (4, 3, 5)
    u, v = np.zeros(padded_shape(cells, 0)), np.zeros(padded_shape(cells, 1))
    u[...], v[...] = 3.0, 4.0  # |U| = 5 everywhere
    free_u, free_v = np.ones(u.shape, np.uint8), np.ones(v.shape, np.uint8)
    free_u[2, 2, wall_law.FIRST] = 0
    rate = 0.1
    wall_law.floor_drag(u, v, free_u, free_v, rate, np.zeros(u.shape[:2]))
    first, inner = (slice(1, -1), slice(1, -1), wall_law.FIRST), (Ellipsis, slice(2, None))
    expected_u = np.full(u[first].shape, 3.0 / (1.0 + rate * 5.0))
    expected_u[1, 1] = 3.0  # the face that is not free
    np.testing.assert_allclose(u[first], expected_u, rtol=1e-15)
    np.testing.assert_allclose(v[first], 4.0 / (1.0 + rate * 5.0), rtol=1e-15)
    assert np.all(u[inner] == 3.0) and np.all(v[inner] == 4.0)


def _outlet_and_inflow(ground: str, resolution: int = 96, seconds: float = 5.0):
    """The lowest layers' u at the last cell column after ``seconds`` of a flat channel,
    and the inflow's log law at the same heights."""
    scene = _flat_scene(ground)
    grid = Grid.from_domain(scene.lower, scene.upper, resolution)
    cfg = compose_config(["wind=navier_stokes", "scene=fence"])
    wind = make_wind(cfg.wind, scene, grid)
    for _ in range(int(round(seconds / 0.05))):
        wind.step(0.05, Obstacles.rigid_only(()))
    z = grid.axes()[2][:4]
    law = superpose(scene.sources, np.stack([np.full(4, 1.0), np.full(4, 0.1), z], axis=1))
    return wind.velocity()[-1, :, :4, 0].mean(axis=0), law[:, 0]


def test_over_a_rough_ground_the_log_law_inflow_keeps_its_profile():
    """A flat channel 24 m long at h = 0.25 m (z_1 = 0.125 m, just above z_0 = 0.1 m): on
    the rough ground the four lowest layers at the outlet keep the inflow's log law within
    5 %; on a no-slip floor, whose stress there is 0.22 u_*^2, the first layer speeds up
    to over three times it."""
    rough, law = _outlet_and_inflow("rough")
    np.testing.assert_allclose(rough, law, rtol=0.05)
    smooth, _ = _outlet_and_inflow("no_slip")
    assert smooth[0] > 3.0 * law[0]
