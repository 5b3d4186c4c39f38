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
def _plus_zero(v):
    """``v + 0.0`` in ``v``'s own type (-0.0 becomes 0.0), as numpy's sums start from 0."""
    return v if v != 0 else abs(v)


@njit(cache=True, nogil=True)
def _block_sum(x: np.ndarray, lo: int, n: int):
    """numpy's sum of a run of 1 to 128 values: in order below 8, else 8 partial sums (in
    registers: an allocation per call would cost more than the sum)."""
    if n < 8:
        acc = _plus_zero(x[lo])
        for i in range(1, n):
            acc = acc + x[lo + i]
        return acc
    r0, r1, r2, r3 = x[lo], x[lo + 1], x[lo + 2], x[lo + 3]
    r4, r5, r6, r7 = x[lo + 4], x[lo + 5], x[lo + 6], x[lo + 7]
    i = 8
    while i < n - n % 8:
        r0, r1, r2, r3 = r0 + x[lo + i], r1 + x[lo + i + 1], r2 + x[lo + i + 2], r3 + x[lo + i + 3]
        r4, r5, r6, r7 = r4 + x[lo + i + 4], r5 + x[lo + i + 5], r6 + x[lo + i + 6], r7 + x[lo + i + 7]
        i += 8
    acc = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        acc = acc + x[lo + i]
        i += 1
    return acc


@njit(cache=True, nogil=True)
def pairwise_sum(x: np.ndarray, lo: int, n: int):
    """``x[lo:lo + n]`` (n >= 1) summed in ``x``'s dtype as numpy's ``add.reduce`` sums a run along
    its inner loop: blocks of at most 128 values (:func:`_block_sum`), halved above that and the
    halves added. The halving is walked with a stack, not recursion (numba's cache cannot hold
    recursion)."""
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
def _segment_sums(X: np.ndarray, lo: int, hi: int, out: np.ndarray, parts: np.ndarray) -> None:
    """``out[c] = X[lo:hi, c].sum()`` for every channel as numpy's ``add.reduceat`` sums a float32
    window segment: the first row plus the others in numpy's pairwise order (plus 0 when there are
    none). The loops run over the channels innermost, so that they vectorise; ``parts`` is
    scratch space of shape (8, channels)."""
    ch = X.shape[1]
    m = hi - lo - 1  # values after the first
    if m > 128:  # long segments: channel by channel (rare)
        for c in range(ch):
            out[c] = X[lo, c] + pairwise_sum(X[:, c], lo + 1, m)
        return
    if m == 0:
        for c in range(ch):
            out[c] = _plus_zero(X[lo, c])
        return
    if m < 8:
        for c in range(ch):
            out[c] = _plus_zero(X[lo + 1, c])
        for i in range(lo + 2, hi):
            for c in range(ch):
                out[c] = out[c] + X[i, c]
    else:
        for j in range(8):
            for c in range(ch):
                parts[j, c] = X[lo + 1 + j, c]
        i = 8
        while i < m - m % 8:
            for j in range(8):
                for c in range(ch):
                    parts[j, c] = parts[j, c] + X[lo + 1 + i + j, c]
            i += 8
        for c in range(ch):
            out[c] = ((parts[0, c] + parts[1, c]) + (parts[2, c] + parts[3, c])) + (
                (parts[4, c] + parts[5, c]) + (parts[6, c] + parts[7, c]))
        while i < m:
            for c in range(ch):
                out[c] = out[c] + X[lo + 1 + i, c]
            i += 1
    for c in range(ch):
        out[c] = X[lo, c] + out[c]


@njit(cache=True, nogil=True)
def _std_rows(V: np.ndarray, lo: int, hi: int, total: np.ndarray, out: np.ndarray) -> None:
    """``out[c] = V[lo:hi, c].std()`` as numpy computes it over a window view whose channels are
    the inner loop: sums row after row, the mean, then the squared deviations row after row."""
    ch = V.shape[1]
    n = np.float32(hi - lo)
    for c in range(ch):
        total[c] = V[lo, c]
    for i in range(lo + 1, hi):
        for c in range(ch):
            total[c] = total[c] + V[i, c]
    for c in range(ch):
        total[c] = total[c] / n
    for c in range(ch):
        d = V[lo, c] - total[c]
        out[c] = d * d
    for i in range(lo + 1, hi):
        for c in range(ch):
            d = V[i, c] - total[c]
            out[c] = out[c] + d * d
    for c in range(ch):
        out[c] = np.sqrt(out[c] / n)


@njit(cache=True, nogil=True)
def window_features(X: np.ndarray, w: int, bounds: np.ndarray, step: int, stats: bool) -> np.ndarray:
    """Per window of ``w`` rows of ``X`` (every ``step`` rows): the mean of each segment
    ``bounds[j]:bounds[j+1]`` per channel, then (``stats``) each channel's standard deviation and
    that of its row-to-row increments; in float32, bit for bit numpy's ``add.reduceat`` / ``std``
    over the window view (what this replaced), without the view's temporaries."""
    n_rows, ch = X.shape
    n = (n_rows - w) // step + 1
    k = bounds.size - 1
    out = np.empty((n, k * ch + (2 * ch if stats else 0)), dtype=np.float32)
    diff = np.empty((max(n_rows - 1, 1), ch), dtype=np.float32)  # row-to-row increments, once
    for i in range(n_rows - 1):
        for c in range(ch):
            diff[i, c] = X[i + 1, c] - X[i, c]
    parts = np.empty((8, ch), dtype=np.float32)
    sums = np.empty(ch, dtype=np.float32)
    total = np.empty(ch, dtype=np.float32)
    for r in range(n):
        s = r * step
        for j in range(k):
            _segment_sums(X, s + bounds[j], s + bounds[j + 1], sums, parts)
            length = np.float32(bounds[j + 1] - bounds[j])
            for c in range(ch):
                out[r, j * ch + c] = sums[c] / length
        if stats:
            _std_rows(X, s, s + w, total, out[r, k * ch : (k + 1) * ch])
            _std_rows(diff, s, s + w - 1, total, out[r, (k + 1) * ch :])
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
