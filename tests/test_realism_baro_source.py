"""The window classifier reads the baro from its own message (issue 47 acc. 3).

A generated flight carries the baro twice: ``highres_imu.pressure_alt`` on the 50 Hz IMU message (the
IMU's message timing) and ``scaled_pressure.press_abs`` at the baro's 10 Hz with the baro's timing. A real
ArduPilot log has ``BARO`` at 10 Hz. Reading the generated flight's baro from the IMU's message compared
the IMU's timing jitter with the fleet's baro (x5-7, a top separating feature in every phase).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from perf import realism_windows as rw
from scart_bench.generator.geo import pressure_at


def _tables(seed: int = 0) -> dict[str, pd.DataFrame]:
    return _flight(seed)[0]


def _flight(seed: int = 0) -> tuple[dict[str, pd.DataFrame], np.ndarray]:
    """A 60 s still flight: the IMU at 50 Hz carrying a baro altitude, the baro's own pressure at 10 Hz."""
    rng = np.random.default_rng(seed)
    t_imu = np.arange(0, 60_000_000, 20_000, dtype=np.int64) + rng.integers(-800, 800, 3000)
    t_baro = np.arange(0, 60_000_000, 100_000, dtype=np.int64)
    alt = 480.0 + 0.1 * rng.standard_normal(len(t_baro))  # m AMSL, 10 cm of noise
    n = len(t_imu)
    imu = pd.DataFrame({"Timestamp": np.sort(t_imu), "xacc": rng.normal(0, 0.1, n), "yacc": rng.normal(0, 0.1, n),
                        "zacc": rng.normal(-9.81, 0.1, n), "xgyro": rng.normal(0, 0.01, n),
                        "ygyro": rng.normal(0, 0.01, n), "zgyro": rng.normal(0, 0.01, n),
                        "abs_pressure": np.interp(t_imu, t_baro, pressure_at(alt) / 100.0),
                        "pressure_alt": np.interp(t_imu, t_baro, alt)})
    baro = pd.DataFrame({"Timestamp": t_baro, "press_abs": (pressure_at(alt) / 100.0).astype(np.float32),
                         "temperature": np.full(len(t_baro), 2500)})
    return {"highres_imu": imu, "scaled_pressure": baro}, alt


def test_a_flight_with_both_reads_the_baros_own_message():
    f = rw.signals_from_tables("gen", _tables(), "generated")
    assert f.sources["baro_alt"] == "scaled_pressure.press_abs"
    t, _ = f.signals["baro_alt"]
    assert rw.native_hz(t) == pytest.approx(10.0)  # the baro's rate, not the IMU's 50 Hz
    assert f.sources["acc_x"] == "highres_imu.xacc"


def test_without_its_own_message_the_baro_comes_from_the_imus():
    tables = _tables()
    del tables["scaled_pressure"]
    f = rw.signals_from_tables("gen", tables, "generated")
    assert f.sources["baro_alt"] == "highres_imu.pressure_alt"


def test_the_pressure_reads_the_same_metres_as_the_altitude():
    """float32 hPa at 10 cm of noise: the ISA altitude of the pressure is the logged altitude to a
    millimetre (a linear 0.1127 hPa/m read it 1.5 % large at 480 m)."""
    tables, truth = _flight()
    f = rw.signals_from_tables("gen", tables, "generated")
    _, alt = f.signals["baro_alt"]
    assert np.max(np.abs(alt - truth)) < 0.01
    assert np.std(np.diff(alt)) / np.std(np.diff(truth)) == pytest.approx(1.0, abs=0.005)
