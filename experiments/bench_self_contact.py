"""Where a self-contact pass spends its time, on the flag of ``bench_cloth.py`` in its wind.

The flag runs with ``cloth.self_collision=true`` for ``--warmup`` frames, then
``--frames`` frames that count the passes (``TreeFit.passes``: the frame's last substep,
every substep that moved far enough, and a second pass after one that pushed a pair).
Over one substep's share of the last frame's motion (the last pass at the frame's start,
the positions 1 / substeps of the way to its end) each phase of one pass is timed alone,
the median of ``--repeats`` calls: the refit of the patch bounds and cones with their
growth by the vertices' moves (``ms_refit``: ``refit`` and ``grow_by_moves``), the
leaf-pair search at the thickness (``leaf_pairs``), the close-pair search at the pass's
largest pair reach (``close_pairs``: vertex-triangle, then edge-edge) and the whole pass
(``self_contacts``, on a copy), with the counts each one hands on. A leaf pair whose two
patches' triangles keep their normals within the contact cone (60 degrees) of their mean
is counted as ``flat_leaf_pairs``: how many of the tested pairs are neighbours on a gently
curved sheet rather than layers that may touch. Of the pairs of two patches,
``adjacent_leaf_pairs`` share a vertex; ``bridged_leaf_pairs`` counts the pairs the
search leaves out because a third leaf joins the two into one flat connected patch (the
leaf pairs without that test, ``bridge`` false, less those with it).

    PYTHONPATH=$PWD python experiments/bench_self_contact.py [--frames 60] [--sizes 40x25 64x64]

appends one row per flag size to ``experiments/results/bench_self_contact.csv``.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # before numba is imported
import time
from pathlib import Path

import numpy as np

from experiments.bench_cloth import flag_simulation
from experiments.rows import show_and_append, stamp
from windbench.cloth import self_contact as sc_kernels

OUT = Path(__file__).resolve().parent / "results" / "bench_self_contact.csv"
FIELDS = [
    "date", "code", "nu", "nv", "triangles", "leaves", "substeps", "frames",
    "passes_per_frame", "passes_per_frame_max", "ms_frame_median", "ms_refit",
    "ms_leaf_pairs", "ms_close_pairs", "ms_pass", "leaf_pairs", "flat_leaf_pairs",
    "adjacent_leaf_pairs", "bridged_leaf_pairs", "vertex_triangle_pairs", "edge_pairs",
    "pushed", "load_average_1min",
]  # fmt: skip


def median_ms(fn, *args, repeats: int):
    """(median wall ms of ``repeats`` calls of fn(*args) after one, fn's last result)."""
    out = fn(*args)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn(*args)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times)), out


def flat_pairs(sc, fit, pairs) -> int:
    """Leaf pairs whose triangles' normals all lie within the contact cone of their mean."""
    tree, normals = sc.tree, fit.normals
    count = 0
    for a, b in pairs:
        ids = np.concatenate(
            [tree.order[tree.first[k] : tree.first[k] + tree.count[k]] for k in (a, b)]
        )
        n = normals[ids] / np.linalg.norm(normals[ids], axis=1, keepdims=True)
        axis = n.sum(axis=0) / np.linalg.norm(n.sum(axis=0))
        count += bool((n @ axis).min() > np.cos(sc_kernels.CONTACT_CONE))
    return count


def adjacent_pairs(sc, pairs) -> int:
    """Pairs of two leaves that share a vertex (the leaves' neighbour lists)."""
    nbr_ptr, nbr = sc.tree.nbr_ptr, sc.tree.nbr
    return sum(
        int(b in nbr[nbr_ptr[a] : nbr_ptr[a + 1]])
        for a, b in (tuple(int(k) for k in p) for p in pairs)
    )


def measure(nu: int, nv: int, frames: int, warmup: int, repeats: int) -> dict:
    """One row: the pass count over ``frames`` frames and the phases of one pass."""
    sim = flag_simulation((nu, nv), frames + warmup, False, ["cloth.self_collision=true"])
    for n in range(warmup):
        sim.step(n)
    solver = sim.cloth_solver
    sc, fit = solver.tables.self_contact, solver.workspace.fit
    passes, frame_s = [], []
    for n in range(warmup, warmup + frames):
        anchor = np.ascontiguousarray(sim.state.positions).copy()
        start = time.perf_counter()
        sim.step(n)
        frame_s.append(time.perf_counter() - start)
        passes.append(int(fit.passes[0]))
    x = anchor + (sim.state.positions - anchor) / solver.settings.substeps
    moves = sc_kernels.vertex_moves(x, anchor, np.empty(x.shape[0]))
    reach = sc_kernels.pair_reach(moves.max(), moves.max(), sc.thickness)
    tri, tree, gap = sc.triangles, sc.tree, sc.thickness

    def bounds():
        sc_kernels.refit(tree, tri, x, fit)
        sc_kernels.grow_by_moves(tree, moves, fit.box, fit.dop)

    ms_refit, _ = median_ms(bounds, repeats=repeats)
    cos = sc_kernels._COS_CONTACT
    ms_pairs, (pairs, found) = median_ms(
        sc_kernels.leaf_pairs, tree, fit, cos, gap, True, repeats=repeats
    )
    ms_close, (vt, ee) = median_ms(
        sc_kernels.close_pairs, sc, x, fit.box, pairs, found, reach, repeats=repeats
    )
    bridged = sc_kernels.leaf_pairs(tree, fit, cos, gap, False)[1] - found
    inv_mass = solver.tables.constraints.inv_mass
    ms_pass, pushed = median_ms(
        lambda: sc_kernels.self_contacts(sc, inv_mass, x.copy(), anchor, fit), repeats=repeats
    )
    return {
        **stamp(),
        "nu": nu,
        "nv": nv,
        "triangles": tri.shape[0],
        "leaves": int((tree.left < 0).sum()),
        "substeps": solver.settings.substeps,
        "frames": frames,
        "passes_per_frame": round(float(np.mean(passes)), 2),
        "passes_per_frame_max": max(passes),
        "ms_frame_median": round(1e3 * float(np.median(frame_s)), 2),
        "ms_refit": round(ms_refit, 3),
        "ms_leaf_pairs": round(ms_pairs, 3),
        "ms_close_pairs": round(ms_close, 3),
        "ms_pass": round(ms_pass, 3),
        "leaf_pairs": int(found),
        "flat_leaf_pairs": flat_pairs(sc, fit, pairs[:found]),
        "adjacent_leaf_pairs": adjacent_pairs(sc, pairs[:found]),
        "bridged_leaf_pairs": bridged,
        "vertex_triangle_pairs": len(vt),
        "edge_pairs": len(ee),
        "pushed": int(pushed),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--warmup", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--sizes", nargs="+", default=["40x25", "64x64"])
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    rows = []
    for size in args.sizes:
        nu, nv = (int(k) for k in size.split("x"))
        rows.append(measure(nu, nv, args.frames, args.warmup, args.repeats))
    shown = ["nu", "nv", "passes_per_frame", "ms_pass", "leaf_pairs", "bridged_leaf_pairs"]
    show_and_append(args.out, rows, FIELDS, shown)


if __name__ == "__main__":
    main()
