"""Confidence intervals of the benchmark's rates and threshold-free scores.

- :func:`wilson`: the 95 % Wilson score interval of a binomial rate ``k / n`` (Wilson 1927). It
  stays inside [0, 1] and is sensible for the small counts of a benchmark table (11 attacked
  flights make a rate move in 9 % steps); the normal-approximation interval is not.
- :func:`design_interval` with :func:`cluster_weights`: the interval of a rate under clustering and
  the threshold's own uncertainty (see :mod:`scart_bench.benchmark.metrics`'s ``PaperTable``).
- :func:`bootstrap_auc`: a percentile bootstrap interval of a two-sample score (ROC-AUC, AUC-PR)
  over flights: normal and attacked flights are resampled with replacement separately, so every
  resample has both classes. Seeded, so the same scores always give the same interval.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

#: Two-sided 95 % standard normal quantile.
Z95 = 1.959963984540054
#: Bootstrap resamples and seed of the intervals in the tables.
N_BOOTSTRAP = 1000
BOOTSTRAP_SEED = 0


def wilson(k: float, n: float, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval ``(low, high)`` of ``k`` successes in ``n`` trials; NaN when n = 0."""
    n = float(n)
    if n <= 0 or math.isnan(n) or math.isnan(float(k)):
        return float("nan"), float("nan")
    k = float(k)
    if not 0 <= k <= n:
        raise ValueError(f"wilson: {k} successes out of {n} trials")
    p = k / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2.0 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z2 / (4.0 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_auc(metric: Callable[[np.ndarray, np.ndarray], float], normal: np.ndarray, attacked: np.ndarray,
                  n_boot: int = N_BOOTSTRAP, seed: int = BOOTSTRAP_SEED, level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap interval of ``metric(labels, scores)`` over flight scores.

    ``normal`` / ``attacked``: one score per flight of each class, resampled separately.
    NaN when a class is empty.
    """
    a = np.asarray(normal, dtype=np.float64).reshape(-1)
    b = np.asarray(attacked, dtype=np.float64).reshape(-1)
    if a.size == 0 or b.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    labels = np.r_[np.zeros(a.size), np.ones(b.size)]
    ia = rng.integers(0, a.size, size=(n_boot, a.size))
    ib = rng.integers(0, b.size, size=(n_boot, b.size))
    values = np.array([metric(labels, np.r_[a[x], b[y]]) for x, y in zip(ia, ib)])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return float("nan"), float("nan")
    tail = (1.0 - level) / 2.0
    lo, hi = np.quantile(values, [tail, 1.0 - tail])
    return float(lo), float(hi)


def cluster_weights(clusters: np.ndarray, strata: np.ndarray, n_boot: int,
                    rng: np.random.Generator) -> np.ndarray:
    """``(n_boot, n)`` bootstrap weights: how often each item's cluster was drawn when the clusters
    of every stratum are resampled with replacement (as many as the stratum has)."""
    clusters = np.asarray(clusters).reshape(-1)
    strata = np.asarray(strata).reshape(-1)
    codes, inv = np.unique(clusters.astype(str), return_inverse=True)
    counts = np.zeros((n_boot, codes.size))
    for s in np.unique(strata.astype(str)):
        members = np.unique(inv[strata.astype(str) == s])
        draws = rng.integers(0, members.size, size=(n_boot, members.size))
        flat = (draws + np.arange(n_boot)[:, None] * members.size).ravel()
        counts[:, members] = np.bincount(flat, minlength=n_boot * members.size).reshape(n_boot, members.size)
    return counts[:, inv]


def design_effect(k: float, n: float, boot: np.ndarray) -> float:
    """Kish's design effect of a rate ``k / n`` from its bootstrap replicates: ``var(boot)`` over
    the binomial variance ``p (1 - p) / n``; NaN when the rate is 0 or 1 (no spread to measure)."""
    b = np.asarray(boot, dtype=np.float64)
    b = b[np.isfinite(b)]
    p = k / n if n > 0 else float("nan")
    if not (0.0 < p < 1.0) or b.size < 2:
        return float("nan")
    return float(b.var()) / (p * (1.0 - p) / n)


def design_interval(k: float, n: float, boot: np.ndarray, n_eff_fallback: float, z: float = Z95,
                    level: float = 0.95) -> tuple[float, float]:
    """The interval of a rate ``k / n`` from its bootstrap replicates ``boot`` (clusters and the
    threshold resampled): the hull of the percentile interval and the Wilson interval at the
    bootstrap's effective sample size ``n_eff = n / deff`` (:func:`design_effect`; at most ``n``).
    When the rate is 0 or 1 the bootstrap has no spread to measure the design effect from, and
    ``n_eff = n_eff_fallback`` (the caller's estimate from a rate of the same flights, or the number
    of independent units). NaN when ``n`` is 0."""
    if n <= 0:
        return float("nan"), float("nan")
    p = k / n
    b = np.asarray(boot, dtype=np.float64)
    b = b[np.isfinite(b)]
    var = float(b.var()) if b.size > 1 else 0.0
    if 0.0 < p < 1.0 and var > 0.0:
        n_eff = min(float(n), p * (1.0 - p) / var)
    else:
        n_eff = min(float(n), float(max(n_eff_fallback, 1.0)))
    w_lo, w_hi = wilson(p * n_eff, n_eff, z)
    if b.size == 0:
        return w_lo, w_hi
    tail = (1.0 - level) / 2.0
    b_lo, b_hi = np.quantile(b, [tail, 1.0 - tail])
    return float(min(w_lo, b_lo)), float(max(w_hi, b_hi))
