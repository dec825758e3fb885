"""Two-way coupling through pressure (``wind.coupling=projection``) measured.

- ``plate``: the drag coefficient ``F_x / (1/2 rho U^2 A)`` of a static 1 m square plate
  normal to a uniform 2 m/s wind in an 8 x 4 x 4 m channel (6 % blockage) after 2.5 s, at
  32, 48 and 64 cells along the channel, with the runs' default eddy viscosity
  (``mixing_length``; Hoerner: 1.17 for a free plate): of the force the cloth feels
  (``drag_coefficient``: the pressure jump and the §3 law on the air at the plate,
  ``aero.subgrid_law``) and of the jump alone (``jump_drag_coefficient``);
- ``two_flags_wall``: the scene at 32 and 64 cells (``--resolutions``) in a developed
  flow (the scene's automatic spin-up, two flow-through times, then 4 s recorded) at dt
  1/60 and 0.01 (``--dts``), ``paper`` and ``projection`` coupling and ``none`` (one-way:
  the §3 law in the wake the wall alone makes): whether it completes, each flag's mean |F|
  over the recorded steps, the sheltered-to-exposed force ratio, and each flag's mean
  force along the wind (``*_force_x``, N: negative where the flag is drawn upstream, as
  the sheltered flag is toward the wall by the reversed flow and low pressure of the
  wall's near wake).

    PYTHONPATH=$PWD python experiments/projection_coupling.py [--flags-only] [--out F]
        [--resolutions 32 64] [--dts 0.016666666666666666 0.01] [key=value ...]

writes ``experiments/results/projection_coupling.csv``; ``key=value`` overrides go to the
flag runs (e.g. ``cloth.self_collision=true``). The force ratio's uncertainty: its spread
over BLOCKS equal blocks of the recorded steps (standard error of the block ratios' mean),
since the sheltered flag's force is a small mean of a fluctuating wake.
"""

from __future__ import annotations

import argparse
import csv
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # before numba is imported
from pathlib import Path

import numpy as np

from experiments.validation_ns.problems import backend
from windbench.aero import cloth_forces
from windbench.cli import compose_config
from windbench.cloth.mesh import flag_mesh
from windbench.config import AeroConfig
from windbench.errors import SimulationDiverged
from windbench.simulate import Simulation, prepare
from windbench.wind.base import Obstacles

OUT = Path(__file__).resolve().parent / "results" / "projection_coupling.csv"
BLOCKS = 4  # blocks of the recorded steps for the force ratio's standard error
U = 2.0  # m/s
CHANNEL = {
    "name": "channel",
    "domain": {"min": [0.0, 0.0, 0.0], "max": [8.0, 4.0, 4.0]},
    "boundary": dict(
        x_min="inflow", x_max="outflow", y_min="slip", y_max="slip", z_min="slip", z_max="slip"
    ),
    "sources": [{"type": "uniform", "velocity": [U, 0.0, 0.0]}],
    "reference_speed": U,
}


def plate_drag(resolution: int, duration: float = 2.5) -> dict:
    """The static plate's drag coefficient at ``resolution`` cells along the channel."""
    wind = backend(CHANNEL, resolution, coupling="projection", turbulence="mixing_length")
    mesh = flag_mesh(
        {
            "name": "plate",
            "type": "flag",
            "origin": [3.0, 1.5, 1.5],
            "size": [1.0, 1.0],
            "resolution": [8, 8],
            "u_axis": [0.0, 1.0, 0.0],
            "v_axis": [0.0, 0.0, 1.0],
        },
        "plate",
    )
    plate = Obstacles((), mesh.vertices, np.zeros_like(mesh.vertices), mesh.triangles)
    dt = 0.5 * wind.h / U
    for _ in range(int(round(duration / dt))):
        wind.step(dt, plate)
    loads = wind.cloth_pressure_loads()
    air = AeroConfig()
    at_plate = wind.sample(plate.cloth_positions)
    still = (plate.cloth_positions, plate.cloth_velocities)
    total = cloth_forces(*still, at_plate, plate.cloth_triangles, loads, air)[0].sum(axis=0)
    return {
        "case": "plate",
        "resolution": resolution,
        "drag_coefficient": total[0] / (0.5 * air.air_density * U**2),
        "jump_drag_coefficient": loads.sum(axis=0)[0] / (0.5 * U**2),
    }


def flags(coupling: str, dt: float, resolution: int, extra: list[str]) -> dict:
    """two_flags_wall at ``resolution`` cells with ``coupling`` at ``dt`` (and the
    overrides ``extra``), 4 s after the spin-up."""
    cfg = compose_config(
        [
            "scene=two_flags_wall",
            "wind=navier_stokes",
            f"wind.coupling={coupling}",
            f"grid.resolution={resolution}",
            f"sim.dt={dt}",
            "sim.duration=4.0",
            "sim.spinup=auto",
            "sim.progress=false",
            *extra,
        ]
    )
    sim = Simulation(prepare(cfg))
    steps = sim.setup.spinup_steps + sim.setup.n_steps
    status = "complete"
    try:
        for n in range(steps):
            sim.step(n)
    except SimulationDiverged:
        status = "diverged"
    vectors = np.asarray(sim.recorder.rows["aero_force"])  # (steps, flags, 3)
    force = np.linalg.norm(vectors, axis=-1)
    late = force.mean(axis=0)  # the recorded steps: after the spin-up
    along = vectors[..., 0].mean(axis=0)
    blocks = [b.mean(axis=0) for b in np.array_split(force, BLOCKS)]
    ratios = np.array([b[1] / b[0] for b in blocks])
    return {
        "case": f"two_flags_wall_{coupling}",
        "resolution": resolution,
        "dt": dt,
        "status": status,
        "steps": force.shape[0],
        "exposed_force": late[0],
        "sheltered_force": late[1],
        "force_ratio": late[1] / late[0],
        "force_ratio_sem": float(ratios.std(ddof=1) / np.sqrt(BLOCKS)),
        "exposed_force_x": along[0],
        "sheltered_force_x": along[1],
        "overrides": " ".join(extra),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--flags-only", action="store_true", help="no plate runs")
    parser.add_argument("--resolutions", type=int, nargs="+", default=[32, 64])
    parser.add_argument("--dts", type=float, nargs="+", default=[1.0 / 60.0, 0.01])
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("overrides", nargs="*", help="key=value for the flag runs")
    args = parser.parse_args()
    rows = [] if args.flags_only else [plate_drag(n) for n in (32, 48, 64)]
    rows += [
        flags(c, dt, n, args.overrides)
        for n in args.resolutions
        for dt in args.dts
        for c in ("paper", "projection", "none")
    ]
    keys = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    for row in rows:
        print(row)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
