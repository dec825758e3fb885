"""Tiny runs for the report tests: settings and a runner that insists on completion."""

from __future__ import annotations

from pathlib import Path

from windbench.cli import compose_config
from windbench.simulate import run

TINY = ["output.snapshots=2", "output.probe_points=3", "sim.progress=false"]
WALL = ["scene=two_flags_wall", "grid.resolution=20", "sim.dt=0.05", "sim.duration=0.3"]
FRAMES = "output.frames.interval=0.1"
SHIRT = ["scene=shirt", "grid.resolution=24", "sim.duration=0.05", "output.frames.interval=0.01"]


def run_ok(folder: Path, *overrides: str):
    result = run(compose_config([*TINY, *overrides]), folder)
    assert result.status == "complete", result.failure
    return result.path
