"""One detector's evaluation: its saved scores checked against the run's flights, the protocol's
operating point applied, and the outcome of every attacked flight.

The counting rules live here; the metric classes (:mod:`benchmark.metrics`) and the tables
(:mod:`benchmark.tables`) only read the :class:`Evaluation` this module builds.

- A flight is flagged when its score (max row score over the counted rows) is above the flight
  threshold; a row alarms when its score is above the row threshold (both calibrated on the
  validation flights by :mod:`benchmark.protocol`), outside the burn-in after arming.
- Scores must be finite. A NaN or inf never becomes a number: :func:`build_evaluation` raises
  :class:`ScoreError` and the job is reported as ERROR.

The detection rule (per attacked flight, :func:`flight_outcomes`): the flight is *detected* when
at least one row alarms inside an attack window (rows labelled ``Is_Anomaly``, i.e. the windows
``[start, end)`` of the event log); *at the end* when its first alarm comes within the end
transient after the window, *late* when it comes after that, else *missed*. *Flagged anywhere*
(flight score above the flight threshold, whatever the row) is the paper's lenient rule, reported
as its own column, never instead. Attacked flights whose attack changed nothing (``no_effect`` in
the manifest) have their own role and enter no rate.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from scart_bench.benchmark.protocol import ATTACK_MODES, Protocol, counted_masks, counted_max, counted_rows  # noqa: F401 (benchmark.scoring)
from scart_bench.errors import ScartBenchError


class ScoreError(ScartBenchError):
    """Saved or returned scores are unusable: NaN/inf, missing flights, wrong length."""


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
    #: the small-data operating point (Protocol.hourly_point) when alpha was not attainable, else None
    hourly: dict | None = None

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
    counted = counted_masks(protocol, scored, {fid: truth[fid][0] for fid in scored.index})
    validation = {fid: checked[fid] for fid in scored.index[scored["role"] == "validation"]}
    hourly = protocol.hourly_point(validation, {f: counted[f] for f in validation},
                                   {fid: truth[fid][0] for fid in validation})
    # the small-data operating point is computed once here; otherwise the flight-score rules
    t_flight, t_row = ((hourly["threshold"], hourly["threshold"]) if hourly is not None
                       else protocol.thresholds(validation, counted))
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
                      int(rows_scored), protocol, "own" if own else "calibrated", None if own else hourly)


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


def _attack_window(row: pd.Series, fr: FlightRows) -> tuple[int, int | None] | None:
    """(onset, end) of a flight's attack from the manifest, else from its labels; None if none."""
    start, end = row.get("attack_start_us"), row.get("attack_end_us")
    if start is not None and not pd.isna(start):
        return int(start), (None if end is None or pd.isna(end) else int(end))
    on = np.flatnonzero(fr.label == 1)
    if on.size == 0:
        return None
    return int(fr.timestamp[on[0]]), int(fr.timestamp[on[-1]]) + 1


def calibration_table(ev: Evaluation) -> pd.DataFrame:
    """Per validation flight: its flight score, when in the flight its maximum occurred (seconds
    after arming, over the counted rows and over all rows) and whether it sets the threshold."""
    val = ev.flights[ev.flights["role"] == "validation"]
    armed = (pd.to_numeric(val["armed_us"], errors="coerce") if "armed_us" in val.columns
             else pd.Series(np.nan, index=val.index))
    def bound(col: str) -> pd.Series:
        return (pd.to_numeric(val[col], errors="coerce") if col in val.columns
                else pd.Series(np.nan, index=val.index))

    lift, down = bound("liftoff_us"), bound("touchdown_us")
    rows = []
    for fid in val.index:
        fr = ev.rows[fid]
        arm = float(fr.timestamp[0]) if pd.isna(armed[fid]) else float(armed[fid])
        kept = fr.kept
        at = fr.timestamp[np.flatnonzero(kept)[np.argmax(fr.score[kept])]] if kept.any() else fr.timestamp[0]
        raw = fr.timestamp[int(np.argmax(fr.score))]
        rows.append({"flight_id": fid, "score": float(val.at[fid, "score"]), "max_after_arming_s": (at - arm) / 1e6,
                     "raw_max_after_arming_s": (raw - arm) / 1e6,
                     "max_after_liftoff_s": (at - lift[fid]) / 1e6 if not pd.isna(lift[fid]) else np.nan,
                     "max_before_touchdown_s": (down[fid] - at) / 1e6 if not pd.isna(down[fid]) else np.nan,
                     "sets_threshold": bool(math.isfinite(ev.flight_threshold)
                                            and float(val.at[fid, "score"]) == ev.flight_threshold)})
    cols = [c for c in CALIBRATION_COLUMNS if "liftoff_us" in val.columns or c not in PHASE_CALIBRATION_COLUMNS]
    return pd.DataFrame(rows, columns=cols)


#: calibration.csv's columns (per validation flight): seconds are from arming, take-off and to touchdown
#: (the last two empty where the run has no phase bounds)
CALIBRATION_COLUMNS = ("flight_id", "score", "max_after_arming_s", "raw_max_after_arming_s",
                       "max_after_liftoff_s", "max_before_touchdown_s", "sets_threshold")
#: the columns a run without phase bounds (made before protocol v3) does not have
PHASE_CALIBRATION_COLUMNS = ("max_after_liftoff_s", "max_before_touchdown_s")
