"""Quantities by meaning on real logs (issue 48 items 2 and 6): attitude from a quaternion (PX4, ROS),
ArduPilot's EKF peers, quantities constant for the whole flight (logs without GPS), no-value markers."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.logs.offline import applicable, attack_file, summary_line, with_phases
from scart_bench.generator.logs.orientation import (
    euler_from_quaternion,
    listen_view,
    quaternion_from_euler,
    recorded_view,
)
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.scart.meanings import input_fields
from scart_bench.generator.scart.spec import ScenarioError

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
ULOG = SHARED / "ulog" / "sample_px4_events.ulg"
FLEET = SHARED / "dataflash" / "fleet"
ERLE = FLEET / "erlebrain_24.bin"  # APM:Copter 3.4: NKF1 (EKF2), no GPS: AHR2 lat/lon and NKF1 PN/PE read 0
NO_GPS = FLEET / "arducopter_25-9-2014_1.bin"  # no GPS message, EKF1 held at 0, no current sensor (CURR 0)
QUICK = ROOT / "data" / "scenarios" / "quick.toml"
Q = ["q_0", "q_1", "q_2", "q_3"]


def _scenario(tmp_path, target: str, offset: float, start_s: float = 8.0) -> Path:
    path = tmp_path / "sc.toml"
    path.write_text(f"""[scenario]
id = "bias"
[[scenario.start]]
condition = "time_window"
start_s = {start_s}
[[scenario.end]]
condition = "duration"
seconds = 5.0
[[scenario.actions]]
action = "bias"
target = ["{target}"]
offset = {offset}
""")
    return path


@pytest.mark.skipif(not ULOG.exists(), reason=f"{ULOG} not found")
def test_a_roll_attack_on_a_px4_log_rotates_its_quaternion(tmp_path):
    out = attack_file(ULOG, _scenario(tmp_path, "attitude.roll", 0.1), tmp_path / "out", topics=["vehicle_attitude"])
    src = load_flight_file(ULOG, topics=["vehicle_attitude"])["vehicle_attitude"]
    copy = load_flight_file(out / "flights" / "csv-bias")["vehicle_attitude"]
    assert list(copy.columns) == list(src.columns)  # the derived angles are not written
    q0, q = src[Q].to_numpy(), copy[Q].to_numpy()
    moved = (q != q0).any(axis=1)
    assert 20 < moved.sum() < len(q)  # 5 s of a 20-50 Hz topic, the rest bit for bit the log's
    assert np.abs(np.linalg.norm(q[moved], axis=1) - 1.0).max() < 1e-12  # still a unit quaternion
    d = euler_from_quaternion(q[moved]) - euler_from_quaternion(q0[moved])
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    np.testing.assert_allclose(d[:, 0], 0.1, atol=1e-9)  # roll moved by the attack's 0.1 rad
    np.testing.assert_allclose(d[:, 1:], 0.0, atol=1e-9)  # pitch and yaw as they were
    assert np.sign(np.sum(q[moved] * q0[moved], axis=1)).min() > 0  # the logged sign kept: a small change


def test_a_quaternion_component_is_no_target_of_its_own(tmp_path):
    tables = {"vehicle_attitude": _attitude_table()}
    with pytest.raises(ScenarioError, match="unit quaternion only when rotated"):
        for job in load_configurations(_scenario(tmp_path, "vehicle_attitude.q_1", 0.1), check_topics=False):
            for sc in job:
                sc.validate_topics(input_fields([listen_view(tables)]))


def _attitude_table(frame_cols=Q, frame="ned"):
    import pandas as pd

    angles = np.column_stack([np.linspace(-0.2, 0.2, 50), np.linspace(0.1, -0.1, 50), np.linspace(-3.0, 3.0, 50)])
    q = quaternion_from_euler(angles, frame)
    return pd.DataFrame({"Timestamp": np.arange(50) * 20_000, **{c: q[:, i] for i, c in enumerate(frame_cols)}})


def test_ros_orientations_read_as_ned_roll_pitch_yaw():
    # a ROS orientation (ENU world, FLU body): level, nose north = yaw +90 deg about ENU's up axis
    import pandas as pd

    cols = ["orientation_w", "orientation_x", "orientation_y", "orientation_z"]
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    north = pd.DataFrame({"Timestamp": [0, 1], "orientation_w": [c, c], "orientation_x": [0.0, 0.0],
                          "orientation_y": [0.0, 0.0], "orientation_z": [s, s]})
    view = listen_view({"imu": north})["imu"]
    np.testing.assert_allclose(view[["roll", "pitch", "yaw"]].to_numpy(), 0.0, atol=1e-12)  # NED yaw 0 = north
    # a nose-up attitude in NED (pitch +0.2) is a rotation about FLU's left axis by -0.2 in ROS
    up = quaternion_from_euler(np.array([[0.0, 0.2, 0.0]]), "enu")
    ros = euler_from_quaternion(up[:, [0, 1, 2, 3]], "ned")  # the same numbers read in ENU/FLU's own angles
    assert ros[0, 1] == pytest.approx(-0.2) and ros[0, 2] == pytest.approx(np.pi / 2)
    # an attack on the derived roll goes back into the ROS quaternion, pitch and yaw untouched
    table = _attitude_table(cols, "enu")
    view = listen_view({"imu": table})["imu"].copy()
    view.loc[10:19, "roll"] += 0.05
    back = recorded_view({"imu": view})["imu"]
    assert list(back.columns) == list(table.columns)
    before, after = table[cols].to_numpy(), back[cols].to_numpy()
    assert (after[:10] == before[:10]).all() and (after[20:] == before[20:]).all()
    d = euler_from_quaternion(after, "enu") - euler_from_quaternion(before, "enu")
    np.testing.assert_allclose(d[10:20, 0], 0.05, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * d[10:20, 1:])), 0.0, atol=1e-9)


def test_a_ros_messages_constants_are_no_columns():
    pytest.importorskip("rosbags")
    from rosbags.typesys import Stores, get_typestore

    from scart_bench.generator.logs.rosbag import flatten

    status = get_typestore(Stores.ROS2_HUMBLE).types["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
    assert flatten(status) == {"status": 0.0, "service": 1.0}  # not STATUS_FIX, SERVICE_GPS ... (constants)


@pytest.fixture(scope="module")
def erle():
    if not ERLE.exists():
        pytest.skip(f"{ERLE} not found")
    return load_flight_file(ERLE, topics=["ahr2", "nkf1", "att", "curr"])


def test_a_log_without_gps_has_its_position_counted_not_applicable(erle, tmp_path):
    jobs = load_configurations(QUICK, check_topics=False)
    fit, reasons = applicable(jobs, with_phases(erle), "erlebrain_24")
    # the 30 attitude configurations apply (ATT); the 36 on position would only move zeros (AHR2 lat/lon,
    # NKF1 PN/PE read 0 for the whole flight): not attacked, counted with the reason
    assert len(fit) == 30 and all("attitude" in job[0].id for job in fit)
    assert reasons == {"position.lat constant for the whole flight (ahr2.Lat = 0)": 36}
    assert "36 position.lat constant for the whole flight (ahr2.Lat = 0)" in summary_line(reasons, 66)
    (job,) = load_configurations(_scenario(tmp_path, "position", 10.0), check_topics=False)
    with pytest.raises(ScenarioError, match=r"position constant for the whole flight \(ahr2.Lat = 0 and 3 more\)"):
        job[0].validate_topics(input_fields([listen_view(erle)]))


def test_the_ekf2_position_and_velocity_resolve_by_meaning(erle, tmp_path):
    available = input_fields([listen_view(erle)])
    (job,) = load_configurations(_scenario(tmp_path, "velocity", 1.0), check_topics=False)
    assert job[0].resolved(available).actions[0][1]["target"] == ["nkf1.VN", "nkf1.VE", "nkf1.VD"]
    (job,) = load_configurations(_scenario(tmp_path, "attitude.roll", 0.1), check_topics=False)
    assert job[0].resolved(available).actions[0][1]["target"] == ["att.Roll", "ahr2.Roll", "nkf1.Roll"]


def test_dataflash_battery_fields_that_read_zero_for_the_whole_log_are_missing(erle):
    curr = erle["curr"]  # a voltage sensor, no current sensor
    assert curr["Curr"].isna().all() and curr["CurrTot"].isna().all()
    assert curr["Volt"].notna().all() and curr["Volt"].iloc[0] == pytest.approx(5.9514, abs=1e-4)
    assert set(curr.attrs["no_value"]) == {"Curr", "CurrTot"}


@pytest.mark.skipif(not NO_GPS.exists(), reason=f"{NO_GPS} not found")
def test_a_log_with_no_gps_and_no_battery_sensor():
    t = load_flight_file(NO_GPS, topics=["curr", "ekf1", "att"])
    assert t["curr"][["Volt", "Curr", "Vcc", "CurrTot"]].isna().all().all()
    assert t["curr"]["ThrOut"].notna().all()  # the throttle is a reading, 0 or not
    fit, reasons = applicable(load_configurations(QUICK, check_topics=False), with_phases(t), "25-9-2014_1")
    # no GPS, AHR2 or POS message (position.lat: not in the log) and EKF1 held at 0: the reason given is
    # the one that says most
    assert len(fit) == 30 and reasons == {"position.x constant for the whole flight (ekf1.PN = 0)": 36}
    available = input_fields([listen_view(t)])
    assert available["ekf1"].constant["PN"] == 0.0  # the EKF never ran: its position is held at 0
    from scart_bench.generator.scart.meanings import resolve_target

    with pytest.raises(ScenarioError, match=r"position constant for the whole flight \(ekf1.PN = 0 and 1 more\)"):
        resolve_target("position", available, "here")


def test_mavlink_no_value_markers_are_missing_values(tmp_path):
    pytest.importorskip("pymavlink")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    enc = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    frames = []
    for k in range(5):
        t = 1_700_000_000_000_000 + 100_000 * k
        frames += [(t, mav.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3)),
                   (t + 1, mav.MAVLink_battery_status_message(0, 0, 0, 2500, [16000, 15900] + [65535] * 8, -1,
                                                              -1, -1, 80)),
                   (t + 2, mav.MAVLink_gps_raw_int_message(k, 3, 473977420, 85455940, 488000, 65535, 65535,
                                                           65535, 65535, 255))]
    (tmp_path / "f.tlog").write_bytes(b"".join(struct.pack(">Q", t) + m.pack(enc) for t, m in frames))
    t = load_flight_file(tmp_path / "f.tlog")
    bat = t["battery_status"]
    assert bat["voltages_0"].iloc[0] == 16.0 and bat["voltages_1"].iloc[0] == 15.9
    assert bat[[f"voltages_{k}" for k in range(2, 10)]].isna().all().all()  # unused cells: not 65.535 V
    assert bat["current_battery"].isna().all() and bat["battery_remaining"].iloc[0] == 0.8
    gps = t["gps_raw_int"]
    assert gps[["eph", "epv", "vel", "cog", "satellites_visible"]].isna().all().all()
    assert gps["lat"].iloc[0] == 47.397742
    assert bat.attrs["no_value"]["voltages_2"] == 5
