"""Backend ``navier_stokes``: stable fluids (paper §4.1) two-way coupled with cloth.

One module per operator: :mod:`.advection`, :mod:`.diffusion`, :mod:`.forcing`,
:mod:`.projection` (with the Poisson solver in :mod:`.multigrid` and
:mod:`.coarse_levels`), :mod:`.boundaries` and :mod:`.coupling`; :mod:`.backend` holds the
config schema and the :class:`NavierStokesWind` that runs them in the paper's order.
"""

from windbench.wind.navier_stokes.backend import NavierStokesConfig, NavierStokesWind

__all__ = ["NavierStokesConfig", "NavierStokesWind"]
