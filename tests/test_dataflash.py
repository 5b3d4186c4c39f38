"""ArduPilot DataFlash (.bin) import: the two shared ArduCopter logs, and small logs written here byte
by byte (FMT/UNIT/MULT/FMTU, multi-instance sensors, damage) and read back by pymavlink's DFReader."""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import numpy as np
import pytest

from scart_bench.cli.main import main
from scart_bench.dataset import DatasetError, open_dataset
from scart_bench.generator.logs.importers import load_flight_file

DF_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dataflash"
LOITER = DF_DIR / "arducopter_loiter_rtl.bin"
LOG_181 = DF_DIR / "arducopter_181.bin"
needs_logs = pytest.mark.skipif(not (LOITER.exists() and LOG_181.exists()), reason=f"DataFlash logs not in {DF_DIR}")

# What the shared logs hold, counted with pymavlink (DFReader.recv_msg over the whole file) and the
# README: message counts, and the ArduCopter flight modes seen.
COUNTS = {LOITER: {"gps": 992, "imu": 11775, "att": 2356, "baro": 2357},
          LOG_181: {"gps": 675, "imu": 6223, "att": 1245, "baro": 1245}}
MODES = {LOITER: {2, 5, 6, 9}, LOG_181: {0, 2, 5}}


@pytest.fixture(scope="module")
def logs():
    return {LOITER: load_flight_file(LOITER), LOG_181: load_flight_file(LOG_181, allow_corrupt=True)}


@needs_logs
@pytest.mark.parametrize("log", [LOITER, LOG_181], ids=["loiter_rtl", "181"])
def test_shared_logs(logs, log):
    tables = logs[log]
    for topic, n in COUNTS[log].items():
        assert len(tables[topic]) == n, topic
    for topic, df in tables.items():
        ts = df["Timestamp"].to_numpy()
        assert df["Timestamp"].dtype == np.int64 and (np.diff(ts) > 0).all(), topic
        assert all(df[c].dtype == np.float64 for c in df.columns[1:]), topic
        assert "TimeMS" not in df.columns or topic == "gps", topic  # the clock became Timestamp
    assert min(int(df["Timestamp"].iloc[0]) for df in tables.values()) == 0  # time zero: the first message
    gps = tables["gps"]
    assert np.allclose(gps["Lat"][gps["Status"] >= 3], 42.8458, atol=2e-3)  # degrees, not 1e-7 deg
    assert np.allclose(gps["Lng"][gps["Status"] >= 3], -2.6885, atol=2e-3)
    # a GPS message's time is its boot time (T), not its GPS time of week (TimeMS): within the IMU's span
    imu = tables["imu"]["Timestamp"]
    assert imu.iloc[0] - 1e6 < gps["Timestamp"].iloc[0] and gps["Timestamp"].iloc[-1] < imu.iloc[-1] + 1e6
    assert set(tables["mode"]["Mode"].astype(int)) == MODES[log]
    assert tables["att"].attrs["dataflash_message"] == "ATT" and "parm" not in tables and "msg" not in tables


@needs_logs
def test_topic_selection_keeps_time_zero(logs):
    part = load_flight_file(LOITER, topics=["gps", "mode"])
    assert list(part) == ["gps", "mode"]
    for topic in part:
        assert part[topic]["Timestamp"].equals(logs[LOITER][topic]["Timestamp"])
    with pytest.raises(DatasetError, match=r"arducopter_loiter_rtl.bin: topic\(s\) \['nope'\] not found .* it has: .*'gps'"):
        load_flight_file(LOITER, topics=["gps", "nope"])


@needs_logs
def test_a_cut_last_message_is_read_up_to_it_with_a_warning(caplog):
    # the shared 181 log ends in the first 16 bytes of a message (the logger stopped at a 4 KiB boundary):
    # as ArduPilot logs usually end, so it is read without --allow-corrupt, and the same as with it
    with caplog.at_level(logging.WARNING):
        t = load_flight_file(LOG_181)
    assert "last DataFlash message is cut by the end of the file (692208 of 692224 bytes" in caplog.text
    assert not t["gps"].attrs.get("file_corruption")
    again = load_flight_file(LOG_181, allow_corrupt=True)
    assert set(t) == set(again) and all(t[k].equals(again[k]) for k in t)


@needs_logs
def test_garbled_bytes_in_the_middle(tmp_path, caplog):
    data = bytearray(LOITER.read_bytes())
    data[400_000:400_040] = b"x" * 40
    bad = tmp_path / "bad.bin"
    bad.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=r"bad.bin: the DataFlash log is damaged: \d+ byte\(s\) between messages"):
        load_flight_file(bad)
    with caplog.at_level(logging.WARNING):
        t = load_flight_file(bad, allow_corrupt=True)
    clean = load_flight_file(LOITER)
    for topic, df in t.items():  # a garbled message's time (a 23-day jump) is dropped, not kept
        assert df["Timestamp"].iloc[-1] <= clean[topic]["Timestamp"].iloc[-1] + 1, topic
    assert len(t["imu"]) >= len(clean["imu"]) - 2


# ----------------------------------------------------------------------------------------------
# a DataFlash log written here: the format messages of a current ArduPilot log

FORMATS = {"B": "B", "b": "b", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "Q": "Q", "L": "i", "e": "i",
           "M": "B", "N": "16s", "Z": "64s", "n": "4s", "d": "d"}


class _Log:
    def __init__(self):
        self.out = bytearray()
        self.fmts: dict[int, str] = {128: "BBnNZ"}

    def msg(self, mtype: int, *values) -> None:
        packed = [v.encode() if isinstance(v, str) else v for v in values]
        self.out += b"\xa3\x95" + bytes([mtype]) + struct.pack("<" + "".join(FORMATS[c] for c in self.fmts[mtype]),
                                                               *packed)

    def fmt(self, mtype: int, name: str, fmt: str, columns: str) -> None:
        length = 3 + struct.calcsize("<" + "".join(FORMATS[c] for c in fmt))
        self.fmts[mtype] = fmt
        self.msg(128, mtype, length, name, fmt, columns)


def _modern_log() -> bytes:
    log = _Log()
    log.fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")
    log.fmt(177, "UNIT", "QbZ", "TimeUS,Id,Label")
    log.fmt(178, "MULT", "Qbd", "TimeUS,Id,Mult")
    log.fmt(179, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds")
    for uid, label in (("s", "s"), ("#", "instance"), ("G", "Gauss"), ("D", "deglatitude"), ("U", "deglongitude"),
                       ("m", "m"), ("-", "")):
        log.msg(177, 1000, ord(uid), label)
    for mid, mult in (("F", 1e-6), ("C", 1e-3), ("G", 1e-7), ("B", 1e-2), ("-", 0.0)):
        log.msg(178, 1000, ord(mid), mult)
    log.fmt(180, "MAG", "QBhhh", "TimeUS,I,MagX,MagY,MagZ")
    log.fmt(181, "GPS", "QBIHLLe", "TimeUS,I,GMS,GWk,Lat,Lng,Alt")
    log.fmt(182, "MODE", "QMBB", "TimeUS,Mode,ModeNum,Rsn")
    log.msg(179, 1000, 180, "s#GGG", "F-CCC")
    log.msg(179, 1000, 181, "s#s-DUm", "F-C-GGB")
    log.msg(182, 2_000_000, 0, 0, 1)
    for k in range(50):
        t = 2_000_000 + 100_000 * k
        for inst in (0, 1):
            log.msg(180, t + inst, inst, 200 + k, -100 - inst, 400)
        if k % 2 == 0:
            log.msg(181, t + 5, 0, 300_000_000 + 100 * k, 2300, 473977420 + k, 85455940, 48800)
    log.msg(182, 6_000_000, 5, 5, 2)
    return bytes(log.out)


def test_modern_format_units_multipliers_instances(tmp_path):
    path = tmp_path / "modern.bin"
    path.write_bytes(_modern_log())
    t = load_flight_file(path)
    assert sorted(t) == ["gps", "mag", "mag_1", "mode"]  # one topic per instance (the FMTU '#' field)
    # time zero: the first timed message (the UNIT messages at 1 ms), whichever topics are kept
    assert t["mag"].attrs["origin_us"] == 1000 and t["mode"]["Timestamp"].tolist() == [1_999_000, 5_999_000]
    assert t["mag"]["MagX"].iloc[3] == pytest.approx(0.203)  # mGauss x MULT 'C' (1e-3) -> Gauss
    assert t["mag_1"]["MagY"].iloc[0] == pytest.approx(-0.101)
    assert t["mag"].attrs["units"]["MagX"] == "mGauss"  # pymavlink's unit with the multiplier's prefix
    gps = t["gps"]
    assert gps["Lat"].iloc[1] == 47.3977422 and gps["Lng"].iloc[0] == 8.545594  # 'L': 1e-7 deg, exact
    assert gps["Alt"].iloc[0] == 488.0  # 'e': the format's own x 0.01, not MULT 'B' again
    assert gps["GMS"].iloc[0] == pytest.approx(300_000.0)  # ms x MULT 'C' -> s
    assert gps["Timestamp"].iloc[1] == 2_199_005 and "I" not in gps.columns and "TimeUS" not in gps.columns


def test_modern_log_cut_and_junk(tmp_path):
    data = _modern_log()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[:-5])
    assert len(load_flight_file(cut)["mode"]) == 1  # the cut MODE message is not read, the rest is
    padded = tmp_path / "padded.bin"
    padded.write_bytes(data + b"\xff" * 200)  # a block log's unwritten end of page: not damage
    assert len(load_flight_file(padded)["mode"]) == 2
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"not a log " * 100)
    with pytest.raises(DatasetError, match=r"junk.bin: no DataFlash message found in 1000 bytes; expected a .bin log"):
        load_flight_file(junk)
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    with pytest.raises(DatasetError, match="empty.bin: the DataFlash log is empty"):
        load_flight_file(empty)


@needs_logs
def test_cli_import(tmp_path, capsys):
    ds = tmp_path / "mine"
    assert main(["import", str(LOITER), "--out", str(ds), "--split", "train"]) == 0
    assert main(["import", str(LOG_181), "--out", str(ds), "--split", "test"]) == 0  # cut at its end only
    m = open_dataset(ds).manifest
    assert sorted(m["flight_id"]) == ["log-arducopter_181", "log-arducopter_loiter_rtl"]
