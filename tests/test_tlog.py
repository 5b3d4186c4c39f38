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
