"""The DeepOD adapters' window features: the compiled kernel gives numpy's window-view values bit
for bit (the expression it replaced), so scores did not move when it came in."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

pytest.importorskip("deepod")

from scart_bench.detectors.deepod_models import DeepSVDD  # noqa: E402
from scart_bench.detectors.statistical import pad_start  # noqa: E402


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
