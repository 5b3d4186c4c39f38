"""The detectors' compiled kernels (numba), in one module so that numba's on-disk cache, which is
keyed by the file of each function, is renewed for all of them when any changes (a cached kernel
keeps the compiled code of the functions it calls).

Each gives the same bits as the numpy expression it replaced, so scores did not move when it came
in (``tests/test_detector_kernels.py`` holds them to those expressions): sums follow numpy's
floating-point summation orders (:func:`pairwise_sum`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _block_sum(x: np.ndarray, lo: int, n: int):
    """numpy's sum of a run of at most 128 values: in order below 8, else 8 partial sums."""
    acc = np.zeros(1, dtype=x.dtype)
    if n < 8:
        for i in range(n):
            acc[0] = acc[0] + x[lo + i]
        return acc[0]
    r = np.empty(8, dtype=x.dtype)
    for j in range(8):
        r[j] = x[lo + j]
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] = r[j] + x[lo + i + j]
        i += 8
    acc[0] = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        acc[0] = acc[0] + x[lo + i]
        i += 1
    return acc[0]


@njit(cache=True, nogil=True)
def pairwise_sum(x: np.ndarray, lo: int, n: int):
    """``x[lo:lo + n]`` summed in ``x``'s dtype as numpy's ``add.reduce`` sums a run along its
    inner loop: blocks of at most 128 values (:func:`_block_sum`), halved above that and the halves
    added. The halving is walked with a stack, not recursion (numba's cache cannot hold recursion)."""
    if n <= 128:
        return _block_sum(x, lo, n)
    s_lo = np.empty(64, dtype=np.int64)
    s_n = np.empty(64, dtype=np.int64)
    stage = np.zeros(64, dtype=np.int64)  # 0: not split yet, 1: left half pending, 2: right half pending
    left = np.empty(64, dtype=x.dtype)
    value = left[:1].copy()
    top = 0
    s_lo[0], s_n[0] = lo, n
    while top >= 0:
        if s_n[top] > 128:  # split: the left half first
            half = s_n[top] // 2
            half -= half % 8
            stage[top] = 1
            s_lo[top + 1], s_n[top + 1], stage[top + 1] = s_lo[top], half, 0
            top += 1
            continue
        value[0] = _block_sum(x, s_lo[top], s_n[top])
        top -= 1
        while top >= 0:  # hand the value up
            if stage[top] == 1:  # it was the left half: now the right one
                left[top] = value[0]
                stage[top] = 2
                half = s_n[top] // 2
                half -= half % 8
                s_lo[top + 1], s_n[top + 1], stage[top + 1] = s_lo[top] + half, s_n[top] - half, 0
                top += 1
                break
            value[0] = left[top] + value[0]  # it was the right half: the node's sum
            top -= 1
    return value[0]


@njit(cache=True, nogil=True)
def _segment_sum(x: np.ndarray, lo: int, hi: int, column: int) -> np.float32:
    """``x[lo:hi, column]`` summed as numpy's ``add.reduceat`` sums a float32 window segment:
    the first value plus the others in numpy's pairwise order."""
    return x[lo, column] + pairwise_sum(x[:, column], lo + 1, hi - lo - 1)


@njit(cache=True, nogil=True)
def window_features(X: np.ndarray, w: int, bounds: np.ndarray, step: int, stats: bool) -> np.ndarray:
    """Per window of ``w`` rows of ``X`` (every ``step`` rows): the mean of each segment
    ``bounds[j]:bounds[j+1]`` per channel, then (``stats``) each channel's standard deviation and
    that of its row-to-row increments; in float32, bit for bit numpy's ``add.reduceat`` / ``std``
    over the window view (what this replaced), in one pass without the view's temporaries."""
    n_rows, ch = X.shape
    n = (n_rows - w) // step + 1
    k = bounds.size - 1
    out = np.empty((n, k * ch + (2 * ch if stats else 0)), dtype=np.float32)
    diff = np.empty((max(w - 1, 1), ch), dtype=np.float32)
    for r in range(n):
        s = r * step
        for c in range(ch):
            for j in range(k):
                length = np.float32(bounds[j + 1] - bounds[j])
                out[r, j * ch + c] = _segment_sum(X, s + bounds[j], s + bounds[j + 1], c) / length
        if not stats:
            continue
        for c in range(ch):  # numpy's std over the window axis: sums row after row
            total = X[s, c]
            for i in range(1, w):
                total = total + X[s + i, c]
            mean = total / np.float32(w)
            d = X[s, c] - mean
            var = d * d
            for i in range(1, w):
                d = X[s + i, c] - mean
                var = var + d * d
            out[r, k * ch + c] = np.sqrt(var / np.float32(w))
            for i in range(w - 1):
                diff[i, c] = X[s + i + 1, c] - X[s + i, c]
            total = diff[0, c]
            for i in range(1, w - 1):
                total = total + diff[i, c]
            mean = total / np.float32(w - 1)
            d = diff[0, c] - mean
            var = d * d
            for i in range(1, w - 1):
                d = diff[i, c] - mean
                var = var + d * d
            out[r, (k + 1) * ch + c] = np.sqrt(var / np.float32(w - 1))
    return out


@njit(cache=True, nogil=True)
def bitmap_distances(cells_of: np.ndarray, cells: int, lag_start: np.ndarray, lead_start: np.ndarray,
                      end: np.ndarray, full_history: float) -> np.ndarray:
    """Per row, the weighted squared distance between the max-normalised cell counts of the lag
    window ``[lag_start, lead_start)`` and the lead window ``[lead_start, end)``.

    The windows only move forward, so their counts are kept up to date word by word; the result
    is bit for bit the array expression it replaced (counts from prefix sums, numpy's pairwise sum
    over the cells), without its (rows x cells) temporaries.
    """
    n = cells_of.size
    lag = np.zeros(cells, dtype=np.int64)
    lead = np.zeros(cells, dtype=np.int64)
    sq = np.empty(cells)
    out = np.empty(n)
    a = b = c = 0  # the counted windows: lag [a, b), lead [b, c)
    for t in range(n):
        while c < end[t]:
            lead[cells_of[c]] += 1
            c += 1
        while b < lead_start[t]:
            lead[cells_of[b]] -= 1
            lag[cells_of[b]] += 1
            b += 1
        while a < lag_start[t]:
            lag[cells_of[a]] -= 1
            a += 1
        peak_lag = peak_lead = 0
        for k in range(cells):
            peak_lag = max(peak_lag, lag[k])
            peak_lead = max(peak_lead, lead[k])
        for k in range(cells):
            d = (lead[k] / peak_lead if peak_lead > 0 else 0.0) - (lag[k] / peak_lag if peak_lag > 0 else 0.0)
            sq[k] = d * d
        weight = min(1.0, (end[t] - lag_start[t]) / full_history) if lead_start[t] > lag_start[t] else 0.0
        out[t] = pairwise_sum(sq, 0, cells) * weight
    return out
