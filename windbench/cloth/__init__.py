"""Cloth meshes and cloth solvers.

``SOLVERS`` maps ``cloth.solver`` names to ``module:Class``; a solver is built as
``Solver(model, bodies, params)`` and advances with ``step(state, forces, dt) -> state``;
``Solver.check(model, params)`` raises ConfigError for bad settings without building it.
"""

from __future__ import annotations

import importlib

from windbench.errors import ConfigError

SOLVERS: dict[str, str] = {
    "static": "windbench.cloth.model:StaticCloth",
    "xpbd": "windbench.cloth.solver:XPBDCloth",
}


def solver_class(params):
    """The class ``cloth.solver`` names; ConfigError listing the known ones otherwise."""
    name = params.solver
    if name not in SOLVERS:
        raise ConfigError("cloth.solver", f"unknown solver {name!r}; allowed {sorted(SOLVERS)}")
    module, cls = SOLVERS[name].split(":")
    return getattr(importlib.import_module(module), cls)


def check_cloth_solver(params, model) -> None:
    """ConfigError for an unknown solver, a bad ``cloth.*`` value or material (no build)."""
    solver_class(params).check(model, params)


def make_cloth_solver(params, model, bodies):
    """Build the solver ``cloth.solver`` names for the cloths of ``model`` and ``bodies``."""
    return solver_class(params)(model, bodies, params)
