"""The IMU's lever arm (SensorParams.imu_offset_m) and the rotors' downwash on the baro (SensorParams.baro_downwash_pa),
issue 47 acceptance 3: the accelerometer off the centre of gravity reads the rocking's angular acceleration with the
slope the offset says, the same in both engines; `--like` fits the offset from fleet logs and a profile TOML's bad
offset is refused naming the key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import bad_profile_key_is_refused, kernel_matches_numpy

from scart_bench.cli.main import main
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.params import DT, MissionParams, SensorParams
from scart_bench.generator.physics.sensors import Sensors

FLEET = Path(__file__).parents[1].parent / "shared/data/dataflash/fleet"
#: no noise or bias: the samples are the motion alone
QUIET = SensorParams(accel_noise_density=0.0, gyro_noise_density=0.0, accel_bias_random_walk=0.0,
                     gyro_bias_random_walk=0.0, accel_vibration=(0.0, 0.0, 0.0))


def _rocking(offset: tuple[float, float, float], seconds: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """(accelerometer y, d(gyro x)/dt) of a vehicle rolling +-0.3 rad/s at 2 Hz about its centre of gravity (no
    translation), from the numpy sensor model."""
    sensors = Sensors(dataclasses.replace(QUIET, imu_offset_m=offset), DT)
    st = sensors.init_state(1, [np.random.default_rng(0)])
    st.accel_bias[:], st.gyro_bias[:] = 0.0, 0.0
    R = np.eye(3)[None]
    steps = int(seconds / DT)
    acc_y, gyro_x = np.empty(steps), np.empty(steps)
    for k in range(steps):
        omega = np.array([[0.3 * np.sin(2 * np.pi * 2.0 * k * DT), 0.0, 0.0]])
        a, g = sensors.imu(st, np.zeros((1, 3)), omega, R, np.zeros((1, 12)))
        acc_y[k], gyro_x[k] = a[0, 1], g[0, 0]
    return acc_y[1:], np.diff(gyro_x) / DT


def test_an_offset_imu_reads_the_roll_acceleration_with_the_offset_s_slope():
    """An IMU 5 cm above the centre of gravity (r_z = -0.05 m, FRD): acc_y = -alpha_x r_z, so acc_y follows
    d(gyro_x)/dt with slope +0.05 m (the fleet's logs: 2-12 cm); at the centre it follows nothing."""
    acc_y, alpha = _rocking((0.0, 0.0, -0.05))
    assert np.corrcoef(acc_y, alpha)[0, 1] > 0.99
    slope = float(np.dot(acc_y, alpha) / np.dot(alpha, alpha))
    assert abs(slope - 0.05) < 1e-3, slope
    acc_y, alpha = _rocking((0.0, 0.0, 0.0))
    assert np.all(acc_y == 0.0)


def test_the_kernel_reads_the_lever_arm_and_the_downwash_as_the_numpy_reference_step():
    """Same seeds, same draws: every recorded message of the compiled kernel within 1e-9 of the reference's, with an
    offset IMU, the downwash on the baro and coloured noise; and the offset reaches the telemetry's accelerometer."""
    sensors = SensorParams(imu_offset_m=(0.02, -0.01, -0.05), baro_downwash_pa=2.0, baro_noise_pa=0.5,
                           baro_noise_cutoff_hz=3.0, gyro_vibration=(0.05, 0.05, 0.02), gyro_noise_cutoff_hz=3.0)
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=4.0), sensors=sensors)
    ker = kernel_matches_numpy(cfg)
    centred = simulate([3, 4], dataclasses.replace(cfg, sensors=dataclasses.replace(sensors, imu_offset_m=(0.0, 0.0, 0.0))),
                       engine="kernel")
    assert not np.allclose(centred.simulator["highres_imu"][1], ker.simulator["highres_imu"][1])


def test_the_downwash_is_quiet_on_the_ground_and_loud_at_hover():
    """The baro's downwash scales with the rotors' thrust: motors stopped, the pressure noise is the sensor's
    own; at hover thrust the downwash adds in squares."""
    params = dataclasses.replace(QUIET, baro_noise_pa=0.5, baro_downwash_pa=2.0, baro_drift_pa=0.0)
    sensors = Sensors(params, DT)
    st = sensors.init_state(4, [np.random.default_rng(i) for i in range(4)])
    rng = np.random.default_rng(3)
    pos = np.zeros((4, 3))

    def std(thrust):
        p = np.array([sensors.baro(st, pos, rng.standard_normal((4, 2)), thrust)[0] for _ in range(4000)])
        return float((p - p.mean(axis=0)).std())

    assert abs(std(None) / 0.5 - 1) < 0.1
    assert abs(std(np.ones(4)) / np.hypot(0.5, 2.0) - 1) < 0.1


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """`generate --like` on two fleet logs (flights: 2): the folder it wrote."""
    out = tmp_path_factory.mktemp("like") / "out"
    logs = [FLEET / "arducopter_09-10-2014_30.bin", FLEET / "arducopter_10-11-2014_104.bin"]
    assert main(["generate", "--like", *map(str, logs), "--normal-only", "--flights", "2", "--out", str(out)]) == 0
    return out


def test_like_writes_a_fitted_imu_offset_that_reads_back(fitted):
    """The two logs' 0.5-5 Hz horizontal accelerometer follows their angular acceleration (correlation 0.84, r_z
    -4.5 and -8.1 cm): the profile carries an IMU above the centre of gravity, and reads back with it."""
    from scart_bench.generator.like.profile_file import read_profile

    text = (fitted / "profile.toml").read_text()
    assert "imu_offset_m" in text
    cfg = read_profile(fitted / "profile.toml").config
    r = cfg.sensors.imu_offset_m
    assert -0.1 < r[2] < -0.03, r
    assert np.linalg.norm(r) > 0.03


@pytest.mark.parametrize("value, expected", [
    ("[0.0, 0.0]", "sensors.imu_offset_m: expected a list of 3 values"),
    ("[0.0, 0.0, 'low']", "sensors.imu_offset_m[2]: expected a finite number"),
    ("[0.0, 0.0, -2.5]", "sensors.imu_offset_m[2]: expected a number in [-1, 1]"),
])
def test_a_bad_imu_offset_in_a_profile_exits_2_naming_the_key(tmp_path, capsys, value, expected):
    bad_profile_key_is_refused(tmp_path, capsys, "sensors", "imu_offset_m", value, expected)



def test_the_kernel_s_band_passed_sticks_are_the_reference_s():
    """The pilot's band-pass (MissionParams.pilot_stick_highpass_hz): the compiled kernel's sticks are the numpy
    reference's value for value, of unit standard deviation per unit amplitude, with a fraction of the two lags'
    power below the high-pass corner."""
    import math

    from scipy.signal import welch

    from scart_bench.generator.engine import kernel as K
    from scart_bench.generator.engine import kernel_layout as L
    from scart_bench.generator.flight_software.pilot import Pilot, pilot_start, stick_highpass, stick_params

    lags = MissionParams(ground_phase=False, pilot_stick_deg=5.0, pilot_stick_hz=0.5, pilot_yaw_deg=2.0,
                         pilot_throttle=0.04)
    band = dataclasses.replace(lags, pilot_stick_highpass_hz=0.5)
    start = pilot_start([11], band)
    ref = Pilot(band)
    st = ref.init_state(start)
    row = np.zeros(L.WIDTH)
    row[L.PILOT_RNG], row[L.PILOT_GAIN] = start[0]
    p = np.zeros(L.N_PARAMS)
    p[L.PARAM_INDEX["pilot"]:L.PARAM_INDEX["pilot"] + 9] = stick_params(band)
    p[L.PARAM_INDEX["pilot_hp"]:L.PARAM_INDEX["pilot_hp"] + 4] = stick_highpass(band)
    for _ in range(300):
        want = ref.step(st, np.array([10.0]), np.array([3.0]))[0]
        got = [K._pilot_stick(row, p, a, row[L.PILOT_GAIN]) for a in range(4)]
        assert got == list(want)

    def roll(m: MissionParams) -> np.ndarray:
        pilot = Pilot(m)
        s = pilot.init_state(np.array([[12345.0, 1.0]]))
        return np.array([pilot.step(s, np.array([10.0]), np.array([3.0]))[0, 0] for _ in range(30000)])

    x_band, x_lags = roll(band), roll(lags)
    assert abs(x_band.std() / math.radians(5.0) - 1) < 0.1 and abs(x_lags.std() / math.radians(5.0) - 1) < 0.1
    f, p_band = welch(x_band, fs=50.0, nperseg=2000)
    _, p_lags = welch(x_lags, fs=50.0, nperseg=2000)
    low = (f > 0) & (f < 0.2)
    assert p_band[low].sum() < 0.3 * p_lags[low].sum()
