"""The baro's slow wander (SensorParams.baro_wander_pa, baro_wander_tau_s) and the estimator's baro trust fitted with it,
issue 47 acceptance 3: the wander moves the baro below 0.5 Hz and leaves its sample-to-sample noise, the same in both
engines, off by default; `--like` fits it and the estimator's baro noise from the logs' still hover."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from conftest import kernel_matches_numpy
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
    cfg = FlightConfig(mission=MissionParams(ground_phase=False, max_duration_s=4.0), sensors=sensors)
    ker = kernel_matches_numpy(cfg)
    still = simulate([3, 4], dataclasses.replace(cfg, sensors=dataclasses.replace(sensors, baro_wander_pa=0.0)),
                     engine="kernel")
    assert not np.allclose(ker.simulator["scaled_pressure"][1], still.simulator["scaled_pressure"][1])


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
