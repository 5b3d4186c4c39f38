"""The ``uorb`` view: a generated flight written with PX4 uORB topic names, fields and units.

A detector trained on generated flights can then score a real PX4 ULog imported with
:func:`scart_bench.generator.logs.importers.load_flight_file` (``scart-bench import``): the topics and
field names here are the importer's for a PX4 ULog (checked against the shared RflyMAD SIL log in
tests/test_uorb.py), in PX4's units (quaternion ``q_0..q_3`` w, x, y, z body FRD -> NED; NED
metres; latitude/longitude in degrees as the importer gives them; pressure in Pa).

Where it comes from: :func:`uorb_view` maps the flight's **simulator view** -- the messages the
flight controller itself composed, before the link and the navigator -- so it is what the flight
controller's internal topics hold:

- a ``sensor``-point attack (sensors -> estimator) alters what the flight controller receives:
  it shows in ``sensor_combined``, ``vehicle_air_data`` and ``vehicle_gps_position`` (and,
  through the estimator, in the attitude and position estimates);
- a ``link``-point attack alters the telemetry on its way to the navigator only: it never reaches
  the flight controller's topics. Its rows are still labelled (``Is_Anomaly`` marks when an
  attack was active, in every view, as in the simulator view); what the uORB view can show of it
  is the closed loop's physical reaction (the navigator steering on false data);
- a ``command``-point attack alters the setpoints the flight controller follows: its effect is
  in the estimates the vehicle's motion drives.

Rates are a PX4 log's (no value is interpolated or repeated). A flight flown with the uORB view
(``FlightConfig.uorb``, ``generate --uorb``) has the flight controller's own streams, recorded by
the engine at the rates of PX4's logger (generator.telemetry.schedule.UORB_STREAMS) and stamped
with the flight's timing like every topic (generator.telemetry.timing: the IMU's logger drops,
jitter): ``sensor_combined`` at ~190 Hz (200 Hz rows of the 250 Hz IMU, as IMU_INTEG_RATE makes
them; the shared logs 187-250 Hz), ``vehicle_attitude`` at 20 Hz, ``vehicle_local_position`` at
10 Hz, ``actuator_controls_0`` (the thrust demand) at 20 Hz and ``actuator_outputs`` (the motors'
PWM) at 10 Hz. The other topics are made of the simulator view's messages, on a clock of their own
where PX4 logs them slower (``UorbTopic.own_rate_hz``: the latest row at each tick):
``vehicle_air_data`` at 20 Hz, ``vehicle_global_position`` at 5 Hz. A flight without the streams
(csv mode) has ``sensor_combined`` at the simulator view's 50 Hz and no actuator topics.
Fields PX4 has that the generator does not produce
(estimator bookkeeping, receiver internals, device ids, absolute clocks) are left out, each named
with its reason in :data:`OMITTED`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from scart_bench.dataset import LABEL_COLUMNS, DatasetError, combine
from scart_bench.dataset.schema import HOME_ALT, HOME_LAT, HOME_LON, TOPICS
from scart_bench.generator.physics.rotation import quat_from_euler
from scart_bench.generator.telemetry.schedule import UORB_STREAMS

#: PX4's CONSTANTS_AIR_GAS_CONST (J/(kg K)) and 0 degC in K, as vehicle_air_data's ``rho`` uses them.
AIR_GAS_CONST = 287.1
ZERO_CELSIUS_K = 273.15
#: Microseconds one IMU sample covers (the 250 Hz simulation step): sensor_combined's integral_dt.
IMU_SAMPLE_US = 4000.0
#: PX4 SITL's PWM outputs (PWM_MAIN_MIN/MAX/DISARM, us): an output of thrust fraction u is 1000 + 1000 u
#: (the RflyMAD SIL log: 1263 at hover with a thrust demand of 0.264), 900 disarmed.
PWM_MIN, PWM_MAX, PWM_DISARMED = 1000.0, 2000.0, 900.0
N_MOTORS = 4

Columns = Callable[[pd.DataFrame], dict[str, np.ndarray]]


@dataclass(frozen=True)
class UorbTopic:
    """One uORB topic: what it is made of and how its fields are computed."""

    name: str
    source: str | None  # simulator-view topic (scart_bench.dataset.schema); None: only from ``stream``
    fields: tuple[str, ...]
    compute: Columns
    meaning: str
    #: a clock of its own (Hz): where the rows it is made of come faster, the topic has the row due at
    #: each tick (the latest sample), as PX4's logger writes it; None: every row
    own_rate_hz: float | None = None
    #: the flight controller's stream (generator.telemetry.schedule.UORB_STREAMS) it is made of when the
    #: flight was flown with the uORB view; else (csv mode, a recording) ``source``
    stream: str | None = None

    def source_rate_hz(self, from_stream: bool) -> float:
        """The rate of the rows the topic is made of (Hz): its stream's or its source message's."""
        if from_stream:
            return UORB_STREAMS[self.stream][0]
        return TOPICS[self.source].rate_hz

    def rate_from(self, from_stream: bool) -> float:
        """The rate of the topic's rows (Hz): its own clock's where that is slower, else its rows'."""
        rate = self.source_rate_hz(from_stream)
        return min(rate, self.own_rate_hz) if self.own_rate_hz is not None else rate

    @property
    def rate_hz(self) -> float:
        """The topic's rate in a flown flight's view (Hz): from its stream where it has one."""
        return self.rate_from(self.stream is not None)


def own_clock_rows(timestamps: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of the rows a topic on its own ``rate_hz`` clock takes from a faster source: the first
    row at or after each tick from the first row's time (sorted timestamps, µs)."""
    ts = np.asarray(timestamps, dtype=np.int64)
    if ts.size == 0:
        return np.zeros(0, dtype=np.int64)
    ticks = ts[0] + np.arange(0, ts[-1] - ts[0] + 1, 1e6 / rate_hz)
    return np.unique(np.searchsorted(ts, ticks, side="left"))


def _col(df: pd.DataFrame, name: str) -> np.ndarray:
    return df[name].to_numpy(dtype=np.float64)


def _sensor_combined(d: pd.DataFrame) -> dict[str, np.ndarray]:
    n = len(d)
    return {
        "gyro_rad_0": _col(d, "xgyro"), "gyro_rad_1": _col(d, "ygyro"), "gyro_rad_2": _col(d, "zgyro"),
        "gyro_integral_dt": np.full(n, IMU_SAMPLE_US),
        "accelerometer_timestamp_relative": np.zeros(n),  # accel and gyro are one sample
        "accelerometer_m_s2_0": _col(d, "xacc"), "accelerometer_m_s2_1": _col(d, "yacc"),
        "accelerometer_m_s2_2": _col(d, "zacc"),
        "accelerometer_integral_dt": np.full(n, IMU_SAMPLE_US),
    }


def _vehicle_attitude(d: pd.DataFrame) -> dict[str, np.ndarray]:
    if "q_0" in d.columns:  # the estimator's quaternion (its stream)
        return {f"q_{k}": _col(d, f"q_{k}") for k in range(4)}
    q = quat_from_euler(_col(d, "roll"), _col(d, "pitch"), _col(d, "yaw"))
    return {f"q_{k}": q[:, k] for k in range(4)}


def _vehicle_local_position(d: pd.DataFrame) -> dict[str, np.ndarray]:
    n = len(d)
    out = {k: _col(d, k) for k in ("x", "y", "z", "vx", "vy", "vz")}
    # the estimator's origin is home (the simulator's projection centre)
    out.update({"ref_lat": np.full(n, HOME_LAT), "ref_lon": np.full(n, HOME_LON), "ref_alt": np.full(n, HOME_ALT)})
    return out


def _vehicle_global_position(d: pd.DataFrame) -> dict[str, np.ndarray]:
    return {"lat": _col(d, "lat"), "lon": _col(d, "lon"), "alt": _col(d, "alt")}


def _vehicle_gps_position(d: pd.DataFrame) -> dict[str, np.ndarray]:
    return {
        "lat": _col(d, "lat"), "lon": _col(d, "lon"), "alt": _col(d, "alt"), "eph": _col(d, "eph"),
        "epv": _col(d, "epv"), "vel_m_s": _col(d, "vel"), "vel_n_m_s": _col(d, "vn"), "vel_e_m_s": _col(d, "ve"),
        "vel_d_m_s": _col(d, "vd"), "cog_rad": _col(d, "cog"), "fix_type": _col(d, "fix_type"),
        "satellites_used": _col(d, "satellites_visible"),
    }


def _vehicle_air_data(d: pd.DataFrame) -> dict[str, np.ndarray]:
    pa = _col(d, "abs_pressure") * 100.0  # hPa -> Pa
    temp = _col(d, "temperature")
    return {"baro_alt_meter": _col(d, "pressure_alt"), "baro_temp_celcius": temp, "baro_pressure_pa": pa,
            "rho": pa / (AIR_GAS_CONST * (temp + ZERO_CELSIUS_K))}


def _actuator_controls(d: pd.DataFrame) -> dict[str, np.ndarray]:
    return {"control_3": _col(d, "thrust")}


def _actuator_outputs(d: pd.DataFrame) -> dict[str, np.ndarray]:
    armed = _col(d, "armed") > 0.5
    out = {"noutputs": np.full(len(d), float(N_MOTORS))}
    for k in range(N_MOTORS):
        out[f"output_{k}"] = np.where(armed, PWM_MIN + (PWM_MAX - PWM_MIN) * _col(d, f"motor_{k}"), PWM_DISARMED)
    return out


def _battery_status(d: pd.DataFrame) -> dict[str, np.ndarray]:
    return {"voltage_v": _col(d, "voltage"), "current_a": _col(d, "current"), "remaining": _col(d, "remaining")}


#: The uORB topics of the view, in order, at a PX4 log's rates (its logger's default profile, as the
#: shared logs have them). A flight flown with the uORB view has the flight controller's own streams:
#: the IMU at ~200 Hz, the attitude at 20 Hz, the local position at 10 Hz and the actuators; a
#: flight without them (csv mode) has its simulator view's messages, the IMU at 50 Hz, on the same
#: clocks where those are slower. The baro rides on highres_imu (every 50 Hz row holds the latest
#: baro sample) rather than scaled_pressure (10 Hz), on a 20 Hz clock of its own as
#: ``vehicle_air_data`` has in PX4 logs (18.3-20 Hz in the shared logs); the global position on a
#: 5 Hz clock (the SIL log: 5.1 Hz).
UORB_TOPICS: dict[str, UorbTopic] = {t.name: t for t in (
    UorbTopic("sensor_combined", "highres_imu",
              ("gyro_rad_0", "gyro_rad_1", "gyro_rad_2", "gyro_integral_dt", "accelerometer_timestamp_relative",
               "accelerometer_m_s2_0", "accelerometer_m_s2_1", "accelerometer_m_s2_2", "accelerometer_integral_dt"),
              _sensor_combined, "IMU sample as the estimator receives it: gyro rad/s and specific force m/s^2, body FRD",
              stream="sensor_combined"),
    UorbTopic("vehicle_attitude", "attitude", ("q_0", "q_1", "q_2", "q_3"), _vehicle_attitude,
              "estimated attitude, unit quaternion (w, x, y, z), body FRD -> NED", own_rate_hz=20.0,
              stream="vehicle_attitude"),
    UorbTopic("vehicle_local_position", "local_position_ned",
              ("x", "y", "z", "vx", "vy", "vz", "ref_lat", "ref_lon", "ref_alt"), _vehicle_local_position,
              "estimated position (m) and velocity (m/s) NED from home; the origin (deg, m AMSL)", own_rate_hz=10.0,
              stream="vehicle_local_position"),
    UorbTopic("vehicle_global_position", "global_position_int", ("lat", "lon", "alt"), _vehicle_global_position,
              "estimated latitude, longitude (deg) and altitude AMSL (m)", own_rate_hz=5.0),
    UorbTopic("vehicle_gps_position", "gps_raw_int",
              ("lat", "lon", "alt", "eph", "epv", "vel_m_s", "vel_n_m_s", "vel_e_m_s", "vel_d_m_s", "cog_rad",
               "fix_type", "satellites_used"), _vehicle_gps_position,
              "GPS receiver output: deg, m AMSL, accuracies m, velocity m/s NED, course rad"),
    UorbTopic("vehicle_air_data", "highres_imu", ("baro_alt_meter", "baro_temp_celcius", "baro_pressure_pa", "rho"),
              _vehicle_air_data, "barometer: pressure Pa, temperature degC, altitude AMSL m, air density kg/m^3",
              own_rate_hz=20.0),
    UorbTopic("battery_status", "battery_status", ("voltage_v", "current_a", "remaining"), _battery_status,
              "battery: voltage V, current A, state of charge 0..1"),
    UorbTopic("actuator_controls_0", None, ("control_3",), _actuator_controls,
              "collective thrust demand, 0..1 of the maximum (0 disarmed): the hover throttle",
              stream="actuator_controls_0"),
    UorbTopic("actuator_outputs", None, ("noutputs", *(f"output_{k}" for k in range(N_MOTORS))), _actuator_outputs,
              "motor outputs as PWM us: 1000 + 1000 x the rotor's thrust fraction armed, 900 disarmed",
              own_rate_hz=10.0, stream="actuator_controls_0"),
)}
#: The topics a detector's table (:func:`uorb_table`) is made of: every topic of the view but the
#: actuators, which a csv-mode flight and many logs do not have.
TABLE_TOPICS = tuple(name for name in UORB_TOPICS if not name.startswith("actuator_"))

_ESTIMATOR = "estimator bookkeeping the generator's estimator does not publish"
_CLOCK = "an absolute clock of the flight controller (boot or UTC time), no sensor data"
_NOT_MODELLED = "not modelled by the generator"
_RECEIVER = "a GPS receiver internal the simulated receiver does not report"
#: Fields the importer gives for a PX4 ULog (RflyMAD SIL log) that the uORB view leaves out, and why.
OMITTED: dict[str, dict[str, str]] = {
    "sensor_combined": {"accelerometer_clipping": "clipping is " + _NOT_MODELLED},
    "vehicle_attitude": {
        "timestamp_sample": _CLOCK,
        **{f"delta_q_reset_{k}": _ESTIMATOR for k in range(4)}, "quat_reset_counter": _ESTIMATOR},
    "vehicle_local_position": {
        "timestamp_sample": _CLOCK, "ref_timestamp": _CLOCK,
        **{k: _ESTIMATOR for k in ("delta_xy_0", "delta_xy_1", "delta_z", "delta_vxy_0", "delta_vxy_1", "delta_vz",
                                   "delta_heading", "xy_reset_counter", "z_reset_counter", "vxy_reset_counter",
                                   "vz_reset_counter", "heading_reset_counter", "xy_valid", "z_valid",
                                   "v_xy_valid", "v_z_valid", "xy_global", "z_global", "vxy_max", "vz_max",
                                   "hagl_min", "hagl_max")},
        **{k: "not in the flight controller's LOCAL_POSITION_NED message the view is made of"
           for k in ("z_deriv", "ax", "ay", "az", "heading", "eph", "epv", "evh", "evv")},
        **{k: "no distance sensor is simulated" for k in ("dist_bottom", "dist_bottom_valid",
                                                         "dist_bottom_sensor_bitfield")}},
    "vehicle_global_position": {
        "timestamp_sample": _CLOCK, "alt_ellipsoid": "no geoid model: only altitude AMSL is simulated",
        **{k: _ESTIMATOR for k in ("delta_alt", "lat_lon_reset_counter", "alt_reset_counter", "dead_reckoning")},
        **{k: "not in the GLOBAL_POSITION_INT message the view is made of" for k in ("eph", "epv")},
        **{k: "no terrain estimate is simulated" for k in ("terrain_alt", "terrain_alt_valid")}},
    "vehicle_gps_position": {
        "time_utc_usec": _CLOCK, "timestamp_time_relative": _CLOCK,
        "alt_ellipsoid": "no geoid model: only altitude AMSL is simulated",
        **{k: _RECEIVER for k in ("s_variance_m_s", "c_variance_rad", "hdop", "vdop", "noise_per_ms",
                                  "jamming_indicator", "jamming_state", "vel_ned_valid", "selected")},
        **{k: "no dual-antenna heading is simulated" for k in ("heading", "heading_offset")}},
    "vehicle_air_data": {"timestamp_sample": _CLOCK, "baro_device_id": "a device id, no sensor data"},
    "actuator_controls_0": {
        "timestamp_sample": _CLOCK,
        **{f"control_{k}": "the roll, pitch and yaw demands: the generator's rate controller computes torques (N m), "
           "not PX4's normalised mixer inputs" for k in range(3)},
        **{f"control_{k}": "an auxiliary control (flaps, gear) a multicopter does not use" for k in range(4, 8)}},
    "actuator_outputs": {f"output_{k}": "no such output: the quadrotor has four motors" for k in range(N_MOTORS, 16)},
    "battery_status": {
        **{k: "the battery's filter is " + _NOT_MODELLED for k in ("voltage_filtered_v", "current_filtered_a",
                                                                  "current_average_a")},
        **{k: "a smart-battery report the simulated 4S analog pack does not give"
           for k in ("discharged_mah", "scale", "temperature", "cell_count", *(f"voltage_cell_v_{i}" for i in range(14)),
                     "max_cell_voltage_delta", "average_power", "available_energy", "remaining_capacity",
                     "design_capacity", "nominal_voltage", "capacity", "cycle_count", "run_time_to_empty",
                     "average_time_to_empty", "serial_number", "manufacture_date", "state_of_health", "max_error",
                     "interface_error", "average_time_to_full", "over_discharge_count", "connected", "source",
                     "priority", "id", "is_powering_off", "warning")}},
}


#: Column patterns (``topic.field`` globs, as ``Detector.exclude`` / ``scart-bench run --exclude`` take them)
#: whose values depend on where and with what vehicle a flight is flown, not on how it behaves: the
#: absolute position and altitude, the local frame's origin, the barometer's absolute pressure,
#: temperature and density (site elevation and weather), and the battery (the pack). Excluding them
#: lets a detector fitted on generated flights (Zurich, a 4S pack) score a log flown elsewhere.
SITE_DEPENDENT = ("*.lat", "*.lon", "*.alt", "vehicle_local_position.ref_*", "vehicle_air_data.*",
                  "battery_status.*")


def uorb_view(simulator: dict[str, pd.DataFrame], streams: dict[str, pd.DataFrame] | None = None
              ) -> dict[str, pd.DataFrame]:
    """The uORB topics of one flight from its simulator-view tables (``Timestamp``, labels, fields)
    and, where it was flown with them, the rows of the flight controller's streams, per uORB topic
    on its own clock and timing (``streams``: :func:`scart_bench.generator.telemetry.tables.
    uorb_stream_tables`), which a topic takes instead of its simulator-view message.

    Each table: ``Timestamp`` (µs from the flight's start, the row's), the label columns the
    source has (``Is_Anomaly``, ``Anomaly_Ids``, ``Anomaly_Kind``), then the uORB fields as float64.
    A uORB topic with neither its stream nor its source message is left out. Pure: the same tables
    give the same view.
    """
    streams = streams or {}
    out: dict[str, pd.DataFrame] = {}
    for name, topic in UORB_TOPICS.items():
        from_stream = name in streams
        src = streams[name] if from_stream else simulator.get(topic.source) if topic.source else None
        if src is None:
            continue
        if not from_stream and topic.own_rate_hz is not None and topic.own_rate_hz < topic.source_rate_hz(False):
            src = src.iloc[own_clock_rows(src["Timestamp"].to_numpy(), topic.own_rate_hz)]
        lead = ["Timestamp", *(c for c in LABEL_COLUMNS if c in src.columns)]
        table = src[lead].reset_index(drop=True).copy()
        values = topic.compute(src)
        for field in topic.fields:
            table[field] = np.asarray(values[field], dtype=np.float64)
        out[name] = table
    return out


def uorb_table(topics: dict[str, pd.DataFrame], windows=(), base_topic: str = "sensor_combined",
               names: tuple[str, ...] = TABLE_TOPICS) -> pd.DataFrame:
    """A detector's table of a flight's uORB topics: generated (:func:`uorb_view`) or imported from a
    PX4 ULog (:func:`scart_bench.generator.logs.importers.load_flight_file`).

    Only the uORB topics ``names`` (:data:`TABLE_TOPICS`: all but the actuators) and their fields are
    kept (an imported log's other topics and fields are dropped), resampled like a ``most_frequent``
    combined table on ``base_topic``'s timestamps (each topic's last value at or before the row).
    ``windows``: attack windows for the labels. Raises DatasetError naming a uORB topic or field the
    flight lacks.
    """
    kept: dict[str, pd.DataFrame] = {}
    for name in names:
        topic = UORB_TOPICS[name]
        if name not in topics:
            raise DatasetError(f"uORB topic {name!r} missing; the flight has {sorted(topics)}")
        df = topics[name]
        missing = [f for f in topic.fields if f not in df.columns]
        if missing:
            raise DatasetError(f"uORB topic {name!r}: field(s) {missing} missing")
        kept[name] = df[["Timestamp", *topic.fields]]
    return combine(kept, windows, base_topic=base_topic)["most_frequent"]
