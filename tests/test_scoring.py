"""Metrics and protocol on tiny hand-computed cases."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.metrics import roc_auc_score

from scart_bench.benchmark.evaluation import Evaluation, ScoreError, build_evaluation, flight_outcomes
from scart_bench.benchmark.intervals import bootstrap_auc, wilson
from scart_bench.benchmark.metrics import (
    DEFAULT_METRICS,
    DetectionDelay,
    FalseAlarmRate,
    FlightROCAUC,
    PaperTable,
    PointwisePRF,
    RangePRF,
    ScoringLatency,
    TatbulZeroPRF,
    alarm_events,
    compute_metrics,
    detection_delay,
    point_prf,
    range_prf,
    range_scores,
    roc_auc,
    runs,
)
from scart_bench.benchmark.protocol import Protocol, ProtocolError, Splits, ThresholdRule, assign_roles
from scart_bench.benchmark.tables import (
    PAPER_COLUMNS,
    breakdown,
    detectability_bins,
    format_value,
    markdown_table,
)

# -- array-level metrics ----------------------------------------------------------------------


def test_runs():
    assert runs(np.array([0, 1, 1, 0, 1])).tolist() == [[1, 3], [4, 5]]
    assert runs(np.array([1, 1, 1])).tolist() == [[0, 3]]
    assert runs(np.zeros(4)).shape == (0, 2)
    assert runs(np.array([], dtype=bool)).shape == (0, 2)


def test_roc_auc_hand_computed():
    assert roc_auc([0, 0, 1, 1], [0.1, 0.4, 0.35, 0.8]) == pytest.approx(0.75)
    assert roc_auc([0, 1], [0.5, 0.5]) == pytest.approx(0.5)
    assert roc_auc([0, 0, 1], [1.0, 2.0, 3.0]) == pytest.approx(1.0)
    assert np.isnan(roc_auc([1, 1], [0.1, 0.2]))


@pytest.mark.parametrize("seed", range(5))
def test_roc_auc_equals_sklearn_with_ties(seed):
    rng = np.random.default_rng(seed)
    y = rng.integers(0, 2, 200)
    y[:2] = (0, 1)
    s = np.round(rng.normal(size=200) + y, 1)  # rounding makes many ties
    assert roc_auc(y, s) == pytest.approx(roc_auc_score(y, s), abs=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_average_precision_equals_sklearn_with_ties(seed):
    from sklearn.metrics import average_precision_score

    from scart_bench.benchmark.vus import average_precision

    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 300))
    y = rng.integers(0, 2, n)
    y[:2] = (0, 1)
    s = np.round(rng.normal(size=n) + y, int(rng.integers(0, 3)))  # rounding makes many ties
    assert average_precision(y, s) == pytest.approx(average_precision_score(y, s), abs=1e-12)
    assert average_precision([0, 0, 1, 1], [0.1, 0.4, 0.35, 0.8]) == pytest.approx(5 / 6)
    assert np.isnan(average_precision([0, 0], [0.1, 0.2]))


def test_roc_auc_rejects_nan_and_bad_labels():
    with pytest.raises(ScoreError):
        roc_auc([0, 1], [0.1, np.nan])
    with pytest.raises(ValueError):
        roc_auc([0, 2], [0.1, 0.2])


def test_point_prf():
    p, r, f = point_prf(np.array([0, 1, 1, 0, 1]), np.array([0, 1, 0, 1, 1]))
    assert (p, r, f) == pytest.approx((2 / 3, 2 / 3, 2 / 3))
    assert point_prf(np.array([0, 1]), np.array([0, 0])) == (0.0, 0.0, 0.0)


def test_range_scores_flat_bias_alpha_zero():
    real, pred = np.array([[2, 6]]), np.array([[0, 3], [5, 8]])
    rec, prec = range_scores(real, pred)
    assert rec.tolist() == pytest.approx([0.5])          # 2 of 4 rows covered
    assert prec.tolist() == pytest.approx([1 / 3, 1 / 3])  # 1 of 3 rows inside, each
    rec, _ = range_scores(real, pred, cardinality="reciprocal")
    assert rec.tolist() == pytest.approx([0.25])         # two fragments: x 1/2
    p, r, f = range_prf([real], [pred])
    assert (p, r, f) == pytest.approx((1 / 3, 0.5, 0.4))


def test_range_prf_over_flights():
    # flight A: half the attack covered, one clean alarm; flight B (normal): one false alarm range
    p, r, f = range_prf([np.array([[0, 4]]), np.zeros((0, 2))], [np.array([[0, 2]]), np.array([[1, 3]])])
    assert (p, r, f) == pytest.approx((0.5, 0.5, 0.5))
    assert range_prf([np.array([[0, 4]])], [np.zeros((0, 2))]) == (0.0, 0.0, 0.0)


def test_detection_delay_and_alarm_events():
    ts = np.array([0, 1, 2, 3, 4]) * 1_000_000
    alarms = np.array([1, 0, 0, 1, 1], dtype=bool)
    assert detection_delay(ts, alarms, 1_500_000, 3_500_000) == pytest.approx(1.5)
    assert np.isnan(detection_delay(ts, alarms, 1_500_000, 2_500_000))
    assert detection_delay(ts, alarms, 0, None) == 0.0
    assert alarm_events(np.array([1, 1, 0, 1, 0, 0, 1])) == 3
    assert alarm_events(np.zeros(3)) == 0


# -- protocol ---------------------------------------------------------------------------------


def test_threshold_rules():
    assert ThresholdRule("max", 0.05).calibrate([0.2, 1.0]) == pytest.approx(1.05)
    assert ThresholdRule("max", 0.05).calibrate([-2.0, -1.0]) == pytest.approx(-0.95)
    assert ThresholdRule("quantile", 0.0, q=0.999).calibrate(np.arange(1001) / 1000) == pytest.approx(0.999)
    with pytest.raises(ProtocolError):
        ThresholdRule().calibrate([0.1, np.nan])
    with pytest.raises(ProtocolError):
        ThresholdRule().calibrate([])
    with pytest.raises(ProtocolError):
        ThresholdRule("median")


def _manifest(rows):
    return pd.DataFrame(rows, columns=["flight_id", "mode", "split"])


def test_splits_and_roles():
    m = _manifest([("a", "normal", "train"), ("b", "normal", "validation"), ("c", "normal", "test"),
                   ("d", "simulation", "test"), ("e", "csv", "test")])
    s = Splits.from_manifest(m)
    assert (s.train, s.validation, s.test_normal, s.test_attacked) == (("a",), ("b",), ("c",), ("d", "e"))
    assert s.scored == ("b", "c", "d", "e")
    assert assign_roles(m).tolist() == ["train", "validation", "test_normal", "test_attacked", "test_attacked"]


@pytest.mark.parametrize("rows, words", [
    ([("a", "normal", "train"), ("d", "simulation", "train")], "attacked flights must all be 'test'"),
    ([("a", "normal", "train"), ("c", "normal", "test")], "split 'validation'"),
    ([("a", "normal", "train"), ("b", "normal", "validation"), ("d", "replay", "test")], "mode 'replay'"),
    ([("a", "normal", "train"), ("a", "normal", "validation")], "more than once"),
])
def test_splits_reject_bad_manifests(rows, words):
    with pytest.raises(ProtocolError, match=words):
        Splits.from_manifest(_manifest(rows))


# -- one detector's evaluation, by hand -------------------------------------------------------

US = 1_000_000
TS = np.array([0, 1, 2, 3]) * US


#: Protocol v1 (the largest validation score + 5 %, no burn-in, no end transient): the hand-checked
#: cases below were written for it; protocol v2 has tests of its own (tests/test_protocol_v2.py).
V1 = Protocol(ThresholdRule("max"), ThresholdRule("max"), burn_in_s=0.0, end_transient_s=0.0)


def _case(test_scores=None, protocol=V1):
    """Two validation, two normal test, two simulation and one csv attacked flight."""
    flights = pd.DataFrame([
        ("v1", "validation", "normal", None, None, None, pd.NA, pd.NA, 1800.0),
        ("v2", "validation", "normal", None, None, None, pd.NA, pd.NA, 1800.0),
        ("n1", "test_normal", "normal", None, None, None, pd.NA, pd.NA, 1800.0),
        ("n2", "test_normal", "normal", None, None, None, pd.NA, pd.NA, 1800.0),
        ("a1", "test_attacked", "simulation", "bias", "attitude.roll", "link", 1 * US, 3 * US, 4.0),
        ("a2", "test_attacked", "simulation", "noise", "attitude.roll", "link", 1 * US, 3 * US, 4.0),
        ("c1", "test_attacked", "csv", "bias", "gps_raw_int.lat", "sensor", 1 * US, pd.NA, 4.0),
        ("t0", "train", "normal", None, None, None, pd.NA, pd.NA, 1800.0),  # never scored
    ], columns=["flight_id", "role", "mode", "action", "target", "injection_point", "attack_start_us",
                "attack_end_us", "duration_s"])
    for c in ("attack_start_us", "attack_end_us"):
        flights[c] = flights[c].astype("Int64")
    labels = {"v1": [0, 0], "v2": [0, 0], "n1": [0, 0], "n2": [0, 0], "a1": [0, 1, 1, 0], "a2": [0, 1, 1, 0],
              "c1": [0, 1, 1, 1]}
    truth = {f: (TS[:len(y)], np.array(y, dtype=np.int8)) for f, y in labels.items()}
    scores = {"v1": [0.1, 0.5], "v2": [0.2, 0.9], "n1": [0.3, 1.0], "n2": [0.2, 0.3],
              "a1": [0.1, 0.5, 2.0, 0.1], "a2": [0.1, 0.1, 0.1, 0.1], "c1": [0.1, 0.1, 0.1, 5.0]}
    scores.update(test_scores or {})
    scores = {k: np.array(v, dtype=np.float64) for k, v in scores.items()}
    return build_evaluation("toy", flights, truth, scores, protocol, fit_seconds=1.0, score_seconds=2.0,
                            rows_scored=1_000_000)


def test_thresholds_come_from_validation_only():
    ev = _case()
    assert ev.flight_threshold == pytest.approx(0.9 * 1.05)
    assert ev.row_threshold == pytest.approx(0.9 * 1.05)
    moved = _case({"n1": [50.0, 60.0], "a2": [-5.0, 100, 100, 100]})
    assert (moved.flight_threshold, moved.row_threshold) == (ev.flight_threshold, ev.row_threshold)
    assert "t0" not in ev.flights.index


def test_paper_table_and_roc_auc():
    ev = _case()
    got = PaperTable()(ev)
    assert {k: got[k] for k in ("tp_simulation", "tp_csv", "tn_no_attack", "n_simulation", "n_csv",
                                "n_no_attack")} == {"tp_simulation": 0.5, "tp_csv": 1.0, "tn_no_attack": 0.5,
                                                    "n_simulation": 2.0, "n_csv": 1.0, "n_no_attack": 2.0}
    assert (got["tp_simulation_wilson_lo"], got["tp_simulation_wilson_hi"]) == pytest.approx(wilson(1, 2))
    # the reported interval (cluster bootstrap) is never narrower than Wilson's
    assert got["tp_simulation_lo"] <= got["tp_simulation_wilson_lo"] <= got["tp_simulation_wilson_hi"] \
        <= got["tp_simulation_hi"]
    assert (got["late_simulation"], got["flagged_simulation"], got["flagged_csv"]) == (0.0, 0.5, 1.0)
    auc = FlightROCAUC()(ev)
    assert auc["roc_auc"] == pytest.approx(4 / 6)
    assert auc["roc_auc"] == pytest.approx(roc_auc_score([0, 0, 1, 1, 1], [1.0, 0.3, 2.0, 0.1, 5.0]))
    assert auc["roc_auc_simulation"] == pytest.approx(0.5)
    assert auc["roc_auc_csv"] == pytest.approx(1.0)


def test_row_metrics():
    ev = _case()
    # alarms: n1 row 1, a1 row 2, c1 row 3; attack rows: a1 2, a2 2, c1 3
    assert PointwisePRF()(ev) == pytest.approx(
        {"point_precision": 2 / 3, "point_recall": 2 / 7, "point_f1": 2 * (2 / 3) * (2 / 7) / (2 / 3 + 2 / 7)})
    r = (1 / 2 + 0 + 1 / 3) / 3
    assert TatbulZeroPRF()(ev) == pytest.approx(
        {"rt0_precision": 2 / 3, "rt0_recall": r, "rt0_f1": 2 * (2 / 3) * r / (2 / 3 + r)})
    # TSB-AD's R-based P/R on the concatenated rows: 3 alarm ranges (one on n1, outside every
    # attack), 3 real ranges; recall = 0.2 * existence + 0.8 * coverage
    rp, rr = 2 / 3, (0.2 * 2 + 0.8 * (1 / 2 + 1 / 3)) / 3
    assert RangePRF()(ev) == pytest.approx({"r_precision": rp, "r_recall": rr, "r_f1": 2 * rp * rr / (rp + rr)})
    # a1: onset 1 s, first alarm 2 s -> 1 s; c1: onset 1 s, no end, alarm 3 s -> 2 s; a2 undetected
    assert DetectionDelay()(ev) == pytest.approx({"delay_median_s": 1.5, "delay_p90_s": 1.9, "n_delay": 2,
                                                  "late_delay_median_s": float("nan"), "n_late": 0}, nan_ok=True)
    # one alarm event on two half-hour normal flights
    assert FalseAlarmRate()(ev) == pytest.approx({"false_alarms_per_hour": 1.0, "normal_test_hours": 1.0})
    assert ScoringLatency()(ev) == pytest.approx({"latency_us_per_row": 2.0})


def test_compute_metrics_columns():
    out = compute_metrics(_case())
    expected = [c for m in DEFAULT_METRICS for c in m.columns] + ["flight_threshold", "row_threshold"]
    assert list(out) == expected
    assert all(isinstance(v, float) for v in out.values())


def test_metric_entry_point_is_validated():
    with pytest.raises(TypeError):
        PaperTable()({"not": "an evaluation"})


def test_breakdown():
    bd = breakdown(_case())
    action_all = bd[(bd["dimension"] == "action") & (bd["mode"] == "all")].set_index("value")
    assert action_all.loc["bias", ["n", "detected", "tp_rate"]].tolist() == [2, 2, 1.0]
    assert action_all.loc["noise", ["n", "detected", "tp_rate"]].tolist() == [1, 0, 0.0]
    sim = bd[(bd["dimension"] == "injection_point") & (bd["mode"] == "simulation")].set_index("value")
    assert sim.loc["link", ["n", "detected"]].tolist() == [2, 1]
    assert set(bd["dimension"]) == {"action", "target", "injection_point"}


def test_breakdown_by_detectability_bin():
    ev = _case()
    flights = ev.flights.assign(detectability=pd.Series({"a1": 12.0, "a2": 0.4, "c1": np.nan}))
    ev = Evaluation(ev.detector, flights, ev.rows, ev.flight_threshold, ev.row_threshold)
    bd = breakdown(ev)
    det = bd[(bd["dimension"] == "detectability_bin") & (bd["mode"] == "all")].set_index("value")
    assert det[["n", "detected"]].to_dict("index") == {">=10 sd": {"n": 1, "detected": 1},
                                                         "<1 sd": {"n": 1, "detected": 0},
                                                         "n/a": {"n": 1, "detected": 1}}
    assert detectability_bins(pd.Series([0.5, 1.0, 2.9, 3.0, 10.0, np.nan])).tolist() == [
        "<1 sd", "1-3 sd", "1-3 sd", "3-10 sd", ">=10 sd", "n/a"]


def test_breakdown_reports_the_impact_of_simulation_flights():
    ev = _case()
    flights = ev.flights.assign(
        impact_max_dev_m=pd.Series({"a1": 20.0, "a2": 0.0}), impact_final_dev_m=pd.Series({"a1": 2.0, "a2": 0.0}),
        impact_mission_completed=pd.Series({"a1": False, "a2": True}, dtype="boolean"),
        impact_crashed=pd.Series({"a1": True, "a2": False}, dtype="boolean"))
    bd = breakdown(Evaluation(ev.detector, flights, ev.rows, ev.flight_threshold, ev.row_threshold))
    action = bd[(bd["dimension"] == "action") & (bd["mode"] == "all")].set_index("value")
    cols = ["impact_n", "max_dev_median_m", "final_dev_median_m", "mission_completed", "crashed"]
    assert action.loc["bias", cols].tolist() == [1, 20.0, 2.0, 0, 1]  # the csv flight has no twin
    assert action.loc["noise", cols].tolist() == [1, 0.0, 0.0, 1, 0]
    assert breakdown(ev)["impact_n"].eq(0).all()  # a dataset made before paired flights


def test_alarm_after_the_window_is_late_not_detected():
    """Acceptance 1: an alarm only after the window is late (with its delay after the end); an
    alarm inside the window is a detection (with its delay after the onset)."""
    labels = [0, 1, 1, 0, 0, 0]  # window [1 s, 3 s)
    ts = np.arange(6) * US
    flights = pd.DataFrame([
        ("v1", "validation", "normal", pd.NA, pd.NA),
        ("late", "test_attacked", "simulation", 1 * US, 3 * US),
        ("inside", "test_attacked", "simulation", 1 * US, 3 * US),
        ("never", "test_attacked", "csv", 1 * US, 3 * US),
    ], columns=["flight_id", "role", "mode", "attack_start_us", "attack_end_us"])
    truth = {f: (ts, np.array(labels if f != "v1" else [0] * 6, dtype=np.int8)) for f in flights["flight_id"]}
    scores = {"v1": np.full(6, 1.0),
              "late": np.array([0, 0, 0, 0, 5.0, 0]),      # alarm at 4 s: 1 s after the end
              "inside": np.array([0, 0, 5.0, 0, 0, 5.0]),  # alarm at 2 s: 1 s after the onset
              "never": np.zeros(6)}
    ev = build_evaluation("toy", flights, truth, scores, V1)
    f = ev.flights
    assert f.loc["late", "outcome"] == "late" and f.loc["late", "late_delay_s"] == pytest.approx(1.0)
    assert np.isnan(f.loc["late", "delay_s"])
    assert f.loc["inside", "outcome"] == "detected" and f.loc["inside", "delay_s"] == pytest.approx(1.0)
    assert f.loc["never", "outcome"] == "missed"
    assert f.loc["late", "flagged"]  # the paper's lenient rule would have counted it
    got = PaperTable()(ev)
    assert (got["tp_simulation"], got["late_simulation"], got["flagged_simulation"]) == (0.5, 0.5, 1.0)
    assert (got["tp_csv"], got["late_csv"]) == (0.0, 0.0)
    assert flight_outcomes(f, ev.rows).loc["late", "outcome"] == "late"


def test_wilson_interval_by_hand():
    """Acceptance 3: 9 of 11 -> 81.8 % [52-95]; 0 of 4 -> [0-49]; as the closed form gives."""
    z = 1.959963984540054
    for k, n in ((9, 11), (0, 4), (4, 4), (1, 2)):
        p = k / n
        centre = (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z / (1 + z * z / n) * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
        assert wilson(k, n) == pytest.approx((max(centre - half, 0), min(centre + half, 1)), abs=1e-12)
    assert wilson(9, 11) == pytest.approx((0.5230, 0.9486), abs=1e-4)
    assert wilson(0, 4) == pytest.approx((0.0, 0.4899), abs=1e-4)
    assert all(np.isnan(wilson(0, 0)))
    assert format_value(9 / 11, "pct_ci", *wilson(9, 11)) == "81.8 % [52-95]"


def test_bootstrap_interval_is_seeded_and_brackets_the_value():
    normal, attacked = np.array([0.1, 0.4, 0.3, 0.2]), np.array([0.35, 0.8, 0.9, 0.05, 0.6])
    a = bootstrap_auc(roc_auc, normal, attacked)
    assert a == bootstrap_auc(roc_auc, normal, attacked)
    assert a[0] <= roc_auc(np.r_[np.zeros(4), np.ones(5)], np.r_[normal, attacked]) <= a[1]
    assert all(np.isnan(bootstrap_auc(roc_auc, normal, [])))


@pytest.mark.parametrize("bad, words", [
    ({"a1": [0.1, np.nan, 0.2, 0.3]}, "NaN/inf"),
    ({"n2": [0.1, np.inf]}, "NaN/inf"),
    ({"c1": [0.1, 0.2]}, "2 scores for the 4 rows"),
    ({"v1": [np.nan, 0.1]}, "NaN/inf"),
])
def test_bad_scores_raise_never_replaced(bad, words):
    with pytest.raises(ScoreError, match=words):
        _case(bad)


def test_missing_flight_scores():
    ev = _case()
    flights = ev.flights.reset_index(drop=True)
    truth = {f: (r.timestamp, r.label) for f, r in ev.rows.items()}
    scores = {f: r.score for f, r in ev.rows.items() if f != "a2"}
    with pytest.raises(ScoreError, match="no scores for flight a2"):
        build_evaluation("toy", flights, truth, scores, V1)


def test_markdown_table_shows_status_not_zeros():
    metrics = pd.DataFrame([
        {"detector": "good", "status": "OK", "tp_simulation": 0.5, "tp_csv": 1.0, "tn_no_attack": 1.0,
         "roc_auc": 0.75, "delay_median_s": float("nan")},
        {"detector": "bad", "status": "TIMEOUT", "tp_simulation": float("nan")},
    ])
    metrics.loc[0, ["tp_simulation_lo", "tp_simulation_hi"]] = wilson(1, 2)
    cols = PAPER_COLUMNS[:3] + tuple(c for c in PAPER_COLUMNS if c[1] == "roc_auc") + PAPER_COLUMNS[-1:]
    text = markdown_table(metrics, cols)
    lines = text.splitlines()
    assert lines[0] == ("| Detector | TP Simulation (in window) | TP CSV (in window) | TN No Attack | ROC-AUC | "
                        "Median delay (s) | Status |")
    assert lines[2] == "| good | 50.0 % [9-91] | 100.0 % | 100.0 % | 0.750 | n/a | OK |"
    assert lines[3] == "| bad | TIMEOUT | TIMEOUT | TIMEOUT | TIMEOUT | TIMEOUT | TIMEOUT |"


@pytest.mark.parametrize("seed", range(4))
def test_row_metrics_from_one_sort_equal_the_separate_definitions(seed):
    """A long series with a few short attacks (most rows far from any range) and tied scores:
    the pooled row metrics equal scikit-learn's ROC-AUC and AP and this module's VUS."""
    from sklearn.metrics import average_precision_score

    from scart_bench.benchmark.vus import row_metrics, vus

    rng = np.random.default_rng(seed)
    y = np.zeros(30_000, dtype=np.int8)
    for start in rng.choice(29_000, size=3, replace=False):
        y[start : start + rng.integers(5, 400)] = 1
    s = np.round(rng.standard_normal(y.size) * 4) / 4 + y * rng.random()
    got = row_metrics(y, s)
    assert got["roc_auc"] == pytest.approx(roc_auc_score(y, s), abs=1e-12)
    assert got["auc_pr"] == pytest.approx(average_precision_score(y, s), abs=1e-12)
    assert (got["vus_roc"], got["vus_pr"]) == vus(y, s)
    assert np.isnan(row_metrics(np.zeros(50), rng.random(50))["vus_pr"])


def test_scoring_module_reexports_the_split_modules():
    """benchmark.scoring stays importable as before the split (issue 46): every name it exports is the object
    of the module that now holds it."""
    from scart_bench.benchmark import evaluation, metrics, scoring, tables

    homes = (evaluation, metrics, tables)
    for name in scoring.__all__:
        obj = getattr(scoring, name)
        held = [m for m in homes if name in vars(m)]
        assert held, name
        assert all(vars(m)[name] is obj for m in held), name
    assert {"build_evaluation", "PaperTable", "markdown_table", "rate_summary", "TIMING_COLUMNS"} <= set(scoring.__all__)
