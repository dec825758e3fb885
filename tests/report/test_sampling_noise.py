"""The time mean's own error: the steady window's blocks (simulate.Recorder), their
batch-means standard error and the sampling noise of a lee error (report.lee), against
answers known without the code: the block means of a linear signal, the spread of the
mean of an AR(1) process, and E[lee_error^2] = d^2 + noise^2 for noisy means."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from windbench.report.collect import RunRecord
from windbench.report.comparison import reference_table
from windbench.report.lee import (
    beyond_noise,
    choose_references,
    lee_error,
    lee_error_by_height,
    sampling_noise,
    time_mean_error,
)
from windbench.simulate import Recorder, window_block

U_REF = 6.0


def _setup(start: float, end: float, blocks: int):
    cfg = SimpleNamespace(output=SimpleNamespace(window_blocks=blocks))
    return SimpleNamespace(cfg=cfg, analysis_start=start, end_time=end)


def test_the_window_splits_into_equal_blocks_whose_means_average_to_its_mean():
    """Steps t_j = 0.1 j, j = 1..40, window from t = 1 (steps 10-40: the first at the
    window's start), 3 blocks: a probe wind equal to t has the block means of t over
    steps 10-20, 21-30, 31-40, and the count-weighted block means give the window mean."""
    dt, blocks = 0.1, 3
    rec = Recorder(_setup(start=1.0, end=4.0, blocks=blocks))
    for j in range(1, 41):
        t = j * dt
        rec.accumulate_probes(t, np.full((2, 3), t))
    assert list(rec.block_count) == [11, 10, 10]
    means = rec.block_sum[:, 0, 0] / rec.block_count
    np.testing.assert_allclose(means, [1.5, 2.55, 3.55], rtol=1e-12)
    window = rec.probe_sum[0, 0] / rec.probe_count
    assert np.average(means, weights=rec.block_count) == pytest.approx(window, rel=1e-12)
    assert window_block(4.0, 1.0, 4.0, 3) == 2 and window_block(9.0, 1.0, 4.0, 3) == 2


def test_batch_means_give_the_spread_of_the_time_mean_of_an_ar1_process():
    """x_k = phi x_(k-1) + e_k, stationary variance 1: the mean of n samples has variance
    (1 + phi) / ((1 - phi) n) for n >> 1 / (1 - phi); the batch-means estimate over 4
    blocks, averaged over realisations, recovers it (within its own sampling spread)."""
    phi, n, blocks, series = 0.9, 8000, 4, 400
    rng = np.random.default_rng(7)
    x = np.empty((n, series))
    x[0] = rng.normal(size=series)
    innovations = rng.normal(scale=math.sqrt(1 - phi**2), size=(n, series))
    for k in range(1, n):
        x[k] = phi * x[k - 1] + innovations[k]
    expected = math.sqrt((1 + phi) / ((1 - phi) * n))
    block_means = x.reshape(blocks, n // blocks, series).mean(axis=1)
    estimated = time_mean_error(block_means)
    assert x.mean(axis=0).std() == pytest.approx(expected, rel=0.1)  # the process is right
    assert np.sqrt(np.mean(estimated**2)) == pytest.approx(expected, rel=0.1)


def _noisy_run(points, mean, spread, rng, blocks=4, **settings):
    """A record whose B block means scatter about ``mean`` with standard deviation
    ``spread`` (so its window mean has standard error spread / sqrt(B))."""
    block_wind = mean + spread * rng.normal(size=(blocks, *mean.shape))
    rec = RunRecord(Path(f"/runs/{settings}{rng.random()}/windbench.nc"), "complete")
    rec.settings = settings
    rec.lee_points, rec.reference_speed = points, U_REF
    rec.lee_block_wind, rec.lee_wind = block_wind, block_wind.mean(axis=0)
    return rec


def test_the_lee_error_splits_by_height_into_parts_that_sum_to_its_square():
    """A run that differs from its reference by 3 m/s along x at one of five heights only:
    that height holds all of lee_error^2 = (3 / U)^2 / 5, the means are the two winds'."""
    rng = np.random.default_rng(5)
    g = np.linspace(0.1, 0.9, 5)
    points = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    ref = _noisy_run(points, rng.normal(size=points.shape), 0.0, rng)
    shifted = ref.lee_wind.copy()
    shifted[points[:, 2] == g[3], 0] -= 3.0
    run = _noisy_run(points, shifted, 0.0, rng)
    parts = lee_error_by_height(run, ref)
    assert [z for z, *_ in parts] == pytest.approx(g)
    assert [p for *_, p in parts] == pytest.approx([0, 0, 0, (3.0 / U_REF) ** 2 / 5, 0])
    assert sum(p for *_, p in parts) == pytest.approx(lee_error(run, ref) ** 2)
    at = points[:, 2] == g[3]
    assert parts[3][1:3] == pytest.approx((shifted[at, 0].mean(), ref.lee_wind[at, 0].mean()))


def test_the_sampling_noise_is_the_lee_error_of_runs_with_the_same_true_mean():
    """Two runs with true means d apart: E[lee_error^2] = (|d| / U)^2 + noise^2, over many
    pairs of realisations (noise from each pair's own blocks, its mean squared known:
    spread^2 (1 / 4 + 1 / 4) 3 / U^2)."""
    rng = np.random.default_rng(3)
    g = np.linspace(0.1, 0.9, 5)
    points = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    mean, spread = rng.normal(size=points.shape), 0.4
    truth = math.sqrt(spread**2 * 0.5 * 3) / U_REF
    for offset in (np.zeros(3), np.array([0.3, 0.0, -0.4])):  # |d| = 0 and 0.5 m/s
        pairs = [
            (_noisy_run(points, mean + offset, spread, rng), _noisy_run(points, mean, spread, rng))
            for _ in range(300)
        ]
        errors = np.array([lee_error(a, b) for a, b in pairs])
        noise = np.array([sampling_noise(a, b) for a, b in pairs])
        assert np.sqrt(np.mean(noise**2)) == pytest.approx(truth, rel=0.05)
        d = np.linalg.norm(offset) / U_REF
        assert np.mean(errors**2) == pytest.approx(d**2 + truth**2, rel=0.05)


def test_the_reference_states_the_sampling_noise_of_its_e21():
    rng = np.random.default_rng(5)
    points = rng.uniform(size=(20, 3))
    mean = rng.normal(size=points.shape)
    levels = [
        _noisy_run(
            points, mean + k, 0.2 * k, rng, scene="fence", wind="navier_stokes", resolution=r
        )
        for k, r in ((1, 128), (2, 64))  # the coarse level 1 m/s off in each component
    ]
    for rec in levels:
        rec.config = {"wind.advection": "second_order"}
    ref = choose_references(levels)["fence"]
    assert ref.noise == pytest.approx(sampling_noise(levels[1], levels[0]), rel=1e-12)
    s_fine = levels[0].lee_block_wind.std(axis=0, ddof=1) / 2.0
    s_coarse = levels[1].lee_block_wind.std(axis=0, ddof=1) / 2.0
    by_hand = np.sqrt(np.mean(np.sum(s_fine**2 + s_coarse**2, axis=1))) / U_REF
    assert ref.noise == pytest.approx(by_hand, rel=1e-12)
    assert sampling_noise(levels[0], levels[0]) == 0.0  # the reference against itself
    row = reference_table({"fence": ref}).iloc[0]
    assert row["e21 sampling noise"] == ref.noise
    assert row["e21 beyond noise"] == pytest.approx(math.sqrt(ref.difference**2 - ref.noise**2))
    assert beyond_noise(0.3, 0.5) == 0.0 and beyond_noise(0.5, 0.3) == pytest.approx(0.4)
    levels[0].lee_block_wind = None  # a dataset from before the window blocks
    assert math.isnan(sampling_noise(levels[1], levels[0]))
