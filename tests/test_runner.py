"""The benchmark run end to end on a small synthetic dataset with cheap plugin detectors."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from run_fixtures import ATTACKS, plugin, quality, write_dataset
from sklearn.metrics import roc_auc_score

from scart_bench.benchmark.metrics import DEFAULT_METRICS
from scart_bench.benchmark.store import RunStore, read_npz
from scart_bench.cli.main import main

ZS, DIFF = plugin("ZScore"), plugin("Diff")
OK_PAIR = ["--detectors", "zscore_test,diff_test", "--plugin", ZS, "--plugin", DIFF]


@pytest.fixture(scope="session")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("data") / "ds")


@pytest.fixture(scope="session")
def reference_run(dataset, tmp_path_factory) -> Path:
    """An uninterrupted local run of the two working test detectors."""
    out = tmp_path_factory.mktemp("runs") / "reference"
    assert main(["run", *OK_PAIR, "--dataset", str(dataset), "--out", str(out), "--jobs", "2"]) == 0
    return out


def snapshot(folder: Path) -> dict[str, tuple[str, int]]:
    """Content hash and mtime of every file under a folder."""
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


# -- a full run -------------------------------------------------------------------------------


def test_run_folder_layout(reference_run, dataset):
    names = {str(p.relative_to(reference_run)) for p in reference_run.rglob("*") if p.is_file()}
    expected = {"config.json", "flights.csv", "truth.parquet", "arming.csv", "phases.csv", "results.csv", "metrics.csv",
                "metrics.md", "breakdown.csv", "flight_scores.csv", "calibration.csv", ".lock", "checksums.json"}
    for det in ("zscore_test", "diff_test"):
        expected |= {f"jobs/{det}/{f}" for f in ("status.json", "params.json", "scores.npz", "log.txt")}
    assert names == expected  # and no temp file left behind

    config = json.loads((reference_run / "config.json").read_text())
    assert config["seed"] == 0 and config["identity"]["seed"] == 0
    assert config["dataset"]["path"] == str(dataset.resolve())
    assert config["dataset"]["info"]["profile"] == "test"
    assert config["dataset"]["flights"] == {"train": 4, "validation": 3, "test_normal": 3, "test_attacked": 6,
                                            "no_effect": 0, "csv_source": 0}
    assert config["versions"]["numpy"] == np.__version__
    assert "git" in config and config["detectors"] == ["zscore_test", "diff_test"]
    assert config["jobs"]["zscore_test"]["params"]["random_state"] == 0

    status = json.loads((reference_run / "jobs/zscore_test/status.json").read_text())
    assert status["status"] == "OK" and status["rows_scored"] == 12 * 1000
    assert status["n_train_flights"] == 4 and status["n_scored_flights"] == 12
    scores = read_npz(reference_run / "jobs/zscore_test/scores.npz")
    assert len(scores) == 12 and all(s.dtype == np.float64 and s.shape == (1000,) for s in scores.values())

    metrics = pd.read_csv(reference_run / "metrics.csv")
    assert metrics.columns.tolist() == [
        "detector", "status", "message", *(c for m in DEFAULT_METRICS for c in m.columns), "flight_threshold",
        "row_threshold", "fit_s", "score_s", "rows"]
    for r in ("tp_simulation", "tp_csv", "tn_no_attack", "far_no_attack", "fa_before_onset_csv"):
        assert {f"{r}_lo", f"{r}_hi", f"{r}_wilson_lo", f"{r}_wilson_hi"} <= set(metrics.columns)
    assert {"auc_pr_prior", "alpha", "threshold_after_arming_s"} <= set(metrics.columns)

    results = pd.read_csv(reference_run / "results.csv")
    assert results["detector"].tolist() == ["zscore_test", "diff_test"]
    assert (results["status"] == "OK").all() and (results["rows"] == 12000).all()


def test_metrics_of_the_reference_run(reference_run):
    m = pd.read_csv(reference_run / "metrics.csv").set_index("detector")
    z = m.loc["zscore_test"]
    # two of three attacks per mode are large; the third is far below the noise. Three validation flights
    # cannot reach alpha = 5 %: the threshold is their largest score, which two held-out flights beat
    assert (z["tp_simulation"], z["tp_csv"], z["tn_no_attack"]) == (2 / 3, 2 / 3, 1 / 3)
    assert z["alpha_attainable"] == 0.0 and z["n_validation"] == 3
    assert (z["n_simulation"], z["n_csv"], z["n_no_attack"]) == (3, 3, 3)
    assert z["delay_median_s"] == pytest.approx(0.0)
    assert z["false_alarms_per_hour"] > 0.0 and z["latency_us_per_row"] > 0

    fs = pd.read_csv(reference_run / "flight_scores.csv")
    for det in ("zscore_test", "diff_test"):
        test = fs[(fs["detector"] == det) & fs["role"].isin(["test_normal", "test_attacked"])]
        y = (test["role"] == "test_attacked").astype(int)
        assert m.loc[det, "roc_auc"] == pytest.approx(roc_auc_score(y, test["score"]))
        attacked = test[test["role"] == "test_attacked"].set_index("flight_id")
        invisible = [a[0] for a in ATTACKS if a[4] < 0.1]
        # the invisible ones are flagged no more often than the held-out normal flights
        assert attacked.loc[invisible, "flagged"].mean() <= test[test["role"] == "test_normal"]["flagged"].mean()

    bd = pd.read_csv(reference_run / "breakdown.csv")
    row = bd[(bd["detector"] == "zscore_test") & (bd["dimension"] == "action") & (bd["value"] == "bias")
             & (bd["mode"] == "all")].iloc[0]
    assert (row["n"], row["detected"]) == (4, 3)

    md = (reference_run / "metrics.md").read_text()
    assert "| zscore_test | 66.7 % [0-100] | 66.7 % [0-100] | 33.3 % [0-100] |" in md
    assert "alpha not attainable" in md
    assert "3 held-out normal test flights" in md and "no_effect, excluded from every rate): 0" in md


def test_score_recomputes_from_saved_scores(reference_run, tmp_path, capsys):
    run = tmp_path / "copy"
    shutil.copytree(reference_run, run)
    for name in ("metrics.csv", "metrics.md", "breakdown.csv", "flight_scores.csv", "results.csv"):
        (run / name).unlink()
    assert main(["score", str(run)]) == 0
    pd.testing.assert_frame_equal(pd.read_csv(run / "metrics.csv"), pd.read_csv(reference_run / "metrics.csv"))
    pd.testing.assert_frame_equal(pd.read_csv(run / "breakdown.csv"), pd.read_csv(reference_run / "breakdown.csv"))
    out = capsys.readouterr().out
    head = [c.strip() for c in out.splitlines()[0].strip("|").split("|")]  # the terminal table (--wide: all)
    assert head[:4] == ["Detector", "TP Simulation", "TP CSV", "TN No Attack"]


def test_score_gives_the_same_tables_in_one_process_or_several(reference_run, tmp_path):
    """The reference run scored its two detectors in two processes (its --jobs); one process
    writes the same files byte for byte."""
    run = tmp_path / "copy"
    shutil.copytree(reference_run, run)
    assert main(["score", str(run), "--jobs", "1"]) == 0
    for name in ("metrics.csv", "metrics.md", "breakdown.csv", "flight_scores.csv"):
        assert (run / name).read_bytes() == (reference_run / name).read_bytes(), name
    assert main(["score", str(run), "--jobs", "0"]) == 2


def test_saved_nan_scores_make_the_job_an_error(reference_run, tmp_path):
    from scart_bench.benchmark.store import RunStore, atomic_write_bytes, npz_bytes

    run = tmp_path / "copy"
    shutil.copytree(reference_run, run)
    scores = read_npz(run / "jobs/diff_test/scores.npz")
    scores["sim-000"][5] = np.nan
    atomic_write_bytes(run / "jobs/diff_test/scores.npz", npz_bytes(scores))
    RunStore(run).seal("jobs/diff_test/scores.npz")  # changed on purpose: past the run's checksum
    assert main(["score", str(run)]) == 3  # the other detector is scored; the exit says one job failed
    m = pd.read_csv(run / "metrics.csv").set_index("detector")
    assert m.loc["diff_test", "status"] == "ERROR" and "NaN" in m.loc["diff_test", "message"]
    assert np.isnan(m.loc["diff_test", "tp_simulation"])
    assert m.loc["zscore_test", "status"] == "OK"


# -- isolation --------------------------------------------------------------------------------


def test_failing_detectors_become_status_rows(dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SCART_TEST_PID_DIR", str(tmp_path))
    out = tmp_path / "run"
    t0 = time.monotonic()
    rc = main(["run", "--detectors", "zscore_test,fail_fit_test,nan_score_test,hang_test",
               *(x for c in ("ZScore", "FailFit", "NaNScore", "Hang") for x in ("--plugin", plugin(c))),
               "--dataset", str(dataset), "--out", str(out), "--jobs", "2", "--timeout", "12"])
    # 12 s: a worker that only raises in fit took over 5 s to start under a load of 6 on 2 cores
    assert rc == 3  # after writing everything, naming the failed jobs
    assert time.monotonic() - t0 < 60
    res = pd.read_csv(out / "results.csv").set_index("detector")
    assert res["status"].to_dict() == {"zscore_test": "OK", "fail_fit_test": "ERROR",
                                       "nan_score_test": "ERROR", "hang_test": "TIMEOUT"}
    assert "RuntimeError: boom in fit" in res.loc["fail_fit_test", "message"]
    assert "NaN" in res.loc["nan_score_test", "message"]
    assert "12 s timeout" in res.loc["hang_test", "message"]
    assert "boom in fit" in (out / "jobs/fail_fit_test/log.txt").read_text()  # the traceback
    for det in ("fail_fit_test", "nan_score_test", "hang_test"):
        assert not (out / "jobs" / det / "scores.npz").exists()
    # the hanging worker was really killed
    pid = int((tmp_path / "hang.pid").read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    captured = capsys.readouterr()
    table = " ".join(captured.out.split())  # the terminal table's cells are padded to their column
    assert "3 job(s) did not finish OK: fail_fit_test (ERROR), nan_score_test (ERROR), hang_test (TIMEOUT)" in captured.err
    assert "| hang_test | TIMEOUT | TIMEOUT |" in table
    assert "| nan_score_test | ERROR |" in table
    m = pd.read_csv(out / "metrics.csv").set_index("detector")
    assert m.loc["zscore_test", "tp_simulation"] == pytest.approx(2 / 3)
    assert m.loc[["fail_fit_test", "nan_score_test", "hang_test"], "tp_simulation"].isna().all()


# -- resume -----------------------------------------------------------------------------------


def test_failed_job_exits_3_and_resume_finishes_it(dataset, tmp_path, monkeypatch, capsys):
    fit_log = tmp_path / "fits.txt"
    monkeypatch.setenv("SCART_TEST_FIT_LOG", str(fit_log))
    monkeypatch.setenv("SCART_TEST_FAIL_MARKER", str(tmp_path / "failed"))
    out = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test,fail_once_test", "--plugin", ZS, "--plugin", plugin("FailOnce"),
            "--dataset", str(dataset), "--out", str(out)]
    assert main(args) == 3
    assert "1 job(s) did not finish OK: fail_once_test (ERROR)" in capsys.readouterr().err
    assert (out / "metrics.md").exists() and pd.read_csv(out / "results.csv")["status"].tolist() == ["OK", "ERROR"]
    kept = snapshot(out / "jobs/zscore_test")
    assert main([*args, "--resume"]) == 0  # only the failed job runs again, and now finishes
    assert snapshot(out / "jobs/zscore_test") == kept
    assert fit_log.read_text().split() == ["zscore_test", "fail_once_test"]
    assert pd.read_csv(out / "results.csv")["status"].tolist() == ["OK", "OK"]


def test_interrupted_run_resumes_without_recomputing(dataset, reference_run, tmp_path, monkeypatch):
    # a shell starts background jobs with SIGINT ignored, and Python then has no Ctrl-C handler:
    # give this process the default one for the duration of the test
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _interrupt_and_resume(dataset, reference_run, tmp_path, monkeypatch)
    finally:
        signal.signal(signal.SIGINT, previous)


def _interrupt_and_resume(dataset, reference_run, tmp_path, monkeypatch):
    fit_log = tmp_path / "fits.txt"
    monkeypatch.setenv("SCART_TEST_FIT_LOG", str(fit_log))
    monkeypatch.setenv("SCART_TEST_INTERRUPT_MARKER", str(tmp_path / "interrupted"))
    out = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test,interrupt_test,diff_test", "--plugin", ZS,
            "--plugin", plugin("InterruptOnce"), "--plugin", DIFF, "--dataset", str(dataset),
            "--out", str(out), "--jobs", "1"]
    assert main(args) == 130  # Ctrl-C while interrupt_test runs
    assert RunStore(out).read_status("zscore_test")["status"] == "OK"
    assert RunStore(out).read_status("interrupt_test") is None  # unfinished: no status at all
    assert RunStore(out).read_status("diff_test") is None
    res = pd.read_csv(out / "results.csv").set_index("detector")
    assert res.loc["interrupt_test", "status"] == "UNFINISHED"
    assert fit_log.read_text().split() == ["zscore_test"]
    before = snapshot(out / "jobs/zscore_test")

    args[-1] = "2"  # the remaining jobs in parallel
    assert main([*args, "--resume"]) == 0
    assert snapshot(out / "jobs/zscore_test") == before  # not recomputed
    assert sorted(fit_log.read_text().split()) == ["diff_test", "interrupt_test", "zscore_test"]
    got = quality(out)
    pd.testing.assert_frame_equal(got.loc[["zscore_test", "diff_test"]], quality(reference_run))
    # interrupt_test scores like zscore_test once it stops interrupting
    pd.testing.assert_series_equal(got.loc["interrupt_test", "tp_simulation":],
                                   got.loc["zscore_test", "tp_simulation":], check_names=False)

    # running the same config again without --resume recomputes everything
    fit_log.write_text("")
    assert main(args) == 0
    assert sorted(fit_log.read_text().split()) == ["diff_test", "interrupt_test", "zscore_test"]


def test_resume_reruns_a_job_whose_params_changed(reference_run, tmp_path, dataset):
    run = tmp_path / "copy"
    shutil.copytree(reference_run, run)
    params = json.loads((run / "jobs/diff_test/params.json").read_text())
    params["key"]["params"]["random_state"] = 99  # as if made with other parameters
    (run / "jobs/diff_test/params.json").write_text(json.dumps(params))
    kept, redone = snapshot(run / "jobs/zscore_test"), snapshot(run / "jobs/diff_test")
    assert main(["run", *OK_PAIR, "--dataset", str(dataset), "--out", str(run), "--resume"]) == 0
    assert snapshot(run / "jobs/zscore_test") == kept
    assert snapshot(run / "jobs/diff_test")["status.json"] != redone["status.json"]
    pd.testing.assert_frame_equal(quality(run), quality(reference_run))


# -- dask -------------------------------------------------------------------------------------


def test_dask_local_cluster_gives_identical_metrics(reference_run, dataset, tmp_path):
    out = tmp_path / "dask"
    assert main(["run", *OK_PAIR, "--dataset", str(dataset), "--out", str(out), "--jobs", "2",
                 "--executor", "dask"]) == 0
    pd.testing.assert_frame_equal(quality(out), quality(reference_run))
    for det in ("zscore_test", "diff_test"):
        a, b = read_npz(out / "jobs" / det / "scores.npz"), read_npz(reference_run / "jobs" / det / "scores.npz")
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_dask_refuses_a_dataset_its_workers_cannot_read(dataset, tmp_path):
    from scart_bench.benchmark.executors import DaskExecutor
    from scart_bench.errors import RunError

    executor = DaskExecutor(jobs=1)
    try:
        executor.check_dataset(str(dataset))  # the workers see it: nothing to say
        with pytest.raises(RunError, match=r"1 of 1 worker\(s\) cannot read the dataset .*same path"):
            executor.check_dataset(str(tmp_path / "only-on-the-client"))
    finally:
        executor.close()


# -- bad input --------------------------------------------------------------------------------


@pytest.fixture()
def existing_run(reference_run, tmp_path) -> Path:
    run = tmp_path / "existing"
    shutil.copytree(reference_run, run)
    return run


def _bad(kind: str, dataset: Path, run: Path, tmp_path: Path) -> tuple[list[str], str]:
    base = ["run", "--dataset", str(dataset), "--out", str(run), "--plugin", ZS, "--plugin", DIFF]
    if kind == "unknown detector":
        return [*base, "--detectors", "zscore_test,no_such_detector"], "unknown detector 'no_such_detector'"
    if kind == "dataset without manifest":
        empty = tmp_path / "not_a_dataset"
        empty.mkdir()
        args = ["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(empty), "--out", str(run)]
        return args, "no manifest"
    if kind == "unreachable scheduler":
        return [*base, "--detectors", "zscore_test", "--executor", "dask", "--scheduler",
                "tcp://127.0.0.1:1"], "cannot reach a dask scheduler"
    if kind == "different seed":
        return [*base, "--detectors", "zscore_test", "--seed", "7"], "different config (seed: 0 -> 7)"
    if kind == "different seed, --resume":
        return [*base, "--detectors", "zscore_test", "--seed", "7", "--resume"], "different config"
    if kind == "different dataset":
        other = write_dataset(tmp_path / "other", seed=5)
        return ["run", "--dataset", str(other), "--out", str(run), "--plugin", ZS, "--detectors",
                "zscore_test"], "different config (dataset_fingerprint:"
    if kind == "bad plugin":
        return [*base, "--detectors", "zscore_test", "--plugin", str(tmp_path / "missing.py:X")], "does not exist"
    if kind == "not a run folder":
        stray = run / "jobs" / "zscore_test"
        return [*base, "--detectors", "zscore_test", "--out", str(stray)], "no config.json"
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["unknown detector", "dataset without manifest", "unreachable scheduler",
                                  "different seed", "different seed, --resume", "different dataset",
                                  "bad plugin", "not a run folder"])
def test_bad_input_exits_2_and_loses_nothing(kind, dataset, existing_run, tmp_path, capsys):
    args, words = _bad(kind, dataset, existing_run, tmp_path)
    before = snapshot(existing_run)
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert words in err
    assert len(err.splitlines()) == 1 and err.startswith("scart-bench run: error:")
    assert snapshot(existing_run) == before


def test_score_of_a_non_run_folder_exits_2(tmp_path, capsys):
    assert main(["score", str(tmp_path)]) == 2
    assert "not a scart-bench run folder" in capsys.readouterr().err


# -- the profile's dataset --------------------------------------------------------------------


def test_profile_dataset_is_generated_once_and_reused(dataset, tmp_path, monkeypatch):
    calls = []

    from scart_bench.generator.engine.flight_batch import FLIGHT_DEFAULTS

    def generate_dataset(profile: str, out: Path, seed: int, fmt: str = "parquet") -> Path:
        calls.append((profile, Path(out), seed))
        shutil.copytree(dataset, out)
        info = json.loads((Path(out) / "dataset.json").read_text())  # as this version's generator writes it
        (Path(out) / "dataset.json").write_text(json.dumps({**info, "flight_defaults": FLIGHT_DEFAULTS}))
        return Path(out)

    fake = types.ModuleType("scart_bench.generator.generate")
    fake.generate_dataset = generate_dataset
    monkeypatch.setitem(sys.modules, "scart_bench.generator.generate", fake)
    monkeypatch.chdir(tmp_path)
    args = ["run", "--detectors", "zscore_test", "--plugin", ZS, "--seed", "3"]
    assert main(args) == 0
    assert calls == [("quick", Path("data/datasets/quick-seed3"), 3)]
    config = json.loads((tmp_path / "runs/quick-seed3/config.json").read_text())
    assert config["dataset"]["path"] == str((tmp_path / "data/datasets/quick-seed3").resolve())
    assert main([*args, "--resume"]) == 0
    assert len(calls) == 1


# -- the console script -----------------------------------------------------------------------


def test_console_script(reference_run, tmp_path):
    exe = Path(sys.executable).with_name("scart-bench")
    if not exe.exists():
        pytest.skip("the scart-bench console script is not installed in this environment")
    run = tmp_path / "copy"
    shutil.copytree(reference_run, run)
    done = subprocess.run([str(exe), "score", str(run)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "| zscore_test | 66.7 % [0-100] | 66.7 % [0-100] | 33.3 % [0-100] |" in " ".join(done.stdout.split())
    bad = subprocess.run([str(exe), "run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(tmp_path),
                          "--out", str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2
    assert len(bad.stderr.strip().splitlines()) == 1
    assert bad.stderr.startswith(f"scart-bench run: error: {tmp_path}: no manifest.parquet or manifest.csv")
    assert not (tmp_path / "x").exists()


def test_costliest_jobs_start_first_and_tables_keep_the_order(dataset, tmp_path, monkeypatch):
    """Jobs are handed to the executor by their detectors' cost hint, costliest first (two long jobs
    must not end up last on one worker); results and metrics keep the order the user gave."""
    from scart_bench.benchmark import executors
    from scart_bench.detectors.registry import available

    started: list[str] = []
    make = executors.make_executor

    def recording(*args, **kwargs):
        ex = make(*args, **kwargs)
        run = ex.run

        def run_recorded(specs, timeout, on_done, **kwargs):
            started.extend(s.detector for s in specs)
            return run(specs, timeout, on_done, **kwargs)

        ex.run = run_recorded
        return ex

    monkeypatch.setattr(executors, "make_executor", recording)
    chosen = ["statistical", "tsbitmaps", *OK_PAIR[1].split(",")]
    costs = {n: available()[n].cls.relative_cost for n in ("statistical", "tsbitmaps")}
    assert costs["tsbitmaps"] > costs["statistical"]
    out = tmp_path / "run"
    assert main(["run", "--detectors", ",".join(chosen), *OK_PAIR[2:], "--dataset", str(dataset),
                 "--out", str(out), "--jobs", "2"]) == 0
    assert started.index("tsbitmaps") < started.index("statistical")
    assert pd.read_csv(out / "results.csv")["detector"].tolist() == chosen
    assert pd.read_csv(out / "metrics.csv")["detector"].tolist() == chosen


def test_the_runs_labels_read_back_as_written(tmp_path):
    """truth.parquet keeps every scored flight's timestamps and labels, in order, under its id
    (long ids, as the paper profile's, flights of one row, and no flights at all)."""
    rng = np.random.default_rng(3)
    ids = [f"csv-paper-sinusoid-imu-L3-d30-{'x' * 90}-{k}" for k in (7, 2, 11)] + ["normal-0", "one-row"]
    truth = {fid: (np.cumsum(rng.integers(1, 9000, n)).astype(np.int64), (rng.random(n) < 0.3).astype(np.int8))
             for fid, n in zip(ids, (2665, 40, 3001, 1200, 1))}
    store = RunStore(tmp_path / "run")
    store.path.mkdir()
    store.write_truth(truth)
    back = store.read_truth()
    assert list(back) == ids
    for fid in ids:
        np.testing.assert_array_equal(back[fid][0], truth[fid][0])
        np.testing.assert_array_equal(back[fid][1], truth[fid][1])
    empty = RunStore(tmp_path / "empty")
    empty.path.mkdir()
    empty.write_truth({})
    assert empty.read_truth() == {}


def test_the_profile_dataset_made_by_older_defaults_is_generated_again(tmp_path, monkeypatch, capsys):
    """The profile's own dataset (data/datasets/<profile>-seed<N>) is a cache of this version's
    generator: one made with older flight defaults is regenerated, not scored under this version's name."""
    import scart_bench.generator.generate as generate
    from scart_bench.benchmark.config import RunConfig
    from scart_bench.benchmark.runner import prepare_dataset
    from scart_bench.generator.engine.flight_batch import FLIGHT_DEFAULTS

    path = write_dataset(tmp_path / "quick-seed0")  # written without flight_defaults: reads as 1
    calls = []
    monkeypatch.setattr(generate, "generate_dataset",
                        lambda profile, out, seed, **kw: calls.append((profile, seed, kw)) or Path(out))
    cfg = RunConfig(profile="quick", seed=0, data_root=tmp_path)
    assert prepare_dataset(cfg) == path
    assert calls == [("quick", 0, {"overwrite": True})]
    assert f"made with generator defaults 1, this version makes {FLIGHT_DEFAULTS}" in capsys.readouterr().err
    info = json.loads((path / "dataset.json").read_text())
    (path / "dataset.json").write_text(json.dumps({**info, "flight_defaults": FLIGHT_DEFAULTS}))
    calls.clear()
    assert prepare_dataset(cfg) == path and calls == [], "a dataset of this version's defaults is reused"
