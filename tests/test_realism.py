"""Realism against real PX4 logs: the realism script's figures, calibrated noise, GPS accuracy levels."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from perf import realism
from scart_bench.cli.main import main
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.params import GPS_ACCURACY, MissionParams, SensorParams, with_gps_accuracy
from scart_bench.generator.profiles import PROFILES
from scart_bench.generator.telemetry.tables import flight_views

ULOGS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ulog"
RFLYMAD = ULOGS / "rflymad_TestCase_1_1000000000.ulg"
HOVER = FlightConfig(mission=MissionParams(takeoff_hold_s=10.0, max_duration_s=30.0))  # arm by 12 s, climb, hover


@pytest.fixture(scope="module")
def hover_flights():
    """Two short flights per GPS accuracy level that take off and hover (one batch per level)."""
    out = {}
    for level in GPS_ACCURACY:
        batch = simulate([11, 12], with_gps_accuracy(HOVER, level))
        out[level] = [realism.from_tables(f"{level}-{i}", flight_views(batch, i, ())[1]) for i in range(2)]
    return out


def _need_log():
    if not RFLYMAD.exists():
        pytest.skip(f"{RFLYMAD} is not here")


def test_rflymad_log_figures_are_read_from_its_own_topics():
    _need_log()
    f = realism.figures(realism.read_ulog(RFLYMAD))
    assert 150 < f["imu rate Hz"][0] < 260 and f["imu jitter CV"][0] > 0.1  # sensor_combined, jittery
    assert 8 < f["gps rate Hz"][0] < 12 and f["gps first msg s"][0] > 2  # GPS starts late
    assert f["gyro z std rad/s"][1] == "hover" and 0.001 < f["gyro z std rad/s"][0] < 0.01
    assert 0.2 < f["gps eph m"][0] < 0.5
    # the hover throttle of its vehicle (actuator_controls_0), its PWM outputs at 10 Hz
    assert f["hover thrust 0-1"][1] == "hover" and 0.2 < f["hover thrust 0-1"][0] < 0.35
    assert 9 < f["actuators rate Hz"][0] < 11


def test_a_log_without_sensor_combined_falls_back_on_related_topics():
    _need_log()
    data = realism.ulog_topics(RFLYMAD)
    for topic in ("sensor_combined", "vehicle_gps_position", "vehicle_air_data"):
        del data[topic]
    f = realism.figures(realism.from_ulog_topics("partial", data))
    assert 0 < f["gyro z std rad/s"][0] < 0.02  # from vehicle_angular_velocity
    assert 0 < f["acc x std m/s2"][0] < 0.2  # from vehicle_acceleration
    assert 0 < f["baro alt std m"][0] < 1 and 0.5 < f["baro rate Hz"][0] < 2  # sensor_baro (logged at 1 Hz)
    assert 0.5 < f["gps rate Hz"][0] < 2 and f["gps eph m"][0] > 0  # sensor_gps
    f = realism.figures(realism.from_ulog_topics("empty", {}))
    assert all(math.isnan(v) for v, _ in f.values())


def test_generated_hover_noise_is_within_the_real_logs_range(hover_flights):
    figs = [realism.figures(f) for f in hover_flights["simulator"]]
    for f in figs:
        assert f["gyro z std rad/s"][1] == "hover"
        # the RflyMAD SIL log at hover: gyro z 0.0034 rad/s, accelerometer x/y 0.035/0.032 m/s^2
        assert 0.002 < f["gyro z std rad/s"][0] < 0.0055
        assert 0.015 < f["acc y std m/s2"][0] < 0.055
        # gyro x/y 0.0064/0.0059 rad/s: the vehicle's roll and pitch jitter at hover, 8-9x the log's
        # before the estimator's output predictor, about 1.3-1.45x since defaults 4 (docs/realism.md;
        # the median over more flights is checked against 1.5x below)
        assert f["gyro x std rad/s"][0] < 3 * 0.0064 and f["gyro y std rad/s"][0] < 3 * 0.0059
        assert 0.0006 < f["mag z std gauss"][0] < 0.0035  # the SITL logs: 0.0007-0.0021
    assert SensorParams().accel_noise_density < 0.002  # calibrated, not Gazebo's 0.004


@pytest.fixture(scope="module")
def sil_ratios():
    """Median figure of 6 default flights with a 12 s hover over the RflyMAD SIL log's, per sensor profile."""
    _need_log()
    log = realism.figures(realism.read_ulog(RFLYMAD))
    out = {}
    for profile in ("gazebo", "rflymad"):
        figs = [realism.figures(f) for f in realism.generated_flights(6, sensor_profile=profile)]
        out[profile] = {k: np.nanmedian([f[k][0] for f in figs]) / log[k][0] for k in log
                        if k.split()[0] in ("gyro", "acc", "mag", "baro") and "std" in k}
    return out


def test_gyro_x_y_at_hover_within_1_5x_of_the_sil_log(sil_ratios):
    """Issue 34's floor: default flights' roll and pitch rate noise at still hover, vs the SIL log's."""
    r = sil_ratios["gazebo"]
    assert 1 / 1.5 < r["gyro x std rad/s"] < 1.5 and 1 / 1.5 < r["gyro y std rad/s"] < 1.5, r


def test_the_rflymad_sensor_profile_puts_every_axis_within_1_5x_of_its_log(sil_ratios):
    """gyro, accelerometer and magnetometer x/y/z and the baro altitude; the default (gazebo) profile's
    baro is 3x the SIL log's, as the Gazebo SITL and hardware logs' are."""
    r = sil_ratios["rflymad"]
    assert len(r) == 10
    outside = {k: round(v, 2) for k, v in r.items() if not 1 / 1.5 < v < 1.5}
    assert not outside, outside
    assert sil_ratios["gazebo"]["baro alt std m"] > 2.0


def test_generate_refuses_an_unknown_sensor_profile(tmp_path, capsys):
    out = tmp_path / "ds"
    assert main(["generate", "--flights", "1", "--normal-only", "--sensor-profile", "sil", "--out", str(out)]) == 2
    assert "--sensor-profile 'sil': expected one of gazebo, rflymad" in capsys.readouterr().err
    assert not out.exists()


def test_gps_accuracy_levels_report_what_they_name(hover_flights):
    sim = np.median([realism.figures(f)["gps eph m"][0] for f in hover_flights["simulator"]])
    rr = [realism.figures(f) for f in hover_flights["real_receiver"]]
    assert 0.2 < sim < 0.5
    for f in rr:  # eph/epv ~2.8/5.9 m at 12 satellites, scaled by 12 / satellites (8-16)
        assert 2.0 < f["gps eph m"][0] < 4.3 and 4.3 < f["gps epv m"][0] < 9.0
    spec = GPS_ACCURACY["real_receiver"]["sensors"]
    assert math.hypot(spec["gps_noise_h"], spec["gps_bias_h"]) == pytest.approx(2.8, abs=0.05)
    assert math.hypot(spec["gps_noise_v"], spec["gps_bias_v"]) == pytest.approx(5.9, abs=0.05)


def test_real_receiver_flights_still_fly_the_mission():
    cfg = with_gps_accuracy(FlightConfig(mission=MissionParams(max_duration_s=50.0)), "real_receiver")
    batch = simulate([11, 12, 13], cfg)
    for i in range(3):
        nav, _ = flight_views(batch, i, ())
        assert nav["setpoint"]["seq"].max() >= 2  # it got past the first corner on fused GPS


def test_every_profile_names_a_gps_accuracy_level():
    for p in PROFILES.values():
        assert p.gps_accuracy in GPS_ACCURACY
        # the sensors and the estimator are the defaults at the profile's GPS level (the profile's
        # mission mix and airframes are its own: docs/missions.md)
        expected = with_gps_accuracy(FlightConfig(), p.gps_accuracy)
        assert p.flight_config().sensors == expected.sensors
        assert p.flight_config().estimator == expected.estimator
    rr = dataclasses.replace(PROFILES["quick"], gps_accuracy="real_receiver").flight_config()
    assert rr.sensors.gps_bias_h == GPS_ACCURACY["real_receiver"]["sensors"]["gps_bias_h"]
    with pytest.raises(ValueError, match="expected one of simulator, real_receiver"):
        with_gps_accuracy(FlightConfig(), "perfect")


def test_generate_refuses_an_unknown_gps_accuracy(tmp_path, capsys):
    out = tmp_path / "ds"
    assert main(["generate", "--flights", "1", "--normal-only", "--gps-accuracy", "perfect", "--out", str(out)]) == 2
    assert "--gps-accuracy 'perfect': expected one of simulator, real_receiver" in capsys.readouterr().err
    assert not out.exists()


def test_table_puts_generated_and_logs_side_by_side_with_ratios(hover_flights):
    gen = hover_flights["simulator"]
    log = realism.Flight("some.ulg", times={"imu": np.arange(0, 2, 0.005)})
    text = realism.table(gen, [log])
    header, _, *rows = text.splitlines()
    assert "generated (n=2)" in header and "some" in header and "gen/log" in header
    imu = next(r for r in rows if r.startswith("imu rate Hz"))
    assert imu.split()[-1] == "0.25"  # 50 Hz generated vs 200 Hz
    md = realism.table(gen, [log], markdown=True)
    assert md.splitlines()[1].startswith("|---")


def test_every_axis_is_a_row_of_the_table(hover_flights):
    text = realism.table(hover_flights["simulator"], [])
    for sensor, unit in (("gyro", "rad/s"), ("acc", "m/s2"), ("mag", "gauss")):
        for axis in "xyz":
            assert any(r.startswith(f"{sensor} {axis} std {unit}") for r in text.splitlines()), (sensor, axis)
    assert "baro alt std m" in text


def test_realism_reads_a_generated_dataset_and_a_log_folder(tmp_path, capsys):
    from scart_bench.generator.generate import generate_dataset

    out = generate_dataset("quick", tmp_path / "ds", n_normal=2, with_attacks=False, uorb=True,
                           config=FlightConfig(mission=MissionParams(max_duration_s=25.0)))
    for view in ("simulator", "uorb"):
        flights = realism.dataset_flights(out, 5, view)
        assert len(flights) == 2
        f = realism.figures(flights[0])
        # realistic timing (the link's 50 Hz IMU at the ArduCopter logs' CV ~0.05, the uORB view's
        # 250 Hz rows at the SIL log's 0.39), GPS at its fix
        assert f["imu jitter CV"][0] > 0.03 and f["gps first msg s"][0] > 2.5
        assert np.isfinite(f["gyro x std rad/s"][0]) and np.isfinite(f["baro alt std m"][0])
    _need_log()
    assert realism.main(["--dataset", str(out), "--logs", str(ULOGS), "--flights", "2"]) == 0
    text = capsys.readouterr().out
    assert "generated (n=2)" in text and "rflymad_TestCase_1_100" in text and "mag z std gauss" in text


def test_two_sample_auc_is_near_half_for_alike_flights_and_one_for_different_ones():
    rng = np.random.default_rng(0)

    def flights(n, jitter, noise):
        out = []
        for i in range(n):
            t = np.cumsum(0.02 * (1 + jitter * rng.standard_normal(2000)).clip(0.1))
            out.append(realism.Flight(f"f{i}", times={"imu": t, "gps": t[::5], "baro": t[::2]},
                                      gyro_x=(t, noise * rng.standard_normal(t.size))))
        return out

    a, b = flights(12, 0.3, 0.01), flights(6, 0.3, 0.01)
    assert 0.2 < realism.two_sample_auc(a, b, repeats=5) < 0.8
    c = flights(6, 0.02, 0.05)
    assert realism.two_sample_auc(a, c, repeats=5) > 0.95
