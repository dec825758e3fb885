"""Tiny runs that keep animation frames, and the report built from them (shared by
test_media.py and the browser test)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.report.tiny_runs import FRAMES, SHIRT, WALL, run_ok


@pytest.fixture(scope="session")
def frame_runs(tmp_path_factory) -> Path:
    """Runs that keep frames: two_flags_wall with particles and global, a shirt (global)."""
    root = tmp_path_factory.mktemp("frames")
    run_ok(  # the gust front crossing the domain: no spin-up, cells of 0.5 m
        root / "wall_particles",
        *WALL,
        "wind=particles",
        FRAMES,
        "sim.spinup=0",
        "grid.resolution=32",
    )
    run_ok(root / "wall_global", *WALL, "wind=global", FRAMES)
    run_ok(root / "shirt_global", *SHIRT, "wind=global")
    return root


@pytest.fixture(scope="session")
def media_report(frame_runs, tmp_path_factory):
    from windbench.report import build_report

    out = tmp_path_factory.mktemp("media") / "rep"
    return build_report([frame_runs], out=out, progress=False)
