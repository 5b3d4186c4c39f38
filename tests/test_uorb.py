"""The uORB view: a generated flight with PX4's topic names, fields and units, scored like a real ULog."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.cli.main import main
from scart_bench.dataset import DatasetError, open_dataset
from scart_bench.detectors.statistical import Statistical
from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.params import STEP_US
from scart_bench.generator.telemetry.tables import flight_views, uorb_stream_tables
from scart_bench.generator.telemetry.uorb import (
    OMITTED,
    SITE_DEPENDENT,
    TABLE_TOPICS,
    UORB_TOPICS,
    uorb_table,
    uorb_view,
)

SHARED = Path(__file__).parents[1].parent / "shared/data/ulog"
RFLYMAD = SHARED / "rflymad_TestCase_1_1000000000.ulg"
needs_rflymad = pytest.mark.skipif(not RFLYMAD.exists(), reason=f"shared RflyMAD log not found in {SHARED}")

LABELS = ["Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind"]
#: The issue's topics (the RflyMAD log has vehicle_gps_position at 10 Hz; its sensor_gps is logged at 1 Hz).
EXPECTED_TOPICS = ("sensor_combined", "vehicle_attitude", "vehicle_local_position", "vehicle_global_position",
                   "vehicle_gps_position", "vehicle_air_data", "battery_status")
#: and, in a flight flown with the uORB view, the actuators (the hover throttle)
ACTUATOR_TOPICS = ("actuator_controls_0", "actuator_outputs")
#: The importer's fields for the RflyMAD log that the view leaves out: written out here, so that a
#: field dropped from the view without saying why fails this test (reasons: generator.telemetry.uorb.OMITTED).
_BATTERY_SMART = ("discharged_mah scale temperature cell_count max_cell_voltage_delta average_power available_energy "
                  "remaining_capacity design_capacity nominal_voltage capacity cycle_count run_time_to_empty "
                  "average_time_to_empty serial_number manufacture_date state_of_health max_error interface_error "
                  "average_time_to_full over_discharge_count connected source priority id is_powering_off "
                  "warning").split() + [f"voltage_cell_v_{i}" for i in range(14)]
DOCUMENTED_OMISSIONS = {
    "sensor_combined": {"accelerometer_clipping"},
    "vehicle_attitude": {"timestamp_sample", "delta_q_reset_0", "delta_q_reset_1", "delta_q_reset_2",
                         "delta_q_reset_3", "quat_reset_counter"},
    "vehicle_local_position": set(
        "timestamp_sample ref_timestamp delta_xy_0 delta_xy_1 delta_z delta_vxy_0 delta_vxy_1 delta_vz delta_heading "
        "xy_reset_counter z_reset_counter vxy_reset_counter vz_reset_counter heading_reset_counter xy_valid z_valid "
        "v_xy_valid v_z_valid xy_global z_global vxy_max vz_max hagl_min hagl_max z_deriv ax ay az heading eph epv "
        "evh evv dist_bottom dist_bottom_valid dist_bottom_sensor_bitfield".split()),
    "vehicle_global_position": set("timestamp_sample alt_ellipsoid delta_alt lat_lon_reset_counter alt_reset_counter "
                                   "dead_reckoning eph epv terrain_alt terrain_alt_valid".split()),
    "vehicle_gps_position": set("time_utc_usec timestamp_time_relative alt_ellipsoid s_variance_m_s c_variance_rad "
                                "hdop vdop noise_per_ms jamming_indicator jamming_state vel_ned_valid selected heading "
                                "heading_offset".split()),
    "vehicle_air_data": {"timestamp_sample", "baro_device_id"},
    "battery_status": {"voltage_filtered_v", "current_filtered_a", "current_average_a", *_BATTERY_SMART},
    "actuator_controls_0": {"timestamp_sample", "control_0", "control_1", "control_2", "control_4", "control_5",
                            "control_6", "control_7"},
    "actuator_outputs": {f"output_{k}" for k in range(4, 16)},
}


@pytest.fixture(scope="module")
def flown_view():
    """A default flight (PX4 start, take-off, hover) flown with the uORB view: (simulator view, uORB view)."""
    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.params import MissionParams

    batch = simulate([5], FlightConfig(mission=MissionParams(max_duration_s=30.0), uorb=True))
    _, sim = flight_views(batch, 0)
    return sim, uorb_view(sim, uorb_stream_tables(batch, 0))


@pytest.fixture(scope="module")
def rflymad() -> dict[str, pd.DataFrame]:
    return load_flight_file(RFLYMAD, topics=list(EXPECTED_TOPICS + ACTUATOR_TOPICS))


@pytest.fixture(scope="module")
def attacked_views(attacked_fleet):
    """Per flight of the shared attacked fleet (normal, link spoof, sensor GPS jump, sensor drift):
    (navigator view, simulator view, uORB view, windows)."""
    batch, layer, k = attacked_fleet
    out = {}
    for name, i in k.items():
        windows = layer.labelled_windows(i, (int(batch.exit_step[i]) + 1) * STEP_US)
        nav, sim = flight_views(batch, i, windows)
        out[name] = (nav, sim, uorb_view(sim), windows)
    return out


def _fields(df: pd.DataFrame) -> set[str]:
    return set(df.columns) - {"Timestamp", *LABELS}


@needs_rflymad
def test_topics_and_fields_are_the_importers_for_a_px4_ulog(attacked_views, flown_view, rflymad):
    assert tuple(attacked_views["normal"][2]) == EXPECTED_TOPICS  # made of the simulator view alone
    view = flown_view[1]
    assert tuple(view) == EXPECTED_TOPICS + ACTUATOR_TOPICS
    assert {t: set(o) for t, o in OMITTED.items()} == DOCUMENTED_OMISSIONS
    for topic in EXPECTED_TOPICS + ACTUATOR_TOPICS:
        real = _fields(rflymad[topic])
        ours = _fields(view[topic])
        assert ours <= real, f"{topic}: fields PX4 does not have: {ours - real}"
        assert real - ours == DOCUMENTED_OMISSIONS[topic], topic
        assert list(view[topic].columns[:4]) == ["Timestamp", *LABELS]
        assert all(view[topic][f].dtype == np.float64 for f in ours)


@needs_rflymad
def test_units_are_px4s(attacked_views, rflymad):
    view = attacked_views["normal"][2]
    sc, real_sc = view["sensor_combined"], rflymad["sensor_combined"]
    # specific force at hover, body z down: about -g in both
    for table in (sc, real_sc):
        assert -10.3 < table["accelerometer_m_s2_2"].median() < -9.3
    q = view["vehicle_attitude"][["q_0", "q_1", "q_2", "q_3"]].to_numpy()
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    air, real_air = view["vehicle_air_data"], rflymad["vehicle_air_data"]
    for table in (air, real_air):
        assert (table["baro_pressure_pa"].between(8e4, 1.1e5)).all()  # Pa, not hPa
        assert (table["rho"].between(1.0, 1.3)).all()  # kg/m^3
        assert (table["baro_temp_celcius"].between(-10, 50)).all()
    # baro altitude AMSL from the pressure by the standard atmosphere, as PX4 computes it (the log's too)
    for table in (air, real_air):
        std_atm = (1 - (table["baro_pressure_pa"] / 101325.0) ** (1 / 5.25588)) / 2.25577e-5
        assert np.allclose(table["baro_alt_meter"], std_atm, atol=0.5)
    lp = view["vehicle_local_position"]
    assert lp["z"].min() < -5  # NED: up is negative z
    gp, gps = view["vehicle_global_position"], view["vehicle_gps_position"]
    for table in (gp, gps, rflymad["vehicle_global_position"], rflymad["vehicle_gps_position"]):
        assert table["lat"].between(-90, 90).all() and table["lon"].between(-180, 180).all()
        assert table["lat"].std() < 0.01  # degrees, one flight's few hundred metres
    # global altitude AMSL = the local position's origin altitude minus z
    lpi = lp.set_index("Timestamp")
    common = np.intersect1d(gp["Timestamp"], lp["Timestamp"])
    alt = gp.set_index("Timestamp").loc[common, "alt"]
    assert np.allclose(alt, lpi.loc[common, "ref_alt"] - lpi.loc[common, "z"])
    assert np.allclose(gps["vel_m_s"], np.hypot(gps["vel_n_m_s"], gps["vel_e_m_s"]))
    assert gps["cog_rad"].between(0, 2 * np.pi).all()
    bat = view["battery_status"]
    assert bat["voltage_v"].between(12, 17).all() and bat["remaining"].between(0, 1).all()


def _rate(ts: np.ndarray) -> float:
    return (len(ts) - 1) * 1e6 / (ts[-1] - ts[0])


def _cv(ts: np.ndarray) -> float:
    dt = np.diff(ts)
    return float(dt.std() / dt.mean())


def test_rates_are_the_recorded_ones(attacked_views, flown_view):
    view = attacked_views["normal"][2]  # made of the simulator view: its IMU rows (50 Hz), other topics on their clocks
    for name in EXPECTED_TOPICS:
        want = UORB_TOPICS[name].rate_from(False)
        assert abs(_rate(view[name]["Timestamp"].to_numpy()) - want) <= 0.1 * want, name
    assert UORB_TOPICS["sensor_combined"].rate_from(False) == 50.0  # one 250 Hz IMU sample per row: not resampled
    for name, table in flown_view[1].items():  # flown with the uORB view: the streams' rates
        if name != "sensor_combined":  # its logger loses rows: below
            want = UORB_TOPICS[name].rate_hz
            assert abs(_rate(table["Timestamp"].to_numpy()) - want) <= 0.1 * want, name


@needs_rflymad
def test_a_default_flight_has_a_px4_logs_rates_and_jitter_in_the_uorb_view(flown_view, rflymad):
    """IMU at 175-226 Hz with 4 and 8 ms intervals (the shared logs: 187-200 Hz, jitter CV 0.35-0.87),
    attitude at 20 Hz and local position at 10 Hz on their own clocks, jittered about as the SIL log."""
    view = flown_view[1]
    imu = view["sensor_combined"]["Timestamp"].to_numpy()
    assert 175 < _rate(imu) < 226 and 175 < _rate(rflymad["sensor_combined"]["Timestamp"].to_numpy()) < 226
    assert 0.3 < _cv(imu) < 0.5  # the SIL log: 0.386
    dt_ms = np.round(np.diff(imu) / 1000)
    assert np.mean((dt_ms == 4) | (dt_ms == 8)) > 0.5
    for name, hz in (("vehicle_attitude", 20.0), ("vehicle_local_position", 10.0), ("actuator_outputs", 10.0)):
        ts = view[name]["Timestamp"].to_numpy()
        real = rflymad[name]["Timestamp"].to_numpy()
        assert abs(_rate(ts) - hz) < 0.5 and abs(_rate(real) - hz) < 0.5, name
        assert 0.5 * _cv(real) < _cv(ts) < 2.0 * _cv(real), name
    assert not np.array_equal(view["vehicle_attitude"]["Timestamp"], view["vehicle_local_position"]["Timestamp"][:5])


def test_the_imu_rows_are_the_samples_the_estimator_received(flown_view):
    """sensor_combined at 200 Hz holds the 250 Hz samples themselves: every 50 Hz highres_imu row of the
    simulator view is one of them (same values), none is interpolated or repeated."""
    sim, view = flown_view
    imu = view["sensor_combined"]
    ours = set(np.round(imu["gyro_rad_0"].to_numpy(), 12))
    theirs = np.round(sim["highres_imu"]["xgyro"].to_numpy(), 12)
    assert np.mean([g in ours for g in theirs]) > 0.7  # the rest fall on the 250 Hz samples the 200 Hz rows skip
    assert imu["gyro_rad_0"].nunique() == len(imu)


@needs_rflymad
def test_hover_throttle_and_motor_outputs_are_in_the_view(flown_view, rflymad):
    """The thrust demand (0-1) and the motors' PWM as PX4 logs them: disarmed 900 us and 0 on the
    ground, at hover the Iris's thrust-to-weight (about 0.5; the SIL log's vehicle: 0.26), and the
    outputs 1000 + 1000 x the thrust fraction, as in the SIL log (1263 us at 0.264)."""
    view = flown_view[1]
    ctl, out = view["actuator_controls_0"], view["actuator_outputs"]
    assert ctl["control_3"].iloc[0] == 0 and (out.iloc[0][[f"output_{k}" for k in range(4)]] == 900).all()
    hover = ctl["control_3"].iloc[-40:]  # the last 2 s: in the hover hold
    assert 0.45 < hover.median() < 0.6
    pwm = out[[f"output_{k}" for k in range(4)]].iloc[-20:].to_numpy()
    assert (out["noutputs"] == 4).all()
    assert abs((pwm.mean() - 1000) / 1000 - hover.median()) < 0.03  # the motors share the collective thrust
    real = rflymad["actuator_controls_0"]["control_3"]
    real_pwm = rflymad["actuator_outputs"]["output_0"]
    assert abs(real_pwm.median() - (1000 + 1000 * real.median())) < 10


def test_a_sensor_attack_shows_and_a_link_attack_does_not_reach_the_flight_controller(attacked_views):
    normal = attacked_views["normal"][2]["vehicle_gps_position"]
    # sensor GPS jump: the receiver's output the flight controller gets is altered, and labelled
    _, _, jump, windows = attacked_views["jump"]
    g = jump["vehicle_gps_position"]
    assert windows and g["Is_Anomaly"].sum() > 0
    inside = g["Is_Anomaly"].to_numpy() == 1
    assert (g["Anomaly_Kind"][inside] == "attack").all()
    before = g["Timestamp"] < windows[0][0]
    assert np.array_equal(g.loc[before, "lat"], normal.loc[before, "lat"])  # one seed: equal before the attack
    east = (g.loc[inside, "lon"] - normal.loc[inside, "lon"]) * np.deg2rad(1) * 6371000 * np.cos(np.deg2rad(47.4))
    assert 45 < east.median() < 55  # the 50 m jump east
    # link GPS spoofing: labelled in the uORB view too, but its values are the flight controller's
    # (the simulator view's), not the spoofed ones the navigator received
    nav, sim, spoof, windows = attacked_views["spoof"]
    g = spoof["vehicle_gps_position"]
    inside = g["Is_Anomaly"].to_numpy() == 1
    assert inside.any()
    assert np.array_equal(g["lat"], sim["gps_raw_int"]["lat"])
    assert np.abs(g.loc[inside, "lat"] - nav["gps_raw_int"].loc[inside, "lat"]).max() > 1e-4  # spoofed > 10 m
    assert np.array_equal(g["Is_Anomaly"], sim["gps_raw_int"]["Is_Anomaly"])


def test_the_view_is_deterministic(attacked_fleet, attacked_views):
    batch, _, k = attacked_fleet
    sim = attacked_views["jump"][1]
    again = uorb_view({t: df.copy() for t, df in sim.items()})
    for name, df in attacked_views["jump"][2].items():
        pd.testing.assert_frame_equal(df, again[name])


@needs_rflymad
def test_a_detector_fitted_on_generated_uorb_views_scores_the_real_log(normal_fleet, rflymad):
    assert TABLE_TOPICS == EXPECTED_TOPICS  # the actuators, which a csv-mode flight lacks, stay out of the table
    train = [uorb_table(uorb_view(flight_views(normal_fleet, i)[1])) for i in range(4)]
    det = Statistical(window=25).fit(train)
    real = uorb_table(rflymad)
    assert set(det.columns_) <= set(real.columns)
    assert {c.split(".")[0] for c in det.columns_} >= {"sensor_combined", "vehicle_attitude", "vehicle_air_data"}
    scores = det.score(real)
    assert scores.shape == (len(real),) and np.isfinite(scores).all()
    # the real log's other topics and fields are not in the table
    assert len(real.columns) == len(train[0].columns)
    # where the flight was flown (Zurich vs the log's site) is not behaviour: without those columns
    # far fewer of the real log's rows are alarms
    site_free = Statistical(window=25).fit(train, exclude=list(SITE_DEPENDENT))
    assert not any(c.endswith((".lat", ".lon", ".alt")) or c.startswith("vehicle_air_data") for c in site_free.columns_)
    assert np.mean(site_free.score(real) > 1) < np.mean(scores > 1)


def test_generate_uorb_writes_and_reads_the_view(tmp_path, capsys):
    args = ["generate", "--flights", "2", "--normal-only", "--uorb", "--seed", "4", "--timing", "realistic"]
    out, again = tmp_path / "ds", tmp_path / "again"
    assert main([*args, "--out", str(out)]) == 0
    assert main([*args, "--out", str(again)]) == 0
    ds = open_dataset(out)
    for fid in ds.manifest["flight_id"]:  # same seed and options: the same uORB tables
        for t in EXPECTED_TOPICS:
            pd.testing.assert_frame_equal(ds.topic(fid, t, view="uorb"), open_dataset(again).topic(fid, t, view="uorb"))
    fid = ds.manifest["flight_id"].iloc[0]
    assert ds.topics(fid, "uorb") == sorted(EXPECTED_TOPICS + ACTUATOR_TOPICS)
    att = ds.topic(fid, "vehicle_attitude", view="uorb")
    assert list(att.columns) == ["Timestamp", *LABELS, "q_0", "q_1", "q_2", "q_3"]
    assert 19 < _rate(att["Timestamp"].to_numpy()) < 21
    # the estimator's attitude: what the simulator view's attitude (50 Hz, Euler angles) says at the same time
    sim = {t: ds.topic(fid, t, view="simulator") for t in ("attitude", "highres_imu", "gps_raw_int")}
    from_sim = uorb_view(sim)["vehicle_attitude"]
    at = np.searchsorted(from_sim["Timestamp"], att["Timestamp"]).clip(0, len(from_sim) - 1)
    near = np.abs(from_sim["Timestamp"].to_numpy()[at] - att["Timestamp"].to_numpy()) < 1000
    q, q_sim = att[["q_0", "q_1", "q_2", "q_3"]].to_numpy(), from_sim[["q_0", "q_1", "q_2", "q_3"]].to_numpy()[at]
    assert near.sum() > 10 and np.abs(np.abs(np.sum(q * q_sim, axis=1))[near] - 1).max() < 1e-3
    # realistic timing: the simulator view's message times (GPS from its fix), kept
    gps = ds.topic(fid, "vehicle_gps_position", view="uorb")
    assert gps["Timestamp"].iloc[0] >= 3_000_000
    assert np.array_equal(gps["Timestamp"], sim["gps_raw_int"]["Timestamp"])
    assert ds.config(fid)["flight_config"]["uorb"] is True
    # without the option there is no uORB view, and asking for it says so
    plain = tmp_path / "plain"
    assert main(["generate", "--out", str(plain), "--flights", "1", "--normal-only", "--seed", "4"]) == 0
    ds = open_dataset(plain)
    with pytest.raises(DatasetError, match="no uorb view.*--uorb"):
        ds.topics(ds.manifest["flight_id"].iloc[0], "uorb")
    with pytest.raises(DatasetError, match="view 'bogus'"):
        ds.topic(ds.manifest["flight_id"].iloc[0], "attitude", view="bogus")


def test_a_flight_without_a_uorb_topic_is_refused_naming_it(attacked_views):
    view = dict(attacked_views["normal"][2])
    del view["vehicle_air_data"]
    with pytest.raises(DatasetError, match="uORB topic 'vehicle_air_data' missing"):
        uorb_table(view)
    view = attacked_views["normal"][2] | {"battery_status": attacked_views["normal"][2]["battery_status"].drop(
        columns=["remaining"])}
    with pytest.raises(DatasetError, match=r"'battery_status': field\(s\) \['remaining'\] missing"):
        uorb_table(view)


def test_baro_is_on_its_own_20hz_clock_with_the_log_rates_jitter():
    """vehicle_air_data at ~20 Hz (the shared logs: 18.3-20 Hz), not on every IMU row; its interval
    jitter is between the SIL log's and the CubeOrange's (0.025-0.2), and the values are the baro's."""
    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.params import MissionParams

    _, sim = flight_views(simulate([31], FlightConfig(mission=MissionParams(max_duration_s=20.0))), 0)
    view = uorb_view(sim)
    air, imu = view["vehicle_air_data"]["Timestamp"].to_numpy(), view["sensor_combined"]["Timestamp"].to_numpy()
    rate = (len(air) - 1) * 1e6 / (air[-1] - air[0])
    assert 19.0 < rate < 21.0 and len(imu) > 2 * len(air)
    dt = np.diff(air)
    assert 0.02 < dt.std() / dt.mean() < 0.3
    assert np.isin(air, imu).all(), "the latest baro sample of a flight-controller row"
