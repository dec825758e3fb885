"""Lee-zone accuracy against a reference wind (issue 6, item 4).

``lee_error = sqrt(mean_p |u_run(p) - u_ref(p)|^2) / U_free`` over the probe points ``p`` of
the scene's ``lee`` box that both runs share, at each run's last wind snapshot; ``U_free`` is
the scene's nominal free-stream speed, its ``reference_speed`` (the fastest source's speed
unless the scene sets it; the same U_ref that scales the divergence figures). The measured
speed in the ``free_stream`` box is not used: where flows meet (``opposing_sources``) the
Navier-Stokes air there can all but stop, and dividing by it would blow the error up. The probe lattice depends only on the scene and
``output.probe_points``, not on the grid, so runs at different resolutions and with different
backends compare point by point.

The reference of a scene is the finest ``navier_stokes`` run of that scene among the inputs
(highest resolution, then smallest time step, then lowest seed), or the finest run of that
scene found under ``--reference`` (again preferring ``navier_stokes``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from windbench.report.collect import RunRecord

REFERENCE_BACKEND = "navier_stokes"
POINT_DECIMALS = 9  # probe points match when equal to 1 nm


def _finest_key(rec: RunRecord):
    s = rec.settings
    return (
        -int(s.get("resolution") or 0),
        float(s.get("dt") or math.inf),
        int(s.get("seed") or 0),
        str(rec.path),
    )


def _finest_per_scene(pool: Sequence[RunRecord], only_ns: bool) -> dict[str, RunRecord]:
    pool = [r for r in pool if r.status == "complete" and r.lee_points is not None]
    refs: dict[str, RunRecord] = {}
    for scene in sorted({str(r.settings.get("scene")) for r in pool}):
        here = [r for r in pool if str(r.settings.get("scene")) == scene]
        ns = [r for r in here if r.settings.get("wind") == REFERENCE_BACKEND]
        if ns or not only_ns:
            refs[scene] = min(ns or here, key=_finest_key)
    return refs


def choose_references(
    records: Sequence[RunRecord], reference_records: Sequence[RunRecord] | None = None
) -> dict[str, RunRecord]:
    """scene -> reference run (see module docstring); scenes without one are absent.

    Runs under ``--reference`` win for their scenes; other scenes keep the finest
    ``navier_stokes`` run among the inputs.
    """
    refs = _finest_per_scene(records, only_ns=True)
    if reference_records is not None:
        refs.update(_finest_per_scene(reference_records, only_ns=False))
    return refs


def lee_error(run: RunRecord, ref: RunRecord) -> float:
    """RMS over common lee probe points of |u_run - u_ref|, divided by the free-stream speed."""
    if run.lee_points is None or ref.lee_points is None or len(ref.lee_points) == 0:
        return math.nan
    index = {tuple(p): i for i, p in enumerate(np.round(ref.lee_points, POINT_DECIMALS))}
    pairs = [
        (i, index[tuple(p)])
        for i, p in enumerate(np.round(run.lee_points, POINT_DECIMALS))
        if tuple(p) in index
    ]
    if not pairs:
        return math.nan
    mine, theirs = np.asarray(pairs).T
    diff = run.lee_wind[mine] - ref.lee_wind[theirs]
    u_free = ref.reference_speed
    if not (u_free > 0):
        u_free = ref.free_stream_speed  # a dataset without the attribute
    if not (u_free > 0):
        return math.nan
    return float(np.sqrt(np.mean(np.sum(diff * diff, axis=1))) / u_free)


def assign_lee_errors(records: Sequence[RunRecord], refs: dict[str, RunRecord]) -> None:
    """Store ``lee_error`` (and the reference's path) in each readable record's figures."""
    for rec in records:
        if not rec.figures:
            continue
        ref = refs.get(rec.settings.get("scene"))
        rec.figures["lee_error"] = lee_error(rec, ref) if ref is not None else math.nan
        rec.figures["is_reference"] = bool(ref is not None and ref.path == rec.path)
