"""Metrics: small functions on arrays, and metric classes over one detector's
:class:`~scart_bench.benchmark.evaluation.Evaluation` (built by :mod:`benchmark.evaluation`).

Every metric class has a ``name``, the ``columns`` it produces and one validated entry point,
``metric(evaluation) -> {column: float}``. Conventions:

- Flagging, row alarms, the detection rule and each attacked flight's outcome are decided once,
  by :mod:`benchmark.evaluation`; a metric only counts them.
- Rates over an empty set are NaN (e.g. the TP rate of csv mode when there is no csv flight).
  Precision / recall with a zero denominator are 0.0 (scikit-learn's ``zero_division`` default).

Metrics:

- paper table: ``tp_simulation`` / ``tp_csv`` (fraction of attacked test flights of that mode that
  are detected), ``tn_no_attack`` (fraction of held-out normal test flights not flagged); beside
  them ``late_*`` (fraction late) and ``flagged_*`` (fraction flagged anywhere). Every rate has
  its 95 % Wilson interval (``<rate>_lo`` / ``<rate>_hi``) and its count of flights (``n_*``).
- ``roc_auc`` / ``auc_pr``: flight-level ROC-AUC (ties counted half, equal to
  ``sklearn.metrics.roc_auc_score``) and average precision, held-out normal (0) vs attacked (1)
  flights, with seeded bootstrap 95 % intervals; ROC-AUC per mode too.
- threshold-free row-level metrics in TSB-AD's definitions (:mod:`benchmark.vus`), pooled over
  the rows of all test flights (flights concatenated) and averaged per attacked flight:
  ``row_roc_auc``, ``row_auc_pr``, ``vus_roc``, ``vus_pr``.
- point-wise precision / recall / F1 over the rows of all test flights (label ``Is_Anomaly``).
- ``r_precision`` / ``r_recall`` / ``r_f1``: range-based precision / recall / F1 as TSB-AD
  reports them under "R-based-F1" (alpha 0.2 for recall, reciprocal cardinality), on the row
  alarms of the test flights concatenated.
- ``rt0_precision`` / ``rt0_recall`` / ``rt0_f1``: this project's earlier range variant (Tatbul
  et al. 2018 with alpha = 0, flat bias, cardinality factor 1; ranges never cross flights): the
  recall of a real range is the fraction of it covered by alarms, the precision of an alarm
  range the fraction of it inside real ranges.
- detection delay: per detected flight, seconds from attack onset to the first row alarm inside
  the window; median and 90th percentile (``n_delay`` flights). Late flights: median seconds from
  the end of the window to their first alarm (``late_delay_median_s``).
- false alarms per flight-hour: alarm events (contiguous runs of row alarms) on held-out normal
  test flights divided by their total duration.
- scoring latency: the job's total ``score`` time divided by the rows it scored (microseconds).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import pandas as pd

from scart_bench.benchmark.evaluation import Evaluation, FlightRows, ScoreError, calibration_table
from scart_bench.benchmark.intervals import (
    BOOTSTRAP_SEED,
    N_BOOTSTRAP,
    bootstrap_auc,
    cluster_weights,
    design_effect,
    design_interval,
    wilson,
)
from scart_bench.benchmark.protocol import ATTACK_MODES
from scart_bench.benchmark.vus import VUS_WINDOW, average_precision, r_prf, roc_auc_from_sorted, row_metrics

#: Columns of metrics.csv that measure time, not detection quality (they differ between runs).
TIMING_COLUMNS = ("latency_us_per_row", "fit_s", "score_s")


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
    return roc_auc_from_sorted(np.sort(s), np.sort(s[y == 1]))


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


#: The rates of the paper's table and beside it (each with ``_lo`` / ``_hi`` and ``_wilson_lo`` /
#: ``_wilson_hi`` columns). ``tp_*``: in-window detection (the headline); ``tp_end_*``: in the
#: window or in the end transient; ``fa_before_onset_*``: attacked flights with a false alarm
#: before the attack started; ``far_no_attack``: held-out normal flights flagged (1 - TN).
RATES = ("tp_simulation", "tp_csv", "tn_no_attack", "tp_end_simulation", "tp_end_csv", "late_simulation",
         "late_csv", "flagged_simulation", "flagged_csv", "fa_before_onset_simulation", "fa_before_onset_csv",
         "far_no_attack")
#: Replicates of the cluster bootstrap behind every rate's interval.
RATE_BOOTSTRAP = N_BOOTSTRAP


def _levels(ev: Evaluation, f: pd.DataFrame, col: str) -> np.ndarray:
    """Per-flight values compared with a threshold: a zone maximum, or the flight score (own alarm
    rule: 1.0 when flagged)."""
    if col == "score" and ev.alarm_source == "own":
        return f["flagged"].astype(bool).to_numpy(np.float64)
    return f[col].to_numpy(np.float64)


def _indicator(ev: Evaluation, name: str, f: pd.DataFrame, t_row: np.ndarray, t_flight: np.ndarray) -> np.ndarray:
    """``(B, n)`` booleans: whether each flight of ``f`` counts for rate ``name`` at each pair of
    thresholds (row, flight)."""
    tr, tf = t_row[:, None], t_flight[:, None]
    if name.startswith("tp_end_"):
        return np.maximum(_levels(ev, f, "window_max"), _levels(ev, f, "end_max"))[None, :] > tr
    if name.startswith("tp_"):
        return _levels(ev, f, "window_max")[None, :] > tr
    if name.startswith("late_"):
        caught = np.maximum(_levels(ev, f, "window_max"), _levels(ev, f, "end_max"))[None, :] > tr
        return ~caught & (_levels(ev, f, "after_max")[None, :] > tr)
    if name.startswith("flagged_") or name == "far_no_attack":
        return _levels(ev, f, "score")[None, :] > tf
    if name == "tn_no_attack":
        return ~(_levels(ev, f, "score")[None, :] > tf)
    if name.startswith("fa_before_onset_"):
        return _levels(ev, f, "pre_max")[None, :] > tr
    raise KeyError(name)


def _resampled_thresholds(ev: Evaluation, rng: np.random.Generator, n_boot: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and flight thresholds re-calibrated on validation flights resampled with replacement
    (the threshold's own uncertainty); fixed where the rule cannot be (own alarms: 0.5 on 0/1)."""
    if ev.alarm_source == "own":
        return np.full(n_boot, 0.5), np.full(n_boot, 0.5)
    if ev.hourly is not None:  # calibrated on windows, not flight scores: held fixed
        return np.full(n_boot, ev.row_threshold), np.full(n_boot, ev.flight_threshold)
    val = ev.flights.loc[ev.flights["role"] == "validation", "score"].to_numpy(np.float64)
    fixed = (np.full(n_boot, ev.row_threshold), np.full(n_boot, ev.flight_threshold))
    if ev.protocol is None or val.size == 0:
        return fixed
    sample = val[rng.integers(0, val.size, size=(n_boot, val.size))]
    tf = ev.protocol.flight_rule.calibrate_many(sample)
    tr = ev.protocol.row_rule.calibrate_many(sample)
    return (fixed[0] if tr is None else tr), (fixed[1] if tf is None else tf)


def _onsets_in_burn_in(ev: Evaluation) -> int:
    """Attacked flights whose attack starts before the burn-in after arming ends (their first rows
    cannot alarm): the summary says how many, since a grid that starts attacks that early loses them."""
    burn = ev.protocol.burn_in_s if ev.protocol is not None else 0.0
    a = ev.test("test_attacked")
    if burn <= 0 or not len(a) or "attack_start_us" not in a.columns:
        return 0
    start = pd.to_numeric(a["attack_start_us"], errors="coerce")
    armed = (pd.to_numeric(a["armed_us"], errors="coerce") if "armed_us" in a.columns else pd.Series(
        [float(ev.rows[f].timestamp[0]) if ev.rows[f].timestamp.size else 0.0 for f in a.index], index=a.index))
    return int((start < armed + burn * 1e6).sum())


def _independent_units(f: pd.DataFrame) -> int:
    """How many independent units a group of flights holds: csv copies of one source recording
    count once."""
    if "source_flight" not in f.columns or not len(f):
        return len(f)
    src = f["source_flight"].astype(object).where(f["source_flight"].notna(), None)
    units = [s if (m == "csv" and s) else fid for fid, m, s in zip(f.index, f["mode"].astype(str), src)]
    return len(set(units))


class PaperTable(Metric):
    """The paper's table with the in-window rule (TP = detected inside the attack window), the
    end-transient, late, flagged-anywhere and false-alarm rates beside it.

    Every rate has its count (``n_*``), its Wilson interval (``*_wilson_lo`` / ``*_wilson_hi``, as
    if every flight were independent and the threshold known) and its interval (``*_lo`` /
    ``*_hi``) from a cluster bootstrap: clusters (:func:`flight_clusters`: csv copies of one
    recording, one configuration in both modes) are resampled within normal and attacked flights,
    and each replicate re-calibrates the threshold on validation flights resampled with
    replacement; the interval is the hull of the percentile interval and the Wilson interval at
    the bootstrap's effective sample size (:func:`~scart_bench.benchmark.intervals.design_interval`).
    """

    name = "paper"
    columns = (*(f"{r}{s}" for r in RATES for s in ("", "_lo", "_hi", "_wilson_lo", "_wilson_hi")),
               "n_simulation", "n_csv", "n_no_attack", "n_units_csv", "n_validation", "alpha",
               "alpha_attainable", "detected_after_fa_simulation", "detected_after_fa_csv", "n_onset_in_burn_in")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        out: dict[str, float] = {}
        attacked = {m: ev.test("test_attacked", m) for m in ATTACK_MODES}
        normal = ev.test("test_normal")
        groups = {**{f"{k}_{m}": attacked[m] for k in ("tp", "tp_end", "late", "flagged", "fa_before_onset")
                     for m in ATTACK_MODES}, "tn_no_attack": normal, "far_no_attack": normal}
        test = ev.test()
        rng = np.random.default_rng(BOOTSTRAP_SEED)
        t_row, t_flight = _resampled_thresholds(ev, rng, RATE_BOOTSTRAP)
        weights = (cluster_weights(test["cluster"].astype(str).to_numpy() if "cluster" in test.columns
                                   else test.index.to_numpy(), test["role"].to_numpy(), RATE_BOOTSTRAP, rng)
                   if len(test) else np.zeros((RATE_BOOTSTRAP, 0)))
        position = {fid: i for i, fid in enumerate(test.index)}
        point_t = np.array([0.5 if ev.alarm_source == "own" else ev.row_threshold])
        point_f = np.array([0.5 if ev.alarm_source == "own" else ev.flight_threshold])
        deff: dict[str, float] = {}  # per group of flights: the design effect of its headline rate
        for name in RATES:
            f = groups[name]
            n = len(f)
            if n == 0:
                out.update({name: float("nan"), **{f"{name}{s}": float("nan")
                                                   for s in ("_lo", "_hi", "_wilson_lo", "_wilson_hi")}})
                continue
            k = float(_indicator(ev, name, f, point_t, point_f)[0].sum())
            w = weights[:, [position[i] for i in f.index]]
            hits = (w * _indicator(ev, name, f, t_row, t_flight)).sum(axis=1)
            total = w.sum(axis=1)
            boot = np.divide(hits, total, out=np.full(total.shape, np.nan), where=total > 0)
            group = name.rpartition("_")[2] if name.endswith(ATTACK_MODES) else "normal"
            d = design_effect(k, n, boot)
            if group not in deff and math.isfinite(d):
                deff[group] = d
            # a rate of 0 or 100 % has no spread of its own: the design effect of the same flights'
            # first rate with one, never fewer units than the independent ones
            units = _independent_units(f)
            fallback = max(units, n / max(deff[group], 1.0)) if group in deff else units
            out[name] = k / n
            out[f"{name}_lo"], out[f"{name}_hi"] = design_interval(k, n, boot, fallback)
            out[f"{name}_wilson_lo"], out[f"{name}_wilson_hi"] = wilson(k, n)
        n_val = int((ev.flights["role"] == "validation").sum())
        alpha = ev.protocol.alpha if ev.protocol is not None and ev.alarm_source == "calibrated" else None
        out.update(n_simulation=len(attacked["simulation"]), n_csv=len(attacked["csv"]), n_no_attack=len(normal),
                   n_units_csv=_independent_units(attacked["csv"]), n_validation=n_val,
                   alpha=float("nan") if alpha is None else alpha,
                   alpha_attainable=float("nan") if alpha is None else float(
                       ev.protocol.flight_rule.attainable(n_val)))
        for m in ATTACK_MODES:
            a = attacked[m]
            out[f"detected_after_fa_{m}"] = int(((a["outcome"] == "detected") & a["alarm_before_onset"].astype(bool))
                                                .sum()) if len(a) else 0
        out["n_onset_in_burn_in"] = _onsets_in_burn_in(ev)
        return out


class FlightROCAUC(Metric):
    """Threshold-free flight-level ROC-AUC and AUC-PR (average precision): held-out normal vs
    attacked flights, with seeded bootstrap 95 % intervals; ROC-AUC per mode too. ``auc_pr_prior``
    is the AUC-PR of a detector that ranks at random (the share of attacked flights), and
    ``auc_pr_lift`` the AUC-PR over it: with many more attacked than normal flights an AUC-PR near
    1 says little by itself."""

    name = "roc_auc"
    columns = ("roc_auc", "roc_auc_lo", "roc_auc_hi", "auc_pr", "auc_pr_lo", "auc_pr_hi", "auc_pr_prior",
               "auc_pr_lift", *(f"roc_auc_{m}" for m in ATTACK_MODES))

    def compute(self, ev: Evaluation) -> dict[str, float]:
        normal = ev.test("test_normal")["score"].to_numpy(np.float64)
        attacked = ev.test("test_attacked")["score"].to_numpy(np.float64)
        labels = np.r_[np.zeros(normal.size), np.ones(attacked.size)]
        both = normal.size > 0 and attacked.size > 0
        out = {"roc_auc": roc_auc(labels, np.r_[normal, attacked])}
        out["roc_auc_lo"], out["roc_auc_hi"] = bootstrap_auc(roc_auc, normal, attacked)
        out["auc_pr"] = average_precision(labels, np.r_[normal, attacked]) if both else float("nan")
        out["auc_pr_lo"], out["auc_pr_hi"] = bootstrap_auc(average_precision, normal, attacked)
        out["auc_pr_prior"] = attacked.size / labels.size if both else float("nan")
        out["auc_pr_lift"] = out["auc_pr"] / out["auc_pr_prior"] if both else float("nan")
        for m in ATTACK_MODES:
            a = ev.test("test_attacked", m)["score"].to_numpy(np.float64)
            out[f"roc_auc_{m}"] = roc_auc(np.r_[np.zeros(normal.size), np.ones(a.size)], np.r_[normal, a])
        return out


class ThresholdFree(Metric):
    """Row-level threshold-free metrics in TSB-AD's definitions (:mod:`benchmark.vus`): pooled over
    the test flights (concatenated) and averaged over the attacked test flights."""

    name = "threshold_free"
    columns = ("row_roc_auc", "row_auc_pr", "vus_roc", "vus_pr", "flight_mean_auc_pr", "flight_mean_vus_roc",
               "flight_mean_vus_pr")

    def __init__(self, window: int = VUS_WINDOW):
        self.window = window

    def compute(self, ev: Evaluation) -> dict[str, float]:
        ids = ev.test().index
        if len(ids) == 0:
            return dict.fromkeys(self.columns, float("nan"))
        # the burn-in rows leave the row metrics too (rows[f].kept), as they leave calibration and alarms
        pooled = row_metrics(np.concatenate([ev.rows[f].label[ev.rows[f].kept] for f in ids]),
                             np.concatenate([ev.rows[f].score[ev.rows[f].kept] for f in ids]), self.window)
        out = {"row_roc_auc": pooled["roc_auc"], "row_auc_pr": pooled["auc_pr"], "vus_roc": pooled["vus_roc"],
               "vus_pr": pooled["vus_pr"]}
        per = [(m["auc_pr"], m["vus_roc"], m["vus_pr"])
               for m in (row_metrics(ev.rows[f].label[ev.rows[f].kept], ev.rows[f].score[ev.rows[f].kept],
                                     self.window)
                         for f in ev.test("test_attacked").index if ev.rows[f].label[ev.rows[f].kept].any())]
        per_a = np.array(per, dtype=np.float64).reshape(-1, 3)
        means = per_a.mean(axis=0) if len(per_a) else np.full(3, np.nan)
        out.update(flight_mean_auc_pr=means[0], flight_mean_vus_roc=means[1], flight_mean_vus_pr=means[2])
        return out


def _pooled_rows(ev: Evaluation) -> tuple[np.ndarray, np.ndarray] | None:
    """(labels, alarms) of every row of the test flights, concatenated; None without test flights."""
    ids = ev.test().index
    if len(ids) == 0:
        return None
    return np.concatenate([ev.rows[f].label for f in ids]), np.concatenate([ev.rows[f].alarm for f in ids])


class PointwisePRF(Metric):
    """Point-wise precision / recall / F1 over the rows of all test flights."""

    name = "pointwise"
    columns = ("point_precision", "point_recall", "point_f1")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        pooled = _pooled_rows(ev)
        if pooled is None:
            return dict.fromkeys(self.columns, float("nan"))
        y, p = pooled
        return dict(zip(self.columns, point_prf(y, p)))


class RangePRF(Metric):
    """Range-based precision / recall / F1 as TSB-AD reports them ("R-based-F1"), on the row
    alarms of the test flights concatenated (:func:`benchmark.vus.r_prf`)."""

    name = "range"
    columns = ("r_precision", "r_recall", "r_f1")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        pooled = _pooled_rows(ev)
        if pooled is None:
            return dict.fromkeys(self.columns, float("nan"))
        y, p = pooled
        return dict(zip(self.columns, r_prf(y, p)))


class TatbulZeroPRF(Metric):
    """This project's earlier range variant: Tatbul et al. 2018 with alpha 0, flat bias and
    cardinality factor 1 (``"reciprocal"`` available); ranges never cross flights."""

    name = "range_t0"
    columns = ("rt0_precision", "rt0_recall", "rt0_f1")

    def __init__(self, cardinality: str = "one"):
        self.cardinality = cardinality

    def compute(self, ev: Evaluation) -> dict[str, float]:
        ids = ev.test().index
        if len(ids) == 0:
            return dict.fromkeys(self.columns, float("nan"))
        real = [runs(ev.rows[f].label.astype(bool)) for f in ids]
        pred = [runs(ev.rows[f].alarm) for f in ids]
        return dict(zip(self.columns, range_prf(real, pred, self.cardinality)))


class DetectionDelay(Metric):
    """Seconds from attack onset to the first row alarm inside the attack window (detected
    flights), and from the end of the window to the first alarm after it (late flights)."""

    name = "delay"
    columns = ("delay_median_s", "delay_p90_s", "n_delay", "late_delay_median_s", "n_late")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        att = ev.test("test_attacked")
        d = att["delay_s"].dropna().to_numpy(np.float64) if len(att) else np.zeros(0)
        late = att["late_delay_s"].dropna().to_numpy(np.float64) if len(att) else np.zeros(0)
        out = {"delay_median_s": float(np.median(d)) if d.size else float("nan"),
               "delay_p90_s": float(np.quantile(d, 0.9)) if d.size else float("nan"), "n_delay": d.size,
               "late_delay_median_s": float(np.median(late)) if late.size else float("nan"), "n_late": late.size}
        return out


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
            fr = ev.rows[fid]
            events += alarm_events(fr.alarm)
            # the burn-in's share of the flight is not watched: its time is not counted either
            seconds += _duration_s(row, fr) * (float(fr.kept.mean()) if fr.kept.size else 1.0)
        hours = seconds / 3600.0
        return {"false_alarms_per_hour": events / hours if hours > 0 else float("nan"),
                "normal_test_hours": hours}


#: Seconds after arming within which a validation maximum counts as "near arming" in the summary.
NEAR_ARMING_S = 10.0
#: Seconds from take-off or touchdown within which a validation maximum counts as "near the ends".
NEAR_ENDS_S = 3.0
#: CalibrationPoint's columns that a run without phase bounds leaves empty (and out of metrics.csv)
HOURLY_METRIC_COLUMNS = ("hourly_rate", "n_windows", "validation_hours")
PHASE_METRIC_COLUMNS = ("threshold_after_liftoff_s", "threshold_before_touchdown_s", "val_max_near_ends")


def _raw_maxima_left_out(ev: Evaluation) -> int:
    """Validation flights whose largest score (all rows) lies outside the counted rows."""
    out = 0
    for fid in ev.flights.index[ev.flights["role"] == "validation"]:
        fr = ev.rows[fid]
        if fr.score.size and not fr.kept[int(np.argmax(fr.score))]:
            out += 1
    return out


class CalibrationPoint(Metric):
    """Where the threshold comes from: seconds after arming of the validation row that sets it,
    how many validation maxima sit within :data:`NEAR_ARMING_S` of arming (over the counted
    rows), and how many of the raw maxima (all rows) the burn-in took out."""

    name = "calibration"
    columns = ("threshold_after_arming_s", "val_max_near_arming", "val_raw_max_in_burn_in",
               "threshold_after_liftoff_s", "threshold_before_touchdown_s", "val_max_near_ends")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        cal = calibration_table(ev)
        sets = cal[cal["sets_threshold"]]
        burn_in = ev.protocol.burn_in_s if ev.protocol is not None else 0.0
        raw = cal["raw_max_after_arming_s"]
        out = {"threshold_after_arming_s": float(sets["max_after_arming_s"].iloc[0]) if len(sets) else float("nan"),
               "val_max_near_arming": int(((cal["max_after_arming_s"] >= 0)
                                           & (cal["max_after_arming_s"] < NEAR_ARMING_S)).sum()),
               "val_raw_max_in_burn_in": (int((raw < burn_in).sum()) if burn_in > 0 else 0)
               if ev.protocol is None or ev.protocol.phases == "burn-in" else _raw_maxima_left_out(ev),
               "threshold_after_liftoff_s": float("nan"), "threshold_before_touchdown_s": float("nan"),
               "val_max_near_ends": float("nan")}
        if "max_after_liftoff_s" in cal.columns:
            lift = pd.to_numeric(cal["max_after_liftoff_s"], errors="coerce")
            down = pd.to_numeric(cal["max_before_touchdown_s"], errors="coerce")
            near = (lift.abs() < NEAR_ENDS_S) | (down.abs() < NEAR_ENDS_S)
            out.update(val_max_near_ends=int(near.sum()))
            if len(sets):
                out.update(threshold_after_liftoff_s=float(lift[sets.index[0]]),
                           threshold_before_touchdown_s=float(down[sets.index[0]]))
        return out


class HourlyPoint(Metric):
    """The small-data operating point when alpha was not attainable (Protocol.hourly_point): the
    stated false alarms per flight-hour, the validation windows and flight-hours it rests on."""

    name = "hourly"
    columns = HOURLY_METRIC_COLUMNS

    def compute(self, ev: Evaluation) -> dict[str, float]:
        h = ev.hourly or {}
        return {"hourly_rate": h.get("rate_per_hour", float("nan")), "n_windows": h.get("windows", float("nan")),
                "validation_hours": h.get("validation_hours", float("nan"))}


class ScoringLatency(Metric):
    """Per-sample scoring latency: total score time / rows scored, in microseconds."""

    name = "latency"
    columns = ("latency_us_per_row",)

    def compute(self, ev: Evaluation) -> dict[str, float]:
        ok = ev.rows_scored > 0 and math.isfinite(ev.score_seconds)
        return {"latency_us_per_row": ev.score_seconds / ev.rows_scored * 1e6 if ok else float("nan")}


#: The metrics of metrics.csv, in column order.
DEFAULT_METRICS: tuple[Metric, ...] = (
    PaperTable(), FlightROCAUC(), ThresholdFree(), PointwisePRF(), RangePRF(), TatbulZeroPRF(), DetectionDelay(),
    FalseAlarmRate(), CalibrationPoint(), HourlyPoint(), ScoringLatency(),
)


def compute_metrics(ev: Evaluation, metrics: tuple[Metric, ...] = DEFAULT_METRICS) -> dict[str, float]:
    """All metric columns of one detector, plus its two thresholds."""
    out: dict[str, float] = {}
    for m in metrics:
        out.update(m(ev))
    out["flight_threshold"] = ev.flight_threshold
    out["row_threshold"] = ev.row_threshold
    return out


# -- the operating characteristic -------------------------------------------------------------

#: Target alphas of the operating characteristic (``scart-bench report``'s figure per detector).
OC_ALPHAS = (0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3)
OC_COLUMNS = ("detector", "alpha", "n_validation", "k", "attainable", "threshold", "tp_simulation", "tp_csv",
              "n_simulation", "n_csv", "far_no_attack", "n_no_attack", "far_expected", "far_lo", "far_hi")


def realised_rate_spread(n: int, alpha: float, level: float = 0.95) -> tuple[int, float, float, float]:
    """The rank ``k`` of the conformal threshold among ``n`` validation flights at ``alpha`` (the largest
    when no order statistic reaches it) and the spread of the false-alarm rate a threshold so calibrated
    realises on new exchangeable normal flights: it is Beta(n + 1 - k, k) distributed over validation sets
    (the complement of the k-th order statistic's coverage, Beta(k, n + 1 - k)); returns (k, its mean
    (n + 1 - k) / (n + 1), and its ``level`` central interval). One validation set's threshold is one
    draw: for 60 flights at 5 % (k = 58, Beta(3, 58)) about 1-11 %."""
    from scipy.stats import beta

    from scart_bench.benchmark.protocol import conformal_rank

    if n < 1:
        raise ValueError(f"realised_rate_spread: n = {n} validation flights; expected at least 1")
    k = min(conformal_rank(n, alpha), n)
    a, b = n + 1 - k, k
    tail = (1.0 - level) / 2.0
    return k, a / (n + 1), float(beta.ppf(tail, a, b)), float(beta.ppf(1.0 - tail, a, b))


def operating_characteristic(ev: Evaluation, alphas: tuple[float, ...] = OC_ALPHAS) -> pd.DataFrame:
    """One detector's flight-level operating characteristic from its scores: for each target ``alpha``,
    the conformal threshold on the validation flight scores, the TP in window per mode (an attacked
    flight whose largest counted score inside the attack window is above it; rows alarm at the flight
    threshold, as under protocol v2) and the false-alarm rate on the held-out normal flights, with the
    spread of the realised rate for the run's number of validation flights
    (:func:`realised_rate_spread`). One row per alpha, columns :data:`OC_COLUMNS`."""
    from scart_bench.benchmark.protocol import ThresholdRule

    val = ev.flights.loc[ev.flights["role"] == "validation", "score"].to_numpy(np.float64)
    normal = ev.test("test_normal")["score"].to_numpy(np.float64)
    window = {m: ev.test("test_attacked", m)["window_max"].to_numpy(np.float64) for m in ATTACK_MODES}
    rows = []
    for alpha in alphas:
        t = ThresholdRule("conformal", alpha=float(alpha)).calibrate(val)
        k, expected, lo, hi = realised_rate_spread(val.size, float(alpha))
        rows.append({"detector": ev.detector, "alpha": float(alpha), "n_validation": val.size, "k": k,
                     "attainable": ThresholdRule("conformal", alpha=float(alpha)).attainable(val.size),
                     "threshold": t,
                     **{f"tp_{m}": float((w > t).mean()) if w.size else float("nan") for m, w in window.items()},
                     **{f"n_{m}": w.size for m, w in window.items()},
                     "far_no_attack": float((normal > t).mean()) if normal.size else float("nan"),
                     "n_no_attack": normal.size, "far_expected": expected, "far_lo": lo, "far_hi": hi})
    return pd.DataFrame(rows, columns=list(OC_COLUMNS))
