"""Threshold-free and range-based metrics as the TSB-AD benchmark defines them.

Paparrizos, Boniol, Palpanas, Tsay, Elmore and Franklin (2022), "Volume Under the Surface: a
new accuracy evaluation measure for time-series anomaly detection", PVLDB 15(11); Liu and
Paparrizos (2024), "The Elephant in the Room: Towards A Reliable Time-Series Anomaly Detection
Benchmark" (TSB-AD), NeurIPS 2024. The definitions follow TSB-AD's reference code
(``TSB_AD.evaluation``, package ``tsb-ad`` 1.5) so that the numbers are comparable with the
field's tables; ``tests/test_vus.py`` cross-checks them against that package.

- :func:`vus`: VUS-ROC and VUS-PR. The labels are extended by a soft border of ``w // 2`` rows
  on each side (``sqrt(1 - d / w)``), range-aware TPR / FPR / precision are computed at
  ``n_thresholds`` score thresholds, and the areas under the ROC and PR curves are averaged over
  the border widths ``w = 0 .. window``. Vectorised here with sorted cumulative sums (one pass
  per width), the reference loops over thresholds and ranges.
- :func:`auc_pr`: average precision (``sklearn.metrics.average_precision_score``, in array code);
  :func:`row_roc_auc`: row-level ROC-AUC; :func:`row_metrics`: ROC-AUC, AUC-PR and VUS of one
  series from one sort of its scores (the run's tables use it: 12 M pooled rows at paper scale).
- :func:`r_prf`: range-based precision / recall / F1 of binary predictions (Tatbul et al. 2018
  as TSB-AD parameterises it): recall with alpha 0.2 (existence reward), precision with alpha 0,
  flat positional bias, reciprocal cardinality; ranges are inclusive row ranges.

A series with no anomalous row has no VUS, AUC-PR or range recall: the functions return NaN
(the reference code cannot score it either).
"""

from __future__ import annotations

import numpy as np
from sklearn.metrics import roc_auc_score

#: Border width (rows) of VUS and number of score thresholds, TSB-AD's defaults are the
#: data's period (``slidingWindow``) and 250.
VUS_WINDOW = 100
VUS_THRESHOLDS = 250


def _ranges(label: np.ndarray) -> np.ndarray:
    """Inclusive ``[start, end]`` row ranges of the 1s of a 0/1 vector, ``(n, 2)``.

    As TSB-AD's ``range_convers_new``, which finds ranges from the changes of the vector: a
    vector that is 1 everywhere has no change and so no range (e.g. a detector alarming on every
    row of a flight gets range precision 0 and only the existence part of range recall).
    """
    x = np.asarray(label).reshape(-1).astype(np.int8)
    if x.size and x.all():
        return np.zeros((0, 2), dtype=np.int64)
    d = np.diff(np.concatenate(([0], x, [0])))
    return np.stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1], axis=1).astype(np.int64)


def _count_at_least(sorted_scores: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """For each threshold, how many of the (ascending) scores are >= it."""
    return sorted_scores.size - np.searchsorted(sorted_scores, thresholds, side="left")


def _border_distances(n: int, seq: np.ndarray, in_seq: np.ndarray, reach: int):
    """Rows outside the ranges within ``reach`` rows of one; per row, the distance to the end of
    the range before it, to the start of the range after it, and the smaller of the distances to
    the second range before and after it (``reach + 1`` when farther or absent). Only the rows
    within ``reach`` of a range are looked at (a long series with few ranges costs nothing)."""
    far, r = reach + 1, len(seq)
    offsets = np.arange(1, reach + 1)
    near = np.concatenate([(seq[:, 0:1] - offsets).ravel(), (seq[:, 1:2] + offsets).ravel()])
    rows = np.unique(near[(near >= 0) & (near < n)])
    rows = rows[~in_seq[rows]]
    k = np.searchsorted(seq[:, 1], rows, side="left") - 1  # last range ending before the row
    j = np.searchsorted(seq[:, 0], rows, side="right")  # first range starting after the row

    def gap(valid: np.ndarray, dist: np.ndarray) -> np.ndarray:
        return np.where(valid, np.minimum(dist, far), far)

    d_prev = gap(k >= 0, rows - seq[np.clip(k, 0, r - 1), 1])
    d_next = gap(j < r, seq[np.clip(j, 0, r - 1), 0] - rows)
    d_second = np.minimum(gap(k >= 1, rows - seq[np.clip(k - 1, 0, r - 1), 1]),
                          gap(j + 1 < r, seq[np.clip(j + 1, 0, r - 1), 0] - rows))
    return rows, d_prev, d_next, d_second


def _reach_max(score: np.ndarray, starts: np.ndarray, step: int, reach: int) -> np.ndarray:
    """``(ranges, reach + 1)``: the largest score among rows ``starts + step * 1..d`` (clipped to
    the series) for d = 0..reach; -inf for d = 0."""
    d = np.arange(1, reach + 1)
    idx = starts[:, None] + step * d[None, :]
    vals = np.where((idx >= 0) & (idx < score.size), score[np.clip(idx, 0, score.size - 1)], -np.inf)
    return np.maximum.accumulate(np.hstack([np.full((len(starts), 1), -np.inf), vals]), axis=1)


def vus(labels: np.ndarray, scores: np.ndarray, window: int = VUS_WINDOW,
        n_thresholds: int = VUS_THRESHOLDS) -> tuple[float, float]:
    """``(VUS-ROC, VUS-PR)`` of per-row ``scores`` against 0/1 ``labels``; NaN without anomalies.

    At border width ``w`` (``h = w // 2``), a row outside the true ranges weighs
    ``min(1, sum of sqrt(1 - d / w))`` over the range borders ``d <= h`` rows away (TSB-AD
    ``sequencing``; each term is at least ``sqrt(1/2)``, so two borders make 1); only the rows within ``window // 2`` of a range ever weigh anything, so they
    are sorted by score once and weighed for every width in one array. TP at a threshold is the
    number of true rows plus the border weight at or above it; the label mass adds the same border
    weight to the true rows (TSB-AD's ``l``-window bookkeeping reduces to this).
    """
    label = np.asarray(labels).reshape(-1).astype(np.int64)
    score = np.asarray(scores, dtype=np.float64).reshape(-1)
    if label.shape != score.shape:
        raise ValueError(f"vus: {label.size} labels for {score.size} scores")
    n = label.size
    seq = _ranges(label)
    if n == 0 or len(seq) == 0:
        return float("nan"), float("nan")
    return _vus_sorted(label, score, np.sort(score), np.sort(score[label.astype(bool)]), seq, int(window),
                       n_thresholds)


def _vus_sorted(label: np.ndarray, score: np.ndarray, ascending: np.ndarray, true_ascending: np.ndarray,
                seq: np.ndarray, window: int, n_thresholds: int) -> tuple[float, float]:
    """:func:`vus` given the sorted scores of all rows and of the anomalous rows, and the ranges."""
    n = label.size
    reach = window // 2
    in_seq = label.astype(bool)
    p_total = float(label.sum())
    thresholds = ascending[::-1][np.linspace(0, n - 1, n_thresholds).astype(int)]
    n_pred = _count_at_least(ascending, thresholds).astype(np.float64)
    true_at = _count_at_least(true_ascending, thresholds).astype(np.float64)
    # border rows sorted by score; for every width the weights of those at or above each threshold
    rows, d_prev, d_next, d_second = _border_distances(n, seq, in_seq, reach)
    order = np.argsort(score[rows], kind="stable")
    d_prev, d_next, d_second = d_prev[order], d_next[order], d_second[order]
    above = np.searchsorted(score[rows][order], thresholds, side="left")
    widths = np.arange(window + 1)
    border_at = np.zeros((window + 1, n_thresholds))
    block = max(1, min(window + 1, 1_000_000 // max(len(rows), 1)))  # blocks of widths bound the memory
    for lo in range(0, window + 1, block):
        w = widths[lo : lo + block, None].astype(np.float64)
        h = widths[lo : lo + block, None] // 2
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = (np.where(d_prev <= h, np.sqrt(1 - d_prev / w), 0.0)
                      + np.where(d_next <= h, np.sqrt(1 - d_next / w), 0.0)
                      + (d_second <= h))  # a second range as near: two borders, weight 1
        csum = np.hstack([np.zeros((len(w), 1)), np.cumsum(np.minimum(weight, 1.0), axis=1)])
        border_at[lo : lo + block] = csum[:, -1:] - csum[:, above]
    # existence: per width, the merged widened ranges whose largest score reaches the threshold
    inner = np.maximum.reduceat(np.append(score, -np.inf), np.column_stack([seq[:, 0], seq[:, 1] + 1]).ravel())[::2]
    left = _reach_max(score, seq[:, 0], -1, reach)
    right = _reach_max(score, seq[:, 1], 1, reach)
    hs = np.arange(reach + 1)
    widened = np.maximum(inner[None, :], np.maximum(left.T, right.T))  # (h, ranges)
    split = seq[None, :-1, 1] + hs[:, None] < seq[None, 1:, 0] - hs[:, None]  # TSB-AD new_sequence
    group = np.hstack([np.zeros((len(hs), 1), dtype=np.int64), np.cumsum(split, axis=1)])
    seg_max = np.full(widened.shape, -np.inf)
    np.maximum.at(seg_max, (np.repeat(hs, len(seq)), group.ravel()), widened.ravel())
    if seg_max.size * n_thresholds <= 4_000_000:
        reached = (seg_max[:, :, None] >= thresholds[None, None, :]).sum(axis=1)
    else:  # many ranges: one sorted count per border width
        reached = np.stack([_count_at_least(np.sort(m), thresholds) for m in seg_max])
    existence = (reached / (group[:, -1:] + 1))[widths // 2]  # (widths, thresholds)
    tp = true_at[None, :] + border_at
    p_new = (p_total + (p_total + border_at)) / 2.0
    tpr = np.minimum(tp / p_new, 1.0) * existence
    fpr = (n_pred - tp) / (n - p_new)
    precision = tp / n_pred
    ones, zeros = np.ones((len(widths), 1)), np.zeros((len(widths), 1))
    roc_x, roc_y = np.hstack([zeros, fpr, ones]), np.hstack([zeros, tpr, ones])
    aucs = ((roc_x[:, 1:] - roc_x[:, :-1]) * (roc_y[:, 1:] + roc_y[:, :-1]) / 2.0).sum(axis=1)
    aps = (np.diff(np.hstack([zeros, tpr]), axis=1) * precision).sum(axis=1)
    return float(aucs.mean()), float(aps.mean())


def average_precision(labels: np.ndarray, scores: np.ndarray) -> float:
    """Average precision (``sklearn.metrics.average_precision_score`` for 0/1 labels, to rounding):
    the sum over distinct score thresholds, highest first, of the recall gained times the precision
    there. NaN without positives. Array code: the bootstrap and the per-flight scores call it thousands of times per run."""
    y = np.asarray(labels, dtype=np.float64).reshape(-1)
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    if y.shape != s.shape:
        raise ValueError(f"average_precision: {y.size} labels for {s.size} scores")
    if not y.any():
        return float("nan")
    return _average_precision_sorted(np.sort(s), np.sort(s[y != 0]))


def _average_precision_sorted(ascending: np.ndarray, true_ascending: np.ndarray) -> float:
    """Average precision from the sorted scores of all rows and of the positive rows: at each
    distinct score, highest first, the rows at or above it and the positives among them (counts,
    so the sum is the same whatever sort produced them)."""
    n = ascending.size
    first = np.flatnonzero(np.r_[True, ascending[1:] != ascending[:-1]])  # first row of each distinct score
    above = (n - first)[::-1].astype(np.float64)  # rows at or above each distinct score, highest first
    tps = (true_ascending.size - np.searchsorted(true_ascending, ascending[first], side="left"))[::-1]
    tps = tps.astype(np.float64)
    precision = tps / above
    recall = tps / tps[-1]
    return float(np.sum(np.diff(recall, prepend=0.0) * precision))


def roc_auc_from_sorted(ascending: np.ndarray, true_ascending: np.ndarray) -> float:
    """ROC-AUC as Mann-Whitney U with average ranks, from the sorted scores of all rows and of the
    positive rows: twice a positive's average rank is (rows below) + (rows at or below) + 1, summed
    in integers, so ties count half and the value is exact to one rounding."""
    n_pos = true_ascending.size
    n_neg = ascending.size - n_pos
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    twice = int(np.searchsorted(ascending, true_ascending, side="left").sum()
                + np.searchsorted(ascending, true_ascending, side="right").sum()) + n_pos
    return (twice - n_pos * (n_pos + 1)) / (2 * n_pos * n_neg)


def auc_pr(labels: np.ndarray, scores: np.ndarray) -> float:
    """Average precision of the scores (NaN without an anomalous row)."""
    return average_precision(labels, scores)


def row_roc_auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Row-level ROC-AUC (NaN when a class is empty)."""
    y = np.asarray(labels).reshape(-1).astype(np.int64)
    if y.all() or not y.any():
        return float("nan")
    return float(roc_auc_score(y, np.asarray(scores, dtype=np.float64).reshape(-1)))


def row_metrics(labels: np.ndarray, scores: np.ndarray, window: int = VUS_WINDOW,
                n_thresholds: int = VUS_THRESHOLDS) -> dict[str, float]:
    """Row ROC-AUC, AUC-PR, VUS-ROC and VUS-PR of one series from one sort of its scores (the
    values of :func:`row_roc_auc`, :func:`auc_pr` and :func:`vus`; NaN where those are)."""
    label = np.asarray(labels).reshape(-1).astype(np.int64)
    score = np.asarray(scores, dtype=np.float64).reshape(-1)
    if label.shape != score.shape:
        raise ValueError(f"row_metrics: {label.size} labels for {score.size} scores")
    if label.size and (label.min() < 0 or label.max() > 1):
        raise ValueError("row_metrics: labels must be 0 or 1")
    ascending = np.sort(score)
    true_ascending = np.sort(score[label == 1])
    out = {"roc_auc": roc_auc_from_sorted(ascending, true_ascending), "auc_pr": float("nan"),
           "vus_roc": float("nan"), "vus_pr": float("nan")}
    if true_ascending.size:
        out["auc_pr"] = _average_precision_sorted(ascending, true_ascending)
        seq = _ranges(label)
        if len(seq):
            out["vus_roc"], out["vus_pr"] = _vus_sorted(label, score, ascending, true_ascending, seq, int(window),
                                                        n_thresholds)
    return out


def _range_recall(label: np.ndarray, pred: np.ndarray, alpha: float) -> float:
    """Per range of ``label``: ``alpha`` for being hit at all plus ``1 - alpha`` times the covered
    fraction (flat bias) over the number of ``pred`` ranges touching it (reciprocal cardinality);
    averaged over the ranges. Counts from one cumulative sum, so a long series costs two passes."""
    real, predicted = _ranges(label), _ranges(pred)
    if len(real) == 0:
        return 0.0
    csum = np.r_[0, np.cumsum(pred != 0, dtype=np.int64)]
    hit_rows = csum[real[:, 1] + 1] - csum[real[:, 0]]
    existence = (hit_rows > 0).astype(np.float64)
    covered = hit_rows / (real[:, 1] - real[:, 0] + 1)
    # ranges are sorted and disjoint: those touching [a, b] start at or before b and do not end before a
    touching = (np.searchsorted(predicted[:, 0], real[:, 1], side="right")
                - np.searchsorted(predicted[:, 1], real[:, 0], side="left"))
    overlap = np.where(touching > 0, covered / np.maximum(touching, 1), 0.0)
    return float((alpha * existence.sum() + (1 - alpha) * overlap.sum()) / len(real))


def r_prf(labels: np.ndarray, predictions: np.ndarray) -> tuple[float, float, float]:
    """TSB-AD's range-based (precision, recall, F1) of 0/1 predictions against 0/1 labels."""
    y = np.asarray(labels).reshape(-1)
    p = np.asarray(predictions).reshape(-1)
    if y.shape != p.shape:
        raise ValueError(f"r_prf: {y.size} labels for {p.size} predictions")
    recall = _range_recall(y, p, 0.2)
    precision = _range_recall(p, y, 0.0)
    f1 = 0.0 if precision + recall == 0 else 2 * recall * precision / (precision + recall)
    return precision, recall, f1
