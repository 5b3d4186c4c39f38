"""Metrics: small functions on arrays, and metric classes over one detector's :class:`Evaluation`.

Every metric class has a ``name``, the ``columns`` it produces and one validated entry point,
``metric(evaluation) -> {column: float}``. Conventions:

- A flight is flagged when its score (max row score) is above the flight threshold; a row alarms
  when its score is above the row threshold (both from :mod:`benchmark.protocol`).
- Rates over an empty set are NaN (e.g. the TP rate of csv mode when there is no csv flight).
  Precision / recall with a zero denominator are 0.0 (scikit-learn's ``zero_division`` default).
- Scores must be finite. A NaN or inf never becomes a number: :func:`build_evaluation` raises
  :class:`ScoreError` and the job is reported as ERROR.

Metrics:

- paper table: ``tp_simulation`` / ``tp_csv`` (fraction of attacked test flights of that mode that
  are flagged), ``tn_no_attack`` (fraction of held-out normal test flights not flagged).
- ``roc_auc``: flight-level ROC-AUC, held-out normal (0) vs attacked (1) flights, ties counted
  half (equal to ``sklearn.metrics.roc_auc_score``), and per mode.
- point-wise precision / recall / F1 over the rows of all test flights (label ``Is_Anomaly``).
- range-based precision / recall / F1 (Tatbul et al., NeurIPS 2018) with alpha = 0, flat
  positional bias and cardinality factor 1 (``"one"``; ``"reciprocal"`` = 1/number of overlapping
  ranges is available): the recall of a real range is the fraction of it covered by alarms, the
  precision of an alarm range is the fraction of it inside real ranges; recall averages over all
  real ranges, precision over all alarm ranges (ranges never cross flights).
- detection delay: per attacked flight, seconds from attack onset to the first row alarm at or
  after the onset and before the attack ends; median and 90th percentile over the flights
  detected that way (``n_delay`` of them).
- false alarms per flight-hour: alarm events (contiguous runs of row alarms) on held-out normal
  test flights divided by their total duration.
- scoring latency: the job's total ``score`` time divided by the rows it scored (microseconds).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pandas as pd
from scipy.stats import rankdata

from scart_bench.benchmark.protocol import ATTACK_MODES, Protocol
from scart_bench.detectors.base import flight_score
from scart_bench.errors import ScartBenchError

#: Columns of metrics.csv that measure time, not detection quality (they differ between runs).
TIMING_COLUMNS = ("latency_us_per_row", "fit_s", "score_s")


class ScoreError(ScartBenchError):
    """Saved or returned scores are unusable: NaN/inf, missing flights, wrong length."""


# -- array-level metrics ----------------------------------------------------------------------

def runs(mask: np.ndarray) -> np.ndarray:
    """Contiguous runs of True as an ``(n, 2)`` int array of ``[start, end)`` row indices."""
    m = np.asarray(mask, dtype=bool).reshape(-1).astype(np.int8)
    d = np.diff(np.concatenate(([0], m, [0])))
    return np.stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1)], axis=1).astype(np.int64)


def roc_auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve (Mann-Whitney U with average ranks); NaN when a class is empty."""
    y = np.asarray(labels).reshape(-1)
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    if y.shape != s.shape:
        raise ValueError(f"roc_auc: {y.size} labels for {s.size} scores")
    if not np.all(np.isfinite(s)):
        raise ScoreError("roc_auc: scores contain NaN or inf")
    if not np.all(np.isin(y, (0, 1))):
        raise ValueError("roc_auc: labels must be 0 or 1")
    pos = y == 1
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(s)
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def _ratio(num: float, den: float) -> float:
    return float(num) / float(den) if den else 0.0


def f1(precision: float, recall: float) -> float:
    """Harmonic mean; 0.0 when both are 0."""
    return _ratio(2.0 * precision * recall, precision + recall)


def point_prf(y_true: np.ndarray, y_pred: np.ndarray) -> tuple[float, float, float]:
    """Point-wise (precision, recall, F1) of boolean predictions against 0/1 labels."""
    t = np.asarray(y_true).reshape(-1).astype(bool)
    p = np.asarray(y_pred).reshape(-1).astype(bool)
    if t.shape != p.shape:
        raise ValueError(f"point_prf: {t.size} labels for {p.size} predictions")
    tp = int(np.sum(t & p))
    precision, recall = _ratio(tp, p.sum()), _ratio(tp, t.sum())
    return precision, recall, f1(precision, recall)


def _cardinality(count: np.ndarray, kind: str) -> np.ndarray:
    if kind == "one":
        return np.ones_like(count, dtype=np.float64)
    if kind == "reciprocal":
        return 1.0 / np.maximum(count, 1)
    raise ValueError(f"cardinality {kind!r}: expected 'one' or 'reciprocal'")


def range_scores(real: np.ndarray, pred: np.ndarray, cardinality: str = "one") -> tuple[np.ndarray, np.ndarray]:
    """Per-range rewards in one flight: (recall of each real range, precision of each alarm range).

    ``real`` and ``pred`` are ``(n, 2)`` arrays of ``[start, end)`` ranges (see :func:`runs`);
    alpha = 0 and flat positional bias (Tatbul et al. 2018).
    """
    real = np.asarray(real, dtype=np.int64).reshape(-1, 2)
    pred = np.asarray(pred, dtype=np.int64).reshape(-1, 2)
    if np.any(real[:, 1] <= real[:, 0]) or np.any(pred[:, 1] <= pred[:, 0]):
        raise ValueError("range_scores: every range needs end > start")
    lo = np.maximum(real[:, None, 0], pred[None, :, 0])
    hi = np.minimum(real[:, None, 1], pred[None, :, 1])
    overlap = np.clip(hi - lo, 0, None).astype(np.float64)  # (n_real, n_pred)
    touches = overlap > 0
    recall = (_cardinality(touches.sum(axis=1), cardinality) * overlap.sum(axis=1)
              / (real[:, 1] - real[:, 0]))
    precision = (_cardinality(touches.sum(axis=0), cardinality) * overlap.sum(axis=0)
                 / (pred[:, 1] - pred[:, 0]))
    return recall, precision


def range_prf(real: list[np.ndarray], pred: list[np.ndarray], cardinality: str = "one") -> tuple[float, float, float]:
    """Range-based (precision, recall, F1) over several flights (one range array per flight each)."""
    if len(real) != len(pred):
        raise ValueError(f"range_prf: {len(real)} real range lists for {len(pred)} predicted")
    rec, prec = [], []
    for r, p in zip(real, pred):
        a, b = range_scores(r, p, cardinality)
        rec.append(a)
        prec.append(b)
    rec_all = np.concatenate(rec) if rec else np.zeros(0)
    prec_all = np.concatenate(prec) if prec else np.zeros(0)
    precision = _ratio(prec_all.sum(), prec_all.size)
    recall = _ratio(rec_all.sum(), rec_all.size)
    return precision, recall, f1(precision, recall)


def detection_delay(timestamps_us: np.ndarray, alarms: np.ndarray, start_us: int,
                    end_us: int | None = None) -> float:
    """Seconds from ``start_us`` to the first alarm in ``[start_us, end_us)``; NaN when none."""
    ts = np.asarray(timestamps_us, dtype=np.int64).reshape(-1)
    a = np.asarray(alarms, dtype=bool).reshape(-1)
    if ts.shape != a.shape:
        raise ValueError(f"detection_delay: {ts.size} timestamps for {a.size} alarms")
    inside = a & (ts >= start_us)
    if end_us is not None:
        inside &= ts < end_us
    hit = np.flatnonzero(inside)
    return float((ts[hit[0]] - start_us) / 1e6) if hit.size else float("nan")


def alarm_events(alarms: np.ndarray) -> int:
    """Number of alarm events: contiguous runs of row alarms."""
    return int(runs(alarms).shape[0])


# -- one detector's evaluation ----------------------------------------------------------------

@dataclass(frozen=True)
class FlightRows:
    """Per-row arrays of one scored flight."""

    timestamp: np.ndarray  # int64, microseconds
    label: np.ndarray      # int8, Is_Anomaly
    score: np.ndarray      # float64
    alarm: np.ndarray      # bool, score > row threshold


@dataclass(frozen=True)
class Evaluation:
    """Everything the metrics need about one detector in one run.

    ``flights`` is indexed by flight_id, one row per scored flight (validation and test), with
    the manifest columns plus ``role``, ``score`` (flight score) and ``flagged``.
    """

    detector: str
    flights: pd.DataFrame
    rows: Mapping[str, FlightRows]
    flight_threshold: float
    row_threshold: float
    fit_seconds: float = float("nan")
    score_seconds: float = float("nan")
    rows_scored: int = 0

    def test(self, role: str | None = None, mode: str | None = None) -> pd.DataFrame:
        """Test flights, optionally of one role (test_normal / test_attacked) and mode."""
        f = self.flights[self.flights["role"].isin(("test_normal", "test_attacked"))]
        if role is not None:
            f = f[f["role"] == role]
        if mode is not None:
            f = f[f["mode"] == mode]
        return f


def build_evaluation(detector: str, flights: pd.DataFrame, truth: Mapping[str, tuple[np.ndarray, np.ndarray]],
                     scores: Mapping[str, np.ndarray], protocol: Protocol, *, fit_seconds: float = float("nan"),
                     score_seconds: float = float("nan"), rows_scored: int = 0) -> Evaluation:
    """Check one detector's scores against the run's flights and apply the protocol's thresholds.

    ``flights``: the run's flight table (flight_id, role, mode, ...); ``truth``: flight_id ->
    (timestamps, labels); ``scores``: flight_id -> per-row scores. Raises ScoreError for a
    missing flight, a length mismatch or a NaN/inf score.
    """
    scored = flights[flights["role"].isin(("validation", "test_normal", "test_attacked"))].copy()
    scored["flight_id"] = scored["flight_id"].astype(str)
    scored = scored.set_index("flight_id", drop=False)
    checked: dict[str, np.ndarray] = {}
    for fid in scored.index:
        if fid not in scores:
            raise ScoreError(f"{detector}: no scores for flight {fid}")
        s = np.asarray(scores[fid], dtype=np.float64).reshape(-1)
        if fid not in truth:
            raise ScoreError(f"{detector}: no labels for flight {fid}")
        n = len(truth[fid][0])
        if s.shape[0] != n:
            raise ScoreError(f"{detector}: {s.shape[0]} scores for the {n} rows of flight {fid}")
        bad = int(np.count_nonzero(~np.isfinite(s)))
        if bad:
            raise ScoreError(f"{detector}: {bad} NaN/inf score(s) on flight {fid}")
        checked[fid] = s
    validation = {fid: checked[fid] for fid in scored.index[scored["role"] == "validation"]}
    t_flight, t_row = protocol.thresholds(validation)
    scored["score"] = [flight_score(checked[fid]) for fid in scored.index]
    scored["flagged"] = scored["score"] > t_flight
    rows = {
        fid: FlightRows(np.asarray(truth[fid][0], dtype=np.int64), np.asarray(truth[fid][1], dtype=np.int8),
                        checked[fid], checked[fid] > t_row)
        for fid in scored.index
    }
    return Evaluation(detector, scored, rows, t_flight, t_row, float(fit_seconds), float(score_seconds),
                      int(rows_scored))


# -- metric classes ---------------------------------------------------------------------------

class Metric:
    """A named metric: ``metric(evaluation)`` returns one float per column in ``columns``."""

    name: ClassVar[str] = "metric"
    columns: ClassVar[tuple[str, ...]] = ()

    def __call__(self, ev: Evaluation) -> dict[str, float]:
        if not isinstance(ev, Evaluation):
            raise TypeError(f"{self.name}: expected an Evaluation, got {type(ev).__name__}")
        out = self.compute(ev)
        if tuple(out) != self.columns:
            raise RuntimeError(f"{self.name}: produced {tuple(out)}, declared {self.columns}")
        return {k: float(v) for k, v in out.items()}

    def compute(self, ev: Evaluation) -> dict[str, float]:
        raise NotImplementedError


def _rate(flags: pd.Series) -> float:
    return float(flags.mean()) if len(flags) else float("nan")


class PaperTable(Metric):
    """The paper's table: TP rate per attack mode, TN rate on held-out normal flights."""

    name = "paper"
    columns = ("tp_simulation", "tp_csv", "tn_no_attack", "n_simulation", "n_csv", "n_no_attack")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        sim = ev.test("test_attacked", "simulation")["flagged"]
        csv = ev.test("test_attacked", "csv")["flagged"]
        normal = ev.test("test_normal")["flagged"]
        return {"tp_simulation": _rate(sim), "tp_csv": _rate(csv), "tn_no_attack": _rate(~normal),
                "n_simulation": len(sim), "n_csv": len(csv), "n_no_attack": len(normal)}


class FlightROCAUC(Metric):
    """Threshold-free flight-level ROC-AUC: held-out normal vs attacked (all, then per mode)."""

    name = "roc_auc"
    columns = ("roc_auc", *(f"roc_auc_{m}" for m in ATTACK_MODES))

    def compute(self, ev: Evaluation) -> dict[str, float]:
        normal = ev.test("test_normal")["score"].to_numpy()
        out = {}
        for key, attacked in (("roc_auc", ev.test("test_attacked")),
                              *((f"roc_auc_{m}", ev.test("test_attacked", m)) for m in ATTACK_MODES)):
            a = attacked["score"].to_numpy()
            out[key] = roc_auc(np.r_[np.zeros(normal.size), np.ones(a.size)], np.r_[normal, a])
        return out


class PointwisePRF(Metric):
    """Point-wise precision / recall / F1 over the rows of all test flights."""

    name = "pointwise"
    columns = ("point_precision", "point_recall", "point_f1")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        ids = ev.test().index
        if len(ids) == 0:
            return dict.fromkeys(self.columns, float("nan"))
        y = np.concatenate([ev.rows[f].label for f in ids])
        p = np.concatenate([ev.rows[f].alarm for f in ids])
        return dict(zip(self.columns, point_prf(y, p)))


class RangePRF(Metric):
    """Range-based precision / recall / F1 (Tatbul et al. 2018; alpha 0, flat bias)."""

    name = "range"
    columns = ("range_precision", "range_recall", "range_f1")

    def __init__(self, cardinality: str = "one"):
        self.cardinality = cardinality

    def compute(self, ev: Evaluation) -> dict[str, float]:
        ids = ev.test().index
        if len(ids) == 0:
            return dict.fromkeys(self.columns, float("nan"))
        real = [runs(ev.rows[f].label.astype(bool)) for f in ids]
        pred = [runs(ev.rows[f].alarm) for f in ids]
        return dict(zip(self.columns, range_prf(real, pred, self.cardinality)))


def _attack_window(row: pd.Series, fr: FlightRows) -> tuple[int, int | None] | None:
    """(onset, end) of a flight's attack from the manifest, else from its labels; None if none."""
    start, end = row.get("attack_start_us"), row.get("attack_end_us")
    if start is not None and not pd.isna(start):
        return int(start), (None if end is None or pd.isna(end) else int(end))
    on = np.flatnonzero(fr.label == 1)
    if on.size == 0:
        return None
    return int(fr.timestamp[on[0]]), int(fr.timestamp[on[-1]]) + 1


class DetectionDelay(Metric):
    """Seconds from attack onset to the first row alarm inside the attack window."""

    name = "delay"
    columns = ("delay_median_s", "delay_p90_s", "n_delay")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        delays = []
        for fid, row in ev.test("test_attacked").iterrows():
            fr = ev.rows[fid]
            window = _attack_window(row, fr)
            if window is not None:
                delays.append(detection_delay(fr.timestamp, fr.alarm, *window))
        d = np.array([x for x in delays if not math.isnan(x)])
        if d.size == 0:
            return {"delay_median_s": float("nan"), "delay_p90_s": float("nan"), "n_delay": 0}
        return {"delay_median_s": float(np.median(d)), "delay_p90_s": float(np.quantile(d, 0.9)),
                "n_delay": d.size}


def _duration_s(row: pd.Series, fr: FlightRows) -> float:
    d = row.get("duration_s")
    if d is not None and not pd.isna(d) and float(d) > 0:
        return float(d)
    if fr.timestamp.size < 2:
        return 0.0
    return float(fr.timestamp[-1] - fr.timestamp[0]) / 1e6


class FalseAlarmRate(Metric):
    """Alarm events per flight-hour on held-out normal test flights."""

    name = "false_alarms"
    columns = ("false_alarms_per_hour", "normal_test_hours")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        events, seconds = 0, 0.0
        for fid, row in ev.test("test_normal").iterrows():
            events += alarm_events(ev.rows[fid].alarm)
            seconds += _duration_s(row, ev.rows[fid])
        hours = seconds / 3600.0
        return {"false_alarms_per_hour": events / hours if hours > 0 else float("nan"),
                "normal_test_hours": hours}


class ScoringLatency(Metric):
    """Per-sample scoring latency: total score time / rows scored, in microseconds."""

    name = "latency"
    columns = ("latency_us_per_row",)

    def compute(self, ev: Evaluation) -> dict[str, float]:
        ok = ev.rows_scored > 0 and math.isfinite(ev.score_seconds)
        return {"latency_us_per_row": ev.score_seconds / ev.rows_scored * 1e6 if ok else float("nan")}


#: The metrics of metrics.csv, in column order.
DEFAULT_METRICS: tuple[Metric, ...] = (
    PaperTable(), FlightROCAUC(), PointwisePRF(), RangePRF(), DetectionDelay(), FalseAlarmRate(),
    ScoringLatency(),
)


def compute_metrics(ev: Evaluation, metrics: tuple[Metric, ...] = DEFAULT_METRICS) -> dict[str, float]:
    """All metric columns of one detector, plus its two thresholds."""
    out: dict[str, float] = {}
    for m in metrics:
        out.update(m(ev))
    out["flight_threshold"] = ev.flight_threshold
    out["row_threshold"] = ev.row_threshold
    return out


BREAKDOWN_DIMENSIONS = ("action", "target", "injection_point", "kind")


def breakdown(ev: Evaluation, dimensions: tuple[str, ...] = BREAKDOWN_DIMENSIONS) -> pd.DataFrame:
    """TP rate and count of attacked test flights per value of each dimension, for all modes
    together (mode "all") and per mode."""
    attacked = ev.test("test_attacked")
    rows = []
    for dim in dimensions:
        if dim not in attacked.columns:
            continue
        values = attacked[dim].astype(object).where(attacked[dim].notna(), "(none)").astype(str)
        for mode in ("all", *ATTACK_MODES):
            sel = attacked if mode == "all" else attacked[attacked["mode"] == mode]
            if sel.empty:
                continue
            for value, group in sel.groupby(values.loc[sel.index], sort=True):
                rows.append({"detector": ev.detector, "dimension": dim, "value": value, "mode": mode,
                             "n": len(group), "detected": int(group["flagged"].sum()),
                             "tp_rate": float(group["flagged"].mean())})
    return pd.DataFrame(rows, columns=["detector", "dimension", "value", "mode", "n", "detected", "tp_rate"])


# -- tables -----------------------------------------------------------------------------------

PAPER_COLUMNS = (("TP Simulation", "tp_simulation", "pct"), ("TP CSV", "tp_csv", "pct"),
                 ("TN No Attack", "tn_no_attack", "pct"), ("ROC-AUC", "roc_auc", "f3"),
                 ("Median delay (s)", "delay_median_s", "f2"))
EXTRA_COLUMNS = (("Point P", "point_precision", "f3"), ("Point R", "point_recall", "f3"),
                 ("Point F1", "point_f1", "f3"), ("Range P", "range_precision", "f3"),
                 ("Range R", "range_recall", "f3"), ("Range F1", "range_f1", "f3"),
                 ("p90 delay (s)", "delay_p90_s", "f2"), ("False alarms / h", "false_alarms_per_hour", "f2"),
                 ("Latency (us/row)", "latency_us_per_row", "f1"), ("Fit (s)", "fit_s", "f1"))


def _cell(value, kind: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    v = float(value)
    if kind == "pct":
        return f"{100 * v:.1f}%"
    return f"{v:.{kind[1:]}f}"


def markdown_table(metrics: pd.DataFrame, columns=PAPER_COLUMNS, status: bool = True) -> str:
    """A Markdown table, one row per detector; a failed job shows its status, not numbers."""
    head = ["Detector", *(c[0] for c in columns)] + (["Status"] if status else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for _, r in metrics.iterrows():
        ok = r.get("status") == "OK"
        cells = [str(r["detector"])]
        cells += [_cell(r.get(key), kind) if ok else str(r.get("status")) for _, key, kind in columns]
        if status:
            cells.append(str(r.get("status")))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
