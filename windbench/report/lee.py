"""Lee-zone accuracy against a converged reference wind, with the reference's own error.

``lee_error = sqrt(mean_p |u_run(p) - u_ref(p)|^2) / U_ref`` over the probe points ``p`` of
the scene's ``lee`` box that both runs share, with each run's probe wind averaged over its
steady window (``probe_wind_mean``); U_ref is the scene's ``reference_speed`` (the same
speed that scales the divergence figures). The probe lattice depends only on the scene
and ``output.probe_points``, so runs at any resolution and of any backend compare point by
point.

The reference of a scene is its finest ``navier_stokes`` run with the second-order scheme
(``wind.advection=second_order``; another scheme only where none exists) among the runs
under ``--reference``, or else among the compared runs. Its uncertainty comes from the
coarser runs of the same configuration (the grid-convergence index of Roache 1994, as in
Celik et al. 2008): with e21 the lee difference between the two finest levels and r their
resolution ratio,

    GCI = F_s e21 / (r^p - 1),

p the order observed over three levels (ln(e32 / e21) / ln r, F_s = 1.25) or the scheme's
formal order 2 with two levels (F_s = 3). A reference whose GCI exceeds the smallest
error it ranks is flagged as not converged.

A time mean over a finite window of a fluctuating wake is itself uncertain. With s_p the
standard error of a run's window mean at probe p (batch means over the window's blocks,
``probe_wind_block_mean``, :func:`time_mean_error`), two runs whose true means differ by
d_p give E[lee_error^2] = mean_p |d_p|^2 / U_ref^2 + noise^2, with the sampling noise

    noise = sqrt(mean_p (|s_run,p|^2 + |s_ref,p|^2)) / U_ref

(``lee_noise`` per run, the reference's e21 beside its own): an error or an e21 not well
above its noise is sampling, not model or grid, and a longer window lowers it as
1 / sqrt(window).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from windbench.report.collect import RunRecord

REFERENCE_BACKEND = "navier_stokes"
REFERENCE_SCHEME = "second_order"
FORMAL_ORDER = 2.0
SAFETY_TWO_LEVELS, SAFETY_THREE_LEVELS = 3.0, 1.25
POINT_DECIMALS = 9  # probe points match when equal to 1 nm
LEVEL_KEYS = ("wind.advection", "wind.turbulence", "wind.coupling", "seed")


@dataclass
class Reference:
    """A scene's reference run, its coarser levels and its own uncertainty."""

    scene: str
    run: RunRecord
    levels: list[RunRecord] = field(default_factory=list)  # finest first, the run included
    difference: float = math.nan  # e21: lee difference of the two finest levels / U_ref
    order: float = math.nan  # p used in the GCI
    observed: bool = False  # p observed over three levels (else the formal order)
    gci: float = math.nan  # uncertainty of the reference, fraction of U_ref
    noise: float = math.nan  # sampling noise of e21 (module docstring)
    converged: bool | None = None  # GCI below the smallest error it ranks

    @property
    def path(self):
        return self.run.path


def _resolution(rec: RunRecord) -> int:
    return int(rec.settings.get("resolution") or 0)


def _finest_key(rec: RunRecord):
    s = rec.settings
    return (
        -_resolution(rec),
        float(s.get("dt") or math.inf),
        int(s.get("seed") or 0),
        str(rec.path),
    )


def _candidates(pool: Sequence[RunRecord], scene: str) -> list[RunRecord]:
    return [
        r
        for r in pool
        if r.status == "complete" and r.lee_points is not None and r.settings.get("scene") == scene
    ]


def _pick(here: Sequence[RunRecord], only_ns: bool) -> RunRecord | None:
    ns = [r for r in here if r.settings.get("wind") == REFERENCE_BACKEND]
    second = [r for r in ns if r.config.get("wind.advection") == REFERENCE_SCHEME]
    chosen = second or ns or ([] if only_ns else list(here))
    return min(chosen, key=_finest_key) if chosen else None


def _levels(ref: RunRecord, here: Sequence[RunRecord]) -> list[RunRecord]:
    """The reference and its coarser runs of the same configuration, one per resolution
    (the smallest time step of each), finest first."""
    same = [
        r
        for r in here
        if r.settings.get("wind") == ref.settings.get("wind")
        and all(r.config.get(k) == ref.config.get(k) for k in LEVEL_KEYS)
        and _resolution(r) < _resolution(ref)
    ]
    by_res: dict[int, RunRecord] = {}
    for r in sorted(same, key=_finest_key):
        by_res.setdefault(_resolution(r), r)
    return [ref, *(by_res[k] for k in sorted(by_res, reverse=True))]


def grid_convergence(levels: Sequence[RunRecord]) -> tuple[float, float, bool, float]:
    """(e21, p, observed, GCI) of the finest level (module docstring); NaNs with one level."""
    if len(levels) < 2:
        return math.nan, math.nan, False, math.nan
    r21 = _resolution(levels[0]) / _resolution(levels[1])
    e21 = lee_error(levels[1], levels[0])
    order, observed, safety = FORMAL_ORDER, False, SAFETY_TWO_LEVELS
    if len(levels) >= 3 and e21 > 0:
        e32 = lee_error(levels[2], levels[1])
        r32 = _resolution(levels[1]) / _resolution(levels[2])
        if e32 > e21 and abs(r32 - r21) < 1e-9:
            order, observed, safety = math.log(e32 / e21) / math.log(r21), True, SAFETY_THREE_LEVELS
    return e21, order, observed, safety * e21 / (r21**order - 1.0)


def choose_references(
    records: Sequence[RunRecord], reference_records: Sequence[RunRecord] | None = None
) -> dict[str, Reference]:
    """scene -> :class:`Reference` (module docstring); scenes without one are absent."""
    scenes = {str(r.settings.get("scene")) for r in [*records, *(reference_records or [])]}
    refs: dict[str, Reference] = {}
    for scene in sorted(scenes):
        given = _candidates(reference_records or [], scene)
        here = given or _candidates(records, scene)
        run = _pick(here, only_ns=not given)
        if run is None:
            continue
        levels = _levels(run, here)
        e21, order, observed, gci = grid_convergence(levels)
        noise = sampling_noise(levels[1], levels[0]) if len(levels) > 1 else math.nan
        refs[scene] = Reference(scene, run, levels, e21, order, observed, gci, noise)
    return refs


def _matched(run: RunRecord, ref: RunRecord):
    """(run's indices, reference's indices, U_ref) of the lee probe points both share, or
    None when there are none or no reference speed."""
    if run.lee_points is None or ref.lee_points is None or len(ref.lee_points) == 0:
        return None
    index = {tuple(p): i for i, p in enumerate(np.round(ref.lee_points, POINT_DECIMALS))}
    pairs = [
        (i, index[tuple(p)])
        for i, p in enumerate(np.round(run.lee_points, POINT_DECIMALS))
        if tuple(p) in index
    ]
    u_free = ref.reference_speed
    if not (u_free > 0):
        u_free = ref.free_stream_speed  # a dataset without the attribute
    if not pairs or not (u_free > 0):
        return None
    mine, theirs = np.asarray(pairs).T
    return mine, theirs, u_free


def _squared_differences(run: RunRecord, ref: RunRecord):
    """(run's indices, reference's indices, U_ref, |u_run - u_ref|^2 per common lee probe
    point) of :func:`_matched`, or None."""
    matched = _matched(run, ref)
    if matched is None:
        return None
    mine, theirs, u_free = matched
    diff = run.lee_wind[mine] - ref.lee_wind[theirs]
    return mine, theirs, u_free, np.sum(diff * diff, axis=1)


def lee_error(run: RunRecord, ref: RunRecord) -> float:
    """RMS over common lee probe points of |u_run - u_ref|, divided by the reference speed."""
    found = _squared_differences(run, ref)
    if found is None:
        return math.nan
    _, _, u_free, squared = found
    return float(np.sqrt(np.mean(squared)) / u_free)


def lee_error_by_height(run: RunRecord, ref: RunRecord) -> list[tuple[float, ...]]:
    """Where in the lee box a lee error comes from: per probe height z (m) of the common
    lee points, (z, the run's mean wind along x there, the reference's (m/s), that
    height's part of lee_error^2). The parts sum to ``lee_error(run, ref)**2``."""
    found = _squared_differences(run, ref)
    if found is None:
        return []
    mine, theirs, u_free, squared = found
    u_run, u_ref = run.lee_wind[mine, 0], ref.lee_wind[theirs, 0]
    part = squared / (u_free * u_free * len(mine))
    z = np.round(ref.lee_points[theirs, 2], POINT_DECIMALS)
    return [
        (float(h), float(u_run[z == h].mean()), float(u_ref[z == h].mean()))
        + (float(part[z == h].sum()),)
        for h in np.unique(z)
    ]


def time_mean_error(block_means: np.ndarray) -> np.ndarray:
    """Standard error of a window mean from the means of its B equal consecutive blocks
    (axis 0), the batch-means estimate s = std(block means, ddof 1) / sqrt(B): unbiased
    when a block is long against the flow's correlation time, too small when it is not."""
    blocks = block_means.shape[0]
    return block_means.std(axis=0, ddof=1) / math.sqrt(blocks)


def sampling_noise(run: RunRecord, ref: RunRecord) -> float:
    """The sampling noise of ``lee_error(run, ref)`` (module docstring): 0 for the
    reference itself, NaN when either dataset has no window blocks."""
    matched = _matched(run, ref)
    if matched is None or run.lee_block_wind is None or ref.lee_block_wind is None:
        return math.nan
    if run.path == ref.path:
        return 0.0
    mine, theirs, u_free = matched
    s_run = time_mean_error(run.lee_block_wind)[mine]
    s_ref = time_mean_error(ref.lee_block_wind)[theirs]
    return float(np.sqrt(np.mean(np.sum(s_run**2 + s_ref**2, axis=1))) / u_free)


def beyond_noise(error: float, noise: float) -> float:
    """sqrt(max(error^2 - noise^2, 0)): the part of a lee difference its sampling noise
    does not explain (module docstring; an estimate, as uncertain as the noise)."""
    return math.sqrt(max(error * error - noise * noise, 0.0))


def assign_lee_errors(records: Sequence[RunRecord], refs: dict[str, Reference]) -> None:
    """Store ``lee_error`` and the reference's role in each readable record's figures, and
    decide whether each reference is converged against the errors it ranks."""
    for rec in records:
        if not rec.figures:
            continue
        ref = refs.get(rec.settings.get("scene"))
        rec.figures["lee_error"] = lee_error(rec, ref.run) if ref is not None else math.nan
        rec.figures["lee_noise"] = sampling_noise(rec, ref.run) if ref is not None else math.nan
        rec.figures["is_reference"] = bool(ref is not None and ref.path == rec.path)
        rec.figures["reference_level"] = bool(
            ref is not None and any(r.path == rec.path for r in ref.levels)
        )
    for ref in refs.values():
        ranked = [
            r.figures["lee_error"]
            for r in records
            if r.status == "complete"
            and r.settings.get("scene") == ref.scene
            and not r.figures.get("reference_level")
            and np.isfinite(r.figures.get("lee_error", math.nan))
        ]
        if ranked and np.isfinite(ref.gci):
            ref.converged = bool(ref.gci <= min(ranked))
