"""Each vehicle's vibration (SensorParams.vibration_levels) and rocking (MissionParams.rocking_levels), issue 47
acceptance 3. The vibration: a flight shakes its logged IMU as
the vehicle whose log its mission came from (the ArduCopter fleet's vehicles differ by 10-1000x in IMU vibration
power); the rough vehicles' extra is high-frequency, in the logged IMU and not in the flight controller's loop; the
same in both engines; off by default; `--like` fits a level per log; a profile TOML's bad levels are refused naming
the key. The rocking: a white angular acceleration on the airborne body from the flight's own stream, the same in both
engines, moving the true attitude and the gyro with it; off by default; fitted per log to its gyro's noise."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import bad_profile_key_is_refused, kernel_matches_numpy

from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.params import DT, MissionParams, SensorParams
from scart_bench.generator.physics.sensors import Sensors, flight_vibration_levels, logged_imu

ROUGH = (10.0, 10.0, 10.0, 4.0, 4.0, 4.0)


def test_a_rough_vehicle_s_logged_imu_shakes_that_many_times_as_hard_and_its_controller_does_not_see_it():
    """Hovering motors, white vibration, a level of 10 on the accelerometer and 4 on the gyro: the logged samples'
    sample-to-sample noise is about 10x / 4x the fleet's, what the flight controller gets is the fleet's (level 1)."""
    params = SensorParams(accel_vibration=(0.05, 0.05, 0.1), gyro_vibration=(0.02, 0.02, 0.02),
                          vibration_levels=((1.0,) * 6, ROUGH))
    sensors = Sensors(params, DT)
    st = sensors.init_state(2, [np.random.default_rng(i) for i in range(2)])
    st.vibration_level = flight_vibration_levels(params.vibration_levels, [4, 7])  # seed 4: level 1, seed 7: ROUGH
    rng = np.random.default_rng(5)
    fc, log = [], []
    for _ in range(5000):
        acc, gyro = sensors.imu(st, np.zeros((2, 3)), np.zeros((2, 3)), np.broadcast_to(np.eye(3), (2, 3, 3)),
                                rng.standard_normal((2, 12)), np.ones(2))
        fc.append(np.hstack([acc, gyro]))
        log.append(np.hstack(logged_imu(st, acc, gyro)))
    fc, log = np.array(fc)[::5], np.array(log)[::5]  # a log's 50 Hz
    noise = lambda x: np.diff(x, axis=0).std(axis=0) / np.sqrt(2)  # noqa: E731
    np.testing.assert_allclose(noise(log[:, 0]), noise(fc[:, 0]), rtol=1e-12)  # level 1: the logged IMU is the loop's
    ratio = noise(log[:, 1]) / noise(log[:, 0])
    assert np.all((ratio[:3] > 8.0) & (ratio[:3] < 12.0)), ratio
    assert np.all((ratio[3:] > 3.0) & (ratio[3:] < 5.0)), ratio
    assert np.all(noise(fc[:, 1]) / noise(fc[:, 0]) < 1.2)  # the controller's samples are the fleet's


def test_the_kernel_shakes_as_the_numpy_reference_and_the_flight_flies_the_same_path():
    """Same seeds, same draws: every recorded message of the kernel within 1e-9 of the reference's with levels set;
    the rough flight's logged IMU differs from the same flight without levels, its flown path (truth) does not, and
    the flight at level 1 is the flight without levels."""
    sensors = SensorParams(gyro_vibration=(0.05, 0.05, 0.02), gyro_noise_cutoff_hz=3.0,
                           vibration_levels=((1.0,) * 6, ROUGH))
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=4.0), sensors=sensors)
    ker = kernel_matches_numpy(cfg, seeds=(4, 7))
    plain = simulate([4, 7], dataclasses.replace(cfg, sensors=dataclasses.replace(sensors, vibration_levels=())),
                     engine="kernel")
    imu, imu0 = ker.simulator["highres_imu"][1], plain.simulator["highres_imu"][1]
    np.testing.assert_array_equal(imu[0], imu0[0])
    assert not np.allclose(imu[1], imu0[1])
    np.testing.assert_array_equal(ker.simulator["truth"][1], plain.simulator["truth"][1])


def test_off_by_default():
    """No levels: every flight 1, and a built-in profile's recorded config has no vibration_levels key (so its
    datasets keep their bytes)."""
    from scart_bench.generator.plan import plan_generation

    assert SensorParams().vibration_levels == ()
    assert flight_vibration_levels((), [1, 2]) is None
    plan = plan_generation("quick", seed=3, n_normal=2)
    assert "vibration_levels" not in plan.config_dict["flight_config"]["sensors"]


def test_like_fits_a_level_per_log_from_its_noise_in_the_air():
    """A log whose accelerometer's sample-to-sample noise in the air is 10x the fleet's gets level 10 on it (within
    the cap), 1 on the gyro (at most 1: the rough vehicles' gyro excess is rocking), a quieter gyro its level below 1;
    a log without figures 1."""
    from scart_bench.generator.like.fit import VIBRATION_LEVEL_MAX, Figure, LogMeasure, vibration_levels

    figs = {f"white_hover_{s}_{a}": Figure(v, 8, "") for s, v in (("acc", 0.1), ("gyro", 0.02)) for a in "xyz"}
    rough, quiet, blank = LogMeasure("rough.bin", ""), LogMeasure("quiet.bin", ""), LogMeasure("blank.bin", "")
    rough.hover_white = {"acc_x": 1.0, "acc_y": 0.5, "acc_z": 100.0, "gyro_x": 0.2, "gyro_y": 0.2, "gyro_z": 0.2}
    quiet.hover_white = {"acc_x": 0.05, "acc_y": 0.1, "acc_z": 0.1, "gyro_x": 0.01, "gyro_y": 0.02, "gyro_z": 0.02}
    got = vibration_levels([rough, quiet, blank], figs)
    assert got["rough.bin"] == (10.0, 5.0, VIBRATION_LEVEL_MAX, 1.0, 1.0, 1.0)
    assert got["quiet.bin"] == (0.5, 1.0, 1.0, 0.5, 1.0, 1.0)
    assert got["blank.bin"] == (1.0,) * 6
    assert vibration_levels([rough], figs, ("acc",))["rough.bin"] == (1.0,) * 6  # a low-passed vibration: at most 1
    assert vibration_levels([quiet], figs, ("acc",))["quiet.bin"] == (0.5, 1.0, 1.0, 0.5, 1.0, 1.0)


def test_like_fits_a_rough_vehicle_s_yaw_gyro_above_the_fleet_s_as_high_frequency_vibration():
    """The gyro z (GYRO_HF_AXES) with the fleet's figure at 0.3x its low-passed vibration's per-sample sigma: a log at
    10x the fleet's sample-to-sample noise gets sqrt(1 + 99 x 0.3^2) (its high-frequency rest adds the log's noise
    beyond the fleet's in squares), one below the fleet's its plain level, x and y at most 1 as before; without the
    figure z at most 1 too."""
    from scart_bench.generator.like.fit import Figure, LogMeasure, vibration_levels

    figs = {f"white_hover_{s}_{a}": Figure(v, 8, "") for s, v in (("acc", 0.1), ("gyro", 0.02)) for a in "xyz"}
    rough, quiet = LogMeasure("rough.bin", ""), LogMeasure("quiet.bin", "")
    rough.hover_white = {"acc_x": 0.1, "acc_y": 0.1, "acc_z": 0.1, "gyro_x": 0.2, "gyro_y": 0.2, "gyro_z": 0.2}
    quiet.hover_white = {"acc_x": 0.1, "acc_y": 0.1, "acc_z": 0.1, "gyro_x": 0.02, "gyro_y": 0.02, "gyro_z": 0.01}
    got = vibration_levels([rough, quiet], figs, ("gyro",), {"gyro_z": 0.3})
    assert got["rough.bin"][:5] == (1.0,) * 5
    assert abs(got["rough.bin"][5] - np.sqrt(1.0 + 99.0 * 0.09)) < 1e-3
    assert got["quiet.bin"][5] == 0.5
    assert vibration_levels([rough], figs, ("gyro",))["rough.bin"][5] == 1.0


@pytest.mark.parametrize("value, expected", [
    ("[[1.0, 2.0]]", "sensors.vibration_levels[0]: expected a list of 6 values"),
    ("[[1.0, 1.0, 1.0, 1.0, 1.0, -2.0]]", "sensors.vibration_levels[0][5]: expected a number in [0, 1000]"),
    ("3.0", "sensors.vibration_levels: expected a list of lists of 6 numbers"),
])
def test_bad_vibration_levels_in_a_profile_exit_2_naming_the_key(tmp_path, capsys, value, expected):
    bad_profile_key_is_refused(tmp_path, capsys, "sensors", "vibration_levels", value, expected)


def test_a_profile_with_levels_reads_back():
    """A TOML's levels (lists of 6) become the config's tuple of 6-tuples."""
    import tempfile
    from pathlib import Path

    from scart_bench.generator.like.profile_file import read_profile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "p.toml"
        path.write_text('[profile]\nbase = "quick"\n\n[sensors]\nvibration_levels = [[1, 2, 3, 1, 1, 1], '
                        '[0.5, 0.5, 0.5, 1, 1, 1]]\n')
        levels = read_profile(path).config.sensors.vibration_levels
    assert levels == ((1.0, 2.0, 3.0, 1.0, 1.0, 1.0), (0.5, 0.5, 0.5, 1.0, 1.0, 1.0))


# -- each vehicle's rocking (MissionParams.rocking_levels) ---------------------------------------------------------------


def test_a_rocking_vehicle_moves_in_both_engines_alike_and_the_gyro_reads_the_motion():
    """A white angular acceleration of 30 rad/s^2 per step on roll and pitch: the kernel records every message within
    1e-9 of the numpy reference; the rocking flight's true attitude moves (truth differs) and its gyro's differences
    grow (over 3x), the flight at level 0 is the flight without levels (its own stream: no other draw moves)."""
    m = MissionParams(ground_phase=False, max_duration_s=6.0, rocking_levels=((0.0, 0.0, 0.0), (30.0, 30.0, 0.0)))
    cfg = FlightConfig(mission=m)
    ker = kernel_matches_numpy(cfg, seeds=(4, 7))
    plain = simulate([4, 7], dataclasses.replace(cfg, mission=dataclasses.replace(m, rocking_levels=())), engine="kernel")
    for topic in ("highres_imu", "truth", "attitude"):
        np.testing.assert_array_equal(ker.simulator[topic][1][0], plain.simulator[topic][1][0])
    assert not np.allclose(ker.simulator["truth"][1][1], plain.simulator["truth"][1][1])
    gyro, gyro0 = ker.simulator["highres_imu"][1][1][:, 3:5], plain.simulator["highres_imu"][1][1][:, 3:5]
    ratio = np.diff(gyro, axis=0).std(axis=0) / np.diff(gyro0, axis=0).std(axis=0)
    assert np.all(ratio > 3.0), ratio


def test_rocking_is_off_by_default():
    from scart_bench.generator.physics.vehicle import rocking_start
    from scart_bench.generator.plan import plan_generation

    assert MissionParams().rocking_levels == ()
    assert rocking_start([1, 2], ()) is None
    assert "rocking_levels" not in plan_generation("quick", seed=3, n_normal=2).config_dict["flight_config"]["mission"]


def test_like_fits_the_rocking_that_adds_the_log_s_gyro_noise_in_squares(monkeypatch):
    """Calibration flights with 0.03 rad/s of gyro noise without rocking and 0.05 at the reference level: a log at
    0.05 gets the reference level on x and y, one at the generated figure or below 0, the yaw 0 (not fitted)."""
    from scart_bench.generator.like import fit

    figs = iter([{f"white_gyro_{a}": 0.03 for a in "xyz"}, {f"white_gyro_{a}": 0.05 for a in "xyz"}])
    monkeypatch.setattr(fit, "calibration_figures", lambda config: next(figs))
    rough, quiet = fit.LogMeasure("rough.bin", ""), fit.LogMeasure("quiet.bin", "")
    rough.hover_white = {"gyro_x": 0.05, "gyro_y": 0.05, "gyro_z": 0.05}
    quiet.hover_white = {"gyro_x": 0.02, "gyro_y": 0.03, "gyro_z": 0.05}
    lines: list[str] = []
    got = fit.fit_rocking([rough, quiet], FlightConfig(), lines)
    assert got["rough.bin"] == (fit.ROCKING_REF[0], fit.ROCKING_REF[1], 0.0)
    assert got["quiet.bin"] == (0.0, 0.0, 0.0)
    assert len(lines) == 1 and "1 of 2 logs rock more" in lines[0]


@pytest.mark.parametrize("value, expected", [
    ("[[1.0, 2.0]]", "mission.rocking_levels[0]: expected a list of 3 values"),
    ("[[1.0, -1.0, 0.0]]", "mission.rocking_levels[0][1]: expected a number in [0, 1000]"),
])
def test_bad_rocking_levels_in_a_profile_exit_2_naming_the_key(tmp_path, capsys, value, expected):
    bad_profile_key_is_refused(tmp_path, capsys, "mission", "rocking_levels", value, expected)


def test_the_gyro_z_floor_above_5_hz_is_told_from_a_slow_yaw_motion():
    """The figure the gyro z's vibration is fitted on (fit.BAND_AXES): the std above 5 Hz of a 50 Hz series is a white
    noise's share there (sqrt(20 / 25) of its sigma) whatever a 1 Hz yaw motion 20x its size does, where the
    sample-to-sample noise grows with the motion; the fleet's figure is the still-hover logs' median, and a fleet log's
    gyro z floor lies below its sample-to-sample noise (its differences are a yaw motion's too)."""
    from scart_bench.generator.like.fit import (
        BAND_AXES,
        LogMeasure,
        _band_std,
        _noise_figures,
        fleet_figures,
        measure_log,
    )

    assert "gyro_z" in BAND_AXES
    rng = np.random.default_rng(0)
    t = np.arange(0, 60, 0.02)
    white = 0.01 * rng.standard_normal(len(t))
    moving = white + 0.2 * np.sin(2 * np.pi * 1.0 * t)
    seg = [(0.0, 60.0)]
    assert abs(_band_std(t, white, 50.0, seg) / (0.01 * np.sqrt(0.8)) - 1.0) < 0.1
    assert abs(_band_std(t, moving, 50.0, seg) / _band_std(t, white, 50.0, seg) - 1.0) < 0.05
    assert _noise_figures(t, moving, 50.0, seg)[1] > 1.2 * _noise_figures(t, white, 50.0, seg)[1]
    logs = []
    for v in (0.004, 0.006, 0.02):
        m = LogMeasure(f"{v}.bin", "")
        m.hover, m.hover_white, m.hover_band = {"gyro_z": 0.1}, {"gyro_z": 0.01}, {"gyro_z": v}
        logs.append(m)
    assert fleet_figures(logs)["band_hover_gyro_z"].value == 0.006
    m = measure_log(Path(__file__).parents[1].parent / "shared/data/dataflash/fleet/arducopter_10-11-2014_105.bin")
    assert 0.0 < m.hover_band["gyro_z"] < m.hover_white["gyro_z"], (m.hover_band, m.hover_white)
