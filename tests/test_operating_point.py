"""The operating point chosen after the run (issue 46): ``scart-bench score RUN --alpha A [--burn-in S]``
evaluates the saved scores at another alpha into ``RUN/evaluations/`` without running a job, and leaves the
saved scores and the run's own tables as they were."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pandas as pd
import pytest
from run_fixtures import plugin, write_dataset

from scart_bench.benchmark.store import RunStore
from scart_bench.cli.main import main

PAIR = ["--detectors", "zscore_test,diff_test", "--plugin", plugin("ZScore"), "--plugin", plugin("Diff")]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A small run at alpha 0.5: with its 3 validation flights the threshold is the 2nd of 3, so a lower
    alpha (the largest of 3) must move it."""
    root = tmp_path_factory.mktemp("op")
    ds = write_dataset(root / "ds")
    out = root / "run"
    assert main(["run", *PAIR, "--dataset", str(ds), "--out", str(out), "--alpha", "0.5", "--jobs", "1"]) == 0
    return out


def snapshot(folder: Path) -> dict[str, tuple[str, int]]:
    """sha256 and mtime of every file of the run outside evaluations/."""
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file() and p.relative_to(folder).parts[0] != "evaluations"}


def _no_jobs(*args, **kwargs):
    raise AssertionError("score --alpha ran a job")


def test_score_alpha_moves_the_operating_point_without_running_a_job(run, monkeypatch, capsys):
    import scart_bench.benchmark.executors as executors
    import scart_bench.benchmark.jobs as jobs

    monkeypatch.setattr(executors, "make_executor", _no_jobs)
    monkeypatch.setattr(jobs, "run_job", _no_jobs)
    before = snapshot(run)
    own = pd.read_csv(run / "metrics.csv").set_index("detector")
    assert main(["score", str(run), "--alpha", "0.01", "--jobs", "1"]) == 0
    out = capsys.readouterr()
    assert snapshot(run) == before  # scores, status, the run's own metrics: not touched, not rewritten
    folder = run / "evaluations" / "alpha-0.01"
    assert {p.name for p in folder.iterdir()} == {"metrics.csv", "metrics.md", "breakdown.csv", "flight_scores.csv",
                                                  "calibration.csv", "evaluation.json"}
    ev = pd.read_csv(folder / "metrics.csv").set_index("detector")
    assert (ev["alpha"] == 0.01).all() and (own["alpha"] == 0.5).all()
    assert (ev["flight_threshold"] >= own["flight_threshold"]).all()
    assert (ev["flight_threshold"] > own["flight_threshold"]).any()  # the operating point moved
    for rate in ("far_no_attack", "fa_before_onset_simulation", "fa_before_onset_csv"):
        assert (ev[rate] <= own[rate]).all(), rate
    for rate in ("tp_simulation", "tp_csv", "flagged_simulation"):
        assert (ev[rate] <= own[rate]).all(), rate
    # the threshold-free metrics do not depend on the operating point
    pd.testing.assert_series_equal(ev["roc_auc"], own["roc_auc"])
    record = json.loads((folder / "evaluation.json").read_text())
    assert record["alpha"] == 0.01 and record["run_protocol"]["flight_rule"]["alpha"] == 0.5
    assert set(record["scores_sha256"]) == {"zscore_test", "diff_test"}
    md = (folder / "metrics.md").read_text()
    assert "alpha 0.01" in md and "no job was run" in md
    assert "target alpha 1 % per flight" in out.out and "evaluations/alpha-0.01" in out.err


def test_the_run_still_scores_reports_and_resumes_after_an_evaluation(run, tmp_path):
    assert main(["score", str(run), "--alpha", "0.01", "--burn-in", "2", "--jobs", "1"]) == 0
    ev = pd.read_csv(run / "evaluations" / "alpha-0.01-burnin-2" / "metrics.csv")
    assert (ev["alpha"] == 0.01).all()
    RunStore(run).verify()
    own = (run / "metrics.csv").read_bytes()
    assert main(["score", str(run), "--jobs", "1"]) == 0
    assert (run / "metrics.csv").read_bytes() == own  # the run's own operating point, as before
    assert main(["report", str(run), "--out", str(tmp_path / "report")]) == 0
    ds = json.loads((run / "config.json").read_text())["dataset"]["path"]
    assert main(["run", *PAIR, "--dataset", ds, "--out", str(run), "--alpha", "0.5", "--jobs", "1", "--resume"]) == 0
    assert (run / "evaluations" / "alpha-0.01" / "metrics.csv").is_file()


@pytest.mark.parametrize("option, value", [("--alpha", "1.5"), ("--alpha", "0"), ("--burn-in", "-1")])
def test_a_refused_operating_point_names_its_option(run, capsys, option, value):
    before = snapshot(run)
    assert main(["score", str(run), option, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{option} " in err[0], err
    assert snapshot(run) == before


def test_the_operating_characteristic_recounts_the_tables(run):
    """At the run's alpha and at an evaluation's, the characteristic from the saved scores is the tables' TP
    and false-alarm rate."""
    from scart_bench.benchmark.results import operating_characteristics

    assert main(["score", str(run), "--alpha", "0.01", "--jobs", "1"]) == 0
    oc = operating_characteristics(run, alphas=(0.5, 0.01)).set_index(["detector", "alpha"])
    for alpha, table in ((0.5, run / "metrics.csv"), (0.01, run / "evaluations" / "alpha-0.01" / "metrics.csv")):
        m = pd.read_csv(table).set_index("detector")
        for det in ("zscore_test", "diff_test"):
            for col in ("tp_simulation", "tp_csv", "far_no_attack", "flight_threshold"):
                got = oc.loc[(det, alpha), "threshold" if col == "flight_threshold" else col]
                assert got == pytest.approx(m.loc[det, col]), (alpha, det, col)


def test_the_realised_rate_spread_is_the_beta_law_of_the_order_statistic():
    from scart_bench.benchmark.metrics import realised_rate_spread

    k, mean, lo, hi = realised_rate_spread(60, 0.05)  # the quick profile: the 58th of 60, Beta(3, 58)
    assert k == 58 and mean == pytest.approx(3 / 61)
    assert 0.009 < lo < 0.012 and 0.11 < hi < 0.12
    assert realised_rate_spread(3, 0.01)[0] == 3  # not attainable: the largest, Beta(1, 3)
    with pytest.raises(ValueError, match="n = 0"):
        realised_rate_spread(0, 0.05)


def test_the_report_has_an_operating_characteristic_for_every_detector(run, tmp_path):
    out = tmp_path / "report"
    assert main(["report", str(run), "--out", str(out)]) == 0
    ok = pd.read_csv(run / "metrics.csv").query("status == 'OK'")["detector"].tolist()
    assert ok == ["zscore_test", "diff_test"]
    md = (out / "leaderboard.md").read_text()
    for det in ok:
        png = out / "figures" / f"oc_run_{det}.png"
        assert png.is_file() and png.stat().st_size > 10_000, det
        assert f"figures/oc_run_{det}.png" in md and f"Operating characteristic of {det}" in md
