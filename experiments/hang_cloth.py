"""Where a flag hanging from its pole in still air stretches: a diagnostic of the solver.

Runs the flag scene (``scene=flag``, ``wind=global``, ``scene.sources=[]``, resolution
``nu x nv``) for ``--frames`` frames and prints, every 30 frames, the largest warp/weft edge
strain and the lattice position (i along the flag, j up; column i = 0 is pinned) of that
edge; at the frames of ``--at``, the mean in-plane shear angle of the cells next to the pole
(the angle between the warp and the weft edge at each cell's lower pole-side corner, minus
90 degrees, over the first ``nu // 6`` columns); at the end, the strain percentiles of the
stretch edges and of the cell diagonals (the shear edges).

    PYTHONPATH=$PWD python experiments/hang_cloth.py 64 64 [--frames 240] [--at 10,20] [key=value ...]
"""

from __future__ import annotations

import argparse

import numpy as np
from bench_cloth import flag_simulation  # experiments/ is the script's folder


def shear_angles(x: np.ndarray, nu: int, nv: int) -> np.ndarray:
    """In-plane shear angle (degrees) of each lattice cell, (nu - 1, nv - 1)."""
    grid = x.reshape(nu, nv, 3)
    u = grid[1:, :-1] - grid[:-1, :-1]
    v = grid[:-1, 1:] - grid[:-1, :-1]
    cos = np.einsum("ijk,ijk->ij", u, v) / (np.linalg.norm(u, axis=2) * np.linalg.norm(v, axis=2))
    return np.degrees(np.arcsin(np.clip(cos, -1.0, 1.0)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("nu", type=int)
    parser.add_argument("nv", type=int)
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--at", default="10,20", help="frames at which to print shear angles")
    parser.add_argument("overrides", nargs="*", help="further config overrides, key=value")
    args = parser.parse_intermixed_args()
    nu, nv = args.nu, args.nv
    at = {int(a) for a in args.at.split(",") if a}
    sim = flag_simulation((nu, nv), args.frames, True, args.overrides)
    tables = sim.cloth_solver.tables.constraints
    edges, rest, ns = tables.edges, tables.edge_rest, tables.n_stretch

    def strains() -> np.ndarray:
        x = sim.state.positions
        return np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1) / rest - 1.0

    for n in range(args.frames):
        sim.step(n)
        if n + 1 in at:
            angle = np.abs(shear_angles(sim.state.positions, nu, nv)[: max(nu // 6, 1)])
            print(f"frame {n + 1}: mean |shear angle| next to the pole {angle.mean():.2f} deg")
        if (n + 1) % 30 == 0:
            s = strains()[:ns]
            e = int(np.argmax(s))
            a, b = (divmod(int(v), nv) for v in edges[e])
            print(f"frame {n + 1}: largest stretch {s[e]:.4f} on edge {a}-{b}")
    s = strains()
    st, sh = s[:ns], s[ns:]
    print(
        f"stretch edges: max {st.max():.4f} p99 {np.percentile(st, 99):.4f}; "
        f"diagonals: min {sh.min():.3f} p1 {np.percentile(sh, 1):.3f} "
        f"p99 {np.percentile(sh, 99):.3f} max {sh.max():.3f}"
    )


if __name__ == "__main__":
    main()
