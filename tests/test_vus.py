"""VUS-ROC, VUS-PR, AUC-PR and R-F1 against the reference implementation (acceptance 4).

The reference is TSB-AD's evaluation code (``pip install --no-deps tsb-ad==1.5``; ``make setup``
installs it: its pins would downgrade numpy). Predictions are passed as integers (its range code
takes ``np.diff`` of them) and only series with an anomaly are compared (it cannot score others).
"""

from __future__ import annotations

import numpy as np
import pytest

from scart_bench.benchmark.vus import auc_pr, r_prf, row_roc_auc, vus

basic = pytest.importorskip(
    "TSB_AD.evaluation.basic_metrics",
    reason="tsb-ad is not installed (make setup runs: pip install --no-deps tsb-ad==1.5); "
           "the cross-check against the reference implementation is skipped")
TOL = 1e-6


def reference(labels: np.ndarray, scores: np.ndarray, preds: np.ndarray, window: int) -> dict[str, float]:
    grader = basic.basic_metricor()
    *_, vus_roc, vus_pr = basic.generate_curve(labels.astype(int), scores, window)
    return {"vus_roc": vus_roc, "vus_pr": vus_pr, "auc_pr": grader.metric_PR(labels, scores),
            "auc_roc": grader.metric_ROC(labels, scores),
            "r_f1": grader.metric_RF1(labels, scores, preds=preds.astype(int))}


def ours(labels: np.ndarray, scores: np.ndarray, preds: np.ndarray, window: int) -> dict[str, float]:
    vr, vp = vus(labels, scores, window)
    return {"vus_roc": vr, "vus_pr": vp, "auc_pr": auc_pr(labels, scores), "auc_roc": row_roc_auc(labels, scores),
            "r_f1": r_prf(labels, preds)[2]}


def _synthetic(case: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    rng = np.random.default_rng(100 + case)
    n = 800
    y = np.zeros(n, dtype=int)
    if case == 0:    # one long range
        y[300:420] = 1
    elif case == 1:  # several ranges, one of a single row
        y[50:60] = y[200] = y[400:480] = y[700:705] = 1
    elif case == 2:  # ranges touching both ends
        y[:30] = y[770:] = 1
    elif case == 3:  # close ranges whose borders overlap
        y[100:110] = y[118:130] = y[135:200] = 1
    elif case == 7:  # single-row ranges nearer than the border: rows reach two borders on one side
        y[300] = y[303] = y[305] = y[309:312] = y[320] = 1
    else:            # random ranges
        for _ in range(case):
            s = int(rng.integers(0, n - 60))
            y[s : s + int(rng.integers(1, 60))] = 1
    s = rng.normal(size=n) + y * rng.uniform(0.5, 3.0)
    if case == 4:
        s = np.round(s, 1)  # many tied scores
    preds = (s > np.quantile(s, 0.9)).astype(int)
    if case == 6:  # alarms on every row: TSB-AD sees no predicted range in a constant vector
        preds[:] = 1
    return y, s, preds, (0, 7, 10, 33, 100, 16, 5, 24)[case]


@pytest.mark.parametrize("case", range(8))
def test_synthetic_cases_agree_with_tsb_ad(case):
    y, s, p, window = _synthetic(case)
    want, got = reference(y, s, p, window), ours(y, s, p, window)
    for key in want:
        assert got[key] == pytest.approx(want[key], abs=TOL), key


def test_a_real_runs_scores_agree_with_tsb_ad(quick_dataset, tmp_path):
    """Scores of a built-in detector on generated flights (attacked test flights of a real run)."""
    from scart_bench.benchmark.runner import RunConfig, run_benchmark
    from scart_bench.benchmark.store import RunStore

    out = run_benchmark(RunConfig(detectors=["statistical"], dataset=quick_dataset, out=tmp_path / "run",
                                  progress=False))
    store = RunStore(out.path)
    scores, truth = store.read_scores("statistical"), store.read_truth()
    threshold = float(out.metrics.loc[0, "row_threshold"])
    flights = store.read_flights()
    attacked_rows = flights.loc[flights["role"] == "test_attacked"]
    attacked = attacked_rows["flight_id"].tolist()
    # one flight per action and mode (12 of the quick grid's 132): every kind of labelled range the
    # grid makes, in both modes, against TSB-AD's reference, which costs about 1 s per flight
    spread = attacked_rows.groupby(["mode", "action"], sort=True)["flight_id"].first().tolist()
    compared = 0
    for fid in spread:
        y = truth[fid][1].astype(int)
        s = scores[fid]
        p = (s > threshold).astype(int)
        want, got = reference(y, s, p, 100), ours(y, s, p, 100)
        for key in want:
            assert got[key] == pytest.approx(want[key], abs=TOL), (fid, key)
        compared += 1
    assert compared == attacked_rows.groupby(["mode", "action"]).ngroups >= 10
    # pooled over the attacked flights (rows concatenated), as metrics.csv reports R-F1 and AUC-PR
    y = np.concatenate([truth[f][1] for f in attacked]).astype(int)
    s = np.concatenate([scores[f] for f in attacked])
    p = (s > threshold).astype(int)
    grader = basic.basic_metricor()
    assert r_prf(y, p)[2] == pytest.approx(grader.metric_RF1(y, s, preds=p), abs=TOL)
    assert auc_pr(y, s) == pytest.approx(grader.metric_PR(y, s), abs=TOL)


def test_series_without_anomalies_have_no_score():
    y, s = np.zeros(50, dtype=int), np.random.default_rng(0).normal(size=50)
    assert all(np.isnan(vus(y, s, 10))) and np.isnan(auc_pr(y, s)) and np.isnan(row_roc_auc(y, s))
