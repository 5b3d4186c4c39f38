"""The MAVROS topics the SCART node carries, as dataset topics in MAVROS's own frames and units.

A topic's dataset name is its MAVROS name relative to the namespace, with ``/`` as ``_``
(``local_position/pose`` -> ``local_position_pose``). Fields are named after the message fields
(``x``, ``latitude``, ``fluid_pressure``; the quaternion ``qx..qw``, angular velocity ``wx..wz``,
linear acceleration ``ax..az``) and keep MAVROS's conventions: local positions and velocities in
ENU (x east, y north, z up), body vectors in FLU (y left, z up), degrees of latitude/longitude,
tesla, pascal. Each field carries the quantity the SCART layer converts magnitudes with
(:mod:`scart_bench.generator.scart.units`), so a bias "north 5 m" moves ``y`` of an ENU pose, and a
body-z offset of the project's FRD convention lands on FLU ``z`` with its sign flipped. Nothing here
imports ROS: the transports (ROS 1 now, ROS 2 later) use ``msg_type`` and ``paths``. It lives with the
telemetry, below the attack layer (which reads the quantities) and the ROS node (which carries the topics);
``scart_bench.generator.ros.topics`` still names everything here.
"""

from __future__ import annotations

from dataclasses import dataclass

from scart_bench.dataset.schema import Field


@dataclass(frozen=True)
class RosTopic:
    """One MAVROS topic: dataset name, name under the MAVROS namespace, message type, fields, where they are."""

    name: str
    ros_name: str
    msg_type: str
    rate_hz: float
    fields: tuple[Field, ...]
    paths: tuple[str, ...]  # attribute path of each field inside the message
    direction: str = (
        "telemetry"  # telemetry (flight controller -> mission computer) or mission (its progress)
    )

    @property
    def field_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)

    @property
    def stamped(self) -> bool:
        """The message has a std_msgs/Header (the layer's clock)."""
        return self.msg_type not in ("std_msgs/Float64", "std_msgs/UInt16")


def _q(prefix: str) -> tuple[tuple[Field, ...], tuple[str, ...]]:
    fields = tuple(Field(f"q{a}", "1", f"orientation quaternion {a} (ENU world, FLU body)") for a in "xyzw")
    return fields, tuple(f"{prefix}.{a}" for a in "xyzw")


def _topic(
    name: str,
    ros_name: str,
    msg_type: str,
    rate_hz: float,
    spec: list[tuple[Field, str]],
    direction: str = "telemetry",
) -> RosTopic:
    return RosTopic(
        name, ros_name, msg_type, rate_hz, tuple(f for f, _ in spec), tuple(p for _, p in spec), direction
    )


_QF, _QP = _q("pose.orientation")
_IQF, _IQP = _q("orientation")
_FIX = [
    (Field("latitude", "deg", "latitude (WGS-84)", "latitude"), "latitude"),
    (Field("longitude", "deg", "longitude (WGS-84)", "longitude"), "longitude"),
    (
        Field(
            "altitude",
            "m",
            "altitude (the stand-in: AMSL; MAVROS: above the WGS-84 ellipsoid)",
            "position_up",
        ),
        "altitude",
    ),
]
_ENU_VEL = [
    (Field("vx", "m/s", "velocity east (ENU)", "velocity_e"), "twist.linear.x"),
    (Field("vy", "m/s", "velocity north (ENU)", "velocity_n"), "twist.linear.y"),
    (Field("vz", "m/s", "velocity up (ENU)", "velocity_up"), "twist.linear.z"),
]

#: dataset name -> topic, telemetry as MAVROS publishes it (plugins global_position, local_position, imu, battery)
MAVROS_TOPICS: dict[str, RosTopic] = {
    t.name: t
    for t in (
        _topic("global_position_global", "global_position/global", "sensor_msgs/NavSatFix", 50.0, _FIX),
        _topic(
            "global_position_rel_alt",
            "global_position/rel_alt",
            "std_msgs/Float64",
            50.0,
            [(Field("data", "m", "altitude above home", "position_up"), "data")],
        ),
        _topic(
            "global_position_compass_hdg",
            "global_position/compass_hdg",
            "std_msgs/Float64",
            50.0,
            [(Field("data", "deg", "heading, 0 = north, clockwise", "angle_deg"), "data")],
        ),
        _topic("global_position_raw_fix", "global_position/raw/fix", "sensor_msgs/NavSatFix", 10.0, _FIX),
        _topic(
            "global_position_raw_gps_vel",
            "global_position/raw/gps_vel",
            "geometry_msgs/TwistStamped",
            10.0,
            _ENU_VEL,
        ),
        _topic(
            "local_position_pose",
            "local_position/pose",
            "geometry_msgs/PoseStamped",
            30.0,
            [
                (Field("x", "m", "position east of the origin (ENU)", "position_e"), "pose.position.x"),
                (Field("y", "m", "position north of the origin (ENU)", "position_n"), "pose.position.y"),
                (Field("z", "m", "position up from the origin (ENU)", "position_up"), "pose.position.z"),
                *zip(_QF, _QP, strict=True),
            ],
        ),
        _topic(
            "local_position_velocity_local",
            "local_position/velocity_local",
            "geometry_msgs/TwistStamped",
            30.0,
            [
                *_ENU_VEL,
                (Field("wx", "rad/s", "angular rate about body x (forward)", "rate"), "twist.angular.x"),
                (Field("wy", "rad/s", "angular rate about body y (left)", "rate_flu"), "twist.angular.y"),
                (Field("wz", "rad/s", "angular rate about body z (up)", "rate_flu"), "twist.angular.z"),
            ],
        ),
        _topic(
            "imu_data",
            "imu/data",
            "sensor_msgs/Imu",
            50.0,
            [
                *zip(_IQF, _IQP, strict=True),
                (Field("wx", "rad/s", "angular rate about body x (forward)", "rate"), "angular_velocity.x"),
                (Field("wy", "rad/s", "angular rate about body y (left)", "rate_flu"), "angular_velocity.y"),
                (Field("wz", "rad/s", "angular rate about body z (up)", "rate_flu"), "angular_velocity.z"),
                (Field("ax", "m/s^2", "specific force, body x (forward)", "accel"), "linear_acceleration.x"),
                (Field("ay", "m/s^2", "specific force, body y (left)", "accel_flu"), "linear_acceleration.y"),
                (
                    Field("az", "m/s^2", "specific force, body z (up); about +9.81 in hover", "accel_flu"),
                    "linear_acceleration.z",
                ),
            ],
        ),
        _topic(
            "imu_mag",
            "imu/mag",
            "sensor_msgs/MagneticField",
            50.0,
            [
                (Field("x", "T", "magnetic field, body x (forward)", "field_tesla"), "magnetic_field.x"),
                (Field("y", "T", "magnetic field, body y (left)", "field_tesla_flu"), "magnetic_field.y"),
                (Field("z", "T", "magnetic field, body z (up)", "field_tesla_flu"), "magnetic_field.z"),
            ],
        ),
        _topic(
            "imu_static_pressure",
            "imu/static_pressure",
            "sensor_msgs/FluidPressure",
            10.0,
            [
                (Field("fluid_pressure", "Pa", "static pressure", "pressure_pa"), "fluid_pressure"),
                (Field("variance", "Pa^2", "its variance"), "variance"),
            ],
        ),
        _topic(
            "battery",
            "battery",
            "sensor_msgs/BatteryState",
            2.0,
            [
                (Field("voltage", "V", "battery voltage"), "voltage"),
                (Field("current", "A", "battery current (MAVROS: negative while discharging)"), "current"),
                (Field("percentage", "1", "charge left, 0..1"), "percentage"),
            ],
        ),
        _topic(
            "mission_current",
            "mission/current",
            "std_msgs/UInt16",
            1.0,
            [(Field("data", "", "the mission item the navigator flies to (0: the first corner)"), "data")],
            direction="mission",
        ),
    )
}

#: The setpoints the mission computer sends (to the flight controller, not through the node by default).
SETPOINT_POSITION = ("setpoint_position/local", "geometry_msgs/PoseStamped")
SETPOINT_VELOCITY = ("setpoint_velocity/cmd_vel", "geometry_msgs/TwistStamped")
#: The stand-in's own command and state topics (MAVROS offers services of mavros_msgs, absent here).
COMMAND = ("command", "std_msgs/String")
STATE = ("state", "std_msgs/String")


def topic_fields(topics: dict[str, RosTopic] | None = None) -> dict[str, tuple[str, ...]]:
    """topic -> field names (what the SCART layer resolves scenarios against)."""
    return {n: t.field_names for n, t in (topics or MAVROS_TOPICS).items()}


def field_quantity(topic: str, field: str) -> str | None:
    """The quantity of a MAVROS topic's field, or None when ``topic`` is not one of them."""
    t = MAVROS_TOPICS.get(topic)
    if t is None or field not in t.field_names:
        return None
    return t.fields[t.field_names.index(field)].quantity
