"""The detectors' compiled kernels give the numpy expressions they replaced bit for bit, so scores
did not move when they came in: the DeepOD adapters' window features and TSBitmaps' lag/lead
bitmap distances."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.lib.stride_tricks import sliding_window_view

pytest.importorskip("deepod")

from scart_bench.detectors.deepod_models import DeepSVDD  # noqa: E402
from scart_bench.detectors.statistical import pad_start  # noqa: E402
from scart_bench.detectors.tsbitmaps import TSBitmaps  # noqa: E402


def numpy_windows(X: np.ndarray, w: int, k: int, step: int, stats: bool) -> np.ndarray:
    X = pad_start(X.astype(np.float32), w - 1)
    view = sliding_window_view(X, w, axis=0)[::step]  # (n, channels, w)
    bounds = np.linspace(0, w, k + 1).round().astype(int)
    paa = np.add.reduceat(view, bounds[:-1], axis=2) / np.diff(bounds).astype(np.float32)
    parts = [paa.transpose(0, 2, 1).reshape(view.shape[0], -1)]
    if stats:
        parts += [view.std(axis=2), np.diff(view, axis=2).std(axis=2)]
    return np.concatenate(parts, axis=1)


@pytest.mark.parametrize(("channels", "w", "k", "step", "stats"), [
    (63, 25, 5, 1, True), (63, 25, 5, 5, True), (1, 25, 5, 1, True), (2, 40, 3, 1, True),
    (7, 2, 1, 1, True), (5, 30, 30, 3, False), (3, 300, 2, 7, True), (9, 17, 4, 1, True),
])
def test_window_features_equal_numpys_window_view(channels, w, k, step, stats):
    rng = np.random.default_rng(channels * 1000 + w)
    X = rng.standard_normal((400, channels)) * rng.uniform(0.01, 100, channels) + rng.uniform(-500, 500, channels)
    X[:, 0] = 2.5  # a still channel: zero spread
    det = DeepSVDD(window=w, segments=k, window_stats=stats)
    got = det._windows(X, step)
    want = numpy_windows(X, w, k, step, stats)
    assert got.dtype == np.float32 and got.shape == want.shape
    assert np.array_equal(got, want)


def numpy_bitmap_distance(codes: np.ndarray, bounds, full_history: int) -> np.ndarray:
    _, compact = np.unique(codes, return_inverse=True)
    n, cells = codes.size, int(compact.max()) + 1
    cum = np.zeros((n + 1, cells), dtype=np.int32)
    cum[np.arange(1, n + 1), compact] = 1
    np.cumsum(cum, axis=0, out=cum)
    lag_start, lead_start, end = bounds
    bitmaps = []
    for lo, hi in ((lag_start, lead_start), (lead_start, end)):
        counts = (cum[hi] - cum[lo]).astype(np.float64)
        peak = counts.max(axis=1, keepdims=True)
        bitmaps.append(np.divide(counts, peak, out=np.zeros_like(counts), where=peak > 0))
    dist = np.sum((bitmaps[1] - bitmaps[0]) ** 2, axis=1)
    return dist * np.where(lead_start > lag_start, np.minimum(1.0, (end - lag_start) / full_history), 0.0)


@pytest.mark.parametrize("params", [
    {}, {"alphabet_size": 3, "level_size": 2, "lag_window_size": 50, "lead_window_size": 20},
    {"feature_window_size": 1, "alphabet_size": 8}, {"lag_window_size": 10, "lead_window_size": 10},
])
@pytest.mark.parametrize("rows", [1, 7, 900])
def test_bitmap_distances_equal_the_prefix_sum_expression(params, rows):
    rng = np.random.default_rng(rows)
    X = np.cumsum(rng.standard_normal((900, 6)), axis=0)
    X[:, 2] = 1.0 + (np.arange(900) % 2) * 1e-3  # a nearly still channel: one or two words
    flight = pd.DataFrame(X, columns=[f"imu.c{i}" for i in range(6)])
    det = TSBitmaps(**params).fit([flight.iloc[:450]])
    flight = flight.iloc[:rows]
    Z = det._transform(flight)
    codes = det._subword_codes(Z)
    bounds = det._window_bounds(Z.shape[0])
    full = int(det.lag_window_size) + int(det.lead_window_size)
    for j in range(codes.shape[1]):
        assert np.array_equal(det._bitmap_distance(codes[:, j], bounds, full),
                              numpy_bitmap_distance(codes[:, j], bounds, full))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_pairwise_sum_is_numpys_sum(dtype):
    from scart_bench.detectors._kernels import pairwise_sum

    rng = np.random.default_rng(3)
    for n in [*range(1, 140), 255, 256, 257, 1000, 4099]:  # n >= 1: the kernels never sum nothing
        x = (rng.standard_normal(n + 3) * 1e3).astype(dtype)
        assert pairwise_sum(x, 3, n) == np.add.reduce(x[3:]), n


@pytest.mark.parametrize("min_exceed", [1, 2, 3, 4])
def test_statistical_kth_largest_ratio_is_the_partitions(min_exceed):
    """The statistical detector's k-of-4 rule picks the same ratio as np.partition, ties and NaN included."""
    from scart_bench.detectors.statistical import N_STATISTICS, Statistical

    rng = np.random.default_rng(min_exceed)
    ratios = rng.standard_normal((400, 9, 4)) ** 2
    ratios[::5, :, 1] = ratios[::5, :, 3]  # ties
    ratios[::7, 2, :] = 1.0  # all four equal
    det = Statistical(min_exceed=min_exceed)
    k = N_STATISTICS - min_exceed
    for r in (ratios, np.where(rng.random(ratios.shape) < 0.01, np.nan, ratios)):
        det._ratios = lambda X, r=r: r  # noqa: B023 (the ratios under test, bypassing the statistics)
        expected = np.partition(r, k, axis=-1)[..., k].max(axis=1)
        np.testing.assert_array_equal(det._score(np.zeros((400, 9))), expected)
