"""Hostile buckets and killed URL runs, against a local S3 server (moto) started here.

- A bucket key with ``..`` (or absolute, empty segments, backslash, NUL) is refused by every
  command that maps keys to local files (``run --dataset``, ``score``, ``report``, ``run --resume``
  to a URL run folder, ``attack --dataset``): exit 2, one line naming the URL, the key and the
  folder, and the file the key points at outside the folder is never written.
- ``run --out s3://...`` uploads each finished job as it finishes: killed with SIGKILL after its
  first job, that job is in the bucket and ``--resume`` keeps it; the killed process's staging
  folder is removed by the next command's start.
- A half-uploaded dataset (objects, no manifest) is refused, or replaced with ``overwrite``.
- ``run --out R --resume`` without ``--dataset`` takes the dataset from R's config.json and
  generates nothing into ./data.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from moto_s3 import moto_s3
from run_fixtures import plugin, write_dataset

from scart_bench.cli.main import main
from scart_bench.names import IdError, join_inside, relative_parts

pytest.importorskip("s3fs")
pytest.importorskip("moto.server")

BUCKET = "scart-hostile"
ZS = plugin("ZScore")



@pytest.fixture(scope="module")
def s3():
    """A moto S3 server with a fresh bucket; yields (s3fs filesystem, boto3 client) - the client puts
    raw keys that s3fs might normalise."""
    import boto3

    with moto_s3(BUCKET) as (fs, endpoint):
        yield fs, boto3.client("s3", endpoint_url=endpoint)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("data") / "ds")


def _upload(client, local: Path, prefix: str) -> None:
    for p in sorted(local.rglob("*")):
        if p.is_file():
            client.put_object(Bucket=BUCKET, Key=f"{prefix}/{p.relative_to(local).as_posix()}", Body=p.read_bytes())


def _keys(client, prefix: str) -> list[str]:
    out, token = [], None
    while True:
        kw = {"ContinuationToken": token} if token else {}
        page = client.list_objects_v2(Bucket=BUCKET, Prefix=prefix + "/", **kw)
        out += [o["Key"] for o in page.get("Contents", [])]
        if not page.get("IsTruncated"):
            return out
        token = page["NextContinuationToken"]


def _evil_key(prefix: str, target: Path) -> str:
    """A key under ``prefix`` whose '..' segments climb to / and then go down to ``target``."""
    return f"{prefix}/flights/" + "../" * 40 + str(target).lstrip("/")


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


# -- the join itself ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["../x", "a/../../x", "/etc/passwd", "a//b", "a/", "./a", "a/./b", "a\\..\\b",
                                  "a\x00b", "", "..", 7])
def test_join_inside_refuses_names_that_could_leave(tmp_path, name):
    with pytest.raises(IdError) as exc:
        join_inside(tmp_path, name, "s3://b/ds: object key")
    msg = str(exc.value)
    assert msg.startswith("s3://b/ds: object key ") and str(tmp_path) in msg and "\n" not in msg


def test_join_inside_keeps_plain_names_and_refuses_links_out(tmp_path):
    assert join_inside(tmp_path, "flights/normal-0000/a.parquet", "x") == (
        tmp_path.resolve() / "flights/normal-0000/a.parquet")
    assert relative_parts("a/b.c/..d", "x") == ("a", "b.c", "..d")  # '..d' is a plain name
    (tmp_path / "link").symlink_to("/")
    with pytest.raises(IdError, match="through a link"):
        join_inside(tmp_path, "link/etc/passwd", "x")


# -- a hostile key on every command that reads a bucket -----------------------------------------

def test_bucket_key_with_dotdot_is_refused_everywhere(s3, dataset, tmp_path, monkeypatch, capsys):
    fs, client = s3
    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    target = tmp_path / "outside" / "evil.pth"
    ds = "hostile/ds"
    _upload(client, dataset, ds)
    client.put_object(Bucket=BUCKET, Key=_evil_key(ds, target), Body=b"import os; os.system('echo pwned')\n")
    assert any("/../" in k for k in _keys(client, ds))  # the raw key is stored, '..' and all
    url = f"s3://{BUCKET}/{ds}"

    # run --dataset URL (the dataset is downloaded into the cache)
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", url,
                 "--out", str(tmp_path / "r1")]) == 2
    err = _one_line(capsys)
    assert url in err and "'..'" in err and str(tmp_path / "cache") in err
    assert not target.exists() and not (tmp_path / "r1").exists()

    # attack --dataset URL (a local copy of the dataset, then published back)
    scenario = tmp_path / "bias.toml"
    scenario.write_text('[scenario]\nid = "roll-bias"\ninjection_point = "link"\n'
                        '[[scenario.start]]\ncondition = "time_window"\nstart_s = 5.0\n'
                        '[[scenario.end]]\ncondition = "duration"\nseconds = 5.0\n'
                        '[[scenario.actions]]\naction = "bias"\ntarget = ["attitude.roll"]\noffset = 0.3\n')
    keys = _keys(client, ds)
    assert main(["attack", "--dataset", url, "--scenario", str(scenario)]) == 2
    assert url in _one_line(capsys) and not target.exists()
    assert _keys(client, ds) == keys  # the bucket is untouched

    # a run folder at a URL holding a hostile key: score, report, run --resume
    run = "hostile/run"
    client.put_object(Bucket=BUCKET, Key=f"{run}/config.json", Body=b"{}")
    client.put_object(Bucket=BUCKET, Key=_evil_key(run, target), Body=b"x")
    run_url = f"s3://{BUCKET}/{run}"
    for args in (["score", run_url], ["report", run_url, "--out", str(tmp_path / "rep"), "--no-figures"],
                 ["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset),
                  "--out", run_url, "--resume"]):
        assert main(args) == 2, args
        err = _one_line(capsys)
        assert run_url in err and "'..'" in err and "scart-stage-" in err, err
        assert not target.exists()
    assert not list((tmp_path / "tmp").iterdir())  # no staging folder left behind


@pytest.mark.parametrize("key", ["/abs/evil", "flights//evil", "flights\\..\\..\\evil"])
def test_other_hostile_keys_are_refused(s3, dataset, tmp_path, monkeypatch, capsys, key):
    fs, client = s3
    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "cache"))
    ds = f"odd{abs(hash(key)) % 1000}/ds"
    _upload(client, dataset, ds)
    client.put_object(Bucket=BUCKET, Key=f"{ds}/{key}", Body=b"x")
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", f"s3://{BUCKET}/{ds}",
                 "--out", str(tmp_path / "r")]) == 2
    err = _one_line(capsys)
    assert f"s3://{BUCKET}/{ds}: object key" in err and str(tmp_path / "cache") in err
    assert not (tmp_path / "r").exists()


# -- a URL run killed with SIGKILL ----------------------------------------------------------------

def test_killed_url_run_keeps_finished_jobs_and_its_staging_is_removed(s3, dataset, tmp_path, monkeypatch, capsys):
    fs, client = s3
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    run_url = f"s3://{BUCKET}/killed/run"
    env = {**os.environ, "TMPDIR": str(tmp), "SCART_TEST_PID_DIR": str(tmp_path),
           "SCART_BENCH_CACHE": str(tmp_path / "cache"), "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).parent), os.environ.get("PYTHONPATH")]))}
    args = ["run", "--detectors", "zscore_test,hang_test", "--plugin", ZS, "--plugin", plugin("Hang"),
            "--dataset", str(dataset), "--out", run_url, "--jobs", "1", "--timeout", "300"]
    proc = subprocess.Popen([sys.executable, "-m", "scart_bench", *args], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    hang_pid = None
    try:
        deadline = time.monotonic() + 240
        while not (tmp_path / "hang.pid").exists():  # zscore_test finished, hang_test is fitting
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "hang_test never started"
            time.sleep(0.2)
        hang_pid = int((tmp_path / "hang.pid").read_text())
        while "killed/run/jobs/zscore_test/status.json" not in _keys(client, "killed/run"):
            assert time.monotonic() < deadline, "zscore_test was not uploaded when it finished"
            time.sleep(0.2)
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
        proc.stderr.close()
        if hang_pid is not None:
            for _ in range(50):  # the worker ends itself once its parent is gone
                try:
                    os.kill(hang_pid, 0)
                except ProcessLookupError:
                    break
                time.sleep(0.1)
            else:
                os.kill(hang_pid, signal.SIGKILL)
    keys = {k.split("killed/run/", 1)[1] for k in _keys(client, "killed/run")}
    assert {"config.json", "jobs/zscore_test/status.json", "jobs/zscore_test/scores.npz"} <= keys
    assert "jobs/hang_test/status.json" not in keys and not any(k.startswith("cache/") for k in keys)
    stale = [p for p in tmp.iterdir() if p.name.startswith(f"scart-stage-{proc.pid}-")]
    assert all((p / ".owner").is_file() for p in stale)
    assert stale, list(tmp.iterdir())  # what kill -9 leaves
    jobs = [p for p in tmp.iterdir() if p.name.startswith(f"scart-job-{proc.pid}-")]
    assert jobs and all((p / ".owner").is_file() for p in jobs)  # hang_test's worker folder, owned by the run

    # the next command's start removes it; --resume keeps the uploaded job (and, without --dataset,
    # takes the dataset from the uploaded config.json)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "cache"))
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--out", run_url, "--resume"]) == 0
    err = capsys.readouterr().err
    assert "resume: 1 finished job(s) kept: zscore_test" in err
    assert f"resume: the run's dataset '{dataset}' (from {run_url}/config.json)" in err
    assert not any(p.exists() for p in stale)
    assert not [p for p in tmp.iterdir() if p.name.startswith("scart-stage-")]
    assert not any(p.exists() for p in jobs)


def test_a_jobs_status_is_uploaded_after_its_scores_and_the_checksums(s3, tmp_path, monkeypatch):
    """A job counts as done once its status.json is there: a kill mid-upload must not leave one whose
    scores or recorded checksums are not uploaded yet (--resume from the URL would refuse the run)."""
    from scart_bench import storage

    run = tmp_path / "run"
    for rel in ("config.json", "checksums.json", "jobs/a/status.json", "jobs/a/scores.npz", "jobs/b/alarms.npz",
                "jobs/b/status.json"):
        (run / rel).parent.mkdir(parents=True, exist_ok=True)
        (run / rel).write_text(rel)
    order: list[str] = []
    real = storage.upload_folder

    def recording(local, url, exclude=(), only=None):
        order.extend(sorted(only))
        return real(local, url, exclude, only=only)

    monkeypatch.setattr(storage, "upload_folder", recording)
    url = f"s3://{BUCKET}/order/run"
    pushed = storage.push_folder(run, url, last=("status.json",))
    assert order[-2:] == ["jobs/a/status.json", "jobs/b/status.json"] and len(order) == 6
    (run / "jobs/a/scores.npz").write_text("new scores")
    (run / "checksums.json").write_text("new checksums")
    (run / "jobs/a/status.json").write_text("new status")
    order.clear()
    storage.push_folder(run, url, since=pushed, last=("status.json",))
    assert order == ["checksums.json", "jobs/a/scores.npz", "jobs/a/status.json"]


def test_adding_to_a_url_dataset_uploads_only_the_change_and_a_failure_keeps_the_old_dataset(s3, tmp_path,
                                                                                               monkeypatch):
    """A flight added to a dataset at a URL (sitl/proxy --record, attack --dataset) uploads what changed;
    a failed upload puts the old files and manifest back (a clear and full re-upload left the flights
    that were already there without a manifest)."""
    from scart_bench import storage

    fs, client = s3
    base = tmp_path / "base"
    for rel, text in {"manifest.parquet": "m1", "dataset.json": "d1", "flights/a/x": "a"}.items():
        (base / rel).parent.mkdir(parents=True, exist_ok=True)
        (base / rel).write_text(text)
    url = f"s3://{BUCKET}/append/ds"
    storage.publish_dataset(base, url)
    local = tmp_path / "local"
    shutil.copytree(base, local)
    (local / "flights/b").mkdir()
    (local / "flights/b/x").write_text("b")
    (local / "manifest.parquet").write_text("m2")
    (local / "dataset.json").write_text("d2")

    def body(key: str) -> str:
        return client.get_object(Bucket=BUCKET, Key=f"append/ds/{key}")["Body"].read().decode()

    real = storage.upload_folder
    uploaded: list[str] = []

    def failing(src, dest, exclude=(), only=None):
        if "dataset.json" in (only or ()) and Path(src) == local:
            raise OSError("connection reset while uploading dataset.json")
        uploaded.extend(only or ())
        return real(src, dest, exclude, only=only)

    monkeypatch.setattr(storage, "upload_folder", failing)
    with pytest.raises(OSError, match="connection reset"):
        storage.update_dataset(local, url, base)
    assert body("manifest.parquet") == "m1" and body("dataset.json") == "d1" and body("flights/a/x") == "a"

    uploaded.clear()
    monkeypatch.setattr(storage, "upload_folder", lambda src, dest, exclude=(), only=None: (
        uploaded.extend(only or ()), real(src, dest, exclude, only=only)))
    storage.update_dataset(local, url, base)
    assert body("manifest.parquet") == "m2" and body("dataset.json") == "d2" and body("flights/b/x") == "b"
    assert sorted(uploaded) == ["dataset.json", "flights/b/x"]  # flights/a was already there


def test_stale_temp_folders_only_of_dead_owners_are_removed(tmp_path, monkeypatch):
    from scart_bench.cli.common import owned_tempdir, remove_stale_temp

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    gone = [tmp_path / f"scart-stage-{dead.pid}-abc", tmp_path / f"scart-job-{dead.pid}-x1"]
    for folder in gone:
        (folder / "run").mkdir(parents=True)
        (folder / ".owner").write_text("scart-bench pid\n")
    live = tmp_path / f"scart-stage-{os.getppid()}-abc"  # the parent is alive
    unowned = tmp_path / f"scart-stage-{dead.pid}-noowner"  # no owner file: not made by owned_tempdir
    older = tmp_path / "scart-stage-12345678"  # the old naming (no pid): left alone
    unrelated = tmp_path / f"other-{dead.pid}-abc"
    for folder in (live, unowned, older, unrelated):
        folder.mkdir()
        if folder != unowned:
            (folder / ".owner").write_text("x")
    assert sorted(remove_stale_temp(tmp_path)) == sorted(gone)
    assert all(p.exists() for p in (live, unowned, older, unrelated))
    # a folder whose owner file is locked is in use, whatever its name says (a pid of another namespace)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with owned_tempdir("scart-stage-") as mine:
        assert mine.name.startswith(f"scart-stage-{os.getpid()}-") and (mine / ".owner").is_file()
        held = tmp_path / f"scart-stage-{dead.pid}-held"
        mine.rename(held)
        assert remove_stale_temp(tmp_path) == [] and held.exists()
        held.rename(mine)
    assert not mine.exists()


# -- a half-uploaded dataset and --overwrite ------------------------------------------------------

def test_half_uploaded_dataset_is_replaced_only_with_overwrite(s3, dataset, tmp_path, monkeypatch):
    from scart_bench.storage import StorageError, staged_dataset

    fs, client = s3
    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "cache"))
    prefix = "half/ds"
    _upload(client, dataset / "flights", f"{prefix}/flights")  # flights, no manifest: an upload cut short
    client.put_object(Bucket=BUCKET, Key=f"{prefix}/flights/stray.parquet", Body=b"junk")
    url = f"s3://{BUCKET}/{prefix}"
    with pytest.raises(StorageError, match="holds objects but no manifest.*--overwrite"), staged_dataset(url):
        pass
    assert f"{prefix}/flights/stray.parquet" in _keys(client, prefix)
    with staged_dataset(url, overwrite=True) as local:
        shutil.copytree(dataset, local)
    keys = _keys(client, prefix)
    assert f"{prefix}/manifest.parquet" in keys and f"{prefix}/flights/stray.parquet" not in keys
    # and a failing command with overwrite leaves the URL as it was
    client.put_object(Bucket=BUCKET, Key=f"{prefix}2/x", Body=b"x")
    with pytest.raises(RuntimeError), staged_dataset(f"{url}2", overwrite=True):
        raise RuntimeError("the command failed")
    assert _keys(client, f"{prefix}2") == [f"{prefix}2/x"]


def test_generate_to_a_half_uploaded_url_needs_overwrite_and_then_replaces_it(s3, tmp_path, monkeypatch, capsys):
    from scart_bench.generator.attacks import SCENARIO_DIR

    fs, client = s3
    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "cache"))
    prefix = "half-gen/ds"
    client.put_object(Bucket=BUCKET, Key=f"{prefix}/flights/normal-0000/navigator.parquet", Body=b"cut short")
    args = ["generate", "--profile", "quick", "--flights", "2", "--seed", "3",
            "--scenarios", str(SCENARIO_DIR / "gps_spoof.toml"), "--out", f"s3://{BUCKET}/{prefix}"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "holds objects but no manifest" in err and "--overwrite" in err and len(err.splitlines()) == 1
    assert main([*args, "--overwrite"]) == 0
    keys = _keys(client, prefix)
    assert f"{prefix}/manifest.parquet" in keys
    body = client.get_object(Bucket=BUCKET, Key=f"{prefix}/flights/normal-0000/navigator.parquet")["Body"].read()
    assert body != b"cut short"  # the stray object was replaced by the generated flight


# -- --resume without --dataset -------------------------------------------------------------------

def test_resume_without_dataset_reads_it_from_the_run_and_generates_nothing(dataset, tmp_path, monkeypatch,
                                                                           capsys):
    run = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(dataset),
                 "--out", str(run)]) == 0
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    capsys.readouterr()
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--out", str(run), "--resume"]) == 0
    err = capsys.readouterr().err
    assert "resume: 1 finished job(s) kept" in err and str(dataset) in err
    assert not (cwd / "data").exists()
    # the run's dataset is gone: refused up front, one line naming config.json and the field
    moved = tmp_path / "run2"
    shutil.copytree(run, moved)
    config = json.loads((moved / "config.json").read_text())
    config["dataset"]["path"] = str(tmp_path / "gone")
    (moved / "config.json").write_text(json.dumps(config))
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--out", str(moved), "--resume"]) == 2
    err = _one_line(capsys)
    assert str(moved / "config.json") in err and "dataset.path" in err and "--dataset" in err
    assert not (cwd / "data").exists()
