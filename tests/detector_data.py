"""Synthetic flights for the detector tests, in the combined-table layout.

``normal_flights`` and ``attacked_flight`` are the only interface the tests use; their internals
are a small kinematic stand-in (a 30 m square mission at 50 Hz with wind, tilt, specific force,
magnetometer, barometer and sensor noise) that may later be replaced by the real flight
generator without changing the tests.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from generator.topics import HOME_ALT, HOME_LAT, HOME_LON

RATE_HZ = 50.0
GRAVITY = 9.81
#: Metres per degree of latitude (spherical Earth, as the attack layer converts magnitudes).
M_PER_DEG_LAT = 111_320.0
#: Earth magnetic field at home in NED, gauss.
MAG_NED = np.array([0.21, 0.015, 0.43])
#: (start, end) of the attacked window as fractions of the flight.
ATTACK_WINDOW = (0.4, 0.6)
#: Standard deviation of the position noise of the attacked flight, metres.
ATTACK_NOISE_M = 20.0


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk blend from 0 to 1 for ``tau`` in [0, 1]."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def _mission_path(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """NED position (rows, 3) of take-off, a 30 m square at ~10 m and landing, with jitter."""
    duration = t[-1] + 1.0 / RATE_HZ
    alt = 10.0 + rng.normal(0.0, 0.5)
    side = 30.0 + rng.normal(0.0, 0.3)
    waypoints = np.array(
        [
            [0, 0, 0],
            [0, 0, -alt],
            [side, 0, -alt],
            [side, side, -alt],
            [0, side, -alt],
            [0, 0, -alt],
            [0, 0, 0],
        ],
        dtype=np.float64,
    )
    # Segment boundaries as fractions of the flight: ground, climb, four legs, descent, ground.
    fractions = np.array([0.06, 0.16, 0.33, 0.50, 0.67, 0.84, 0.94]) + rng.normal(0.0, 0.005, 7)
    bounds = np.sort(fractions) * duration
    pos = np.repeat(waypoints[:1], t.size, axis=0)
    for k in range(len(waypoints) - 1):
        s = _min_jerk((t - bounds[k]) / (bounds[k + 1] - bounds[k]))
        pos += np.outer(s, waypoints[k + 1] - waypoints[k])
    return pos


def _smooth_noise(rng: np.random.Generator, n: int, sigma: float, tau_rows: float) -> np.ndarray:
    """First-order low-pass (AR(1)) noise with stationary standard deviation ``sigma``."""
    a = 1.0 / tau_rows
    white = rng.normal(0.0, sigma * np.sqrt(2.0 * a - a * a), n)
    start = rng.normal(0.0, sigma)
    return lfilter([1.0], [1.0, a - 1.0], white, zi=[(1.0 - a) * start])[0]


def _body_from_ned(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, v_ned: np.ndarray) -> np.ndarray:
    """Rotate NED vectors (rows, 3) into the FRD body frame (ZYX Euler angles)."""
    cr, sr, cp, sp, cy, sy = (
        np.cos(roll),
        np.sin(roll),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(yaw),
        np.sin(yaw),
    )
    # Rows of R^T where R maps body -> NED.
    r = np.stack(
        [
            np.stack([cp * cy, cp * sy, -sp], -1),
            np.stack([sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, sr * cp], -1),
            np.stack([cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp], -1),
        ],
        axis=1,
    )
    return np.einsum("nij,nj->ni", r, v_ned)


def _flight(rng: np.random.Generator, rows: int) -> pd.DataFrame:
    n = int(rows)
    t = np.arange(n) / RATE_HZ
    dt = 1.0 / RATE_HZ
    pos = _mission_path(t, rng)
    # Estimator error, common to the global and the local position (they agree within 0.1 m).
    est_err = np.stack([_smooth_noise(rng, n, 0.03, 100.0) for _ in range(3)], -1)
    pos_est = pos + est_err
    vel = np.gradient(pos, dt, axis=0)
    acc = np.gradient(vel, dt, axis=0)
    airborne = pos[:, 2] < -0.05

    # Wind (mean + gusts) and linear drag decide the tilt needed to follow the path.
    wind = rng.normal(0.0, 2.0, 2) + np.stack([_smooth_noise(rng, n, 0.7, 50.0) for _ in range(2)], -1)
    drag = np.zeros((n, 3))
    drag[:, :2] = -0.3 * (vel[:, :2] - wind) * airborne[:, None]
    specific_force = acc - np.array([0.0, 0.0, GRAVITY])
    thrust = specific_force - drag
    yaw = rng.uniform(0.3, 1.2) + _smooth_noise(rng, n, 0.01, 200.0)
    cy, sy = np.cos(yaw), np.sin(yaw)
    fwd = cy * thrust[:, 0] + sy * thrust[:, 1]
    right = -sy * thrust[:, 0] + cy * thrust[:, 1]
    pitch = np.arctan2(fwd, -thrust[:, 2])
    roll = np.arctan2(right, np.hypot(fwd, -thrust[:, 2]))
    # Attitude wobble of the controller in flight.
    roll = roll + airborne * _smooth_noise(rng, n, 0.01, 10.0)
    pitch = pitch + airborne * _smooth_noise(rng, n, 0.01, 10.0)
    rates = np.gradient(np.stack([roll, pitch, yaw], -1), dt, axis=0)

    f_body = _body_from_ned(roll, pitch, yaw, specific_force)
    mag_body = _body_from_ned(roll, pitch, yaw, np.repeat(MAG_NED[None], n, axis=0))
    alt_amsl = HOME_ALT - pos[:, 2]
    pressure = 1013.25 * (1.0 - 2.25577e-5 * alt_amsl) ** 5.25588
    vibration = 0.03 + 0.15 * airborne

    def noisy(x: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
        return x + rng.normal(0.0, 1.0, n) * sigma

    # LOCAL_POSITION_NED is published at 30 Hz: hold the last message on the 50 Hz rows.
    held = np.floor(np.floor(t * 30.0 + 1e-9) / 30.0 * RATE_HZ + 1e-9).astype(int)
    vel_est = vel + np.stack([_smooth_noise(rng, n, 0.03, 20.0) for _ in range(3)], -1)

    lat0 = np.radians(HOME_LAT)
    columns: dict[str, np.ndarray] = {
        "Index": np.arange(n),
        "Timestamp": (np.arange(n) * int(1e6 / RATE_HZ)).astype(np.int64),
        "Is_Anomaly": np.zeros(n, dtype=np.int64),
        "attitude.roll": noisy(roll, 0.002),
        "attitude.pitch": noisy(pitch, 0.002),
        "attitude.yaw": noisy(yaw, 0.002),
        "attitude.rollspeed": noisy(rates[:, 0], 0.005),
        "attitude.pitchspeed": noisy(rates[:, 1], 0.005),
        "attitude.yawspeed": noisy(rates[:, 2], 0.005),
        "highres_imu.xacc": noisy(f_body[:, 0], vibration),
        "highres_imu.yacc": noisy(f_body[:, 1], vibration),
        "highres_imu.zacc": noisy(f_body[:, 2], vibration),
        "highres_imu.xgyro": noisy(rates[:, 0], 0.005),
        "highres_imu.ygyro": noisy(rates[:, 1], 0.005),
        "highres_imu.zgyro": noisy(rates[:, 2], 0.005),
        "highres_imu.xmag": noisy(mag_body[:, 0], 0.002),
        "highres_imu.ymag": noisy(mag_body[:, 1], 0.002),
        "highres_imu.zmag": noisy(mag_body[:, 2], 0.002),
        "highres_imu.abs_pressure": noisy(pressure, 0.012),
        "highres_imu.pressure_alt": noisy(alt_amsl, 0.1),
        "highres_imu.temperature": noisy(25.0 + rng.normal(0.0, 1.0) + 0.01 * t, 0.05),
        "global_position_int.lat": HOME_LAT + pos_est[:, 0] / M_PER_DEG_LAT,
        "global_position_int.lon": HOME_LON + pos_est[:, 1] / (M_PER_DEG_LAT * np.cos(lat0)),
        "global_position_int.alt": HOME_ALT - pos_est[:, 2],
        "global_position_int.relative_alt": -pos_est[:, 2],
        "global_position_int.vx": vel_est[:, 0],
        "global_position_int.vy": vel_est[:, 1],
        "global_position_int.vz": vel_est[:, 2],
        "global_position_int.hdg": np.mod(yaw, 2.0 * np.pi),
        "local_position_ned.x": pos_est[held, 0],
        "local_position_ned.y": pos_est[held, 1],
        "local_position_ned.z": pos_est[held, 2],
        "local_position_ned.vx": vel_est[held, 0],
        "local_position_ned.vy": vel_est[held, 1],
        "local_position_ned.vz": vel_est[held, 2],
    }
    return pd.DataFrame(columns)


def normal_flights(n: int, seed: int, rows: int = 1500) -> list[pd.DataFrame]:
    """``n`` normal flights (combined tables at 50 Hz), reproducible from ``seed``."""
    return [_flight(np.random.default_rng([seed, 0, i]), rows) for i in range(n)]


def attacked_flight(seed: int, rows: int = 1500) -> pd.DataFrame:
    """A flight whose GPS position (global and local) carries 20 m white noise mid-flight.

    ``Is_Anomaly`` is 1 on the attacked rows (the middle fifth of the flight).
    """
    rng = np.random.default_rng([seed, 1])
    flight = _flight(rng, rows)
    start, end = (int(round(f * rows)) for f in ATTACK_WINDOW)
    k = end - start
    lat = flight["global_position_int.lat"].to_numpy()
    noise_lat = rng.normal(0.0, ATTACK_NOISE_M, k) / M_PER_DEG_LAT
    noise_lon = rng.normal(0.0, ATTACK_NOISE_M, k) / (M_PER_DEG_LAT * np.cos(np.radians(lat[start:end])))
    flight.loc[start : end - 1, "global_position_int.lat"] += noise_lat
    flight.loc[start : end - 1, "global_position_int.lon"] += noise_lon
    flight.loc[start : end - 1, "local_position_ned.x"] += rng.normal(0.0, ATTACK_NOISE_M, k)
    flight.loc[start : end - 1, "local_position_ned.y"] += rng.normal(0.0, ATTACK_NOISE_M, k)
    flight.loc[start : end - 1, "Is_Anomaly"] = 1
    return flight
