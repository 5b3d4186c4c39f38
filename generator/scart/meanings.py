"""Topics by meaning: scenario targets and condition topics named by what they measure.

A scenario may name a *quantity* (``gps``, ``position``, ...) instead of a topic, alone (every
field of the quantity) or with one of its fields (``gps.lat``). Against a given input (the
topics passing an injection point of the generator, or the topics of a user's log) a quantity
resolves to every candidate ``topic.field`` the input has: MAVLink names on generated flights,
PX4 uORB names on ULogs, the generator's sensor topics at the sensor point, and the MAVROS topics of
the ROS node (generator.ros.topics, ENU). The table below
is the documented mapping (docs/scenarios.md's "Topics by meaning" table is generated from it by
``python -m scart_bench.cli.doc_tables``; tests/test_doc_tables.py fails when they differ).

An action target that is a topic of the input is that topic (``altitude`` on a generated flight
is the ALTITUDE message); otherwise a quantity is resolved. A condition's ``topic`` that is a
quantity always resolves as one (PX4 logs have a uORB topic named ``mission``), to the first
candidate topic that has what the condition reads. Nothing resolving is an error naming it.
"""

from __future__ import annotations

from scart_bench.generator.scart.spec import ScenarioError

#: quantity -> field -> candidates ("topic.field"), MAVLink / generator sensor / PX4 uORB.
QUANTITIES: dict[str, dict[str, tuple[str, ...]]] = {
    "position": {
        "lat": ("global_position_int.lat", "gps_raw_int.lat", "sensor_gps.lat", "vehicle_global_position.lat",
                "vehicle_gps_position.lat", "vehicle_gps_position.latitude_deg", "sensor_gps.latitude_deg",
                "gps.Lat", "pos.Lat", "ahr2.Lat", "global_position_global.latitude",
                "global_position_raw_fix.latitude"),
        "lon": ("global_position_int.lon", "gps_raw_int.lon", "sensor_gps.lon", "vehicle_global_position.lon",
                "vehicle_gps_position.lon", "vehicle_gps_position.longitude_deg", "sensor_gps.longitude_deg",
                "gps.Lng", "pos.Lng", "ahr2.Lng", "global_position_global.longitude",
                "global_position_raw_fix.longitude"),
        # ArduPilot's EKF position: EKF1 (the first EKF), NKF1 (EKF2), XKF1 (EKF3), the primary core
        "x": ("local_position_ned.x", "vehicle_local_position.x", "ekf1.PN", "nkf1.PN", "xkf1.PN",
              "local_position_pose.y"),
        "y": ("local_position_ned.y", "vehicle_local_position.y", "ekf1.PE", "nkf1.PE", "xkf1.PE",
              "local_position_pose.x"),
    },
    "velocity": {
        "vn": ("global_position_int.vx", "local_position_ned.vx", "gps_raw_int.vn", "sensor_gps.vn",
               "vehicle_local_position.vx", "vehicle_gps_position.vel_n_m_s", "sensor_gps.vel_n_m_s", "ekf1.VN",
               "nkf1.VN", "xkf1.VN", "local_position_velocity_local.vy", "global_position_raw_gps_vel.vy"),
        "ve": ("global_position_int.vy", "local_position_ned.vy", "gps_raw_int.ve", "sensor_gps.ve",
               "vehicle_local_position.vy", "vehicle_gps_position.vel_e_m_s", "sensor_gps.vel_e_m_s", "ekf1.VE",
               "nkf1.VE", "xkf1.VE", "local_position_velocity_local.vx", "global_position_raw_gps_vel.vx"),
        "vd": ("global_position_int.vz", "local_position_ned.vz", "gps_raw_int.vd", "sensor_gps.vd",
               "vehicle_local_position.vz", "vehicle_gps_position.vel_d_m_s", "sensor_gps.vel_d_m_s", "ekf1.VD",
               "nkf1.VD", "xkf1.VD", "gps.VZ", "local_position_velocity_local.vz", "global_position_raw_gps_vel.vz"),
    },
    "altitude": {
        "z": ("local_position_ned.z", "vehicle_local_position.z", "ekf1.PD", "nkf1.PD", "xkf1.PD",
              "local_position_pose.z"),
        "relative": ("global_position_int.relative_alt", "altitude.altitude_relative", "ctun.Alt", "gps.RelAlt",
                     "pos.RelHomeAlt", "global_position_rel_alt.data"),
        "amsl": ("global_position_int.alt", "altitude.altitude_amsl", "vehicle_global_position.alt", "ahr2.Alt",
                 "pos.Alt", "global_position_global.altitude"),
    },
    "attitude": {
        # ArduPilot's ATT, AHR2 and EKF attitudes in degrees (generator.scart.units); a quaternion's roll,
        # pitch and yaw (PX4's vehicle_attitude.q, a ROS orientation) are derived on a recording's
        # replay and written back as a rotated quaternion (generator.logs.orientation)
        "roll": ("attitude.roll", "att.Roll", "ahr2.Roll", "ekf1.Roll", "nkf1.Roll", "xkf1.Roll",
                 "vehicle_attitude.roll", "highres_imu.roll", "imu_data.roll", "imu.roll", "local_position_ned.roll"),
        "pitch": ("attitude.pitch", "att.Pitch", "ahr2.Pitch", "ekf1.Pitch", "nkf1.Pitch", "xkf1.Pitch",
                  "vehicle_attitude.pitch", "highres_imu.pitch", "imu_data.pitch", "imu.pitch",
                  "local_position_ned.pitch"),
        "yaw": ("attitude.yaw", "att.Yaw", "ahr2.Yaw", "ekf1.Yaw", "nkf1.Yaw", "xkf1.Yaw", "vehicle_attitude.yaw",
                "highres_imu.yaw", "imu_data.yaw", "imu.yaw", "local_position_ned.yaw"),
        # PX4's quaternion itself (w, x, y, z): one rotation, never a target of its own (see PARTS)
        "q": ("vehicle_attitude.q_0", "vehicle_attitude.q_1", "vehicle_attitude.q_2", "vehicle_attitude.q_3"),
    },
    "gps": {
        "lat": ("gps_raw_int.lat", "sensor_gps.lat", "vehicle_gps_position.lat", "vehicle_gps_position.latitude_deg",
                "sensor_gps.latitude_deg", "gps.Lat", "global_position_raw_fix.latitude"),
        "lon": ("gps_raw_int.lon", "sensor_gps.lon", "vehicle_gps_position.lon", "vehicle_gps_position.longitude_deg",
                "sensor_gps.longitude_deg", "gps.Lng", "global_position_raw_fix.longitude"),
        "alt": ("gps_raw_int.alt", "sensor_gps.alt", "vehicle_gps_position.alt", "vehicle_gps_position.altitude_msl_m",
                "sensor_gps.altitude_msl_m", "gps.Alt", "global_position_raw_fix.altitude"),
        "vn": ("gps_raw_int.vn", "sensor_gps.vn", "vehicle_gps_position.vel_n_m_s", "sensor_gps.vel_n_m_s",
               "global_position_raw_gps_vel.vy"),
        "ve": ("gps_raw_int.ve", "sensor_gps.ve", "vehicle_gps_position.vel_e_m_s", "sensor_gps.vel_e_m_s",
               "global_position_raw_gps_vel.vx"),
        "vd": ("gps_raw_int.vd", "sensor_gps.vd", "vehicle_gps_position.vel_d_m_s", "sensor_gps.vel_d_m_s", "gps.VZ",
               "global_position_raw_gps_vel.vz"),
        "cog": ("gps_raw_int.cog", "vehicle_gps_position.cog_rad", "sensor_gps.cog_rad", "gps.GCrs"),
    },
    "imu": {
        "xacc": ("highres_imu.xacc", "sensor_accel.x", "sensor_combined.accelerometer_m_s2_0", "imu.AccX", "imu_data.ax"),
        "yacc": ("highres_imu.yacc", "sensor_accel.y", "sensor_combined.accelerometer_m_s2_1", "imu.AccY", "imu_data.ay"),
        "zacc": ("highres_imu.zacc", "sensor_accel.z", "sensor_combined.accelerometer_m_s2_2", "imu.AccZ", "imu_data.az"),
        "xgyro": ("highres_imu.xgyro", "sensor_gyro.x", "sensor_combined.gyro_rad_0", "imu.GyrX", "imu_data.wx"),
        "ygyro": ("highres_imu.ygyro", "sensor_gyro.y", "sensor_combined.gyro_rad_1", "imu.GyrY", "imu_data.wy"),
        "zgyro": ("highres_imu.zgyro", "sensor_gyro.z", "sensor_combined.gyro_rad_2", "imu.GyrZ", "imu_data.wz"),
    },
    "baro": {
        "pressure": ("scaled_pressure.press_abs", "highres_imu.abs_pressure", "sensor_baro.pressure",
                     "vehicle_air_data.baro_pressure_pa", "baro.Press",
                     "imu_static_pressure.fluid_pressure"),
        "alt": ("highres_imu.pressure_alt", "vehicle_air_data.baro_alt_meter", "baro.Alt"),
    },
    "mag": {
        "x": ("highres_imu.xmag", "sensor_mag.x", "vehicle_magnetometer.magnetometer_ga_0", "mag.MagX", "imu_mag.x"),
        "y": ("highres_imu.ymag", "sensor_mag.y", "vehicle_magnetometer.magnetometer_ga_1", "mag.MagY", "imu_mag.y"),
        "z": ("highres_imu.zmag", "sensor_mag.z", "vehicle_magnetometer.magnetometer_ga_2", "mag.MagZ", "imu_mag.z"),
    },
    "battery": {
        "voltage": ("battery_status.voltage", "battery_status.voltage_v", "curr.Volt", "bat.Volt", "battery.voltage"),
        "current": ("battery_status.current", "battery_status.current_a", "curr.Curr", "bat.Curr", "battery.current"),
        "remaining": ("battery_status.remaining",),
    },
    "mission": {
        # flight_phase: derived from a recording in csv mode (generator.logs.phases), the log's own mission
        # progress where it carries a mission, else read from its phases
        "seq": ("setpoint.seq", "flight_phase.seq", "mission_result.seq_current", "mission_current.data"),
    },
    "phase": {
        "phase": ("flight_phase.phase",),  # csv mode only: generator.logs.phases.PHASES index
    },
}

#: Link fields the shipped grids name that no quantity lists under that name: the quantity field they are.
ALIASES = {"altitude.altitude_local": "altitude.relative"}
#: Quantity fields that are parts of another (a quaternion's components are roll, pitch and yaw): a
#: target naming the whole quantity leaves them out.
PARTS = {("attitude", "q")}
#: Quantities a scenario's conditions read (control state): kept when constant for the whole flight.
CONTROL_QUANTITIES = ("mission", "phase")


class ConstantQuantity(ScenarioError):
    """A quantity whose every candidate in this input reads one value for the whole flight."""


class Fields(tuple):
    """A topic's field names in one input, with what csv mode knows of a recording's fields:
    ``constant`` (field -> the one value it reads for the whole flight, NaN when it has none) and
    ``quaternion`` (the components of a quaternion whose roll/pitch/yaw are derived fields here)."""

    constant: dict[str, float]
    quaternion: tuple[str, ...]

    def __new__(cls, names, constant: dict[str, float] | None = None, quaternion: tuple[str, ...] = ()):
        out = super().__new__(cls, names)
        out.constant = dict(constant or {})
        out.quaternion = tuple(quaternion)
        return out


def input_fields(flights: list[dict], exclude: tuple[str, ...] = ()) -> dict[str, Fields]:
    """topic -> :class:`Fields` of recordings replayed together (the first flight's columns, less
    ``Timestamp`` and ``exclude``): a field is constant when it is in every flight's table attrs
    ``constant_fields`` with the same value; the attrs are set on a recording's listen view
    (generator.logs.orientation.listen_view), so generated flights have none."""
    out: dict[str, Fields] = {}
    for topic, df in flights[0].items():
        names = tuple(c for c in df.columns if c != "Timestamp" and c not in exclude)
        const = dict(df.attrs.get("constant_fields", {}))
        for other in flights[1:]:
            theirs = other[topic].attrs.get("constant_fields", {}) if topic in other else {}
            const = {k: v for k, v in const.items() if k in theirs and _same(theirs[k], v)}
        out[topic] = Fields(names, {k: v for k, v in const.items() if k in names},
                            tuple(df.attrs.get("quaternion", ())))
    return out


def _same(a: float, b: float) -> bool:
    return a == b or (a != a and b != b)


def _meaning_index() -> dict[str, str]:
    """``topic.field`` candidate -> the ``quantity.field`` it stands for (the later quantity wins, so
    ``gps_raw_int.lat`` is ``gps.lat``, ``global_position_int.lat`` is ``position.lat``)."""
    out = {c: f"{q}.{f}" for q, fields in QUANTITIES.items() for f, cands in fields.items() for c in cands}
    return {**out, **ALIASES}


#: A concrete field a scenario names that the input lacks is read as the quantity it stands for (the
#: shipped grids name the generator's link fields; on a PX4 or ArduPilot log they resolve by meaning).
MEANING_OF = _meaning_index()

#: What a condition reads from its topic, as (quantity, fields that must all be there) options in
#: order of preference; the condition's ``topic`` defaults to the quantity.
CONDITION_NEEDS: dict[str, tuple[tuple[str, ...], ...]] = {
    "geofence": (("x", "y"), ("lat", "lon")),
    "altitude_above": (("z",), ("relative",)),
    "mission_phase": (("seq",),),
    "flight_phase": (("phase",),),
}


#: The fields altitude_above reads by name (generator.scart.conditions.altitude).
DEFAULT_ALTITUDE = ("relative_alt", "altitude_relative", "z")


def _split(name: str) -> tuple[str, str]:
    topic, _, field = name.partition(".")
    return topic, field


def is_quantity(name: str) -> bool:
    q, f = _split(name)
    return q in QUANTITIES and (not f or f in QUANTITIES[q])


def _candidates(name: str) -> list[str]:
    q, f = _split(name)
    fields = [f] if f else [fld for fld in QUANTITIES[q] if (q, fld) not in PARTS]
    return [c for fld in fields for c in QUANTITIES[q][fld]]


def constant_reason(name: str, constant: list[tuple[str, float]]) -> str:
    """The short reason (for the attack summary line) why quantity ``name`` is not attacked."""
    c, v = constant[0]
    more = f" and {len(constant) - 1} more" if len(constant) > 1 else ""
    return f"{name} constant for the whole flight ({c} = {v:g}{more})"


def _describe(available: dict[str, tuple[str, ...]]) -> str:
    names = sorted(available)
    return ", ".join(names[:40]) + (f", ... ({len(names)} topics)" if len(names) > 40 else "")


def resolve_target(name: str, available: dict[str, tuple[str, ...]], where: str) -> list[str]:
    """The concrete ``topic`` / ``topic.field`` targets of one scenario target in this input."""
    topic, field = _split(name)
    if topic in available and field in getattr(available[topic], "quaternion", ()):
        raise ScenarioError(f"{where}: {name!r} is a component of {topic}'s quaternion, which stays a unit "
                            f"quaternion only when rotated: target {topic}.roll, .pitch or .yaw (or attitude.roll "
                            "...) instead")
    if topic in available and (not field or field in available[topic] or not is_quantity(name)):
        return [name]
    if not is_quantity(name) and topic not in available and name in MEANING_OF:
        name = MEANING_OF[name]  # a link field on a log: what it means there
    if not is_quantity(name):
        return [name]  # validate_topics names what is wrong
    found = [c for c in _candidates(name) if _split(c)[1] in available.get(_split(c)[0], ())]
    if not found:
        looked = sorted({_split(c)[0] for c in _candidates(name)})
        raise ScenarioError(f"{where}: {name!r} (a quantity) matches no topic of this input; it looks for "
                            f"{', '.join(looked)}; the input has: {_describe(available)}")
    # a field that reads one value for the whole flight (a zero GPS on a log without GPS) is no
    # measurement to attack: moving it would make a copy that differs from the flight in nothing real
    constant = [(c, getattr(available[_split(c)[0]], "constant", {}).get(_split(c)[1])) for c in found]
    live = [c for c, v in constant if v is None]
    if not live:
        raise ConstantQuantity(f"{where}: {name!r} (a quantity) is not attacked on this flight: "
                            f"{constant_reason(name, constant)}")
    return live


def resolve_condition_topic(condition: str, params: dict, available: dict[str, tuple[str, ...]],
                            where: str) -> dict:
    """The condition's parameters with a quantity ``topic`` replaced by a concrete topic (and, for
    mission_phase, its ``field``). Raises ScenarioError naming the topic when the input lacks it."""
    name = params.get("topic")
    if not isinstance(name, str):
        return params
    if name not in QUANTITIES:
        if name not in available:
            raise ScenarioError(f"{where}.topic: topic {name!r} is not in this input; it has: {_describe(available)}")
        if condition == "mission_phase" and params.get("field") not in available[name]:
            raise ScenarioError(f"{where}.field: {name} has no field {params.get('field')!r}; it has: "
                                f"{', '.join(available[name])}")
        return params
    for need in CONDITION_NEEDS.get(condition, (tuple(QUANTITIES[name]),)):
        picks = {}
        for fld in need:
            if fld not in QUANTITIES[name]:
                break
            topics = [(t, f) for t, f in map(_split, QUANTITIES[name][fld]) if f in available.get(t, ())]
            if topics:
                picks[fld] = topics[0]
        if len(picks) == len(need) and len({t for t, _ in picks.values()}) == 1:
            topic = next(iter(picks.values()))[0]
            out = {**params, "topic": topic}
            field = next(iter(picks.values()))[1]
            # the field it reads (the layer's copy only; altitude_above finds its own by name on the link, and
            # a group's random streams are keyed on its parameters, so generated flights keep theirs)
            if condition == "mission_phase" or (condition == "altitude_above" and field not in DEFAULT_ALTITUDE):
                out["field"] = field
            return out
    looked = sorted({_split(c)[0] for c in _candidates(name)})
    if name == "phase":
        raise ScenarioError(f"{where}.topic: {condition} reads the flight's phases, which csv mode derives from a "
                            "recording (scart-bench attack); in simulation mode use mission_phase or altitude_above")
    raise ScenarioError(f"{where}.topic: {name!r} (a quantity) matches no topic of this input that {condition} "
                        f"can read; it looks for {', '.join(looked)}; the input has: {_describe(available)}")


