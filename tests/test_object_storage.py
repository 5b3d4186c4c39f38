"""Datasets and run folders at s3:// URLs, served by a local S3 server (moto) started here: a dataset
generated to, run from and reported from the bucket, with dask workers that read it from the URL in
folders of their own (no shared path); bad URLs and missing credentials are one line, exit 2."""

from __future__ import annotations

import logging
from pathlib import Path

import pandas as pd
import pytest
from moto_s3 import moto_s3

from scart_bench.cli.main import main
from scart_bench.generator.attacks import SCENARIO_DIR

pytest.importorskip("s3fs")
pytest.importorskip("moto.server")

BUCKET = "scart-lab"



@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    """A moto S3 server on a free port, the environment pointing at it, and a fresh bucket."""
    with moto_s3(BUCKET) as (fs, _):
        yield fs


@pytest.fixture(scope="module")
def cluster(s3, tmp_path_factory):
    """Two dask worker processes (started after the S3 environment is set), each in its own folder."""
    from distributed import Client, Nanny, Scheduler, SpecCluster

    root = tmp_path_factory.mktemp("s3workers")
    workers = {f"w{i}": {"cls": Nanny, "options": {"nthreads": 1, "local_directory": str(root / f"w{i}"),
                                                   "memory_limit": 0}} for i in range(2)}
    spec = SpecCluster(scheduler={"cls": Scheduler, "options": {"dashboard_address": ":0"}}, workers=workers,
                       silence_logs=logging.ERROR)
    with spec, Client(spec) as client:
        client.wait_for_workers(2)
        spec.client = client
        yield spec


def test_dataset_generated_to_run_from_and_reported_from_s3(s3, cluster, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "client-cache"))
    ds, run, report = f"s3://{BUCKET}/datasets/quick", f"s3://{BUCKET}/runs/r1", f"s3://{BUCKET}/reports/r1"
    # generate: the workers upload their flights, the manifest is uploaded last
    assert main(["generate", "--profile", "quick", "--flights", "4", "--seed", "5", "--batch-size", "2",
                 "--scenarios", str(SCENARIO_DIR / "gps_spoof.toml"), "--out", ds, "--executor", "dask",
                 "--scheduler", cluster.scheduler_address]) == 0
    keys = s3.find(f"{BUCKET}/datasets/quick")
    assert f"{BUCKET}/datasets/quick/manifest.parquet" in keys and f"{BUCKET}/datasets/quick/dataset.json" in keys
    manifest = pd.read_parquet(s3.open(f"{BUCKET}/datasets/quick/manifest.parquet"))
    assert set(manifest["mode"]) == {"normal", "simulation", "csv"} and len(manifest) == 6
    # a second generate to the same URL is refused without --overwrite, and changes nothing
    assert main(["generate", "--profile", "quick", "--flights", "1", "--normal-only", "--out", ds]) == 2
    assert "a dataset is already there" in capsys.readouterr().err
    assert s3.find(f"{BUCKET}/datasets/quick") == keys

    # run: dataset and run folder at URLs; the dask workers download the dataset into their own folders
    assert main(["run", "--detectors", "statistical", "--dataset", ds, "--out", run, "--executor", "dask",
                 "--scheduler", cluster.scheduler_address]) == 0
    out = capsys.readouterr()
    assert f"run folder: {run}" in out.err and "statistical" in out.out
    copies = cluster.client.run(lambda dask_worker: sorted(
        str(p.relative_to(dask_worker.local_directory)) for p in
        Path(dask_worker.local_directory).glob("scart-bench/datasets/*/manifest.parquet")))
    assert sum(len(v) for v in copies.values()) >= 1, copies
    run_keys = {k.split("/runs/r1/", 1)[1] for k in s3.find(f"{BUCKET}/runs/r1")}
    assert {"config.json", "metrics.csv", "jobs/statistical/scores.npz"} <= run_keys
    assert not any(k.startswith("cache/") for k in run_keys)  # the flight cache stays local
    metrics = pd.read_csv(s3.open(f"{BUCKET}/runs/r1/metrics.csv"))
    assert metrics.loc[0, "status"] == "OK"

    # score and report from the URL
    assert main(["score", run]) == 0
    # an evaluation at another alpha (issue 46): uploaded beside the saved scores, the run's own tables kept
    own = s3.cat(f"{BUCKET}/runs/r1/metrics.csv")
    assert main(["score", run, "--alpha", "0.01"]) == 0
    s3.invalidate_cache()
    evaluation = pd.read_csv(s3.open(f"{BUCKET}/runs/r1/evaluations/alpha-0.01/metrics.csv"))
    assert evaluation.loc[0, "alpha"] == 0.01 and s3.cat(f"{BUCKET}/runs/r1/metrics.csv") == own
    assert main(["report", run, "--out", report, "--no-figures"]) == 0
    printed = capsys.readouterr().out
    assert f"{report}/" in printed
    assert any(k.endswith(".html") for k in s3.find(f"{BUCKET}/reports/r1"))
    # resume from the URL: the finished job is kept
    assert main(["run", "--detectors", "statistical", "--dataset", ds, "--out", run, "--resume"]) == 0
    assert "resume: 1 finished job(s) kept" in capsys.readouterr().err


def test_bad_urls_and_missing_credentials_are_one_line(s3, tmp_path, monkeypatch, capsys):
    import s3fs

    gen = ["generate", "--profile", "quick", "--flights", "1", "--normal-only"]
    assert main([*gen, "--out", "s3://no-such-bucket/ds"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "s3://no-such-bucket/ds: cannot access it" in err
    assert main(["run", "--detectors", "statistical", "--dataset", f"s3://{BUCKET}/nothing-here",
                 "--out", str(tmp_path / "r")]) == 2
    assert "no manifest.parquet or manifest.csv there" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    assert main([*gen, "--out", "zz://bucket/ds"]) == 2
    assert "zz://bucket/ds" in capsys.readouterr().err
    for key in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
        monkeypatch.delenv(key)
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "none"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "none"))
    s3fs.S3FileSystem.clear_instance_cache()
    try:
        assert main([*gen, "--out", f"s3://{BUCKET}/nocreds"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"s3://{BUCKET}/nocreds: cannot access it" in err
        assert "credentials" in err
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
    assert not s3.find(f"{BUCKET}/nocreds")


def test_import_and_attack_add_to_a_dataset_at_a_url(s3, tmp_path, monkeypatch, capsys):
    """import creates and then adds to a dataset in the bucket; attack --dataset adds labelled copies
    of its test flights; each publish leaves a complete dataset (manifest last)."""
    import numpy as np

    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "cache"))
    url = f"s3://{BUCKET}/datasets/mine"
    logs = []
    for i in range(2):
        t = np.arange(3000) * 20_000
        df = pd.DataFrame({"timestamp": t, "attitude.roll": 0.05 * np.sin(t / 1e6 + i),
                           "local_position_ned.x": 10 * np.sin(0.2 * t / 1e6), "local_position_ned.y": 10 * np.cos(0.2 * t / 1e6),
                           "local_position_ned.z": -10.0 + 0 * t})
        logs.append(tmp_path / f"flight{i}.csv")
        df.to_csv(logs[-1], index=False)
    assert main(["import", str(logs[0]), "--out", url, "--split", "train"]) == 0
    assert main(["import", str(logs[1]), "--out", url, "--split", "test"]) == 0
    manifest = pd.read_parquet(s3.open(f"{BUCKET}/datasets/mine/manifest.parquet"))
    assert list(manifest["split"]) == ["train", "test"]
    scenario = tmp_path / "bias.toml"
    scenario.write_text('[scenario]\nid = "roll-bias"\ninjection_point = "link"\n'
                        '[[scenario.start]]\ncondition = "time_window"\nstart_s = 20.0\n'
                        '[[scenario.end]]\ncondition = "duration"\nseconds = 10.0\n'
                        '[[scenario.actions]]\naction = "bias"\ntarget = ["attitude.roll"]\noffset = 0.3\n')
    rc = main(["attack", "--dataset", url, "--scenario", str(scenario)])
    assert rc == 0, capsys.readouterr().err
    manifest = pd.read_parquet(s3.open(f"{BUCKET}/datasets/mine/manifest.parquet"))
    assert len(manifest) == 3 and manifest["mode"].tolist()[-1] == "csv"
    assert manifest["attack_start_us"].notna().sum() == 1
    # a failing attack (bad scenario) leaves the dataset in the bucket as it was
    keys = s3.find(f"{BUCKET}/datasets/mine")
    bad = tmp_path / "bad.toml"
    bad.write_text("[scenario]\nid = 'x'\n[[scenario.actions]]\naction = 'no-such-action'\n")
    assert main(["attack", "--dataset", url, "--scenario", str(bad)]) == 2
    assert s3.find(f"{BUCKET}/datasets/mine") == keys
