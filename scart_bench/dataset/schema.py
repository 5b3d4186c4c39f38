"""The telemetry topics on the Simulator <-> Navigator link, with fields, units and rates.

Names follow the MAVLink messages PX4 streams on its onboard link, in snake case. Values are
stored in physical units (metres, m/s, rad, degrees of latitude/longitude), not MAVLink's
scaled integers. This table is the single source of truth for the generator, the attack layer
(unit conversion of magnitudes) and the documentation (``docs/topics.md`` is generated from it).
"""

from __future__ import annotations

from dataclasses import dataclass

#: The PX4 SITL home (Zurich, Gazebo default world).
HOME_LAT = 47.397742
HOME_LON = 8.545594
HOME_ALT = 488.0

#: Simulation step rate; every topic is published on this clock.
SIM_RATE_HZ = 250


@dataclass(frozen=True)
class Field:
    """One field of a topic: its name, unit and meaning."""

    name: str
    unit: str
    meaning: str
    #: Physical quantity the attack layer converts magnitudes from: "position_n",
    #: "position_e", "position_d" (metres along NED), "latitude"/"longitude" (metres -> degrees),
    #: "velocity", "angle", "rate", "accel", "field", "pressure", "other".
    quantity: str = "other"


@dataclass(frozen=True)
class Topic:
    """One telemetry message type on the link."""

    name: str
    rate_hz: float
    direction: str  # "telemetry" (flight controller -> navigator) or "command"
    fields: tuple[Field, ...]
    meaning: str

    @property
    def field_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)

    def columns(self) -> list[str]:
        """Column names of this topic in the combined tables (``topic.field``)."""
        return [f"{self.name}.{f.name}" for f in self.fields]


TOPICS: dict[str, Topic] = {
    t.name: t
    for t in (
        Topic(
            "attitude", 50.0, "telemetry",
            (
                Field("roll", "rad", "roll angle (FRD body, NED world)", "angle"),
                Field("pitch", "rad", "pitch angle", "angle"),
                Field("yaw", "rad", "yaw angle, 0 = north, wrapped to (-pi, pi]", "angle"),
                Field("rollspeed", "rad/s", "body roll rate", "rate"),
                Field("pitchspeed", "rad/s", "body pitch rate", "rate"),
                Field("yawspeed", "rad/s", "body yaw rate", "rate"),
            ),
            "estimated attitude (ATTITUDE)",
        ),
        Topic(
            "highres_imu", 50.0, "telemetry",
            (
                Field("xacc", "m/s^2", "specific force, body x (forward)", "accel"),
                Field("yacc", "m/s^2", "specific force, body y (right)", "accel"),
                Field("zacc", "m/s^2", "specific force, body z (down); about -9.81 in hover", "accel"),
                Field("xgyro", "rad/s", "angular rate, body x", "rate"),
                Field("ygyro", "rad/s", "angular rate, body y", "rate"),
                Field("zgyro", "rad/s", "angular rate, body z", "rate"),
                Field("xmag", "gauss", "magnetic field, body x", "field"),
                Field("ymag", "gauss", "magnetic field, body y", "field"),
                Field("zmag", "gauss", "magnetic field, body z", "field"),
                Field("abs_pressure", "hPa", "static pressure", "pressure"),
                Field("pressure_alt", "m", "barometric altitude AMSL", "position_up"),
                Field("temperature", "degC", "sensor temperature", "other"),
            ),
            "raw IMU, magnetometer and barometer sample (HIGHRES_IMU)",
        ),
        Topic(
            "global_position_int", 50.0, "telemetry",
            (
                Field("lat", "deg", "latitude (WGS84), float64", "latitude"),
                Field("lon", "deg", "longitude (WGS84), float64", "longitude"),
                Field("alt", "m", "altitude AMSL", "position_up"),
                Field("relative_alt", "m", "altitude above home", "position_up"),
                Field("vx", "m/s", "ground velocity north", "velocity_n"),
                Field("vy", "m/s", "ground velocity east", "velocity_e"),
                Field("vz", "m/s", "ground velocity down", "velocity_d"),
                Field("hdg", "rad", "heading, 0 = north, wrapped to [0, 2 pi)", "angle"),
            ),
            "fused global position estimate (GLOBAL_POSITION_INT)",
        ),
        Topic(
            "local_position_ned", 30.0, "telemetry",
            (
                Field("x", "m", "position north of home", "position_n"),
                Field("y", "m", "position east of home", "position_e"),
                Field("z", "m", "position down from home", "position_d"),
                Field("vx", "m/s", "velocity north", "velocity_n"),
                Field("vy", "m/s", "velocity east", "velocity_e"),
                Field("vz", "m/s", "velocity down", "velocity_d"),
            ),
            "fused local position estimate (LOCAL_POSITION_NED)",
        ),
        Topic(
            "gps_raw_int", 10.0, "telemetry",
            (
                Field("lat", "deg", "GPS latitude (WGS84), float64", "latitude"),
                Field("lon", "deg", "GPS longitude (WGS84), float64", "longitude"),
                Field("alt", "m", "GPS altitude AMSL", "position_up"),
                Field("eph", "m", "horizontal accuracy (1 sigma)", "other"),
                Field("epv", "m", "vertical accuracy (1 sigma)", "other"),
                Field("vel", "m/s", "ground speed", "speed"),
                Field("cog", "rad", "course over ground, 0 = north, [0, 2 pi)", "angle"),
                Field("vn", "m/s", "GPS velocity north", "velocity_n"),
                Field("ve", "m/s", "GPS velocity east", "velocity_e"),
                Field("vd", "m/s", "GPS velocity down", "velocity_d"),
                Field("fix_type", "enum", "0-1 no fix, 2 2D, 3 3D fix", "other"),
                Field("satellites_visible", "count", "satellites used", "other"),
            ),
            "raw GPS receiver output (GPS_RAW_INT, with the NED velocity of PX4 sensor_gps)",
        ),
        Topic(
            "scaled_pressure", 10.0, "telemetry",
            (
                Field("press_abs", "hPa", "static pressure", "pressure"),
                Field("temperature", "degC", "barometer temperature", "other"),
            ),
            "barometer (SCALED_PRESSURE)",
        ),
        Topic(
            "altitude", 10.0, "telemetry",
            (
                Field("altitude_amsl", "m", "estimated altitude AMSL", "position_up"),
                Field("altitude_local", "m", "estimated altitude above home (= -z)", "position_up"),
                Field("altitude_relative", "m", "altitude above home", "position_up"),
            ),
            "altitude estimate (ALTITUDE)",
        ),
        Topic(
            "battery_status", 2.0, "telemetry",
            (
                Field("voltage", "V", "battery voltage (4S pack)", "other"),
                Field("current", "A", "battery current", "other"),
                Field("remaining", "1", "state of charge, 0..1", "other"),
            ),
            "battery (BATTERY_STATUS)",
        ),
        Topic(
            "setpoint", 50.0, "command",
            (
                Field("vx", "m/s", "velocity setpoint north", "velocity_n"),
                Field("vy", "m/s", "velocity setpoint east", "velocity_e"),
                Field("vz", "m/s", "velocity setpoint down", "velocity_d"),
                Field("yaw", "rad", "yaw setpoint", "angle"),
                Field("seq", "index", "current mission item (MISSION_CURRENT)", "other"),
                Field("armed", "0/1", "arm request", "other"),
            ),
            "navigator -> flight controller offboard setpoint (SET_POSITION_TARGET_LOCAL_NED)",
        ),
    )
}

TELEMETRY_TOPICS = tuple(n for n, t in TOPICS.items() if t.direction == "telemetry")
COMMAND_TOPICS = tuple(n for n, t in TOPICS.items() if t.direction == "command")

#: Ground-truth vehicle state recorded in the simulator view only (never on the link).
TRUTH_FIELDS = ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "armed", "landed")
TRUTH_RATE_HZ = 50.0

#: Columns that every combined table starts with (the paper's layout).
LEADING_COLUMNS = ("Index", "Timestamp", "Is_Anomaly")


def sensor_columns(columns) -> list[str]:
    """The numeric sensor columns of a combined table (``topic.field``), in order."""
    return [c for c in columns if "." in c]


def topics_markdown() -> str:
    """The topic table as Markdown (for docs/topics.md)."""
    lines = [
        "| topic | field | unit | rate (Hz) | direction | meaning |",
        "|---|---|---|---|---|---|",
    ]
    for t in TOPICS.values():
        for f in t.fields:
            lines.append(f"| {t.name} | {f.name} | {f.unit} | {t.rate_hz:g} | {t.direction} | {f.meaning} |")
    return "\n".join(lines) + "\n"
