"""The Navier-Stokes backend against flows with known answers (paper §4.1): a uniform
oblique free stream stays uniform, the Taylor-Green vortex decays at exp(-2 nu t), plane
Poiseuille flow reaches its parabola. The problems are the refinement study's own
(``experiments/validation_ns/problems.py``), run here at small sizes."""

from __future__ import annotations

import numpy as np

from experiments.validation_ns.problems import free_stream, poiseuille, taylor_green


def test_free_stream_preserved():
    """Uniform oblique wind through inflow/outflow faces stays uniform to 1e-8 relative."""
    for scheme in ("semi_lagrangian", "maccormack"):
        row = free_stream(12, scheme, steps=10)
        assert row["max_rel_deviation"] <= 1e-8, row


def test_taylor_green_decay_rate(record_property):
    """u ~ exp(-2 nu t) (k = 1 per axis); MacCormack within 5 % at 64 cells."""
    mc, _ = taylor_green(64, "maccormack", dt=0.02)
    sl, _ = taylor_green(64, "semi_lagrangian", dt=0.02)
    record_property("taylor_green_maccormack_rel_error", float(mc["rate_rel_error"]))
    record_property("taylor_green_semi_lagrangian_rel_error", float(sl["rate_rel_error"]))
    print(
        f"Taylor-Green 64 cells dt=0.02: MacCormack rate error {mc['rate_rel_error']:+.3%}, "
        f"semi-Lagrangian {sl['rate_rel_error']:+.3%}"
    )
    assert abs(mc["rate_rel_error"]) < 0.05
    assert sl["rate"] > mc["rate"]  # plain semi-Lagrangian is the more dissipative scheme


def test_poiseuille_profile():
    """Steady plane Poiseuille flow: u(y) = f / (2 nu) y (H - y) within 1 % at 16 cells."""
    row, (_, got, exact) = poiseuille(16)
    assert row["linf_rel_error"] <= 0.01
    assert np.all(np.diff(got[: len(got) // 2]) > 0)  # parabolic: rising to mid-channel
    coarse, _ = poiseuille(8)
    assert coarse["linf_rel_error"] > 2.5 * row["linf_rel_error"]  # second order
