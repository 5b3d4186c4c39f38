"""Sharded scoring (--score-shards): fit once, score slices of the flights in parallel, merge; the
scores and metrics equal the unsharded run's, with either executor, and resume stays exact."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from run_fixtures import plugin, quality, write_dataset

from scart_bench.benchmark.sharding import split_flights
from scart_bench.benchmark.store import read_npz
from scart_bench.cli.main import main

ZS, NAN = plugin("ZScore"), plugin("NaNScore")
DETS = ["--detectors", "zscore_test,statistical", "--plugin", ZS]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("data") / "ds")


@pytest.fixture(scope="module")
def unsharded(dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "one"
    assert main(["run", *DETS, "--dataset", str(dataset), "--out", str(out), "--jobs", "2"]) == 0
    return out


def same_scores(a: Path, b: Path, det: str) -> bool:
    x, y = read_npz(a / "jobs" / det / "scores.npz"), read_npz(b / "jobs" / det / "scores.npz")
    return x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x)


def test_split_flights_is_contiguous_balanced_and_complete():
    flights = [f"f{i}" for i in range(7)]
    rows = dict(zip(flights, [100, 100, 100, 400, 100, 100, 100]))
    parts = split_flights(flights, rows, 3)
    assert [f for p in parts for f in p] == flights and len(parts) == 3 and all(parts)
    assert max(sum(rows[f] for f in p) for p in parts) <= 500
    assert split_flights(flights[:2], rows, 5) == [("f0",), ("f1",)]
    assert split_flights(flights, rows, 1) == [tuple(flights)]


@pytest.mark.parametrize("executor", ["local", "dask"])
def test_sharded_scoring_equals_unsharded(executor, dataset, unsharded, tmp_path, capsys):
    out = tmp_path / executor
    assert main(["run", *DETS, "--dataset", str(dataset), "--out", str(out), "--jobs", "2",
                 "--score-shards", "3", "--executor", executor]) == 0
    err = capsys.readouterr().err
    assert "scoring 12 flights in 3 shards" in err and "scoring shard 3/3 done" in err
    pd.testing.assert_frame_equal(quality(out), quality(unsharded))
    for det in ("zscore_test", "statistical"):
        assert same_scores(out, unsharded, det)
        status = json.loads((out / "jobs" / det / "status.json").read_text())
        assert status["status"] == "OK" and status["n_scored_flights"] == 12 and status["n_train_flights"] == 4
    if executor == "local":  # resume: the sharded jobs are finished jobs, whatever the shard count now
        assert main(["run", *DETS, "--dataset", str(dataset), "--out", str(out), "--resume"]) == 0
        assert "resume: 2 finished job(s) kept" in capsys.readouterr().err


def test_a_failed_shard_is_the_jobs_status(dataset, tmp_path, capsys):
    out = tmp_path / "nan"
    rc = main(["run", "--detectors", "nan_score_test", "--plugin", NAN, "--dataset", str(dataset), "--out", str(out),
               "--score-shards", "2"])
    assert rc == 3
    status = json.loads((out / "jobs" / "nan_score_test" / "status.json").read_text())
    assert status["status"] == "ERROR" and status["message"].startswith("scoring shard ")
    assert not (out / "jobs" / "nan_score_test" / "scores.npz").exists()


def test_bad_shard_count_exits_2(dataset, tmp_path, capsys):
    assert main(["run", *DETS, "--dataset", str(dataset), "--out", str(tmp_path / "x"), "--score-shards", "0"]) == 2
    assert "--score-shards 0: expected a positive number" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("executor", ["local", "dask"])
def test_running_jobs_report_their_progress(executor, dataset, tmp_path, monkeypatch, capsys):
    """A running job says how far it is (flights scored, rows per second, time left), on either
    executor and per scoring shard, not only when it ends."""
    monkeypatch.setenv("SCART_BENCH_PROGRESS_S", "0.3")
    shards = ["--score-shards", "2"] if executor == "dask" else []
    assert main(["run", "--detectors", "slow_test", "--plugin", plugin("Slow"), "--dataset", str(dataset),
                 "--out", str(tmp_path / "r"), "--executor", executor, "--jobs", "2", *shards]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "flights scored" in line]
    assert lines, "no progress line"
    name = "slow_test [shard " if executor == "dask" else "slow_test: "
    assert any(line.startswith(name) and "rows/s" in line and "left" in line for line in lines), lines
