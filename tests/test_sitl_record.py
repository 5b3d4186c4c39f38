"""``sitl --record`` writes the flight as it flies: an interrupted recording keeps the flown part.

A recording whose final write fails (a full disk) and one whose process is killed both leave the
journal beside the dataset; the next ``sitl --record`` adds the flown part as a flight marked
incomplete. Loopback only (the vehicle's telemetry goes to a local sink so it runs without a client).
"""

from __future__ import annotations

import errno
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("pymavlink", reason="the sitl needs pymavlink (pip install scart-bench[mavlink])")

from scart_bench.cli.main import main  # noqa: E402
from scart_bench.dataset import open_dataset  # noqa: E402
from scart_bench.generator.sitl.journal import STATE, journal_root  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def sink():
    """Where the vehicle sends its telemetry (``--remote``): it flies from the start, in lockstep."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        yield f"udp:127.0.0.1:{s.getsockname()[1]}"


def _args(out: Path, sink: str, fid: str, seconds: float) -> list[str]:
    return ["sitl", "--listen", "udp:127.0.0.1:0", "--remote", sink, "--lockstep", "--duration", str(seconds),
            "--record", str(out), "--flight-id", fid]


def test_a_recording_that_cannot_be_written_is_kept_and_added_incomplete_at_the_next_start(tmp_path, sink,
                                                                                           monkeypatch, capsys):
    import scart_bench.generator.mavlink.recording as recording

    out = tmp_path / "mine"
    real = recording.save_recording

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recording, "save_recording", disk_full)
    assert main(_args(out, sink, "f1", 3.0)) == 2
    assert "No space left" in capsys.readouterr().err
    assert (journal_root(out) / "f1" / STATE).is_file(), "the flown part is kept"
    monkeypatch.setattr(recording, "save_recording", real)
    assert main(_args(out, sink, "f2", 0.5)) == 0
    assert "recovered flight f1" in capsys.readouterr().err
    ds = open_dataset(out)
    assert set(ds.manifest["flight_id"]) == {"f1", "f2"}
    assert ds.config("f1")["incomplete"] is True and not ds.config("f2").get("incomplete")
    truth = ds.topic("f1", "truth", view="simulator")
    assert truth["Timestamp"].iloc[-1] >= 2.9e6, "the whole 3 s flown are there"
    assert not journal_root(out).exists(), "the journal is gone once its flight is in the dataset"


def test_a_killed_recording_keeps_what_was_flown(tmp_path, sink):
    out = tmp_path / "mine"
    proc = subprocess.Popen([sys.executable, "-m", "scart_bench", *_args(out, sink, "k1", 600)], cwd=ROOT,
                            stderr=subprocess.DEVNULL)
    state = journal_root(out) / "k1" / STATE
    try:
        deadline = time.monotonic() + 120
        flown = 0.0
        while flown < 4.0:
            assert time.monotonic() < deadline and proc.poll() is None, "the sitl never flushed 4 s of flight"
            time.sleep(0.2)
            if state.is_file():
                flown = json.loads(state.read_text())["parts"]["end_us"] / 1e6
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert main(_args(out, sink, "k2", 0.2)) == 0
    ds = open_dataset(out)
    assert ds.config("k1")["incomplete"] is True
    assert ds.manifest.set_index("flight_id").loc["k1", "duration_s"] >= 4.0
    nav = ds.topic("k1", "attitude")
    assert len(nav) > 100 and nav["Timestamp"].is_monotonic_increasing
