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
- :func:`auc_pr`: average precision (``sklearn.metrics.average_precision_score``);
  :func:`row_roc_auc`: row-level ROC-AUC.
- :func:`r_prf`: range-based precision / recall / F1 of binary predictions (Tatbul et al. 2018
  as TSB-AD parameterises it): recall with alpha 0.2 (existence reward), precision with alpha 0,
  flat positional bias, reciprocal cardinality; ranges are inclusive row ranges.

A series with no anomalous row has no VUS, AUC-PR or range recall: the functions return NaN
(the reference code cannot score it either).
"""

from __future__ import annotations

import numpy as np
from sklearn.metrics import average_precision_score, roc_auc_score

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


def _merged(seq: np.ndarray, w: int, length: int) -> list[tuple[int, int]]:
    """Ranges widened by ``w // 2`` each side, overlapping ones merged (TSB-AD ``new_sequence``)."""
    h = w // 2
    out = []
    a = max(int(seq[0, 0]) - h, 0)
    for i in range(len(seq) - 1):
        if seq[i, 1] + h < seq[i + 1, 0] - h:
            out.append((a, int(seq[i, 1]) + h))
            a = int(seq[i + 1, 0]) - h
    out.append((a, min(int(seq[-1, 1]) + h, length - 1)))
    return out


def _extended(label: np.ndarray, seq: np.ndarray, w: int) -> np.ndarray:
    """Labels with a soft border of ``w // 2`` rows each side (TSB-AD ``sequencing``)."""
    ext = label.astype(np.float64).copy()
    n = ext.size
    h = w // 2
    for s, e in seq:
        x1 = np.arange(e + 1, min(e + h + 1, n))
        ext[x1] += np.sqrt(1 - (x1 - e) / w)
        x2 = np.arange(max(s - h, 0), s)
        ext[x2] += np.sqrt(1 - (s - x2) / w)
    return np.minimum(1.0, ext)


def _mask(length: int, segments) -> np.ndarray:
    m = np.zeros(length, dtype=bool)
    for a, b in segments:
        m[a : b + 1] = True
    return m


def _count_at_least(sorted_scores: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """For each threshold, how many of the (ascending) scores are >= it."""
    return sorted_scores.size - np.searchsorted(sorted_scores, thresholds, side="left")


def _sum_at_least(sorted_scores: np.ndarray, weights_csum: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """For each threshold, the sum of the weights of the scores >= it (``weights_csum``: cumsum
    of the weights in ascending score order, with a leading 0)."""
    idx = np.searchsorted(sorted_scores, thresholds, side="left")
    return weights_csum[-1] - weights_csum[idx]


def vus(labels: np.ndarray, scores: np.ndarray, window: int = VUS_WINDOW,
        n_thresholds: int = VUS_THRESHOLDS) -> tuple[float, float]:
    """``(VUS-ROC, VUS-PR)`` of per-row ``scores`` against 0/1 ``labels``; NaN without anomalies."""
    label = np.asarray(labels).reshape(-1).astype(np.int64)
    score = np.asarray(scores, dtype=np.float64).reshape(-1)
    if label.shape != score.shape:
        raise ValueError(f"vus: {label.size} labels for {score.size} scores")
    n = label.size
    seq = _ranges(label)
    if n == 0 or len(seq) == 0:
        return float("nan"), float("nan")
    window = int(window)
    p_total = float(label.sum())
    outer = _mask(n, _merged(seq, window, n))  # TSB-AD's ``l``: ranges widened by the largest border
    in_seq = label.astype(bool)
    thresholds = -np.sort(-score)[np.linspace(0, n - 1, n_thresholds).astype(int)]
    n_pred = _count_at_least(np.sort(score), thresholds).astype(np.float64)
    aucs, aps = [], []
    for w in range(window + 1):
        ext = _extended(label, seq, w)
        segs = _merged(seq, w, n)
        in_l = _mask(n, segs)
        # rows of ``outer``: inside a true range count 1; inside a widened range their border
        # weight only when predicted; elsewhere their border weight always (it is 0 there)
        sel = outer
        s_sel = score[sel]
        order = np.argsort(s_sel, kind="stable")
        s_sorted = s_sel[order]
        seq_sel, l_sel, e_sel = in_seq[sel][order], in_l[sel][order], ext[sel][order]
        c_tp = np.where(seq_sel, 1.0, e_sel)
        tp = _sum_at_least(s_sorted, np.r_[0.0, np.cumsum(c_tp)], thresholds)
        fixed = float(seq_sel.sum()) + float(e_sel[~seq_sel & ~l_sel].sum())
        c_lab = np.where(~seq_sel & l_sel, e_sel, 0.0)
        n_labels = fixed + _sum_at_least(s_sorted, np.r_[0.0, np.cumsum(c_lab)], thresholds)
        seg_max = np.sort(np.array([score[a : b + 1].max() for a, b in segs]))
        existence = _count_at_least(seg_max, thresholds) / len(segs)
        p_new = (p_total + n_labels) / 2.0
        tpr = np.minimum(tp / p_new, 1.0) * existence
        fpr = (n_pred - tp) / (n - p_new)
        precision = tp / n_pred
        roc_x = np.r_[0.0, fpr, 1.0]
        roc_y = np.r_[0.0, tpr, 1.0]
        aucs.append(float(np.dot(roc_x[1:] - roc_x[:-1], (roc_y[1:] + roc_y[:-1]) / 2.0)))
        aps.append(float(np.dot(np.diff(np.r_[0.0, tpr]), precision)))
    return float(sum(aucs) / len(aucs)), float(sum(aps) / len(aps))


def auc_pr(labels: np.ndarray, scores: np.ndarray) -> float:
    """Average precision of the scores (NaN without an anomalous row)."""
    y = np.asarray(labels).reshape(-1).astype(np.int64)
    if not y.any():
        return float("nan")
    return float(average_precision_score(y, np.asarray(scores, dtype=np.float64).reshape(-1)))


def row_roc_auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Row-level ROC-AUC (NaN when a class is empty)."""
    y = np.asarray(labels).reshape(-1).astype(np.int64)
    if y.all() or not y.any():
        return float("nan")
    return float(roc_auc_score(y, np.asarray(scores, dtype=np.float64).reshape(-1)))


def _overlap_reward(real: np.ndarray, pred: np.ndarray, hits: np.ndarray) -> np.ndarray:
    """Per real range: covered fraction (flat bias) times 1 / number of predicted ranges touching it."""
    csum = np.r_[0, np.cumsum(hits)]
    covered = (csum[real[:, 1] + 1] - csum[real[:, 0]]) / (real[:, 1] - real[:, 0] + 1)
    if len(pred) == 0:
        return np.zeros(len(real))
    touching = ((pred[None, :, 0] <= real[:, None, 1]) & (pred[None, :, 1] >= real[:, None, 0])).sum(axis=1)
    return np.where(touching > 0, covered / np.maximum(touching, 1), 0.0)


def _range_recall(label: np.ndarray, pred: np.ndarray, alpha: float) -> float:
    real, predicted = _ranges(label), _ranges(pred)
    if len(real) == 0:
        return 0.0
    existence = np.array([pred[a : b + 1].any() for a, b in real], dtype=np.float64)
    overlap = _overlap_reward(real, predicted, pred.astype(np.int64))
    return float((alpha * existence.sum() + (1 - alpha) * overlap.sum()) / len(real))


def r_prf(labels: np.ndarray, predictions: np.ndarray) -> tuple[float, float, float]:
    """TSB-AD's range-based (precision, recall, F1) of 0/1 predictions against 0/1 labels."""
    y = np.asarray(labels).reshape(-1).astype(np.int64)
    p = np.asarray(predictions).reshape(-1).astype(np.int64)
    if y.shape != p.shape:
        raise ValueError(f"r_prf: {y.size} labels for {p.size} predictions")
    recall = _range_recall(y, p, 0.2)
    precision = _range_recall(p, y, 0.0)
    f1 = 0.0 if precision + recall == 0 else 2 * recall * precision / (precision + recall)
    return precision, recall, f1
