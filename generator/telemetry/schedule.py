"""The Simulator <-> Navigator link: topic schedules and message composition.

Every topic is published on the simulation clock at its documented rate: a topic of rate ``r`` is
due at step ``k`` when ``floor(k r / f_sim)`` increments (always at step 0), which gives the exact
mean rate with at most one simulation step (4 ms) of jitter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scart_bench.dataset.schema import HOME_ALT, SIM_RATE_HZ, TOPICS
from scart_bench.generator.geo import altitude_at, ned_to_latlon
from scart_bench.generator.physics.rotation import euler_from_quat

#: Sensor-level topics (sensors -> flight-controller estimator), for the ``sensor`` injection point.
SENSOR_TOPICS: dict[str, tuple[float, tuple[str, ...]]] = {
    "sensor_accel": (250.0, ("x", "y", "z")),
    "sensor_gyro": (250.0, ("x", "y", "z")),
    "sensor_mag": (100.0, ("x", "y", "z")),
    "sensor_baro": (50.0, ("pressure", "temperature")),
    "sensor_gps": (10.0, ("lat", "lon", "alt", "vn", "ve", "vd", "eph", "epv", "satellites_used", "fix_type")),
}


#: The flight controller's own streams, recorded for the uORB view (generator.telemetry.uorb) when a
#: flight is flown with ``FlightConfig.uorb``: name (the uORB topic it makes) -> (rate Hz, fields).
#: The rates are a PX4 log's (its logger's default profile, as the shared logs show it): the IMU at
#: IMU_INTEG_RATE (200 Hz, from the 250 Hz samples: 4 and 8 ms intervals), the attitude at 20 Hz, the
#: local position at 10 Hz, the actuator controls at 20 Hz (actuator outputs: every second row).
#: Values: the IMU sample the estimator receives (after a sensor-point attack), the estimator's
#: quaternion (body FRD -> NED), the output position (m) and velocity (m/s) NED the telemetry uses,
#: the mixer's motor commands as thrust fractions (0-1 of a rotor's maximum; 0 disarmed), the
#: collective thrust setpoint (0-1 of the maximum) and the armed state (0/1).
UORB_STREAMS: dict[str, tuple[float, tuple[str, ...]]] = {
    "sensor_combined": (200.0, ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro")),
    "vehicle_attitude": (20.0, ("q_0", "q_1", "q_2", "q_3")),
    "vehicle_local_position": (10.0, ("x", "y", "z", "vx", "vy", "vz")),
    "actuator_controls_0": (20.0, ("motor_0", "motor_1", "motor_2", "motor_3", "thrust", "armed")),
}


def due_steps(rate_hz: float, n_steps: int, sim_rate: float = SIM_RATE_HZ) -> np.ndarray:
    """Boolean (n_steps,) mask of the steps at which a topic of ``rate_hz`` is published."""
    k = np.arange(n_steps)
    ticks = np.floor(k * rate_hz / sim_rate + 1e-9)
    due = np.empty(n_steps, dtype=bool)
    due[0] = True
    due[1:] = ticks[1:] != ticks[:-1]
    return due


def is_due(rate_hz: float, step: int) -> bool:
    """Whether a message of ``rate_hz`` is published at ``step``: one step of :func:`due_steps`, for the
    loops that fly step by step (hardware and software in the loop)."""
    if step == 0:
        return True
    return np.floor(step * rate_hz / SIM_RATE_HZ + 1e-9) != np.floor((step - 1) * rate_hz / SIM_RATE_HZ + 1e-9)


@dataclass
class FCSnapshot:
    """What the flight controller knows at one step, from which telemetry is composed."""

    quat: np.ndarray
    rates: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    accel: np.ndarray  # last IMU sample (as received by the estimator)
    gyro: np.ndarray
    mag: np.ndarray
    pressure: np.ndarray  # Pa
    baro_temp: np.ndarray
    gps: dict
    battery: np.ndarray  # (N, 3) voltage, current, remaining
    baro_home_alt: np.ndarray  # (N,)


def compose(topic: str, s: FCSnapshot) -> np.ndarray:
    """The (N, n_fields) message of a telemetry topic, in the field order of scart_bench.dataset.schema."""
    if topic == "attitude":
        eul = euler_from_quat(s.quat)
        return np.column_stack([eul, s.rates])
    if topic == "highres_imu":
        press_hpa = s.pressure / 100.0
        return np.column_stack([s.accel, s.gyro, s.mag, press_hpa, altitude_at(s.pressure), s.baro_temp])
    if topic == "global_position_int":
        lat, lon = ned_to_latlon(s.pos[:, 0], s.pos[:, 1])
        yaw = euler_from_quat(s.quat)[:, 2]
        hdg = np.mod(yaw, 2 * np.pi)
        return np.column_stack([lat, lon, HOME_ALT - s.pos[:, 2], -s.pos[:, 2], s.vel, hdg])
    if topic == "local_position_ned":
        return np.column_stack([s.pos, s.vel])
    if topic == "gps_raw_int":
        g = s.gps
        lat, lon = ned_to_latlon(g["pos"][:, 0], g["pos"][:, 1])
        v = g["vel"]
        vel = np.hypot(v[:, 0], v[:, 1])
        cog = np.mod(np.arctan2(v[:, 1], v[:, 0]), 2 * np.pi)
        return np.column_stack([lat, lon, HOME_ALT - g["pos"][:, 2], g["eph"], g["epv"], vel, cog, v,
                                g["fix_type"], g["satellites"]])
    if topic == "scaled_pressure":
        return np.column_stack([s.pressure / 100.0, s.baro_temp])
    if topic == "altitude":
        return np.column_stack([HOME_ALT - s.pos[:, 2], -s.pos[:, 2], -s.pos[:, 2]])
    if topic == "battery_status":
        return s.battery.copy()
    raise KeyError(f"no composer for topic {topic!r}")


def field_names(topic: str) -> tuple[str, ...]:
    """Field names of a link or sensor topic."""
    if topic in TOPICS:
        return TOPICS[topic].field_names
    if topic in SENSOR_TOPICS:
        return SENSOR_TOPICS[topic][1]
    if topic in UORB_STREAMS:
        return UORB_STREAMS[topic][1]
    from scart_bench.generator.flight_software.commander import CONTROL_TOPICS

    if topic in CONTROL_TOPICS:
        return CONTROL_TOPICS[topic]
    if topic == "truth":
        from scart_bench.dataset.schema import TRUTH_FIELDS

        return TRUTH_FIELDS
    raise KeyError(topic)
