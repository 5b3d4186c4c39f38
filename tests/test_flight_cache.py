"""The run's flight cache: each flight read once per run, the same tables and scores as the dataset."""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from run_fixtures import plugin, write_dataset

from scart_bench.benchmark import flight_cache, runner
from scart_bench.benchmark.flight_cache import (
    CacheInvalid,
    CacheUnsupported,
    FlightCache,
    build_cache,
    cache_key,
    cache_path,
)
from scart_bench.benchmark.jobs import JobSpec, run_job
from scart_bench.benchmark.protocol import Splits
from scart_bench.benchmark.selection import resolve_detectors, with_params
from scart_bench.benchmark.store import RunStore
from scart_bench.cli.main import main
from scart_bench.dataset import Dataset, open_dataset

ZS = plugin("ZScore")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("data") / "ds")


@pytest.fixture()
def reads(monkeypatch) -> Counter:
    """Counts the flight tables this process reads from a dataset, per flight id."""
    counts: Counter = Counter()
    original = Dataset.flight

    def counting(self, flight_id, *args, **kwargs):
        counts[flight_id] += 1
        return original(self, flight_id, *args, **kwargs)

    monkeypatch.setattr(Dataset, "flight", counting)
    return counts


def _same_table(a: pd.DataFrame, b: pd.DataFrame) -> None:
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert list(a.dtypes) == list(b.dtypes) and isinstance(b.index, pd.RangeIndex)
    for c in a.columns:
        if a[c].dtype.kind == "f":  # bit for bit, NaN payloads and -0.0 included
            assert a[c].to_numpy().tobytes() == b[c].to_numpy().tobytes(), c
    # the same memory layout as well: numpy's sums round by it, so the detectors' results depend on it
    num = [c for c in a.columns if a[c].dtype.kind in "biuf"]
    x, y = (t[num].to_numpy(dtype=np.float64, copy=True) for t in (a, b))
    assert (x.flags.c_contiguous, x.flags.f_contiguous) == (y.flags.c_contiguous, y.flags.f_contiguous)


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_cached_flights_are_the_dataset_tables(fmt, tmp_path):
    ds = open_dataset(write_dataset(tmp_path / "ds", fmt=fmt))
    ids = list(ds.manifest["flight_id"])
    cache = build_cache(tmp_path / "cache", cache_key("fp"), ids, ds.flight)
    for fid in ids:
        _same_table(ds.flight(fid), cache.flight(fid))
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp folder left


def test_odd_columns_round_trip_or_are_refused(tmp_path):
    odd = pd.DataFrame({"t": np.array([1, 2, 3], np.int64), "a.x": np.array([np.nan, -0.0, 1.5], np.float32),
                        "a.y": np.array([1e300, np.inf, -np.inf]), "ok": np.array([True, False, True]),
                        "label": pd.array(["", "s1", None], dtype="str"), "ids": np.array(["a", "", "b"], object)})
    other = odd[["a.y", "t"]]  # another column set and order in the same cache
    cache = build_cache(tmp_path / "c", cache_key("fp"), ["f1", "f2"], {"f1": odd, "f2": other}.__getitem__)
    _same_table(odd, cache.flight("f1"))
    _same_table(other, cache.flight("f2"))
    mixed = pd.DataFrame({"v": np.array([1, "x"], dtype=object)})
    with pytest.raises(CacheUnsupported, match="column 'v'"):
        build_cache(tmp_path / "c", cache_key("fp2"), ["f"], lambda fid: mixed)
    FlightCache(tmp_path / "c", cache_key("fp"))  # the failed build left the complete cache as it was
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c"]


def test_float64_columns_of_float32_values_take_half_the_bytes_and_read_back_bit_for_bit(tmp_path):
    rng = np.random.default_rng(0)
    n = 1000
    f32 = rng.normal(size=(n, 3)).astype(np.float32).astype(np.float64)  # what the compact layout gives
    f32[5, 0], f32[6, 1] = np.nan, -0.0
    table = pd.DataFrame({"Timestamp": np.arange(n, dtype=np.int64), "a.x": f32[:, 0],
                          "gps.lat": 47.397742 + rng.normal(size=n) * 1e-5,  # not a float32 value: kept whole
                          "a.y": f32[:, 1], "label": np.array([""] * n, object), "a.z": f32[:, 2]})
    cache = build_cache(tmp_path / "c", cache_key("fp"), ["f"], lambda fid: table)
    _same_table(table, cache.flight("f"))
    sizes = {p.name: p.stat().st_size for p in (tmp_path / "c").glob("*.bin")}
    assert sizes["f8f4.bin"] == 3 * n * 4 and sizes["f8.bin"] == n * 8, sizes


def test_a_cache_of_another_dataset_or_a_damaged_one_is_not_read(tmp_path):
    df = pd.DataFrame({"a.x": np.arange(5.0)})
    folder = tmp_path / "c"
    build_cache(folder, cache_key("fp"), ["f"], lambda fid: df)
    with pytest.raises(CacheInvalid, match="another dataset"):
        FlightCache(folder, cache_key("other"))
    with open(next(folder.glob("*.bin")), "r+b") as fh:
        fh.truncate(8)
    with pytest.raises(CacheInvalid, match="damaged"):
        FlightCache(folder, cache_key("fp"))
    with pytest.raises(CacheInvalid, match="index.json missing"):
        FlightCache(tmp_path / "none")


def test_a_run_reads_each_flight_once_and_every_job_reads_the_cache(dataset, tmp_path, monkeypatch, reads):
    """The runner reads each train/validation/test flight once (labels included); the jobs, in
    their own processes, read only the cache: the dataset's tables are moved away once it is built."""
    build = runner.build_cache
    hidden = dataset.parent / "flights-hidden"

    def build_then_hide(*args, **kwargs):
        cache = build(*args, **kwargs)
        (dataset / "flights").rename(hidden)
        return cache

    monkeypatch.setattr(runner, "build_cache", build_then_hide)
    out = tmp_path / "run"
    try:
        rc = main(["run", "--detectors", "zscore_test,diff_test", "--plugin", ZS, "--plugin", plugin("Diff"),
                   "--dataset", str(dataset), "--out", str(out), "--jobs", "2"])
    finally:
        if hidden.exists():
            hidden.rename(dataset / "flights")
    assert rc == 0
    splits = Splits.from_manifest(open_dataset(dataset).manifest)
    assert reads == Counter(dict.fromkeys([*splits.train, *splits.scored], 1))
    assert pd.read_csv(out / "results.csv")["status"].tolist() == ["OK", "OK"]
    assert not (out / "cache").exists()  # every job finished OK: nothing to resume, the cache is gone


def test_a_failed_job_keeps_the_cache_and_resume_reuses_it(dataset, tmp_path, monkeypatch, reads):
    monkeypatch.setenv("SCART_TEST_FAIL_MARKER", str(tmp_path / "failed"))
    out = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test,fail_once_test", "--plugin", ZS, "--plugin", plugin("FailOnce"),
            "--dataset", str(dataset), "--out", str(out)]
    assert main(args) == 3
    assert FlightCache(cache_path(out)).has(reads)
    reads.clear()
    assert main([*args, "--resume"]) == 0
    assert reads == Counter()  # the kept cache served the resumed job
    assert not (out / "cache").exists()


def test_a_cache_that_no_longer_matches_is_rebuilt(dataset, tmp_path, reads):
    out = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset), "--out", str(out)]
    assert main(args) == 0
    fp = RunStore(out).read_config()["identity"]["dataset_fingerprint"]
    stale = build_cache(cache_path(out), cache_key("not-" + fp), ["normal-000"],
                        lambda fid: pd.DataFrame({"a.x": [1.0]}))  # as if left by another dataset
    reads.clear()
    assert main([*args, "--resume"]) == 0  # the job is finished: nothing runs, nothing is read
    assert reads == Counter() and stale.folder.exists()
    assert main(args) == 0  # the job runs again: the cache is rebuilt from the dataset
    assert set(reads.values()) == {1} and not (out / "cache").exists()


def _spec(dataset: Path, name: str, source: str, overrides: dict, cache: FlightCache | None,
          exclude: tuple[str, ...] | None = None) -> JobSpec:
    splits = Splits.from_manifest(open_dataset(dataset).manifest)
    return JobSpec(name, source, overrides, (), str(dataset), splits.train, splits.scored, 1, exclude=exclude,
                   cache=str(cache.folder) if cache else None, cache_key=cache.key if cache else None)


DETECTORS = ["statistical", "tsbitmaps", "deepsvdd", "goad"]
#: The statistical detector a second time with --exclude: one cache serves every choice of columns.
EXCLUDE = ("attitude.yaw",)


def test_scores_are_byte_identical_with_and_without_the_cache(dataset, tmp_path, reads):
    ds = open_dataset(dataset)
    splits = Splits.from_manifest(ds.manifest)
    cache = build_cache(tmp_path / "c", cache_key("fp"), [*splits.train, *splits.scored], ds.flight)
    quick = {"epochs": 1, "max_train_windows": 200}
    chosen = with_params(resolve_detectors(DETECTORS, {}), {n: quick for n in ("deepsvdd", "goad")})
    for choice, exclude in [*((c, None) for c in chosen), (chosen[0], EXCLUDE)]:
        overrides = choice.overrides(0)
        reads.clear()
        cached = run_job(_spec(dataset, choice.name, choice.source, overrides, cache, exclude))
        assert reads == Counter(), choice.name  # the job read only the cache
        direct = run_job(_spec(dataset, choice.name, choice.source, overrides, None, exclude))
        assert cached.status == direct.status == "OK", (choice.name, cached.message, direct.message)
        assert cached.scores.keys() == direct.scores.keys()
        for fid, s in direct.scores.items():
            assert cached.scores[fid].tobytes() == s.tobytes(), (choice.name, fid)


def test_a_job_falls_back_to_the_dataset_when_the_cache_is_unusable(dataset, tmp_path, reads, capsys):
    ds = open_dataset(dataset)
    splits = Splits.from_manifest(ds.manifest)
    cache = build_cache(tmp_path / "c", cache_key("fp"), [*splits.train, *splits.scored], ds.flight)
    index = json.loads((cache.folder / "index.json").read_text())
    shutil.rmtree(cache.folder)
    reads.clear()
    res = run_job(JobSpec("zscore_test", ZS, {}, (), str(dataset), splits.train, splits.scored,
                          cache=str(cache.folder), cache_key=index["key"]))
    assert res.status == "OK" and sum(reads.values()) == len(splits.train) + len(splits.scored)
    assert "flight cache not used" in capsys.readouterr().err


def test_a_cache_read_by_worker_processes_is_the_same_cache(dataset, tmp_path, monkeypatch):
    """Large runs read their flights in worker processes; the cache they write is byte for byte the
    one read in this process."""
    monkeypatch.setattr(flight_cache, "PARALLEL_READ_MIN", 0)
    ids = Splits.from_manifest(open_dataset(dataset).manifest).scored
    one = build_cache(tmp_path / "one", cache_key("fp"), ids, flight_cache.DatasetReader(dataset))
    two = build_cache(tmp_path / "two", cache_key("fp"), ids, flight_cache.DatasetReader(dataset), workers=2)
    files = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "two").iterdir())
    for name in files:
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes(), name
    _same_table(one.flight(ids[0]), two.flight(ids[0]))


class _FullDisk:
    """A cache file on a disk that fills after ``room`` bytes: writes beyond it, and the flush that
    closing does, fail with ENOSPC (as a real full disk does)."""

    def __init__(self, path, mode, room: int):
        self.fh = open(path, mode)  # noqa: SIM115 (closed by close)
        self.room = room
        self.pending = 0

    def write(self, data: bytes) -> int:
        import errno
        import os

        self.pending += len(data)
        if self.pending > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self.fh.write(data)

    def flush(self) -> None:
        self.fh.flush()

    def fileno(self) -> int:
        return self.fh.fileno()

    def close(self) -> None:
        import errno
        import os

        self.fh.close()
        if self.pending > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_leaves_no_temp_folder_and_resume_works_after(dataset, tmp_path, monkeypatch):
    """The run's cache build fails on a full disk: the run goes on without it, no temporary folder is
    left to hold the space, and once space is freed --resume builds the cache and finishes."""
    real_open = open
    monkeypatch.setattr(flight_cache, "open", lambda path, mode="r", *a, **k: _FullDisk(path, mode, 50_000),
                        raising=False)
    run = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test", "--plugin", plugin("ZScore"), "--dataset", str(dataset),
            "--out", str(run)]
    assert main(args) == 0  # the cache is an optimisation only: the job read the dataset
    assert not list(run.glob("cache/.*"))  # no .flights.build-* left behind
    monkeypatch.setattr(flight_cache, "open", real_open, raising=False)
    (run / "jobs" / "zscore_test" / "status.json").unlink()  # an unfinished job to resume
    assert main([*args, "--resume"]) == 0
    assert json.loads((run / "jobs" / "zscore_test" / "status.json").read_text())["status"] == "OK"
    assert not list(run.glob("cache/.*"))
