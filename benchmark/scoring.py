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

The detection rule (per attacked flight, :func:`flight_outcomes`): the flight is *detected* when
at least one row alarms inside an attack window (rows labelled ``Is_Anomaly``, i.e. the windows
``[start, end)`` of the event log); otherwise it is *late* when a row alarms at or after the end
of its last window, else *missed*. *Flagged anywhere* (flight score above the flight threshold,
whatever the row) is the paper's lenient rule, reported as its own column, never instead.
Attacked flights whose attack changed nothing (``no_effect`` in the manifest) have their own
role and enter no rate.

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
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pandas as pd

from scart_bench.benchmark.intervals import (
    BOOTSTRAP_SEED,
    N_BOOTSTRAP,
    bootstrap_auc,
    cluster_weights,
    design_effect,
    design_interval,
    wilson,
)
from scart_bench.benchmark.protocol import ATTACK_MODES, Protocol, counted_max, counted_rows
from scart_bench.benchmark.vus import VUS_WINDOW, average_precision, r_prf, roc_auc_from_sorted, row_metrics
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


# -- one detector's evaluation ----------------------------------------------------------------

@dataclass(frozen=True)
class FlightRows:
    """Per-row arrays of one scored flight."""

    timestamp: np.ndarray  # int64, microseconds
    label: np.ndarray      # int8, Is_Anomaly
    score: np.ndarray      # float64
    alarm: np.ndarray      # bool: score > row threshold (or the detector's own alarm), outside the burn-in
    counted: np.ndarray | None = None  # bool: outside the burn-in after arming (None: every row)

    @property
    def kept(self) -> np.ndarray:
        """The counted rows' mask (every row when the protocol has no burn-in)."""
        return np.ones(self.score.shape, dtype=bool) if self.counted is None else self.counted


@dataclass(frozen=True)
class Evaluation:
    """Everything the metrics need about one detector in one run.

    ``flights`` is indexed by flight_id, one row per scored flight (validation and test), with
    the manifest columns plus ``role``, ``score`` (flight score), ``flagged``, ``cluster`` and the
    outcome columns of :func:`flight_outcomes`.
    """

    detector: str
    flights: pd.DataFrame
    rows: Mapping[str, FlightRows]
    flight_threshold: float
    row_threshold: float
    fit_seconds: float = float("nan")
    score_seconds: float = float("nan")
    rows_scored: int = 0
    protocol: Protocol | None = None
    #: "calibrated" (score > threshold) or "own" (the detector's own alarm rule)
    alarm_source: str = "calibrated"

    def test(self, role: str | None = None, mode: str | None = None) -> pd.DataFrame:
        """Test flights, optionally of one role (test_normal / test_attacked) and mode."""
        f = self.flights[self.flights["role"].isin(("test_normal", "test_attacked"))]
        if role is not None:
            f = f[f["role"] == role]
        if mode is not None:
            f = f[f["mode"] == mode]
        return f


def _checked_scores(detector: str, scored: pd.DataFrame, truth, scores) -> dict[str, np.ndarray]:
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
    return checked


def flight_clusters(flights: pd.DataFrame) -> pd.Series:
    """Cluster of each flight for the intervals: flights that are not independent share one.

    csv-mode copies of one source recording (``source_flight``) are one cluster, and so are the
    flights of one attack configuration flown in both modes (``scenario_id`` in simulation and csv
    mode): the union of both relations (connected components). Every other flight is its own.
    """
    ids = flights["flight_id"].astype(str).tolist() if "flight_id" in flights.columns else [
        str(i) for i in flights.index]
    parent = list(range(len(ids)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def join(keys: pd.Series) -> None:
        first: dict[str, int] = {}
        for i, k in enumerate(keys.tolist()):
            if k is None or (isinstance(k, float) and math.isnan(k)) or k is pd.NA or k == "":
                continue
            if k in first:
                a, b = find(first[k]), find(i)
                if a != b:
                    parent[b] = a
            else:
                first[k] = i

    attacked = flights["mode"].astype(str).isin(ATTACK_MODES) if "mode" in flights.columns else pd.Series(
        False, index=flights.index)
    if "source_flight" in flights.columns:
        src = flights["source_flight"].astype(object).where(flights["source_flight"].notna(), None)
        join(src.where(attacked, None).map(lambda v: None if v is None else f"source:{v}"))
    if "scenario_id" in flights.columns:
        sc = flights["scenario_id"].astype(object).where(flights["scenario_id"].notna(), None)
        join(sc.where(attacked, None).map(lambda v: None if v is None else f"config:{v}"))
    roots = [ids[find(i)] for i in range(len(ids))]
    return pd.Series(roots, index=flights.index, name="cluster")


def build_evaluation(detector: str, flights: pd.DataFrame, truth: Mapping[str, tuple[np.ndarray, np.ndarray]],
                     scores: Mapping[str, np.ndarray], protocol: Protocol, *, fit_seconds: float = float("nan"),
                     score_seconds: float = float("nan"), rows_scored: int = 0,
                     alarms: Mapping[str, np.ndarray] | None = None) -> Evaluation:
    """Check one detector's scores against the run's flights and apply the protocol's operating point.

    ``flights``: the run's flight table (flight_id, role, mode, ..., ``armed_us`` when known);
    ``truth``: flight_id -> (timestamps, labels); ``scores``: flight_id -> per-row scores;
    ``alarms``: flight_id -> the detector's own row alarms (used when the protocol's alarm rule is
    ``own``). Raises ScoreError for a missing flight, a length mismatch or a NaN/inf score.
    """
    scored = flights[flights["role"].isin(("validation", "test_normal", "test_attacked"))].copy()
    scored["flight_id"] = scored["flight_id"].astype(str)
    scored = scored.set_index("flight_id", drop=False)
    checked = _checked_scores(detector, scored, truth, scores)
    armed = (pd.to_numeric(scored["armed_us"], errors="coerce") if "armed_us" in scored.columns
             else pd.Series(np.nan, index=scored.index))
    counted = {fid: counted_rows(truth[fid][0], armed[fid], protocol.burn_in_s) for fid in scored.index}
    validation = {fid: checked[fid] for fid in scored.index[scored["role"] == "validation"]}
    t_flight, t_row = protocol.thresholds(validation, counted)
    own = protocol.alarm_rule == "own" and alarms is not None
    if own:
        for fid in scored.index:
            a = np.asarray(alarms.get(fid, np.zeros(0)), dtype=bool).reshape(-1)
            if a.shape != checked[fid].shape:
                raise ScoreError(f"{detector}: {a.shape[0]} own alarms for the {checked[fid].shape[0]} rows of "
                                 f"flight {fid}")
    scored["score"] = [counted_max(checked[fid], counted[fid]) for fid in scored.index]
    rows = {}
    for fid in scored.index:
        alarm = (np.asarray(alarms[fid], dtype=bool).reshape(-1) if own else checked[fid] > t_row) & counted[fid]
        rows[fid] = FlightRows(np.asarray(truth[fid][0], dtype=np.int64), np.asarray(truth[fid][1], dtype=np.int8),
                               checked[fid], alarm, counted[fid])
    scored["flagged"] = ([bool(rows[f].alarm.any()) for f in scored.index] if own
                         else (scored["score"] > t_flight).to_numpy())
    scored["cluster"] = flight_clusters(scored).to_numpy()
    outcomes = flight_outcomes(scored, rows, protocol.end_transient_s, own)
    for col in outcomes.columns:
        scored[col] = outcomes[col]
    if own:
        t_flight = t_row = float("nan")
    return Evaluation(detector, scored, rows, t_flight, t_row, float(fit_seconds), float(score_seconds),
                      int(rows_scored), protocol, "own" if own else "calibrated")


#: Per attacked flight, the largest counted score (own rule: 1.0 where a row alarms, else 0.0) in
#: each part of the flight: before onset, inside the windows, in the end transient, after it.
ZONES = ("pre_max", "window_max", "end_max", "after_max")


def _zone_max(values: np.ndarray, mask: np.ndarray) -> float:
    return float(values[mask].max()) if mask.any() else float("-inf")


def flight_outcomes(flights: pd.DataFrame, rows: Mapping[str, FlightRows],
                    end_transient_s: float = 0.0, own: bool = False) -> pd.DataFrame:
    """Per attacked flight: ``outcome`` (detected / at_end / late / missed), ``delay_s`` (onset to
    the first alarm inside the window), ``late_delay_s`` (end of the window to the first alarm
    after it, at_end and late flights), ``alarm_before_onset`` (a row alarm before the attack
    started: a false alarm) and the zone maxima :data:`ZONES` the intervals re-threshold.

    Inside the window = rows labelled ``Is_Anomaly`` (the event log's ``[start, end)`` windows);
    a flight without labelled rows uses the manifest's ``[attack_start_us, attack_end_us)``.
    *At the end*: no alarm inside, a first alarm within ``end_transient_s`` after the end (the
    attacked value snapping back is the attack's own effect); *late*: a first alarm after that.
    Normal flights get an empty outcome.
    """
    out = pd.DataFrame({"outcome": "", "delay_s": np.nan, "late_delay_s": np.nan, "alarm_before_onset": False,
                        **dict.fromkeys(ZONES, np.nan)}, index=flights.index)
    transient = int(round(end_transient_s * 1e6))
    for fid, row in flights.iterrows():
        if row.get("role") != "test_attacked":
            continue
        fr = rows[fid]
        window = _attack_window(row, fr)
        if window is None:
            out.at[fid, "outcome"] = "missed"
            continue
        start, end = window
        inside = fr.label.astype(bool)
        if not inside.any():
            inside = (fr.timestamp >= start) & (fr.timestamp < (end if end is not None else np.iinfo(np.int64).max))
        if end is None:
            end = int(fr.timestamp[np.flatnonzero(inside)[-1]]) + 1 if inside.any() else start
        kept = fr.kept
        level = fr.alarm.astype(np.float64) if own else fr.score
        zones = {"pre_max": kept & (fr.timestamp < start), "window_max": kept & inside,
                 "end_max": kept & ~inside & (fr.timestamp >= end) & (fr.timestamp < end + transient),
                 "after_max": kept & ~inside & (fr.timestamp >= end + transient)}
        for z, m in zones.items():
            out.at[fid, z] = _zone_max(level, m)
        out.at[fid, "alarm_before_onset"] = bool((fr.alarm & zones["pre_max"]).any())
        hit = np.flatnonzero(fr.alarm & inside)
        if hit.size:
            out.at[fid, "outcome"] = "detected"
            out.at[fid, "delay_s"] = max(float(fr.timestamp[hit[0]] - start), 0.0) / 1e6
            continue
        after = np.flatnonzero(fr.alarm & ~inside & (fr.timestamp >= end))
        if after.size:
            first = int(fr.timestamp[after[0]])
            out.at[fid, "outcome"] = "at_end" if first < end + transient else "late"
            out.at[fid, "late_delay_s"] = float(first - end) / 1e6
        else:
            out.at[fid, "outcome"] = "missed"
    return out


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
    """Range-based precision / recall / F1 as TSB-AD reports them ("R-based-F1"), on the row
    alarms of the test flights concatenated (:func:`benchmark.vus.r_prf`)."""

    name = "range"
    columns = ("r_precision", "r_recall", "r_f1")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        ids = ev.test().index
        if len(ids) == 0:
            return dict.fromkeys(self.columns, float("nan"))
        y = np.concatenate([ev.rows[f].label for f in ids])
        p = np.concatenate([ev.rows[f].alarm for f in ids])
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


def calibration_table(ev: Evaluation) -> pd.DataFrame:
    """Per validation flight: its flight score, when in the flight its maximum occurred (seconds
    after arming, over the counted rows and over all rows) and whether it sets the threshold."""
    val = ev.flights[ev.flights["role"] == "validation"]
    armed = (pd.to_numeric(val["armed_us"], errors="coerce") if "armed_us" in val.columns
             else pd.Series(np.nan, index=val.index))
    rows = []
    for fid in val.index:
        fr = ev.rows[fid]
        arm = float(fr.timestamp[0]) if pd.isna(armed[fid]) else float(armed[fid])
        kept = fr.kept
        at = fr.timestamp[np.flatnonzero(kept)[np.argmax(fr.score[kept])]] if kept.any() else fr.timestamp[0]
        raw = fr.timestamp[int(np.argmax(fr.score))]
        rows.append({"flight_id": fid, "score": float(val.at[fid, "score"]), "max_after_arming_s": (at - arm) / 1e6,
                     "raw_max_after_arming_s": (raw - arm) / 1e6,
                     "sets_threshold": bool(math.isfinite(ev.flight_threshold)
                                            and float(val.at[fid, "score"]) == ev.flight_threshold)})
    return pd.DataFrame(rows, columns=["flight_id", "score", "max_after_arming_s", "raw_max_after_arming_s",
                                       "sets_threshold"])


#: Seconds after arming within which a validation maximum counts as "near arming" in the summary.
NEAR_ARMING_S = 10.0


class CalibrationPoint(Metric):
    """Where the threshold comes from: seconds after arming of the validation row that sets it,
    how many validation maxima sit within :data:`NEAR_ARMING_S` of arming (over the counted
    rows), and how many of the raw maxima (all rows) the burn-in took out."""

    name = "calibration"
    columns = ("threshold_after_arming_s", "val_max_near_arming", "val_raw_max_in_burn_in")

    def compute(self, ev: Evaluation) -> dict[str, float]:
        cal = calibration_table(ev)
        sets = cal[cal["sets_threshold"]]
        burn_in = ev.protocol.burn_in_s if ev.protocol is not None else 0.0
        raw = cal["raw_max_after_arming_s"]
        return {"threshold_after_arming_s": float(sets["max_after_arming_s"].iloc[0]) if len(sets) else float("nan"),
                "val_max_near_arming": int(((cal["max_after_arming_s"] >= 0)
                                            & (cal["max_after_arming_s"] < NEAR_ARMING_S)).sum()),
                "val_raw_max_in_burn_in": int((raw < burn_in).sum()) if burn_in > 0 else 0}


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
    FalseAlarmRate(), CalibrationPoint(), ScoringLatency(),
)


def compute_metrics(ev: Evaluation, metrics: tuple[Metric, ...] = DEFAULT_METRICS) -> dict[str, float]:
    """All metric columns of one detector, plus its two thresholds."""
    out: dict[str, float] = {}
    for m in metrics:
        out.update(m(ev))
    out["flight_threshold"] = ev.flight_threshold
    out["row_threshold"] = ev.row_threshold
    return out


BREAKDOWN_DIMENSIONS = ("action", "target", "injection_point", "kind", "detectability_bin")
BREAKDOWN_COLUMNS = ["detector", "dimension", "value", "mode", "n", "detected", "tp_rate", "tp_rate_lo",
                     "tp_rate_hi", "late", "flagged", "impact_n", "max_dev_median_m", "final_dev_median_m",
                     "mission_completed", "crashed"]


def impact_summary(flights: pd.DataFrame) -> dict:
    """The attack's physical impact over a group of attacked flights (those with a twin: the
    simulation-mode ones; :mod:`scart_bench.generator.impact`): how many, median max and final
    deviation of the true path from the twin's (m), how many completed the mission, crashed."""
    if "impact_max_dev_m" not in flights.columns:
        return {"impact_n": 0, "max_dev_median_m": float("nan"), "final_dev_median_m": float("nan"),
                "mission_completed": 0, "crashed": 0}
    dev = pd.to_numeric(flights["impact_max_dev_m"], errors="coerce")
    has = flights[dev.notna()]
    flag = {c: has[c].astype(object).where(has[c].notna(), False).astype(str).str.lower().eq("true")
            if c in has.columns else pd.Series(False, index=has.index)
            for c in ("impact_mission_completed", "impact_crashed")}

    def med(col: str) -> float:
        return float(pd.to_numeric(has[col], errors="coerce").median()) if len(has) else float("nan")

    return {"impact_n": len(has), "max_dev_median_m": med("impact_max_dev_m"),
            "final_dev_median_m": med("impact_final_dev_m"),
            "mission_completed": int(flag["impact_mission_completed"].sum()),
            "crashed": int(flag["impact_crashed"].sum())}


#: Edges of the detectability bins (injected size in validation standard deviations).
DETECTABILITY_EDGES = (1.0, 3.0, 10.0)


def detectability_bins(values: pd.Series) -> pd.Series:
    """Bin labels of detectability values: ``<1 sd``, ``1-3 sd``, ``3-10 sd``, ``>=10 sd``, ``n/a``."""
    v = pd.to_numeric(values, errors="coerce").to_numpy(np.float64)
    labels = np.array(["<1 sd", "1-3 sd", "3-10 sd", ">=10 sd"], dtype=object)
    out = labels[np.searchsorted(np.array(DETECTABILITY_EDGES), np.nan_to_num(v, nan=0.0), side="right")]
    out[~np.isfinite(v)] = "n/a"
    return pd.Series(out, index=values.index, name="detectability_bin")


def breakdown(ev: Evaluation, dimensions: tuple[str, ...] = BREAKDOWN_DIMENSIONS) -> pd.DataFrame:
    """Detected (in-window) count, TP rate with its Wilson interval, late and flagged-anywhere
    counts of the attacked test flights per value of each dimension, for all modes together
    (mode "all") and per mode, with the attack's physical impact (:func:`impact_summary`)."""
    attacked = ev.test("test_attacked")
    if "detectability" in attacked.columns:
        attacked = attacked.assign(detectability_bin=detectability_bins(attacked["detectability"]))
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
                k = int((group["outcome"] == "detected").sum())
                lo, hi = wilson(k, len(group))
                rows.append({"detector": ev.detector, "dimension": dim, "value": value, "mode": mode,
                             "n": len(group), "detected": k, "tp_rate": k / len(group), "tp_rate_lo": lo,
                             "tp_rate_hi": hi, "late": int((group["outcome"] == "late").sum()),
                             "flagged": int(group["flagged"].astype(bool).sum()), **impact_summary(group)})
    return pd.DataFrame(rows, columns=BREAKDOWN_COLUMNS)


# -- tables -----------------------------------------------------------------------------------

#: (header, metrics column, format) of the printed table. ``pct_ci``: a percentage with its
#: interval from ``<column>_lo`` / ``<column>_hi``; ``fN_ci``: N decimals with its interval;
#: ``prior``: AUC-PR with its interval and the AUC-PR of a random ranking.
PAPER_COLUMNS = (("TP Simulation (in window)", "tp_simulation", "pct_ci"),
                 ("TP CSV (in window)", "tp_csv", "pct_ci"),
                 ("TN No Attack", "tn_no_attack", "pct_ci"),
                 ("False alarms, normal", "far_no_attack", "pct_ci"),
                 ("TP Sim (window + end)", "tp_end_simulation", "pct_ci"),
                 ("TP CSV (window + end)", "tp_end_csv", "pct_ci"),
                 ("Late Sim", "late_simulation", "pct_ci"), ("Late CSV", "late_csv", "pct_ci"),
                 ("FA before onset Sim", "fa_before_onset_simulation", "pct_ci"),
                 ("FA before onset CSV", "fa_before_onset_csv", "pct_ci"),
                 ("Flagged anywhere Sim", "flagged_simulation", "pct_ci"),
                 ("Flagged anywhere CSV", "flagged_csv", "pct_ci"),
                 ("ROC-AUC", "roc_auc", "f3_ci"), ("AUC-PR (prior)", "auc_pr", "prior"),
                 ("Median delay (s)", "delay_median_s", "f2"))
EXTRA_COLUMNS = (("VUS-PR", "vus_pr", "f3"), ("VUS-ROC", "vus_roc", "f3"), ("Row AUC-PR", "row_auc_pr", "f3"),
                 ("Row ROC-AUC", "row_roc_auc", "f3"),
                 ("Point P", "point_precision", "f3"), ("Point R", "point_recall", "f3"),
                 ("Point F1", "point_f1", "f3"), ("R-P (TSB-AD)", "r_precision", "f3"),
                 ("R-R (TSB-AD)", "r_recall", "f3"), ("R-F1 (TSB-AD)", "r_f1", "f3"),
                 ("Range F1 (Tatbul a=0)", "rt0_f1", "f3"),
                 ("p90 delay (s)", "delay_p90_s", "f2"), ("Late delay after end (s)", "late_delay_median_s", "f2"),
                 ("False alarms / h", "false_alarms_per_hour", "f2"),
                 ("Latency (us/row)", "latency_us_per_row", "f1"), ("Fit (s)", "fit_s", "f1"))


def _nan(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value)) or bool(pd.isna(value))


def format_value(value, kind: str, lo=None, hi=None) -> str:
    """A number as the tables show it: ``pct`` -> ``81.8 %``, ``pct_ci`` -> ``81.8 % [52-95]``,
    ``fN`` -> N decimals, ``fN_ci`` -> ``0.812 [0.700-0.900]``; ``n/a`` for NaN."""
    if _nan(value):
        return "n/a"
    v = float(value)
    base, _, ci = kind.partition("_")
    text = f"{100 * v:.1f} %" if base == "pct" else f"{v:.{base[1:]}f}"
    if ci and not _nan(lo) and not _nan(hi):
        if base == "pct":
            text += f" [{100 * float(lo):.0f}-{100 * float(hi):.0f}]"
        else:
            text += f" [{float(lo):.{base[1:]}f}-{float(hi):.{base[1:]}f}]"
    return text


def _cell(row, key: str, kind: str) -> str:
    if kind == "prior":
        text = format_value(row.get(key), "f3_ci", row.get(f"{key}_lo"), row.get(f"{key}_hi"))
        prior = row.get(f"{key}_prior")
        return text if _nan(prior) or text == "n/a" else f"{text} ({float(prior):.3f})"
    return format_value(row.get(key), kind, row.get(f"{key}_lo"), row.get(f"{key}_hi"))


def markdown_table(metrics: pd.DataFrame, columns=PAPER_COLUMNS, status: bool = True) -> str:
    """A Markdown table, one row per detector; a failed job shows its status, not numbers."""
    head = ["Detector", *(c[0] for c in columns)] + (["Status"] if status else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for _, r in metrics.iterrows():
        ok = r.get("status") == "OK"
        cells = [str(r["detector"])]
        cells += [_cell(r, key, kind) if ok else str(r.get("status")) for _, key, kind in columns]
        if status:
            cells.append(str(r.get("status")))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


DETECTION_RULE = (
    "detection rule: an attacked flight is detected (TP, the headline) when at least one row alarms inside an "
    "attack window [start, end) of its event log; 'window + end' also counts a first alarm within the end "
    "transient after the window (the attacked value snapping back is the attack's own effect); late when its "
    "first alarm comes after that; missed otherwise. 'Flagged anywhere' (flight score above the flight "
    "threshold, any row) is the paper's lenient rule, shown beside it. 'FA before onset': attacked flights with "
    "a row alarm before the attack started (false alarms the TN column does not see). TN: held-out normal test "
    "flights not flagged; 'False alarms, normal' = 1 - TN, to compare with the target alpha. Attacked flights "
    "whose attack changed nothing (no_effect) are excluded from every rate.")

#: How the rates' intervals are computed (metrics.md, the README).
INTERVAL_METHOD = (
    "intervals: 95 %, cluster bootstrap (1,000 seeded replicates): csv copies of one source recording and the "
    "flights of one configuration flown in both modes form one cluster; clusters are resampled within normal "
    "and within attacked flights, and every replicate re-calibrates the threshold on validation flights resampled "
    "with replacement (the threshold's own uncertainty). The interval shown is the hull of the bootstrap's "
    "percentile interval and the Wilson interval at its effective sample size (at the number of independent "
    "units when a rate is 0 or 100 %); the plain Wilson interval is in metrics.csv (*_wilson_lo/_hi). ROC-AUC "
    "and AUC-PR: bootstrap over flights; AUC-PR in brackets after it is the prior (a random ranking).")


def rate_summary(metrics: pd.DataFrame, no_effect: list[str] = ()) -> list[str]:
    """Markdown lines: how many flights each rate rests on, the operating point (target alpha
    against the measured false-alarm rate, per detector), and the attacked flights left out."""
    ok = metrics[metrics["status"] == "OK"] if "status" in metrics else metrics.iloc[:0]
    lines = ["## Flights behind each rate", ""]
    if len(ok):
        r = ok.iloc[0]
        units = r.get("n_units_csv")
        lines.append(f"- TP / late / flagged Simulation: {int(r['n_simulation'])} attacked simulation-mode test "
                     f"flights; TP / late / flagged CSV: {int(r['n_csv'])} csv-mode flights"
                     + ("" if _nan(units) else f" replaying {int(units)} source recordings")
                     + f"; TN No Attack: {int(r['n_no_attack'])} held-out normal test flights"
                     + ("" if _nan(r.get("n_validation")) else
                        f"; thresholds calibrated on {int(r['n_validation'])} validation normal flights") + ".")
        if not _nan(r.get("n_onset_in_burn_in")) and int(r["n_onset_in_burn_in"]):
            lines.append(f"- **{int(r['n_onset_in_burn_in'])} attacked flights start their attack inside the burn-in "
                         "after arming**: their first attacked rows cannot alarm (see docs/protocol.md).")
        lines += ["", "## Operating point", ""]
        for _, d in ok.iterrows():
            lines.append("- " + operating_point_line(d))
    no_effect = list(no_effect)
    shown = ", ".join(no_effect[:20]) + (" ..." if len(no_effect) > 20 else "")
    lines.append(f"- attacked flights whose attack changed nothing (no_effect, excluded from every rate): "
                 f"{len(no_effect)}" + (f": {shown}" if no_effect else ""))
    lines.append("")
    return lines


def operating_point_line(d) -> str:
    """One detector's operating point in words: its target alpha, the measured false-alarm rate on
    held-out normal flights with its interval, and whether the interval holds alpha."""
    far, lo, hi = d.get("far_no_attack"), d.get("far_no_attack_lo"), d.get("far_no_attack_hi")
    measured = format_value(far, "pct_ci", lo, hi)
    alpha = d.get("alpha")
    if _nan(alpha):
        text = f"**{d['detector']}**: its own alarm rule (no target rate); false alarms on normal flights {measured}"
    else:
        text = (f"**{d['detector']}**: target alpha {100 * float(alpha):g} % per flight; measured on held-out "
                f"normal flights {measured}")
        if not _nan(d.get("alpha_attainable")) and not bool(d.get("alpha_attainable")):
            text += (f" (**alpha not attainable** with {int(d['n_validation'])} validation flights: the threshold "
                     "is the largest validation score)")
        elif not _nan(lo) and not _nan(hi) and not (float(lo) <= float(alpha) <= float(hi)):
            text += " (**the interval does not contain alpha**)"
    fa = [f"{m} {format_value(d.get(f'fa_before_onset_{m}'), 'pct')}" for m in ATTACK_MODES
          if not _nan(d.get(f"fa_before_onset_{m}"))]
    if fa:
        text += "; attacked flights with a false alarm before onset: " + ", ".join(fa)
    after = [int(d.get(f"detected_after_fa_{m}") or 0) for m in ATTACK_MODES]
    if any(after):
        text += (f" ({after[0]} simulation / {after[1]} csv detections follow such a false alarm)")
    fph = d.get("false_alarms_per_hour")
    if not _nan(fph):
        text += f"; {float(fph):.2f} false alarm events per flight-hour"
    return text + "."
