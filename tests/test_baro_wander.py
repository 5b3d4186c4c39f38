"""The baro's slow wander (SensorParams.baro_wander_pa, baro_wander_tau_s) and the estimator's baro trust fitted with it,
issue 47 acceptance 3: the wander moves the baro below 0.5 Hz and leaves its sample-to-sample noise, the same in both
engines, off by default; `--like` fits it and the estimator's baro noise from the logs' still hover."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import bad_profile_key_is_refused, kernel_matches_numpy, kernel_matches_numpy_and_shows
from scipy.signal import periodogram

from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.params import MissionParams, SensorParams
from scart_bench.generator.physics.sensors import Sensors, baro_wander_coefficients

FLEET = Path(__file__).parents[1].parent / "shared/data/dataflash/fleet"


def _baro_error(sensors: SensorParams, seconds: float = 600.0) -> np.ndarray:
    """The pressure error (Pa) of a still baro at 50 Hz, from the numpy sensor model (its offset removed)."""
    model = Sensors(sensors, 1.0 / 250.0)
    st = model.init_state(1, [np.random.default_rng(0)])
    rng = np.random.default_rng(1)
    pos = np.zeros((1, 3))
    out = np.array([model.baro(st, pos, rng.standard_normal((1, 2)))[0][0] for _ in range(int(seconds * 50))])
    return out - out.mean()


def _low_power(x: np.ndarray, hz: float) -> float:
    """Median over 10 s windows of the power below 0.5 Hz (the window classifier's band)."""
    n = int(10 * hz)
    p = []
    for a in range(0, len(x) - n, n):
        f, pxx = periodogram(x[a:a + n], fs=hz, window="hann", detrend="constant")
        p.append(pxx[f < 0.5].sum() * (f[1] - f[0]))
    return float(np.median(p))


def test_the_wander_moves_the_baro_below_half_a_hertz_and_not_its_sample_to_sample_noise():
    """3 Pa of wander on 1 Pa of white noise: the error's std grows to about hypot(1, 3) Pa (the wander's stationary
    sigma is the parameter), its power below 0.5 Hz in 10 s windows over 5x, its sample-to-sample noise at 10 Hz (as
    the fleet logs it) by under 10 %: the wander is smooth (a lag of a Gauss-Markov drive), unlike a plain
    Gauss-Markov error, whose steps would add to it."""
    plain = SensorParams(baro_noise_pa=1.0)
    white = _baro_error(plain)
    wander = _baro_error(dataclasses.replace(plain, baro_wander_pa=3.0, baro_wander_tau_s=2.0))
    assert abs(np.std(white) - 1.0) < 0.05
    assert abs(np.std(wander) / np.hypot(1.0, 3.0) - 1.0) < 0.15, np.std(wander)
    w10, d10 = white[::5], wander[::5]
    assert _low_power(d10, 10.0) > 5.0 * _low_power(w10, 10.0)
    assert np.std(np.diff(d10)) < 1.1 * np.std(np.diff(w10))


def test_the_kernel_s_wander_is_the_numpy_reference_s():
    """Same seeds, same draws: every recorded message of the compiled kernel within 1e-9 of the reference's with the
    wander on beside the downwash and coloured baro noise; and the wander reaches the telemetry's pressure."""
    sensors = SensorParams(baro_wander_pa=4.0, baro_wander_tau_s=1.0, baro_downwash_pa=2.0, baro_noise_pa=0.5,
                           baro_noise_cutoff_hz=3.0)
    kernel_matches_numpy_and_shows(sensors, {"baro_wander_pa": 0.0}, "scaled_pressure")


def test_the_wander_is_off_by_default():
    """No wander: (1, 0), no new state, and a built-in profile's recorded config has no wander key (so its datasets
    keep their bytes)."""
    from scart_bench.generator.plan import plan_generation

    assert SensorParams().baro_wander_pa == 0.0
    assert baro_wander_coefficients(SensorParams()) == (1.0, 0.0)
    sensors = plan_generation("quick", seed=3, n_normal=2).config_dict["flight_config"]["sensors"]
    assert "baro_wander_pa" not in sensors and "baro_wander_tau_s" not in sensors


def test_like_fits_the_estimator_s_trust_then_the_wander_that_adds_in_squares(monkeypatch):
    """Calibration flights whose estimated altitude moves 0.5 / 0.3 / 0.1 x their baro at an estimator baro noise of
    0.3 / 1 / 3 m, and whose baro below 0.5 Hz is 0.1 m without the wander and 0.2 m at the reference: logs at 0.3x
    and 0.25 m get 1 m and the wander sqrt(0.25^2 - 0.1^2) / sqrt(0.2^2 - 0.1^2) x the reference; logs without a still
    hover's window nothing, said in one line."""
    from scart_bench.generator.like import fit

    ratio = {0.3: 0.5, 1.0: 0.3, 3.0: 0.1}

    def flights(config, n=3, seed=12345):
        lf = 0.2 if config.sensors.baro_wander_pa > 0 else 0.1
        return {"baro_lf": lf, "alt_ratio": ratio[config.estimator.baro_noise], "landed": 1.0}

    monkeypatch.setattr(fit, "calibration_figures", flights)
    figs = {"baro_lf": fit.Figure(0.25, 4, ""), "alt_ratio": fit.Figure(0.3, 4, "")}
    lines: list[str] = []
    got = fit.fit_baro_wander(figs, FlightConfig(), lines)
    assert got["baro_noise"][0] == 1.0
    want = fit.BARO_WANDER_REF * np.sqrt(0.25 ** 2 - 0.1 ** 2) / np.sqrt(0.2 ** 2 - 0.1 ** 2)
    assert abs(got["baro_wander_pa"][0] - want) < 1e-3
    assert got["baro_wander_tau_s"][0] == fit.BARO_WANDER_TAU_S
    lines = []
    assert fit.fit_baro_wander({"baro_lf": fit.Figure(float("nan"), 0, "")}, FlightConfig(), lines) == {}
    assert len(lines) == 1 and "baro wander" in lines[0]


def test_a_fleet_log_s_baro_wanders_more_than_its_estimated_altitude():
    """`arducopter_10-11-2014_105.bin` (25 s of still hover): its baro below 0.5 Hz 0.05-0.5 m in 10 s windows, its
    estimated altitude (CTUN.Alt) moving under 0.7x as much as the baro (the inertial navigation follows the baro
    slowly): what the fit reads."""
    from scart_bench.generator.like.fit import measure_log

    m = measure_log(FLEET / "arducopter_10-11-2014_105.bin")
    assert 0.05 < m.baro_lf < 0.5, m.baro_lf
    assert 0.0 < m.alt_ratio < 0.7, m.alt_ratio


def _flow_sigma(speed: float) -> float:
    """The pressure noise's std (Pa) of a baro moving at ``speed`` m/s, 2 Pa of forward flight's noise on 1 Pa."""
    sensors = SensorParams(baro_noise_pa=1.0, baro_speed_pa=2.0, baro_speed_full_m_s=2.0)
    model = Sensors(sensors, 1.0 / 250.0)
    st = model.init_state(1, [np.random.default_rng(0)])
    rng = np.random.default_rng(1)
    model.push_truth(st, 0, np.zeros((1, 3)), np.array([[0.6 * speed, 0.8 * speed, -3.0]]))
    out = np.array([model.baro(st, np.zeros((1, 3)), rng.standard_normal((1, 2)))[0][0] for _ in range(20000)])
    return float(np.std(out))


def test_the_baro_is_louder_in_forward_flight_from_1_m_s_to_full_at_2():
    """Horizontal speed 0 or 0.9 m/s (a climb does not count): the sensor's own 1 Pa; 1.5 m/s: half of the 2 Pa in
    squares; 2 and 16 m/s: hypot(1, 2) (the fleet's baro is as loud at 16 m/s as at 2-3 m/s)."""
    for speed, want in ((0.0, 1.0), (0.9, 1.0), (1.5, np.hypot(1.0, 1.0)), (2.0, np.hypot(1.0, 2.0)),
                        (16.0, np.hypot(1.0, 2.0))):
        assert abs(_flow_sigma(speed) / want - 1.0) < 0.03, (speed, _flow_sigma(speed), want)


def test_the_kernel_s_baro_in_forward_flight_is_the_numpy_reference_s():
    """A flight that takes off and flies the square's first leg at 5 m/s, with the forward flight's noise, the downwash,
    the wander and coloured baro noise: every recorded message of the compiled kernel within 1e-9 of the reference's,
    and the noise reaches the pressure."""
    sensors = SensorParams(baro_speed_pa=3.0, baro_downwash_pa=1.5, baro_noise_pa=0.5, baro_noise_cutoff_hz=3.0,
                           baro_wander_pa=1.0)
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=16.0, takeoff_hold_s=1.0),
                       sensors=sensors)
    ker = kernel_matches_numpy(cfg)
    assert np.abs(ker.simulator["truth"][1][:, :, 3:5]).max() > 2.0  # it flies faster than the full noise's speed
    quiet = simulate([3, 4], dataclasses.replace(cfg, sensors=dataclasses.replace(sensors, baro_speed_pa=0.0)),
                     engine="kernel")
    assert not np.allclose(ker.simulator["scaled_pressure"][1], quiet.simulator["scaled_pressure"][1])


def test_the_baro_in_forward_flight_is_off_by_default():
    from scart_bench.generator.plan import plan_generation

    assert SensorParams().baro_speed_pa == 0.0
    sensors = plan_generation("quick", seed=3, n_normal=2).config_dict["flight_config"]["sensors"]
    assert "baro_speed_pa" not in sensors and "baro_speed_full_m_s" not in sensors


def test_like_fits_the_forward_flight_s_baro_noise_that_adds_in_squares(monkeypatch):
    """Calibration flights at 3 m/s with 0.1 m of baro noise without it and 0.3 m at the reference, logs at 0.2 m:
    the reference x sqrt(0.2^2 - 0.1^2) / sqrt(0.3^2 - 0.1^2); logs at or below 0.1 m: none; no log moving: none, one
    line."""
    from scart_bench.generator.like import fit

    monkeypatch.setattr(fit, "moving_figures", lambda config, n=3, seed=777: 0.3 if config.sensors.baro_speed_pa else 0.1)
    got = fit.fit_baro_speed({"moving_baro": fit.Figure(0.2, 10, "")}, FlightConfig(), [])
    want = fit.BARO_SPEED_REF * np.sqrt(0.2 ** 2 - 0.1 ** 2) / np.sqrt(0.3 ** 2 - 0.1 ** 2)
    assert abs(got["baro_speed_pa"][0] - want) < 1e-3
    assert got["baro_speed_full_m_s"][0] == fit.MOVING_M_S
    assert fit.fit_baro_speed({"moving_baro": fit.Figure(0.08, 10, "")}, FlightConfig(), []) == {}
    lines: list[str] = []
    assert fit.fit_baro_speed({"moving_baro": fit.Figure(float("nan"), 0, "")}, FlightConfig(), lines) == {}
    assert len(lines) == 1


def test_a_fleet_log_s_baro_is_louder_moving_than_at_hover():
    """`arducopter_09-10-2014_25.bin` (GPS, hand-flown at 2 m/s): its baro's sample-to-sample noise at 2 m/s or faster
    over 1.5x its still hover's: what the fit reads."""
    from scart_bench.generator.like.fit import measure_log

    m = measure_log(FLEET / "arducopter_09-10-2014_25.bin")
    assert m.moving_baro > 1.5 * m.hover_white["baro_alt"], (m.moving_baro, m.hover_white["baro_alt"])


@pytest.mark.parametrize("key, value, expected", [
    ("baro_speed_full_m_s", "1.0", "sensors.baro_speed_full_m_s: expected a number in [1.1, 100] (m/s, above the 1 m/s"),
    ("baro_wander_tau_s", "0.0", "sensors.baro_wander_tau_s: expected a number in [0.05, 3600]"),
    ("baro_wander_pa", "-1.0", "sensors.baro_wander_pa: expected a number >= 0"),
])
def test_bad_baro_parameters_in_a_profile_exit_2_naming_the_key(tmp_path, capsys, key, value, expected):
    """A ramp ending where it starts would divide by zero (NaN pressures): refused before anything is flown."""
    bad_profile_key_is_refused(tmp_path, capsys, "sensors", key, value, expected)
