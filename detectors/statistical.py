"""Statistical detector: several rolling statistics, alarm when several thresholds are exceeded at once.

The SCART paper (Rahimi, Girstein, Malits, Mendelson, "SCART: Simulation of Cyber Attacks for
Real-Time") evaluates, beside its learned detectors, a statistical detector built from the mean,
standard deviation, variance and moving average of each sensor field, which flags a point when
several of those thresholds are exceeded at the same time. This module implements that rule on
the trailing window of every row, so the scores are causal.

The module also holds the causal window helpers the other built-in detectors share
(:func:`pad_start`, :func:`rolling_mean`, :func:`rolling_var`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from scart_bench.detectors.base import MAX_WINDOW_ROWS, Detector, DetectorError

#: Floor of every learned spread or threshold, in standardised units (constant channels).
_EPS = 1e-6
#: Number of statistics compared with a threshold at every row and channel.
N_STATISTICS = 4


def pad_start(X: np.ndarray, n: int) -> np.ndarray:
    """``X`` (rows, ...) with ``n`` copies of its first row prepended (causal window padding)."""
    if n <= 0:
        return X
    return np.concatenate([np.repeat(X[:1], n, axis=0), X], axis=0)


def rolling_mean(X: np.ndarray, window: int) -> np.ndarray:
    """Causal rolling mean over the last ``window`` rows of ``X`` (rows, channels).

    Rows before a full window see the first row repeated. Uses prefix sums, so the value of row
    ``i`` is bit-identical whatever rows follow it.
    """
    padded = pad_start(np.asarray(X, dtype=np.float64), window - 1)
    csum = np.concatenate([np.zeros((1,) + padded.shape[1:]), np.cumsum(padded, axis=0)], axis=0)
    return (csum[window:] - csum[:-window]) / window


def rolling_var(X: np.ndarray, window: int) -> np.ndarray:
    """Causal rolling (population) variance over the last ``window`` rows, clipped at zero."""
    mean = rolling_mean(X, window)
    return np.maximum(rolling_mean(X * X, window) - mean * mean, 0.0)


def _sorted4(values: np.ndarray) -> list[np.ndarray]:
    """The four entries of ``values``' last axis in ascending order, as four arrays.

    A five-comparator sorting network over whole arrays: the same values as ``np.sort`` (only
    comparisons, no arithmetic) several times faster than a sort or partition along an axis of 4.
    """
    a, b, c, d = (values[..., i] for i in range(4))
    a, b = np.minimum(a, b), np.maximum(a, b)
    c, d = np.minimum(c, d), np.maximum(c, d)
    a, c = np.minimum(a, c), np.maximum(a, c)
    b, d = np.minimum(b, d), np.maximum(b, d)
    b, c = np.minimum(b, c), np.maximum(b, c)
    return [a, b, c, d]


def _increments(X: np.ndarray) -> np.ndarray:
    """Row-to-row change of each channel; zero on the first row."""
    return np.diff(X, axis=0, prepend=X[:1])


class Statistical(Detector):
    """Rolling mean / std / variance / moving-average thresholds, combined by a k-of-n rule.

    At every row and channel four statistics of the trailing ``window`` rows are compared with
    thresholds learned from the normal training flights, each as a ratio (``> 1`` = exceeded):

    1. the value's z-score against the learned mean and standard deviation, over ``z_threshold``;
    2. the moving average's z-score against the learned distribution of moving averages, over
       ``z_threshold``;
    3. the rolling standard deviation of the row-to-row increments (the noise level), over its
       learned ``quantile``;
    4. the rolling variance of the values (the spread), over its learned ``quantile``.

    Statistics 3 and 4 use different signals on purpose: the standard deviation and the variance
    of the same window are monotone in each other and would always fire together, turning the
    "several thresholds at once" rule into a single test.

    A row is an alarm when at least ``min_exceed`` statistics exceed their threshold on the same
    channel (the paper's rule). The row score is, over channels, the largest ``min_exceed``-th
    largest ratio, so ``score > 1`` exactly when the rule fires.

    Parameters
    ----------
    window : int
        Rows in the trailing window (50 = 1 s at 50 Hz).
    z_threshold : float
        Standard deviations beyond which a value or a moving average is out of range.
    quantile : float
        Quantile (0..1) of the training rolling std / variance used as their thresholds.
    min_exceed : int
        Statistics (1..4) that must exceed their threshold at once on a channel.
    columns : list of str or None
        Sensor columns to use; None for every ``topic.field`` column.
    random_state : int
        Unused (the detector is deterministic); kept for the common interface.

    Attributes
    ----------
    value_mean_, value_std_ : ndarray (channels,)
        Learned mean and standard deviation of each channel.
    ma_mean_, ma_std_ : ndarray (channels,)
        Learned mean and standard deviation of the moving average.
    thresholds_ : ndarray (4, channels)
        Threshold of each statistic, in the order listed above.
    """

    name = "statistical"
    #: parameters counted in rows: a run refuses values not shorter than its shortest flight
    window_params = ("window",)
    relative_cost = 3.6  # us per row, paper flights (scheduling hint)
    description = "mean / std / variance / moving-average thresholds; alarm when several are exceeded at once"
    has_alarms = True

    def __init__(
        self,
        window: int = 50,
        z_threshold: float = 4.0,
        quantile: float = 0.999,
        min_exceed: int = 2,
        columns: list[str] | None = None,
        random_state: int = 0,
    ):
        self.window = window
        self.z_threshold = z_threshold
        self.quantile = quantile
        self.min_exceed = min_exceed
        self.columns = columns
        self.random_state = random_state

    def _check_params(self) -> None:
        if not 2 <= int(self.window) <= MAX_WINDOW_ROWS:
            raise DetectorError(f"{self.name}: window must be at least 2 and at most {MAX_WINDOW_ROWS:,} rows, got "
                                f"{self.window}; expected 2..{MAX_WINDOW_ROWS:,} rows, fewer than the shortest flight has")
        if not 1 <= int(self.min_exceed) <= N_STATISTICS:
            raise DetectorError(
                f"{self.name}: min_exceed must be in 1..{N_STATISTICS}, got {self.min_exceed}"
            )
        if not 0.0 < float(self.quantile) <= 1.0:
            raise DetectorError(f"{self.name}: quantile must be in (0, 1], got {self.quantile}")
        if not float(self.z_threshold) > 0.0:
            raise DetectorError(f"{self.name}: z_threshold must be positive, got {self.z_threshold}")

    def _rolling_statistics(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Moving average, rolling std of increments and rolling variance, each (rows, channels)."""
        w = int(self.window)
        return rolling_mean(X, w), np.sqrt(rolling_var(_increments(X), w)), rolling_var(X, w)

    def _fit(self, X_list: list[np.ndarray]) -> None:
        self._check_params()
        X = np.concatenate(X_list, axis=0)
        stats = [self._rolling_statistics(x) for x in X_list]
        ma, inc_std, var = (np.concatenate(parts, axis=0) for parts in zip(*stats))
        self.history_rows_ = int(self.window) + 1  # the trailing window and one row for its increments
        self.value_mean_ = X.mean(axis=0)
        self.value_std_ = np.maximum(X.std(axis=0), _EPS)
        self.ma_mean_ = ma.mean(axis=0)
        self.ma_std_ = np.maximum(ma.std(axis=0), _EPS)
        q = float(self.quantile)
        z = float(self.z_threshold)
        self.thresholds_ = np.stack(
            [
                np.full(X.shape[1], z),
                np.full(X.shape[1], z),
                np.maximum(np.quantile(inc_std, q, axis=0), _EPS),
                np.maximum(np.quantile(var, q, axis=0), _EPS),
            ]
        )

    def _ratios(self, X: np.ndarray) -> np.ndarray:
        """Ratio of each statistic to its threshold, shape (rows, channels, 4), for standardised ``X``."""
        ma, inc_std, var = self._rolling_statistics(X)
        raw = np.stack(
            [
                np.abs(X - self.value_mean_) / self.value_std_,
                np.abs(ma - self.ma_mean_) / self.ma_std_,
                inc_std,
                var,
            ],
            axis=-1,
        )
        return raw / self.thresholds_.T

    def _score(self, X: np.ndarray) -> np.ndarray:
        k = int(self.min_exceed)
        ratios = self._ratios(X)
        if np.isnan(ratios).any():  # np.partition's order for NaN (last), which the network below lacks
            kth_largest = np.partition(ratios, N_STATISTICS - k, axis=-1)[..., N_STATISTICS - k]
        else:
            kth_largest = _sorted4(ratios)[N_STATISTICS - k]
        return kth_largest.max(axis=1)

    def alarms(self, flight: pd.DataFrame) -> np.ndarray:
        """True on rows where at least ``min_exceed`` thresholds are exceeded at once on a channel."""
        return self.score(flight) > 1.0
