"""Wind backends behind one interface (:class:`windbench.wind.base.WindField`).

Each backend registers itself with its config schema (:mod:`windbench.wind.registry`);
:func:`make_wind` builds the one a run's ``wind`` config names.
"""

from __future__ import annotations

from windbench.wind.registry import (
    WindConfig,
    backends,
    discover,
    get_backend,
    register_backend,
)

__all__ = ["WindConfig", "backend_class", "backends", "discover", "make_wind", "register_backend"]


def backend_class(name: str):
    """The WindField class registered as ``name`` (ConfigError if there is none)."""
    return get_backend(name).cls


def make_wind(params, scene, grid):
    """Build the backend named ``params.name`` for ``scene`` on ``grid``."""
    return backend_class(params.name)(scene, grid, params)
