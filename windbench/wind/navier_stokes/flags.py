"""Compiler flags shared by the numba kernels of the wind backends."""

from __future__ import annotations

# No fast-math flags: strict IEEE arithmetic, so a kernel gives the same bits whether numba
# compiled its callees into it in this process or linked them from its on-disk cache. With
# LLVM free to contract a * b + c into fused multiply-adds and to reorder sums, which it did
# only where a callee was inlined, a run with a cold cache and one with a warm cache drifted
# apart (1e-10 after a step; the chaotic wake amplified it to 0.1 m/s over a few hundred).
# Same configuration and seed give the same numbers; that costs the fused multiply-adds and
# reordered sums of the face pass, the backtrace and the multigrid sweeps.
FAST_MATH: set[str] = set()
