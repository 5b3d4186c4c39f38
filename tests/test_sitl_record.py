"""``sitl --record`` writes the flight as it flies: an interrupted recording keeps the flown part.

A recording whose final write fails (a full disk) and one whose process is killed both leave the
journal beside the dataset; the next ``sitl --record`` adds the flown part as a flight marked
incomplete. Loopback only (the vehicle's telemetry goes to a local sink so it runs without a client).
"""

from __future__ import annotations

import builtins
import errno
import json
import math
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


# --- a full disk: the journal promises only what it keeps ----------------------------------------
class _Disk:
    """The disk under the journals of ``root`` with ``free`` bytes (the files there count): a write
    past it writes what fits and raises ENOSPC; ``frees_up``: the space comes back after the first
    failure (another program deleted something)."""

    def __init__(self, root: Path, free: float, frees_up: bool = False):
        self.root, self.free, self.frees_up, self.failures = root, free, frees_up, 0

    def used(self) -> int:
        return sum(p.stat().st_size for p in self.root.rglob("*") if p.is_file()) if self.root.exists() else 0

    def open(self, path, mode="r", *args, **kwargs):
        fh = builtins.open(path, mode, *args, **kwargs)
        return fh if set(mode) <= {"r", "b", "t"} else _File(fh, self)


class _File:
    def __init__(self, fh, disk: _Disk):
        self.fh, self.disk = fh, disk

    def write(self, data):
        self.fh.flush()
        room = self.disk.free - self.disk.used() if not (self.disk.frees_up and self.disk.failures) else math.inf
        if len(data) > room:
            self.fh.write(data[:max(0, int(room))])
            self.fh.flush()
            self.disk.failures += 1
            raise OSError(errno.ENOSPC, "No space left on device")
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.fh.close()


def _full_disk(monkeypatch, out: Path, free: float, frees_up: bool = False) -> _Disk:
    """The journal's writes go to a disk with ``free`` bytes, and the flight's final write fails."""
    import scart_bench.generator.mavlink.recording as recording
    import scart_bench.generator.sitl.journal as journal

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    disk = _Disk(journal_root(out), free, frees_up)
    monkeypatch.setattr(journal, "open", disk.open, raising=False)
    monkeypatch.setattr(recording, "save_recording", disk_full)
    return disk


def test_with_40_kb_free_the_journal_promises_nothing_it_cannot_keep(tmp_path, sink, monkeypatch, capsys):
    """40 KB hold no flush of the journal (about 90 KB per 2 s): the command says the flight is lost
    instead of promising that the next start adds it; no journal is left to be dropped silently."""
    out = tmp_path / "mine"
    with monkeypatch.context() as m:
        _full_disk(m, out, 40_000)
        assert main(_args(out, sink, "f1", 3.0)) == 2
    err = capsys.readouterr().err
    assert "adds it" not in err and "keeps" not in err, err
    assert f"{journal_root(out) / 'f1'}" in err and "lost" in err, err
    assert not (journal_root(out) / "f1").exists()
    assert main(_args(out, sink, "f2", 0.5)) == 0
    assert set(open_dataset(out).manifest["flight_id"]) == {"f2"}


def test_a_disk_that_fills_mid_flight_keeps_the_part_it_says_and_the_next_start_adds_it(tmp_path, sink, monkeypatch,
                                                                                          capsys):
    out = tmp_path / "mine"
    with monkeypatch.context() as m:
        _full_disk(m, out, 130_000)  # the first flush (2 s) fits, the second does not
        assert main(_args(out, sink, "f1", 5.0)) == 2
    err = capsys.readouterr().err
    assert "keeps its first 2.0 s" in err and f"sitl --record {out}" in err and "as flight f1" in err, err
    assert main(_args(out, sink, "f2", 0.5)) == 0
    assert "recovered flight f1" in capsys.readouterr().err
    ds = open_dataset(out)
    assert set(ds.manifest["flight_id"]) == {"f1", "f2"} and ds.config("f1")["incomplete"] is True
    t = ds.topic("f1", "truth", view="simulator")["Timestamp"]
    assert 1.9e6 <= t.iloc[-1] <= 2.1e6 and t.is_monotonic_increasing, "the first 2 s, whole"
    assert not journal_root(out).exists()


def test_a_disk_that_frees_up_mid_flight_loses_nothing(tmp_path, sink, monkeypatch, capsys):
    """The first flush fails (40 KB free), then space comes back: the next flushes write the whole
    flight from the start, and the next start adds it."""
    out = tmp_path / "mine"
    with monkeypatch.context() as m:
        disk = _full_disk(m, out, 40_000, frees_up=True)
        assert main(_args(out, sink, "f1", 3.0)) == 2
    assert disk.failures == 1
    err = capsys.readouterr().err
    assert "keeps all of it" in err and "as flight f1" in err, err
    assert main(_args(out, sink, "f2", 0.5)) == 0
    ds = open_dataset(out)
    assert set(ds.manifest["flight_id"]) == {"f1", "f2"}
    truth = ds.topic("f1", "truth", view="simulator")
    assert truth["Timestamp"].iloc[-1] >= 2.9e6 and truth["Timestamp"].is_monotonic_increasing
    assert len(truth) == len(truth["Timestamp"].unique()), "no row written twice by the retried flush"


def test_a_journal_that_cannot_start_is_refused_before_the_flight(tmp_path, sink, monkeypatch, capsys):
    out = tmp_path / "mine"
    with monkeypatch.context() as m:
        _full_disk(m, out, 0)
        assert main(_args(out, sink, "f1", 3.0)) == 2
    err = capsys.readouterr().err
    assert "stopped after" not in err, "refused before it flew"
    line = err.strip().splitlines()[-1]
    assert str(journal_root(out) / "f1") in line and "No space left" in line, err
    assert not journal_root(out).exists()


def test_a_journal_without_state_is_never_removed_silently(tmp_path, sink, capsys):
    out = tmp_path / "mine"
    left = journal_root(out) / "old"
    left.mkdir(parents=True)
    (left / "navigator.attitude.ts.i64").write_bytes(b"\0" * 64)
    assert main(_args(out, sink, "f2", 0.2)) == 0
    err = capsys.readouterr().err
    assert f"journal {left} removed" in err and STATE in err, err


def test_a_journal_that_cannot_be_added_is_kept_and_never_reused(tmp_path, sink, capsys):
    """A journal the next start cannot add stays, named; recording again under its flight id is
    refused instead of overwriting it (and removing it with the new flight's journal)."""
    out = tmp_path / "mine"
    bad = journal_root(out) / "f1"
    bad.mkdir(parents=True)
    (bad / STATE).write_text("{ cut", encoding="utf-8")
    assert main(_args(out, sink, "f1", 0.2)) == 2
    err = capsys.readouterr().err
    assert f"journal {bad} not recovered" in err and f"sitl --record {out}" in err, err
    assert "--flight-id f1" in err.strip().splitlines()[-1]
    assert (bad / STATE).read_text(encoding="utf-8") == "{ cut", "the journal is left as it was"
    assert main(_args(out, sink, "f2", 0.2)) == 0
    assert (bad / STATE).read_text(encoding="utf-8") == "{ cut"
