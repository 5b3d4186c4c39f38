"""Live recording into a dataset at a URL: ``sitl --record s3://...`` and ``proxy --record s3://...``
record into a local copy and publish it with its manifest last, adding to a dataset already there
(as a local --record adds to a local one), and never write a local folder named ``s3:``. A flight
whose upload fails stays in its journal in the local cache and is published by the next --record
of that URL. Served by a moto S3 server started here."""

from __future__ import annotations

import contextlib
import errno
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymavlink", reason="live recording needs pymavlink (pip install scart-bench[mavlink])")
pytest.importorskip("s3fs")
pytest.importorskip("moto.server")

from moto_s3 import moto_s3  # noqa: E402

from scart_bench.cli.main import main  # noqa: E402
from scart_bench.dataset import open_dataset  # noqa: E402
from scart_bench.storage import fetch_dataset  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SPOOF = ROOT / "data" / "scenarios" / "gps_spoof.toml"
BUCKET = "live-lab"


def _free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def s3():
    """A moto S3 server on a free port, the environment pointing at it, and a fresh bucket."""
    with moto_s3(BUCKET) as (fs, _):
        yield fs


@pytest.fixture
def here(tmp_path, monkeypatch):
    """The test's own working folder and cache: a local folder ``s3:`` would appear here."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SCART_BENCH_CACHE", str(tmp_path / "cache"))
    return tmp_path


@pytest.fixture
def sink():
    """Where the vehicle sends its telemetry (``--remote``): it flies from the start, in lockstep."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        yield f"udp:127.0.0.1:{s.getsockname()[1]}"


def _sitl(url: str, sink: str, fid: str, seconds: float = 1.0) -> list[str]:
    return ["sitl", "--listen", "udp:127.0.0.1:0", "--remote", sink, "--lockstep", "--duration", str(seconds),
            "--record", url, "--flight-id", fid]


def _flights(url: str) -> set[str]:
    return set(open_dataset(fetch_dataset(url)).manifest["flight_id"])


def test_sitl_records_into_a_url_and_adds_to_the_dataset_there(s3, here, sink, capsys):
    url = f"s3://{BUCKET}/sitl/x"
    assert main(_sitl(url, sink, "s1")) == 0
    assert not (here / "s3:").exists(), "a URL is never a local folder"
    assert s3.exists(f"{BUCKET}/sitl/x/manifest.parquet")
    assert f"flight s1 recorded in {url}" in capsys.readouterr().out
    assert main(_sitl(url, sink, "s2")) == 0
    assert _flights(url) == {"s1", "s2"}, "the second recording is added to the dataset at the URL"
    assert main(_sitl(url, sink, "s2")) == 2, "a flight id the dataset holds is refused up front"
    assert "--flight-id s2" in capsys.readouterr().err
    assert not (here / "s3:").exists()


def test_a_sitl_flight_whose_upload_fails_is_published_by_the_next_record(s3, here, sink, monkeypatch, capsys):
    import scart_bench.generator.mavlink.recording as recording

    url = f"s3://{BUCKET}/sitl/failed"
    real = recording.save_recording

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recording, "save_recording", disk_full)
    assert main(_sitl(url, sink, "u1", 3.0)) == 2
    err = capsys.readouterr().err
    assert "journal" in err and "keeps all of it" in err and f"sitl --record {url}" in err, err
    assert not s3.exists(f"{BUCKET}/sitl/failed/manifest.parquet"), "nothing published after a failure"
    monkeypatch.setattr(recording, "save_recording", real)
    assert main(_sitl(url, sink, "u2", 0.5)) == 0
    assert "recovered flight u1" in capsys.readouterr().err
    ds = open_dataset(fetch_dataset(url))
    assert set(ds.manifest["flight_id"]) == {"u1", "u2"}
    assert ds.config("u1")["incomplete"] is True
    assert ds.topic("u1", "truth", view="simulator")["Timestamp"].iloc[-1] >= 2.9e6
    assert not any(p.is_dir() for p in (here / "cache" / "recordings").glob("*/*.sitl-recording")), \
        "the journal goes once its flight is published"
    assert not (here / "s3:").exists()


def test_a_url_holding_something_else_is_refused_up_front(s3, here, sink, capsys):
    s3.pipe(f"{BUCKET}/notes/readme.txt", b"not a dataset")
    assert main(_sitl(f"s3://{BUCKET}/notes", sink, "n1")) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"s3://{BUCKET}/notes" in err and "no manifest" in err, err
    assert not (here / "s3:").exists()
    assert main(["proxy", "--scenario", str(SPOOF), "--record", f"s3://{BUCKET}/notes", "--duration", "0.1"]) == 2
    assert "no manifest" in capsys.readouterr().err
    assert main(["ros", "node", "--record", f"s3://{BUCKET}/notes", "--duration", "0.1"]) == 2  # before ROS is touched
    assert "no manifest" in capsys.readouterr().err
    assert not (here / "s3:").exists()


@contextlib.contextmanager
def _autopilot(port: int):
    """50 Hz attitude at the proxy's ``port`` while the block runs (the first may precede its bind)."""
    from scart_bench.dataset.schema import TOPICS
    from scart_bench.generator.mavlink.codec import CODECS, Packer

    stop = threading.Event()

    def send():
        packer, row = Packer(), np.full(len(TOPICS["attitude"].fields), 0.1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ap:
            k = 0
            while not stop.is_set():
                ap.sendto(packer.pack(CODECS["attitude"].new_message(row, 20_000 * k), 1, 1, k % 256),
                          ("127.0.0.1", port))
                k += 1
                time.sleep(0.02)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        yield
    finally:
        stop.set()
        sender.join(timeout=5)


def _proxy(url: str, fid: str, seconds: float = 2.0) -> list[str]:
    """``proxy --record url`` fed by :func:`_autopilot` (the mission computer is a socket nobody reads)."""
    port = _free_port()
    return ["proxy", "--listen", f"udp:127.0.0.1:{port}", "--forward", f"udp:127.0.0.1:{_free_port()}",
            "--scenario", str(SPOOF), "--duration", str(seconds), "--flight-id", fid, "--record", url]


def _fly_proxy(argv: list[str]) -> int:
    with _autopilot(int(argv[2].rsplit(":", 1)[1])):
        return main(argv)


def test_proxy_records_into_a_url(s3, here, capsys):
    url = f"s3://{BUCKET}/proxy/y"
    assert _fly_proxy(_proxy(url, "p1")) == 0
    assert not (here / "s3:").exists(), "a URL is never a local folder"
    assert f"flight p1 recorded in {url}" in capsys.readouterr().out
    assert _fly_proxy(_proxy(url, "p2")) == 0
    ds = open_dataset(fetch_dataset(url))
    assert set(ds.manifest["flight_id"]) == {"p1", "p2"}, "the second flight is added to the dataset there"
    assert len(ds.topic("p1", "attitude")) > 20
    assert not (here / "s3:").exists()


def test_a_proxy_flight_whose_upload_fails_is_published_by_the_next_record(s3, here, monkeypatch, capsys):
    import scart_bench.generator.mavlink.recording as recording

    url = f"s3://{BUCKET}/proxy/failed"
    with monkeypatch.context() as m:
        m.setattr(recording, "save_recording", lambda *a, **k: (_ for _ in ()).throw(OSError(errno.EIO, "upload")))
        assert _fly_proxy(_proxy(url, "q1")) == 2
    err = capsys.readouterr().err
    assert "checkpoint" in err and f"proxy --record {url}" in err and "as flight q1" in err, err
    assert not s3.exists(f"{BUCKET}/proxy/failed/manifest.parquet")
    assert _fly_proxy(_proxy(url, "q2")) == 0
    assert "added q1" in capsys.readouterr().err
    ds = open_dataset(fetch_dataset(url))
    assert set(ds.manifest["flight_id"]) == {"q1", "q2"}
    assert ds.config("q1")["incomplete"] is True and len(ds.topic("q1", "attitude")) > 20
