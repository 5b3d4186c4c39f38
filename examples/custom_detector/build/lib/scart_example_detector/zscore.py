"""Rolling z-score of first differences: a small, causal example detector for scart-bench.

Each channel's row-to-row change is compared with the changes seen on normal training flights
(z-score), the absolute z-scores are averaged over a trailing window of ``window`` rows, and the
row's score is the largest channel average. Spoofed, noisy, frozen-then-jumping or replayed
signals change how a channel moves from one sample to the next, which this catches; slow drifts
that move like a normal flight pass unseen (that is what the forecasting detectors are for).

This module imports only numpy and the scart-bench base class, so it also loads as a single file:
``scart-bench run --plugin path/to/zscore.py:RollingZScore``.
"""

from __future__ import annotations

import numpy as np

from scart_bench.detectors.base import Detector, DetectorError


class RollingZScore(Detector):
    """Trailing mean of |z| of first differences, maximum over channels.

    Parameters
    ----------
    columns : list of str or None
        Columns to use (``topic.field``); None for every sensor column.
    random_state : int
        Unused (the detector is deterministic); kept for the shared detector interface.
    window : int
        Rows in the trailing mean of the absolute z-scores (25 rows = 0.5 s at 50 Hz).

    Attributes
    ----------
    diff_mean_, diff_scale_ : ndarray
        Mean and standard deviation of each channel's first difference on the training flights.
    history_rows_ : int
        Trailing rows enough to reproduce a row's score when streaming (``window + 1``).
    """

    name = "zscore"
    description = "Rolling z-score of first differences, max over channels (example plugin)"

    def __init__(self, columns: list[str] | None = None, random_state: int = 0, window: int = 25):
        # scikit-learn convention: store the parameters unchanged, do no work here
        self.columns = columns
        self.random_state = random_state
        self.window = window

    def _fit(self, X_list: list[np.ndarray]) -> None:
        # X_list: one standardised float64 array (rows, channels) per training flight
        if int(self.window) < 1:
            raise DetectorError(f"{self.name}: window must be >= 1, got {self.window}")
        diffs = [np.diff(x, axis=0) for x in X_list if x.shape[0] > 1]
        if not diffs:
            raise DetectorError(f"{self.name}: training flights need at least two rows")
        d = np.concatenate(diffs, axis=0)
        self.diff_mean_ = d.mean(axis=0)
        std = d.std(axis=0)
        self.diff_scale_ = np.where(std > 1e-12, std, 1.0)
        self.history_rows_ = int(self.window) + 1

    def _score(self, X: np.ndarray) -> np.ndarray:
        # causal: row i uses rows i - window .. i only (the first row has no change)
        d = np.diff(X, axis=0, prepend=X[:1])
        z = np.abs((d - self.diff_mean_) / self.diff_scale_)
        z[0] = 0.0
        c = np.cumsum(z, axis=0)
        w = int(self.window)
        total = c.copy()
        total[w:] -= c[:-w]
        n = np.minimum(np.arange(1, X.shape[0] + 1), w)[:, None]
        return (total / n).max(axis=1)
