"""MAVLink telemetry log (.tlog) import: tlogs written here with pymavlink's encoder (each frame
preceded by its 8-byte receive time, as ground stations record them) and read back with mavutil."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

pytest.importorskip("pymavlink")
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from scart_bench.cli.main import main  # noqa: E402
from scart_bench.dataset import DatasetError, open_dataset  # noqa: E402
from scart_bench.generator.logs.importers import load_flight_file  # noqa: E402

T0 = 1_700_000_000_000_000  # receive time of the first frame, us since 1970


def _frames(n: int = 50) -> list[tuple[int, object, int]]:
    """(receive time us, message, source system) of a 10 Hz flight going north 1 m/s, with the ground
    station's own heartbeats (system 255) in between."""
    out = []
    for k in range(n):
        t = T0 + 100_000 * k
        out.append((t, mav.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3), 1))
        out.append((t + 1000, mav.MAVLink_global_position_int_message(
            100 * k, 473977420 + 90 * k, 85455940, 488000 + 10 * k, 100 * k, 100, 0, -1, 9000), 1))
        out.append((t + 2000, mav.MAVLink_gps_raw_int_message(
            100_000 * k, 3, 473977420 + 90 * k, 85455940, 488000, 120, 150, 100, 4500, 10), 1))
        out.append((t + 3000, mav.MAVLink_attitude_message(100 * k, 0.01, -0.02, 1.5, 0.0, 0.0, 0.0), 1))
        if k % 10 == 0:
            out.append((t + 4000, mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3), 255))
            out.append((t + 5000, mav.MAVLink_battery_status_message(
                0, 0, 0, 2500, [16000] + [65535] * 9, 1200, -1, -1, 80 - k), 1))
    return out


def write_tlog(path, frames) -> bytes:
    encoders = {}
    data = bytearray()
    for t, msg, system in frames:
        enc = encoders.setdefault(system, mav.MAVLink(None, srcSystem=system, srcComponent=1 if system != 255 else 190))
        data += struct.pack(">Q", t) + msg.pack(enc)
    path.write_bytes(bytes(data))
    return bytes(data)


def test_tlog_topics_units_and_time(tmp_path):
    path = tmp_path / "flight.tlog"
    write_tlog(path, _frames())
    t = load_flight_file(path)
    assert sorted(t) == ["attitude", "battery_status", "global_position_int", "gps_raw_int", "heartbeat"]
    gpi = t["global_position_int"]
    assert len(gpi) == 50 and gpi["Timestamp"].iloc[0] == 1000 and gpi["Timestamp"].iloc[1] == 101_000
    assert gpi.attrs["origin_us"] == T0  # time zero: the first frame, whichever topics are kept
    assert gpi["lat"].iloc[2] == 47.3977600 and gpi["lon"].iloc[0] == 8.545594  # degE7 -> deg, exact
    assert gpi["alt"].iloc[1] == pytest.approx(488.01) and gpi["relative_alt"].iloc[3] == pytest.approx(0.3)
    assert gpi["vx"].iloc[0] == 1.0 and gpi["vz"].iloc[0] == -0.01  # cm/s -> m/s
    assert gpi["hdg"].iloc[0] == pytest.approx(math.pi / 2)  # cdeg -> rad, as the generator's hdg
    assert gpi.attrs["units"]["lat"] == "deg" and gpi.attrs["units"]["hdg"] == "rad"
    gps = t["gps_raw_int"]
    assert gps["vel"].iloc[0] == 1.0 and gps["cog"].iloc[0] == pytest.approx(math.pi / 4)
    bat = t["battery_status"]
    assert bat["battery_remaining"].tolist() == [0.8, 0.7, 0.6, 0.5, 0.4]  # % -> 0..1
    assert bat["voltages_0"].iloc[0] == 16.0 and bat["current_battery"].iloc[0] == 12.0  # mV -> V, cA -> A
    # the ground station's heartbeats (system 255) are not the vehicle's
    assert len(t["heartbeat"]) == 50 and set(t["heartbeat"]["autopilot"]) == {12.0}
    assert gpi.attrs["other_sources_dropped"] == 5 and gpi.attrs["system"] == 1
    # metres north of the first fix agree with the 1 m/s the messages say (0.1 m per 10 Hz frame)
    north = (gpi["lat"] - gpi["lat"].iloc[0]) * 111_200
    assert np.allclose(np.diff(north), 1.0, atol=0.01)


def test_tlog_topic_selection_and_errors(tmp_path):
    path = tmp_path / "flight.tlog"
    data = write_tlog(path, _frames())
    part = load_flight_file(path, topics=["gps_raw_int"])
    assert list(part) == ["gps_raw_int"] and part["gps_raw_int"]["Timestamp"].iloc[0] == 2000
    with pytest.raises(DatasetError, match=r"flight.tlog: topic\(s\) \['sensor_gps'\] not found in the tlog "
                       r"\(system 1, component 1\); it has: .*'gps_raw_int'"):
        load_flight_file(path, topics=["sensor_gps"])
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(data[:-9])
    with pytest.raises(DatasetError, match=r"cut.tlog: the tlog is damaged: the last \d+ byte\(s\) are a cut frame; "
                       r".*--allow-corrupt"):
        load_flight_file(cut)
    assert len(load_flight_file(cut, allow_corrupt=True)["global_position_int"]) == 50
    bad = tmp_path / "bad.tlog"
    garbled = bytearray(data)
    garbled[2000:2004] = b"zzzz"
    bad.write_bytes(bytes(garbled))
    with pytest.raises(DatasetError, match=r"bad.tlog: the tlog is damaged: 1 frame\(s\) failed their checksum"):
        load_flight_file(bad)
    assert len(load_flight_file(bad, allow_corrupt=True)["global_position_int"]) >= 49
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(b"hello" * 100)
    with pytest.raises(DatasetError, match="junk.tlog: no valid MAVLink frame found in 500 bytes"):
        load_flight_file(junk)


def test_tlog_cli_import_and_attack(tmp_path, capsys):
    path = tmp_path / "gcs_flight.tlog"
    write_tlog(path, _frames(200))
    ds = tmp_path / "mine"
    assert main(["import", str(path), "--out", str(ds), "--split", "test"]) == 0
    assert open_dataset(ds).manifest["flight_id"].tolist() == ["log-gcs_flight"]
    # the generator's own scenario file applies unchanged: the tlog has its MAVLink topic names
    assert main(["attack", "--dataset", str(ds), "--scenario", "data/scenarios/sensor_gps_jump.toml"]) == 0, \
        capsys.readouterr().err
    m = open_dataset(ds).manifest
    assert len(m) == 2 and (m["mode"] == "csv").sum() == 1


def test_a_tlog_recorded_from_the_sitl_by_pymavlink_matches_the_sitls_own_recording(tmp_path):
    """A ground station's tlog (each frame a pymavlink client received, after its 8-byte big-endian
    receive time in microseconds, as mavutil's ``setup_logfile`` writes them; its UDP connection does not
    log, so the client writes them itself) of a ``scart-bench sitl`` flight imports, and its GPS track is the sitl's
    own recording of that flight: the same positions (within the 1e-7 deg of MAVLink's integers) at
    the same boot times."""
    import os
    import socket
    import subprocess
    import sys
    import time
    from pathlib import Path

    from pymavlink import mavutil

    from scart_bench.dataset import open_dataset

    root = Path(__file__).resolve().parents[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rec, tlog = tmp_path / "sitl", tmp_path / "gcs.tlog"
    cmd = [sys.executable, "-m", "scart_bench.cli", "sitl", "--listen", f"udp:127.0.0.1:{port}", "--lockstep",
           "--duration", "4", "--record", str(rec), "--flight-id", "s1"]
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(root)})
    try:
        assert "listening on" in proc.stderr.readline()
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        with tlog.open("wb") as fh:
            while True:  # record everything until the sitl has stopped and gone quiet
                m = conn.recv_match(blocking=True, timeout=0.5)
                if m is None and proc.poll() is not None:
                    break
                if m is not None and m.get_type() != "BAD_DATA":
                    fh.write(struct.pack(">Q", int(time.time() * 1e6)) + m.get_msgbuf())
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    ds_path = tmp_path / "gcs"
    assert main(["import", str(tlog), "--out", str(ds_path), "--split", "test"]) == 0
    ds, own = open_dataset(ds_path), open_dataset(rec)
    (fid,) = ds.manifest["flight_id"]
    for topic, time_field, scale in (("global_position_int", "time_boot_ms", 1000), ("gps_raw_int", "time_usec", 1)):
        got = ds.topic(fid, topic)
        mine = own.topic("s1", topic).set_index("Timestamp")
        assert len(got) > 20, f"{topic}: {len(got)} messages in the tlog"
        at = (got[time_field].to_numpy(np.int64) * scale)
        assert np.isin(at, mine.index).mean() > 0.95, f"{topic}: boot times do not match the sitl's"
        keep = np.isin(at, mine.index)
        ref = mine.loc[at[keep]]
        for f in ("lat", "lon"):
            assert np.abs(got[f].to_numpy()[keep] - ref[f].to_numpy()).max() <= 1.01e-7, f"{topic}.{f}"
        assert np.abs(got["alt"].to_numpy()[keep] - ref["alt"].to_numpy()).max() <= 1.01e-3
