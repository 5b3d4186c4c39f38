"""Generation sharded over dask: same bytes as a local generation; a failed shard commits nothing."""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

import pytest

from scart_bench.cli.main import main
from scart_bench.generator.attacks import SCENARIO_DIR

distributed = pytest.importorskip("distributed")


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """Two worker processes, each in a folder of its own (they share no working folder)."""
    from distributed import Client, LocalCluster, Nanny, Scheduler, SpecCluster

    root = tmp_path_factory.mktemp("workers")
    workers = {f"w{i}": {"cls": Nanny, "options": {"nthreads": 1, "local_directory": str(root / f"w{i}"),
                                                   "memory_limit": 0}} for i in range(2)}
    spec = SpecCluster(scheduler={"cls": Scheduler, "options": {"dashboard_address": None}}, workers=workers,
                       silence_logs=logging.ERROR)
    with spec, Client(spec) as client:
        client.wait_for_workers(2)
        spec.folders = [root / f"w{i}" for i in range(2)]
        yield spec
    assert LocalCluster  # the default cluster of `--executor dask` without --scheduler is a LocalCluster


ARGS = ["generate", "--profile", "quick", "--flights", "4", "--seed", "5", "--batch-size", "2",
        "--scenarios", str(SCENARIO_DIR / "gps_spoof.toml")]


def test_sharded_generation_is_byte_identical_to_local(tmp_path, cluster, capsys):
    assert main([*ARGS, "--out", str(tmp_path / "local")]) == 0
    assert main([*ARGS, "--out", str(tmp_path / "dask"), "--executor", "dask",
                 "--scheduler", cluster.scheduler_address]) == 0
    err = capsys.readouterr().err
    assert "2 normal and 2 attacked shard(s)" in err and "[2/2] shard" in err
    # both executors count every flight written, csv mode's (another process, or shards) included
    assert err.count("generate: normal 4/4, simulation 1/1, csv 1/1 flights in ") == 2
    local, sharded = _digest(tmp_path / "local"), _digest(tmp_path / "dask")
    assert any(k.startswith("flights/sim-") for k in local) and any(k.startswith("flights/csv-") for k in local)
    assert sharded == local
    # the workers flew in their own folders and left nothing there
    for folder in cluster.folders:
        assert folder.is_dir() and not list(folder.rglob("scart-shard-*"))


def test_failed_shard_commits_nothing(tmp_path, monkeypatch, capsys):
    """A shard that fails on its worker: one line naming the shard, exit 2, no dataset at --out."""
    from distributed import LocalCluster

    import scart_bench.generator.plan as gen

    def broken(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(gen, "normal_record", broken)  # seen by thread workers of this process
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0",
                      silence_logs=logging.ERROR) as lc:
        rc = main([*ARGS, "--normal-only", "--out", str(tmp_path / "ds"), "--executor", "dask",
                   "--scheduler", lc.scheduler_address])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "shard normal batch" in err and "No space left on device" in err and "nothing was committed" in err
    assert not (tmp_path / "ds").exists()
    assert not list(tmp_path.glob(".ds*partial*"))


def test_unreachable_scheduler_is_one_line(tmp_path, capsys):
    rc = main([*ARGS, "--normal-only", "--out", str(tmp_path / "ds"), "--executor", "dask",
               "--scheduler", "tcp://127.0.0.1:9"])
    assert rc == 2
    assert "--scheduler tcp://127.0.0.1:9: cannot reach a dask scheduler" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()
