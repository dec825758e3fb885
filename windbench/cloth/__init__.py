"""Cloth meshes and cloth solvers.

``SOLVERS`` maps ``cloth.solver`` names to ``module:Class``; a solver is built as
``Solver(model, bodies, params)`` and advances with ``step(state, forces, dt) -> state``.
"""

from __future__ import annotations

import importlib

from windbench.errors import ConfigError

SOLVERS: dict[str, str] = {
    "static": "windbench.cloth.model:StaticCloth",
    "xpbd": "windbench.cloth.solver:XPBDCloth",
}


def make_cloth_solver(params, model, bodies):
    name = params.solver
    if name not in SOLVERS:
        raise ConfigError("cloth.solver", f"unknown solver {name!r}; allowed {sorted(SOLVERS)}")
    module, cls = SOLVERS[name].split(":")
    return getattr(importlib.import_module(module), cls)(model, bodies, params)
