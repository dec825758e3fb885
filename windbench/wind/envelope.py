"""Time-varying wind of the ``global`` and ``navier_stokes`` backends: each source's time
envelope (``gusts``) and seeded turbulent fluctuation (``turbulence``).

A scene source's ``gusts: {on, off, start}`` entry is the schedule the particle backend
emits by (:class:`~windbench.wind.particles.emission.GustSchedule`: on during
``[start + k (on + off), start + k (on + off) + on)``, k >= 0, off before ``start``); here
it switches the source's own wind on and off, ``e_i(t)`` in {0, 1}:

    w(x, t) = sum_i e_i(t) (w_i(x) + f_i(z) u'_i(x, t)),

u'_i the frozen turbulence of a uniform source with ``turbulence: {intensity,
length_scale}`` (:class:`~windbench.wind.fluctuation.Fluctuation`: von Karman spectrum,
each component's standard deviation ``intensity x |U|``, seeded by ``wind.seed + i``),
scaled by its inflow profile f_i. The ``global`` field applies this to the whole
superposed field; ``navier_stokes`` to the wind it lets in at its inflow faces, from which
the air carries it on; the particles gust through their emission. The same scene and seed
so give the same inflow in all three.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from windbench.wind.fluctuation import Fluctuation
from windbench.wind.particles.emission import GustSchedule, gust_schedule
from windbench.wind.primitives import Primitive, profile_scale, superpose


def envelope_factor(schedule: GustSchedule, t: float) -> float:
    """e(t): 1 while the schedule is on at time t, else 0 (always 1 without gusts)."""
    if not np.isfinite(schedule.on):
        return 1.0
    if t < schedule.start:
        return 0.0
    return 1.0 if (t - schedule.start) % (schedule.on + schedule.off) < schedule.on else 0.0


@dataclass(frozen=True)
class SourceTimes:
    """Model of the time variation of a scene's sources: per source its gust schedule and
    its fluctuation (None: none)."""

    sources: tuple[Primitive, ...]
    schedules: tuple[GustSchedule, ...]
    fluctuations: tuple[Fluctuation | None, ...]

    @classmethod
    def build(cls, scene, seed: int) -> SourceTimes:
        """From the scene's sources and their raw entries (the ``gusts`` keys); checked."""
        schedules = tuple(
            gust_schedule(spec.get("gusts"), f"scene.sources[{i}].gusts")
            for i, spec in enumerate(scene.source_specs)
        )
        fluctuations = tuple(
            Fluctuation.build(*s.turbulence, s.velocity, int(seed) + i) if s.turbulence else None
            for i, s in enumerate(scene.sources)
        )
        return cls(tuple(scene.sources), schedules, fluctuations)

    @property
    def gusty(self) -> bool:
        """Whether any source has gusts."""
        return any(np.isfinite(s.on) for s in self.schedules)

    @property
    def varies(self) -> bool:
        """Whether any source has gusts or a fluctuation."""
        return self.gusty or any(f is not None for f in self.fluctuations)

    def factors(self, t: float) -> np.ndarray:
        """e_i(t) of every source."""
        return np.array([envelope_factor(s, t) for s in self.schedules])

    def wind(self, points, t: float, chosen: Sequence[int] | None = None) -> np.ndarray:
        """sum_i e_i(t) (w_i + f_i u'_i) at world points ``(n, 3)`` over the sources
        ``chosen`` (indices; default all)."""
        pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
        out = np.zeros_like(pts)
        e = self.factors(t)
        for i in range(len(self.sources)) if chosen is None else chosen:
            if e[i] == 0.0:
                continue
            out += e[i] * superpose([self.sources[i]], pts)
            if self.fluctuations[i] is not None:
                scale = profile_scale(self.sources[i], pts)[:, None]
                out += e[i] * self.fluctuations[i](pts, t) * scale
        return out
