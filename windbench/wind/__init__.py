"""Wind backends behind one interface (:class:`windbench.wind.base.WindField`).

``BACKENDS`` maps the ``wind`` config group's names to ``module:Class``; modules are
imported only when chosen, so adding a backend is one line here plus its config schema.
"""

from __future__ import annotations

import importlib

from windbench.errors import ConfigError

BACKENDS: dict[str, str] = {
    "global": "windbench.wind.global_field:GlobalWind",
    "navier_stokes": "windbench.wind.navier_stokes:NavierStokesWind",
    "particles": "windbench.wind.particles:ParticleWind",
}


def backend_class(name: str):
    if name not in BACKENDS:
        raise ConfigError("wind", f"unknown backend {name!r}; allowed {sorted(BACKENDS)}")
    module, cls = BACKENDS[name].split(":")
    return getattr(importlib.import_module(module), cls)


def make_wind(params, scene, grid):
    """Build the backend named ``params.name`` for ``scene`` on ``grid``."""
    return backend_class(params.name)(scene, grid, params)
