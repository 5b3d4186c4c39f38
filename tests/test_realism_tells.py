"""The tells of issue 47 (item 5) fixed at their cause: motor vibration on the accelerometer, a
smooth GPS error, armed time on the ground and the hover before the first leg (docs/realism.md,
"Fixing the tells"; measured on the logs with ``python -m perf.realism_tells``)."""

from __future__ import annotations

import numpy as np
import pytest

from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.flight_software.startup import TAKEOFF_AFTER_ARM_S
from scart_bench.generator.params import DT, MissionParams, SensorParams
from scart_bench.generator.physics.sensors import Sensors, gps_error_coefficients
from scart_bench.generator.telemetry.tables import flight_views


@pytest.fixture(scope="module")
def flight():
    cfg = FlightConfig(timing="ideal", mission=MissionParams(max_duration_s=32.0))
    batch = simulate([5], cfg)
    return flight_views(batch, 0)[1]


def _segments(sim) -> dict[str, tuple[float, float]]:
    truth = sim["truth"]
    t = truth["Timestamp"].to_numpy() / 1e6
    armed = truth["armed"].to_numpy() > 0.5
    ground = truth["landed"].to_numpy() > 0.5
    arm = t[np.argmax(armed)]
    lift = t[np.argmax(armed & ~ground)]
    high = t[np.argmax(-truth["z"].to_numpy() > 9.5)]
    return {"disarmed": (1.0, arm - 0.2), "armed": (arm + 0.3, lift - 0.1), "hover": (high + 2.0, high + 8.0)}


def _diff_std(sim, axis: str, span: tuple[float, float]) -> float:
    imu = sim["highres_imu"]
    t = imu["Timestamp"].to_numpy() / 1e6
    x = imu[axis].to_numpy()[(t > span[0]) & (t < span[1])]
    assert x.size > 40, span
    return float(np.diff(x).std())


def test_the_motors_shake_the_accelerometer_whenever_they_turn(flight):
    """White accelerometer noise at the sensor's level with the motors stopped, more with them
    armed at idle on the ground and about as much at hover (the ArduCopter logs: ground armed
    0.8-1.6x hover), the RflyMAD SIL log's sample-to-sample level there (std of first differences
    at 50 Hz: 0.050 / 0.044 / 0.097 m/s^2)."""
    seg = _segments(flight)
    for axis, hover_target in (("xacc", 0.050), ("yacc", 0.044), ("zacc", 0.097)):
        off, idle, hover = (_diff_std(flight, axis, seg[k]) for k in ("disarmed", "armed", "hover"))
        assert off < 0.035, axis  # the sensor alone: 0.020 per sample
        assert idle > 1.15 * off, axis  # full vibration from idle speed on
        assert 0.7 * idle < hover < 1.4 * idle, axis
        assert 0.7 * hover_target < hover < 1.3 * hover_target, (axis, hover)


def test_white_accelerometer_noise_on_the_ground(flight):
    """Disarmed on the ground the link's 50 Hz accelerometer is white (lag-1 autocorrelation ~0,
    as the PX4 logs; the bias random walk and the IMU stream's 250 Hz timing steps made it 0.3)."""
    imu = flight["highres_imu"]
    t = imu["Timestamp"].to_numpy() / 1e6
    arm = _segments(flight)["disarmed"][1]
    for axis in ("xacc", "yacc", "zacc"):
        x = imu[axis].to_numpy()[(t > 1.0) & (t < arm)]
        x = x - x.mean()
        assert abs(np.dot(x[1:], x[:-1]) / np.dot(x, x)) < 0.15, axis


def test_armed_on_the_ground_then_a_hover_before_the_first_leg(flight):
    """The vehicle takes off TAKEOFF_AFTER_ARM_S after arming (logs: 2.4-5.8 s), and holds at the
    take-off point for takeoff_hold_s (9 s) before the first leg."""
    seg = _segments(flight)
    assert TAKEOFF_AFTER_ARM_S - 0.5 < seg["armed"][1] - seg["armed"][0] + 0.4 < TAKEOFF_AFTER_ARM_S + 1.0
    truth = flight["truth"]
    t = truth["Timestamp"].to_numpy() / 1e6
    speed = np.hypot(truth["vx"].to_numpy(), truth["vy"].to_numpy())
    high = seg["hover"][0] - 2.0
    first_leg = t[np.argmax((t > high) & (speed > 1.0))]
    assert MissionParams().takeoff_hold_s - 1.5 < first_leg - high < MissionParams().takeoff_hold_s + 1.5


def test_the_gps_slow_error_is_smooth_with_its_stated_sigma():
    """The receiver's slow error keeps its sigma (gps_bias_h) and time constant but does not step
    at every fix: a plain Gauss-Markov error stepped ~sqrt(2 dt / tau) sigma (1.7 cm per fix)."""
    p = SensorParams()
    n, dt_gps = 400, 1.0 / p.gps_rate_hz
    sensors = Sensors(p, DT)
    rngs = [np.random.default_rng(i) for i in range(n)]
    st = sensors.init_state(n, rngs)
    noise = np.random.default_rng(99)
    bias = []
    for step in range(3000):
        sensors.gps(st, step, noise.standard_normal((n, 9)), dt_gps)
        bias.append(st.gps_bias[:, 0].copy())
    bias = np.array(bias)
    steps = np.diff(bias[-100:], axis=0).std()
    old_step = np.sqrt(2 * dt_gps / p.gps_bias_tau) * p.gps_bias_h
    assert steps < 0.2 * old_step
    assert 0.75 * p.gps_bias_h < bias[-1].std() < 1.25 * p.gps_bias_h
    a, c = gps_error_coefficients(p, dt_gps)
    assert np.isclose(a, np.exp(-dt_gps / p.gps_bias_tau)) and c.shape == (3,)


def test_gyro_vibration_is_flown_alike_by_both_engines():
    """A fitted profile's gyro vibration (none by default) shakes the gyro once the motors turn, the
    same in the numpy reference step and the compiled kernel."""
    import dataclasses

    cfg = FlightConfig(timing="ideal", mission=MissionParams(ground_phase=False, max_duration_s=4.0))
    shaken = dataclasses.replace(cfg, sensors=dataclasses.replace(cfg.sensors, gyro_vibration=(0.02, 0.02, 0.01)))
    ref = simulate([3], shaken, engine="numpy")
    ker = simulate([3], shaken, engine="kernel")
    quiet = simulate([3], cfg, engine="kernel")
    k_steps, k_vals, _ = ker.simulator["highres_imu"]
    r_steps, r_vals, _ = ref.simulator["highres_imu"]
    np.testing.assert_array_equal(k_steps, r_steps)
    np.testing.assert_allclose(k_vals, r_vals, rtol=0, atol=1e-9)
    t = k_steps * DT
    gyro = slice(3, 6)
    before = t < 0.9  # disarmed: the motors stopped
    spinning = t > 2.0
    d_shaken = np.diff(k_vals[0][:, gyro][spinning], axis=0).std()
    d_quiet = np.diff(quiet.simulator["highres_imu"][1][0][:, gyro][spinning], axis=0).std()
    assert d_shaken > 3 * d_quiet
    np.testing.assert_array_equal(k_vals[0][before][:, gyro], quiet.simulator["highres_imu"][1][0][before][:, gyro])
