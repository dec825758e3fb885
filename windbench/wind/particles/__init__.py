"""Backend ``particles``: particle tracing on flow primitives, with lee (paper §4.2.2).

:mod:`.emission` makes each source's gust particles, :mod:`.tracing` moves them, finds
their hits and marks the cells they reach; :mod:`.backend` holds the config schema and the
:class:`ParticleWind` that turns the marks into a wind field.
"""

from windbench.wind.particles.backend import SORT_EVERY, ParticleConfig, ParticleWind

__all__ = ["SORT_EVERY", "ParticleConfig", "ParticleWind"]
