"""Accuracy of a mesh body's tabulated signed distance against the lattice spacing.

Two meshes whose distance is known: a sphere of radius 0.3 m (a head or torso) and a
capsule of radius 0.045 m (an arm), both fine trimesh meshes. For each spacing h the
signed distance (:mod:`windbench.geometry.sdf`) is sampled at random points within 1 cm of
the surface and compared with the analytic distance of the shape; the table gives the
largest error, the bound chord + h^2 / (4 (r - 1 cm)) (the mesh's own deviation plus the
trilinear interpolation error of a surface of radius r), the largest normal error in
degrees, the lattice's size and the CPU time to build it.

    PYTHONPATH=$PWD python experiments/sdf_accuracy.py

writes ``experiments/results/sdf_accuracy.csv``. windbench tabulates mesh bodies at
h = 1 cm (``spacing``): under a millimetre on an arm-sized radius, below the cloth's 5 mm
collision margin.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import trimesh

from experiments.bench_cloth import write_rows
from windbench.geometry.sdf import lattice_distance, sdf_lattice

OUT = Path(__file__).resolve().parent / "results" / "sdf_accuracy.csv"
SPACINGS = (0.04, 0.02, 0.01, 0.005)
NEAR = 0.01  # m: points within this of the surface


def shapes():
    """(name, mesh, analytic distance, radius, chord error of the mesh)."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.3)
    arm = trimesh.creation.capsule(height=0.3, radius=0.045, count=(64, 64))

    def sphere_d(p):
        return np.linalg.norm(p, axis=1) - 0.3

    def arm_d(p):
        z = np.clip(p[:, 2], -0.15, 0.15)
        return np.linalg.norm(p - np.stack([0 * z, 0 * z, z], axis=1), axis=1) - 0.045

    return (
        ("sphere_r0.3", sphere, sphere_d, 0.3, np.abs(sphere_d(sphere.triangles_center)).max()),
        ("capsule_r0.045", arm, arm_d, 0.045, np.abs(arm_d(arm.triangles_center)).max()),
    )


def near_points(mesh, distance, n: int = 4000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    p = rng.uniform(lo - NEAR, hi + NEAR, (20 * n, 3))
    return p[np.abs(distance(p)) < NEAR][:n]


def measure(mesh, distance, radius: float, chord: float, h: float) -> dict:
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    c0 = time.process_time()
    lattice = sdf_lattice(v, t, h)
    seconds = time.process_time() - c0
    fields, prm = lattice.entry(), np.array([0.0, *v.min(0), *v.max(0)])
    pts = near_points(mesh, distance)
    d, n = np.empty(len(pts)), np.empty((len(pts), 3))
    for i, p in enumerate(pts):
        d[i] = lattice_distance(fields, prm, p[0], p[1], p[2], n[i])
    eps = 1e-6  # the analytic normal by central differences
    grad = np.stack(
        [(distance(pts + eps * e) - distance(pts - eps * e)) / (2 * eps) for e in np.eye(3)], 1
    )
    cos = np.einsum("ij,ij->i", n, grad / np.linalg.norm(grad, axis=1, keepdims=True))
    return {
        "spacing_m": h,
        "max_error_m": np.abs(d - distance(pts)).max(),
        "bound_m": chord + h * h / (4 * (radius - NEAR)),
        "mesh_chord_m": chord,
        "max_normal_error_deg": np.degrees(np.arccos(np.clip(cos.min(), -1, 1))),
        "lattice_points": lattice.values.size,
        "build_cpu_s": seconds,
    }


def main() -> None:
    rows = []
    cases = shapes()
    warm = cases[0][1]
    sdf_lattice(np.asarray(warm.vertices), np.asarray(warm.faces, np.int64), 0.1)  # compiled
    for name, mesh, distance, radius, chord in cases:
        for h in SPACINGS:
            row = {"shape": name, **measure(mesh, distance, radius, chord, h)}
            rows.append(row)
            print(
                ", ".join(
                    f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
                )
            )
    write_rows(rows, OUT, OUT)


if __name__ == "__main__":
    main()
