"""Coloured (low-passed) IMU and baro noise (SensorParams.*_noise_cutoff_hz, issue 47): the lag-1
autocorrelation theory gives, the same in both engines, white and unchanged by default."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import kernel_matches_numpy_and_shows

from scart_bench.generator.engine.compiled import kernel_params
from scart_bench.generator.engine.kernel_layout import PARAM_INDEX
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.like.fit import _noise_figures, cutoff_for
from scart_bench.generator.params import DT, MissionParams, SensorParams
from scart_bench.generator.physics.sensors import Sensors, lowpass_lag1
from scart_bench.generator.plan import plan_generation

#: no bias drift: the samples are the noise alone
STILL = SensorParams(accel_bias_random_walk=0.0, gyro_bias_random_walk=0.0)
#: the motors' vibration alone (the part the cutoffs colour; the sensor's own noise stays white)
SHAKEN = dataclasses.replace(STILL, accel_noise_density=0.0, gyro_noise_density=0.0, accel_vibration=(0.05, 0.05, 0.1),
                             gyro_vibration=(0.02, 0.02, 0.01))


def _lag1(x: np.ndarray) -> float:
    x = x - x.mean()
    return float(np.dot(x[:-1], x[1:]) / np.dot(x, x))


def _imu_noise(params: SensorParams, steps: int = 12000, n: int = 6, seed: int = 1, vibration: float | None = 1.0
               ) -> tuple[np.ndarray, np.ndarray]:
    """(accelerometer, gyro) noise of ``n`` still vehicles, (steps, n, 3) each, from the numpy sensor model, the
    motors at hover speed (``vibration`` 1) or stopped (None)."""
    sensors = Sensors(params, DT)
    rng = np.random.default_rng(seed)
    st = sensors.init_state(n, [np.random.default_rng(seed + i) for i in range(n)])
    st.accel_bias[:], st.gyro_bias[:] = 0.0, 0.0
    R = np.broadcast_to(np.eye(3), (n, 3, 3))
    acc, gyro = np.empty((steps, n, 3)), np.empty((steps, n, 3))
    for k in range(steps):
        a, g = sensors.imu(st, np.zeros((n, 3)), np.zeros((n, 3)), R, rng.standard_normal((n, 12)),
                           None if vibration is None else np.full(n, vibration))
        acc[k], gyro[k] = a, g
    acc[:, :, 2] += 9.80665
    return acc, gyro


def _figures(x: np.ndarray, every: int) -> tuple[float, float, float]:
    """Per-sample std, lag-1 and lag-1 of the differences of ``x`` (steps, n, 3) read every ``every`` samples,
    averaged over the flights and axes."""
    y = x[::every]
    cols = [y[:, i, a] for i in range(y.shape[1]) for a in range(3)]
    return (float(np.mean([c.std() for c in cols])), float(np.mean([_lag1(c) for c in cols])),
            float(np.mean([_lag1(np.diff(c)) for c in cols])))


def test_low_passed_vibration_has_the_lag1_autocorrelation_theory_gives_and_keeps_its_sigma():
    """A 3 Hz gyro cutoff read at 50 Hz: lag-1 0.94, of the differences 0.67 (white: 0 and -0.5, the
    ArduCopter fleet's hover gyro 0.7-0.9); 15 Hz on the accelerometer: 0.33 and -0.23. The per-sample
    sigma is the white one's."""
    white_acc, white_gyro = _imu_noise(SHAKEN)
    acc, gyro = _imu_noise(dataclasses.replace(SHAKEN, gyro_noise_cutoff_hz=3.0, accel_noise_cutoff_hz=15.0))
    sigma_g = np.array(SHAKEN.gyro_vibration)
    sigma_a = np.array(SHAKEN.accel_vibration)
    for x, cutoff, sigma in ((gyro, 3.0, sigma_g), (acc, 15.0, sigma_a)):
        x = x / sigma
        sigma = 1.0
        std, lag1, dlag1 = _figures(x, 5)
        want = lowpass_lag1(cutoff, 1 / DT, 5)
        assert abs(lag1 - want[0]) < 0.03 and abs(dlag1 - want[1]) < 0.04, (cutoff, lag1, dlag1, want)
        assert abs(std / sigma - 1) < 0.1, (cutoff, std, sigma)
    for x in (white_gyro / sigma_g, white_acc / sigma_a):
        std, lag1, dlag1 = _figures(x, 5)
        assert abs(lag1) < 0.03 and abs(dlag1 + 0.5) < 0.03, (lag1, dlag1)
        assert abs(std - 1) < 0.03
    assert lowpass_lag1(3.0, 1 / DT, 5)[1] > 0.6 and lowpass_lag1(15.0, 1 / DT, 5)[1] < -0.2


def test_low_passed_baro_noise_at_the_baro_rate():
    params = dataclasses.replace(STILL, baro_noise_cutoff_hz=3.0, baro_drift_pa=0.0)
    sensors = Sensors(params, DT)
    st = sensors.init_state(4, [np.random.default_rng(i) for i in range(4)])
    rng = np.random.default_rng(9)
    press = np.array([sensors.baro(st, np.zeros((4, 3)), rng.standard_normal((4, 2)))[0] for _ in range(8000)])
    y = (press - press.mean(axis=0))[::5]  # 50 Hz samples read at 10 Hz
    lag1 = np.mean([_lag1(y[:, i]) for i in range(4)])
    dlag1 = np.mean([_lag1(np.diff(y[:, i])) for i in range(4)])
    want = lowpass_lag1(3.0, params.baro_rate_hz, 5)
    assert abs(lag1 - want[0]) < 0.05 and abs(dlag1 - want[1]) < 0.05, (lag1, dlag1, want)
    assert abs(y.std() / params.baro_noise_pa - 1) < 0.1


def test_the_kernel_flies_coloured_noise_as_the_numpy_reference_step():
    """Same seeds, same draws: the compiled kernel's low-pass states follow the reference's, every recorded
    message within 1e-9; and the colour reaches the telemetry's gyro."""
    sensors = SensorParams(accel_noise_cutoff_hz=15.0, gyro_noise_cutoff_hz=3.0, baro_noise_cutoff_hz=3.0,
                           gyro_vibration=(0.05, 0.05, 0.02))
    kernel_matches_numpy_and_shows(sensors, {"gyro_noise_cutoff_hz": 0.0}, "highres_imu")


def test_the_kernel_gives_the_theory_s_colour_armed_on_the_ground_and_white_noise_before_arming():
    """Armed on the ground (motors at idle: full vibration), the telemetry's gyro is the vibration coloured at
    least as theory says at 50 Hz (the rate controller's answer to it on the vehicle's legs adds some: 0.65 for
    theory's 0.47 here); before arming it is the sensor's own noise, white."""
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, arm_delay_s=1.0, max_duration_s=3.8),
                       sensors=dataclasses.replace(STILL, gyro_vibration=(0.02, 0.02, 0.02), gyro_noise_cutoff_hz=5.0))
    batch = simulate([1, 2, 3, 4], cfg, engine="kernel")
    from scart_bench.dataset.schema import TOPICS

    names = TOPICS["highres_imu"].field_names
    steps, vals = batch.simulator["highres_imu"][0], batch.simulator["highres_imu"][1]  # (n, messages, fields)
    t = steps[0] * DT if steps.ndim == 2 else steps * DT
    armed, before = (t > 1.3) & (t < 3.8), t < 0.95
    def dlag1(when):
        cols = [vals[i, when, names.index(f)] for i in range(vals.shape[0]) for f in ("xgyro", "ygyro", "zgyro")]
        return np.mean([_lag1(np.diff(c)) for c in cols])

    want = lowpass_lag1(5.0, 1 / DT, 5)[1]
    assert want - 0.1 < dlag1(armed) < want + 0.3, (dlag1(armed), want)
    assert abs(dlag1(before) + 0.5) < 0.1, dlag1(before)


def test_white_noise_is_the_default_and_unchanged():
    """Cutoff 0 (the default): the samples as drawn, exactly as before coloured noise; the built-in profiles'
    dataset config has no cutoff keys (their datasets stay byte-identical) and the kernel's filters are off."""
    sensors = Sensors(STILL, DT)
    st = sensors.init_state(3, [np.random.default_rng(i) for i in range(3)])
    w = np.random.default_rng(5).standard_normal((3, 12))
    R = np.broadcast_to(np.eye(3), (3, 3, 3))
    acc, gyro = sensors.imu(st, np.zeros((3, 3)), np.zeros((3, 3)), R, w)
    sigma_a = STILL.accel_noise_density * math.sqrt(1 / DT)
    sigma_g = STILL.gyro_noise_density * math.sqrt(1 / DT)
    np.testing.assert_array_equal(acc, np.array([0.0, 0.0, -9.80665]) + st.accel_bias + sigma_a * w[:, 0:3])
    np.testing.assert_array_equal(gyro, st.gyro_bias + sigma_g * w[:, 3:6])
    shaken = Sensors(SHAKEN, DT)  # the motors running: one draw of the combined sigma, as before
    acc, gyro = shaken.imu(st, np.zeros((3, 3)), np.zeros((3, 3)), R, w, np.ones(3))
    np.testing.assert_array_equal(gyro, st.gyro_bias + np.sqrt(0.0 + np.array(SHAKEN.gyro_vibration) ** 2) * w[:, 3:6])
    for name in ("quick", "standard", "paper"):
        cfg = plan_generation(name, seed=0, n_normal=4).config_dict["flight_config"]["sensors"]
        assert not any(k.endswith("_noise_cutoff_hz") for k in cfg), name
    p = kernel_params(FlightConfig(), 28)
    assert all(p[PARAM_INDEX[k] + 5] == 0.0 for k in ("accel_lowpass", "gyro_lowpass", "baro_lowpass"))


@pytest.mark.parametrize("target", [-0.3, 0.2, 0.75, 0.9])
def test_like_reads_the_cutoff_back_from_a_log_s_colour(target):
    """`generate --like`'s figure (lag-1 of the differences on a segment, fit._noise_figures) of low-passed noise
    gives theory's value, and cutoff_for inverts it: a log's colour becomes the cutoff that gives it."""
    cutoff = cutoff_for(target, 250.0, 5)
    assert abs(lowpass_lag1(cutoff, 250.0, 5)[1] - target) < 0.01
    _, gyro = _imu_noise(dataclasses.replace(SHAKEN, gyro_noise_cutoff_hz=cutoff), steps=15000, n=1)
    t = np.arange(15000) * DT
    *_, dlag1 = _noise_figures(t, gyro[:, 0, 0], 50.0, [(0.0, t[-1])])
    assert abs(dlag1 - target) < 0.06, (cutoff, dlag1, target)
    assert cutoff_for(-0.5, 250.0, 5) == 0.0 and cutoff_for(-0.46, 250.0, 5) == 0.0


def test_the_fit_s_least_cutoff_keeps_a_capped_level_at_the_logs_white_noise():
    """`--like` caps the coloured vibration per sample at the logs' hover std (it enters the controllers) and so
    colours no lower than the cutoff at which that cap still gives the logs' sample-to-sample noise: the fleet's
    gyro (0.032 white, 0.136 std at hover) no lower than about 2.9 Hz."""
    from scart_bench.generator.like.fit import cutoff_at_least, white_factor

    fc = cutoff_at_least(0.032 / 0.136, 250.0, 5)
    assert 2.5 < fc < 3.5, fc
    assert white_factor(fc, 250.0, 5) >= 0.032 / 0.136 > white_factor(0.9 * fc, 250.0, 5)
    assert cutoff_at_least(1.0, 250.0, 5) == 0.0  # white noise is needed
