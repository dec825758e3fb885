"""Compiler flags shared by the numba kernels of the wind backends."""

from __future__ import annotations

# LLVM may contract a * b + c into one fused multiply-add and reorder sums (measured, one
# core, A/B in one process: 11-15% less time for the face pass and the backtrace each,
# about 5% per smoothing sweep of the pressure multigrid). Not the no-NaN/no-infinity assumptions,
# so a NaN still propagates and the run stops after the step with the reason.
FAST_MATH = {"contract", "reassoc", "nsz", "arcp"}
