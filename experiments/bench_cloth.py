"""Speed of the coupled cloth step: frames per second of the flag scene at three resolutions.

Targets, per 1/60 s frame including wind sampling, aerodynamics (paper §3) and
body collisions: a 40 x 25 flag >= 300 frames/s, a 64 x 64 cloth >= 60, a 100 x 60 flag
>= 30. Each case runs the real loop (``windbench.simulate.Simulation``, ``wind=global``,
``scene=flag`` with ``scene.cloths.0.resolution=[nu,nv]``) for a few warm-up frames
(numba compiles, cached) and then ``--frames`` timed frames; the figures are the median
and the best of the loop's own ``step_seconds`` phases (wind, aero, cloth, total; the
cloth's contacts, bodies and self-collision, as ``ms_contacts``, part of ``ms_cloth``).

    PYTHONPATH=$PWD python experiments/bench_cloth.py [--frames 120] [--substeps 16] [key=value ...]

writes ``experiments/results/bench_cloth.csv`` (one row per case); ``--shirt`` times the
``shirt`` scene instead (the one-piece garment on the mesh character, ``global`` and
``particles`` wind, target 30 frames/s) into ``bench_shirt.csv``, with the cost of one
body distance query and, over the timed frames, the largest stretch and fraction of edges
beyond the strain limit.
With ``--stretch`` it
records instead how far the stiff membrane stretches at the three sizes (target: under 5%):
the flag hanging from its pole in still air (``scene.sources=[]``; the largest warp/weft
edge strain at the end of 4 s and its maximum over the last 2 s) and in its 6 m/s wind
(the median and the maximum of the largest edge strain over 0.5-4 s), into
``experiments/results/stretch_cloth.csv``; e.g. ``--stretch cloth.threads=false`` gives
the edge-by-edge sweep.

The machine is shared: besides wall time (the loop's ``step_seconds``) each frame's CPU
time of this process is recorded (``time.process_time``), which is what the frame costs
on an idle core: ``ms_cpu_median`` for the whole ``Simulation.step`` (which also records
the step's figures: wind divergence, probes, cloth statistics; ``step_seconds`` leaves
that out) and ``ms_cpu_cloth`` for the cloth solver alone; the 1-minute load average is
written beside them. numba runs with one
thread unless NUMBA_NUM_THREADS is set (threads that wait for a busy core cost far more
than they gain on two shared cores).
"""

from __future__ import annotations

import argparse
import csv
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # before numba is imported
import platform
import time
from pathlib import Path

import numpy as np

from experiments.rows import measured_at
from windbench.cli import compose_config
from windbench.simulate import Simulation, prepare

CASES = (
    ("flag_40x25", (40, 25), 300.0),
    ("cloth_64x64", (64, 64), 60.0),
    ("flag_100x60", (100, 60), 30.0),
)
OUT = Path(__file__).resolve().parent / "results" / "bench_cloth.csv"
STRETCH_OUT = OUT.with_name("stretch_cloth.csv")
SHIRT_OUT = OUT.with_name("bench_shirt.csv")
STRETCH_FRAMES = 240  # 4 s


def flag_simulation(resolution, frames: int, still: bool, extra: list[str]) -> Simulation:
    """The flag scene with a ``nu x nv`` flag for ``frames`` frames, in its 6 m/s wind or,
    with ``still``, hanging from its pole in still air (also used by hang_cloth.py)."""
    nu, nv = resolution
    cfg = compose_config(
        [
            "scene=flag",
            "wind=global",
            f"scene.cloths.0.resolution=[{nu},{nv}]",
            f"sim.duration={frames / 60.0}",
            "sim.progress=false",
            "grid.resolution=16",
            *(["scene.sources=[]"] if still else []),
            *extra,
        ]
    )
    return Simulation(prepare(cfg))


def stretch_case(resolution, still: bool, extra: list[str]) -> dict:
    """Largest warp/weft edge strain per frame of a 4 s flag run (still air or wind)."""
    sim = flag_simulation(resolution, STRETCH_FRAMES, still, extra)
    strain = []
    for n in range(STRETCH_FRAMES):
        sim.step(n)
        strain.append(sim.cloth_solver.max_stretch(sim.state.positions))
    s = np.asarray(strain)
    if still:
        return {"air": "still", "final": s[-1], "max_last_2s": s[120:].max()}
    return {"air": "wind 6 m/s", "median_0.5_4s": np.median(s[30:]), "max_0.5_4s": s[30:].max()}


def bench_case(resolution, frames: int, warmup: int, extra: list[str]) -> dict:
    nu, nv = resolution
    scene = ["scene=flag", "wind=global", f"scene.cloths.0.resolution=[{nu},{nv}]"]
    return timed_frames([*scene, *extra], frames, warmup)


def timed_frames(overrides: list[str], frames: int, warmup: int) -> dict:
    """Median and best frame times of a run of ``overrides`` after ``warmup`` frames."""
    duration = (frames + warmup) / 60.0
    cfg = compose_config(
        [*overrides, f"sim.duration={duration}", "sim.spinup=0", "sim.progress=false"]
    )
    sim = Simulation(prepare(cfg))
    for n in range(warmup):
        sim.step(n)
    solver_step, cpu_cloth = sim.cloth_solver.step, []

    def timed_step(*args):  # CPU time of the cloth solver alone
        c0 = time.process_time()
        out = solver_step(*args)
        cpu_cloth.append(time.process_time() - c0)
        return out

    sim.cloth_solver.step = timed_step
    wall0 = time.perf_counter()
    cpu = []
    for n in range(warmup, warmup + frames):
        c0 = time.process_time()
        sim.step(n)
        cpu.append(time.process_time() - c0)
    wall = (time.perf_counter() - wall0) / frames
    sec = np.asarray(sim.recorder.rows["step_seconds"][warmup:])  # wind, aero, cloth, total
    med = np.median(sec, axis=0)
    rows = sim.recorder.rows  # the cloth's figures over the timed frames: their largest
    worst = {k: max(rows[k][warmup:]) for k in ("max_stretch", "over_strain_limit")}
    stats = sim.cloth_solver.stats(sim.state)
    contacts = sim.recorder.phases.get("contacts", [0.0] * (warmup + frames))[warmup:]
    return {
        "vertices": sim.state.positions.shape[0],
        "substeps": int(cfg.cloth.substeps),
        "frames": frames,
        "ms_wind": 1e3 * med[0],
        "ms_aero": 1e3 * med[1],
        "ms_cloth": 1e3 * med[2],
        "ms_contacts": 1e3 * float(np.median(contacts)),
        "ms_total_median": 1e3 * med[3],
        "ms_total_best": 1e3 * sec[:, 3].min(),
        "ms_loop_wall": 1e3 * wall,
        "fps_median": 1.0 / med[3],
        "ms_cpu_median": 1e3 * float(np.median(cpu)),
        "ms_cpu_cloth": 1e3 * float(np.median(cpu_cloth)),
        "fps_cpu": 1.0 / float(np.median(cpu)),
        "max_stretch": worst["max_stretch"],
        "over_strain_limit": worst["over_strain_limit"],
        "max_penetration": stats["max_penetration"],
        "self_collision": bool(cfg.cloth.self_collision),
        "self_intersections": max(rows["self_intersections"][warmup:]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--warmup", type=int, default=30)
    parser.add_argument("--substeps", type=int, default=None)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--stretch", action="store_true", help="record stretch, not speed")
    parser.add_argument("--shirt", action="store_true", help="the shirt scene (bench_shirt.csv)")
    parser.add_argument("overrides", nargs="*", help="further config overrides, key=value")
    args = parser.parse_args()
    extra = [] if args.substeps is None else [f"cloth.substeps={args.substeps}"]
    extra += args.overrides
    if args.stretch:
        return write_stretch(extra, args.out if args.out != OUT else STRETCH_OUT)
    if args.shirt:
        return write_rows(shirt_rows(args.frames, args.warmup, extra), args.out, SHIRT_OUT)
    rows = []
    for name, res, target in CASES:
        row = {"case": name, "nu": res[0], "nv": res[1], "target_fps": target}
        row.update(bench_case(res, args.frames, args.warmup, extra))
        row["meets_target_wall"] = bool(row["fps_median"] >= target)
        row["meets_target_cpu"] = bool(row["fps_cpu"] >= target)
        rows.append(machine(row))
        print(
            f"{name:12s} {row['fps_median']:7.1f} frames/s wall, {row['fps_cpu']:7.1f} by CPU "
            f"time (target {target:g}); "
            f"cloth {row['ms_cloth']:.2f} ms (contacts {row['ms_contacts']:.2f}), aero {row['ms_aero']:.2f} ms, "
            f"wind {row['ms_wind']:.2f} ms; max stretch {row['max_stretch']:.3f}"
        )
    write_rows(rows, args.out, OUT)


def machine(row: dict) -> dict:
    """What a timing was measured under (the machine is shared)."""
    row["numba_threads"] = os.environ["NUMBA_NUM_THREADS"]
    row["load_average_1min"] = os.getloadavg()[0]
    row["cpus"] = os.cpu_count()
    row["machine"] = platform.processor() or platform.machine()
    row["date"] = measured_at()
    return row


def shirt_rows(frames: int, warmup: int, extra: list[str]) -> list[dict]:
    """The shirt of Fig. 6 (one-piece garment, about a 64 x 64 cloth, on the mesh character)
    in the global and the particle wind, with the cost of one signed-distance query."""
    rows = []
    for wind in ("global", "particles"):
        row = {"case": f"shirt_{wind}", "target_fps": 30.0}
        row.update(timed_frames(["scene=shirt", f"wind={wind}", *extra], frames, warmup))
        row["ns_per_body_query"] = body_query_ns(["scene=shirt", *extra])
        rows.append(machine(row))
        print(
            f"{row['case']:16s} {row['fps_median']:7.1f} frames/s wall, {row['fps_cpu']:7.1f} "
            f"by CPU time; cloth {row['ms_cloth']:.1f} ms; body query "
            f"{row['ns_per_body_query']:.0f} ns; max penetration {row['max_penetration']:.3g} m; "
            f"max stretch {row['max_stretch']:.3f}, {row['over_strain_limit']:.1%} of the "
            "edges beyond the strain limit"
        )
    return rows


def body_query_ns(overrides: list[str], repeats: int = 20) -> float:
    """Nanoseconds per signed distance (and normal) of a cloth vertex to the scene's bodies:
    the query each contact makes, timed over the cloth's rest vertices."""
    from windbench.geometry.bodies import body_table, union_distance
    from windbench.scenes import build_scene

    scene = build_scene(compose_config(overrides).scene)
    points = np.concatenate([c.vertices for c in scene.cloths])
    table = body_table(scene.bodies)
    dist, normal = np.empty(len(points)), np.empty_like(points)
    union_distance(table, points, dist, normal)  # compiled
    c0 = time.process_time()
    for _ in range(repeats):
        union_distance(table, points, dist, normal)
    return 1e9 * (time.process_time() - c0) / (repeats * len(points))


def write_rows(rows: list[dict], out: Path, default: Path) -> None:
    out = out if out != OUT else default
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow(
                {k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()}
            )
    print(f"wrote {out}")


def write_stretch(extra: list[str], out: Path) -> None:
    rows = []
    for name, res, _ in CASES:
        for still in (True, False):
            row = {"case": name, "overrides": " ".join(extra)}
            row.update(stretch_case(res, still, extra))
            rows.append(row)
            print(
                ", ".join(
                    f"{k} {v:.4f}" if isinstance(v, float) else str(v) for k, v in row.items()
                )
            )
    keys = list(dict.fromkeys(k for row in rows for k in row))
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in row.items()})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
