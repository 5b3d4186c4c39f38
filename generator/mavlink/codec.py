"""MAVLink framing and the mapping between link topics and MAVLink messages.

Framing: :func:`split_frames` cuts a UDP datagram into MAVLink 1/2 frames without decoding
them. A frame is accepted when its header is complete, its declared length fits the datagram
and, for a message of the ``common`` dialect, its CRC (with the message's CRC_EXTRA) matches.
Frames of message ids the dialect does not know are accepted on their framing alone (a proxy
cannot check their CRC) and passed on unchanged. Everything else is malformed: counted and
dropped.

Topics: :data:`CODECS` maps each link topic of ``scart_bench.dataset.schema`` to one MAVLink message and
converts both ways, with MAVLink's scaled integers (degE7, mm, cm/s, cdeg) on the wire and
physical units in the arrays. ``docs/proxy.md`` lists the mapping field by field.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scart_bench.dataset.schema import TOPICS
from scart_bench.generator.mavlink import require_pymavlink

mavlink = require_pymavlink()
from pymavlink.generator.mavcrc import x25crc  # noqa: E402  (after the clear error above)

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
SIGNED = 0x01
SIGNATURE_LEN = 13
KNOWN = mavlink.mavlink_map
#: id of the message that closes one step's frame in the generator's lockstep link (passed through)
SYSTEM_TIME_ID = mavlink.MAVLINK_MSG_ID_SYSTEM_TIME
HEARTBEAT_ID = mavlink.MAVLINK_MSG_ID_HEARTBEAT
MISSION_CURRENT_ID = mavlink.MAVLINK_MSG_ID_MISSION_CURRENT
COMMAND_LONG_ID = mavlink.MAVLINK_MSG_ID_COMMAND_LONG
ARM_DISARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
UINT16_MAX = 65535


@dataclass(slots=True)
class Frame:
    """One MAVLink frame inside a datagram: ``data[start:end]`` with its message id."""

    msgid: int
    start: int
    end: int
    version: int
    signed: bool


def _frame_crc(data: bytes, start: int, body_end: int, crc_extra: int) -> int:
    crc = x25crc(data[start + 1:body_end])
    crc.accumulate(bytes((crc_extra,)))
    return crc.crc


def split_frames(data: bytes) -> tuple[list[Frame], int]:
    """The valid frames of a datagram and the number of malformed pieces (dropped).

    A run of bytes that starts no frame counts once; a frame with a bad CRC or an unknown
    incompatibility flag is skipped by its declared length; a truncated frame ends the datagram.
    """
    frames: list[Frame] = []
    bad = 0
    i, n = 0, len(data)
    while i < n:
        magic = data[i]
        if magic == MAGIC_V2:
            if n - i < 12:
                return frames, bad + 1
            plen, flags = data[i + 1], data[i + 2]
            signed = bool(flags & SIGNED)
            total = 12 + plen + (SIGNATURE_LEN if signed else 0)
            if i + total > n:
                return frames, bad + 1
            msgid = data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)
            body_end = i + 10 + plen
            if flags & ~SIGNED:
                ok = False
            else:
                cls = KNOWN.get(msgid)
                ok = cls is None or _frame_crc(data, i, body_end, cls.crc_extra) == (
                    data[body_end] | (data[body_end + 1] << 8))
            if ok:
                frames.append(Frame(msgid, i, i + total, 2, signed))
            else:
                bad += 1
            i += total
        elif magic == MAGIC_V1:
            if n - i < 8:
                return frames, bad + 1
            plen = data[i + 1]
            total = 8 + plen
            if i + total > n:
                return frames, bad + 1
            msgid = data[i + 5]
            body_end = i + 6 + plen
            cls = KNOWN.get(msgid)
            if cls is None or _frame_crc(data, i, body_end, cls.crc_extra) == (
                    data[body_end] | (data[body_end + 1] << 8)):
                frames.append(Frame(msgid, i, i + total, 1, False))
            else:
                bad += 1
            i += total
        else:  # garbage: skip to the next byte that could start a frame
            bad += 1
            j = i + 1
            while j < n and data[j] != MAGIC_V2 and data[j] != MAGIC_V1:
                j += 1
            i = j
    return frames, bad


# -- scaling helpers ------------------------------------------------------------------------------

def _f32(x: float) -> float:
    """The value a float field carries on the wire (IEEE single precision)."""
    return float(np.float32(x))


def _int(x: float, lo: int, hi: int, unknown: int | None = None) -> int:
    if not math.isfinite(x):
        return unknown if unknown is not None else 0
    return int(min(max(round(x), lo), hi))


def _deg_e7(deg: float) -> int:
    return _int(deg * 1e7, -(2**31), 2**31 - 1)


def _cdeg(rad: float) -> int:
    """Angle in [0, 2 pi) as centidegrees 0..35999."""
    if not math.isfinite(rad):
        return UINT16_MAX
    return int(round(math.degrees(rad) * 100.0)) % 36000


def _rad_from_cdeg(c: int) -> float:
    return float("nan") if c == UINT16_MAX else math.radians(c / 100.0)


class LinkState:
    """What a decoder remembers between messages: values that one message lacks and another carries.

    GPS_RAW_INT has no vertical speed: ``gps_raw_int.vd`` is taken from the last
    GLOBAL_POSITION_INT ``vz``. ``setpoint.seq`` and ``setpoint.armed`` come from the last
    MISSION_CURRENT and COMMAND_LONG (MAV_CMD_COMPONENT_ARM_DISARM).
    """

    def __init__(self) -> None:
        self.vz = 0.0
        self.seq = 0.0
        self.armed = 0.0

    def observe(self, msgid: int, msg) -> None:
        """Take in a passing message that feeds a topic without being one (MISSION_CURRENT, arming)."""
        if msgid == MISSION_CURRENT_ID:
            self.seq = float(msg.seq)
        elif msgid == COMMAND_LONG_ID and msg.command == ARM_DISARM:
            self.armed = 1.0 if msg.param1 > 0.5 else 0.0


@dataclass(frozen=True)
class TopicCodec:
    """One link topic carried by one MAVLink message.

    ``decode(msg, state)`` gives the topic's values (physical units, field order of
    scart_bench.dataset.schema); ``fields(values, t_us)`` gives the MAVLink fields that carry them
    (already quantised as on the wire), including the time field; ``time_field`` names the
    message's timestamp and its scale to microseconds.
    """

    topic: str
    message: str
    msgid: int
    time_field: str | None
    time_scale: int
    decode: Callable
    fields: Callable

    def time_us(self, msg) -> int | None:
        if self.time_field is None:
            return None
        return int(getattr(msg, self.time_field)) * self.time_scale

    def new_message(self, values: np.ndarray, t_us: int):
        """A pymavlink message carrying ``values`` at time ``t_us`` (the generator's flight controller)."""
        cls = KNOWN[self.msgid]
        return cls(**{**_DEFAULTS.get(self.topic, {}), **self.fields(values, t_us)})

    def alter(self, msg, values: np.ndarray, before: np.ndarray) -> int:
        """Overwrite the fields of ``msg`` whose encoding changes from ``before`` to ``values``.

        Fields the change does not touch (and the time field) keep their received value.
        Returns the number of MAVLink fields written.
        """
        new, old = self.fields(values, 0), self.fields(before, 0)
        n = 0
        for name, v in new.items():
            if name != self.time_field and v != old[name] and not (v != v and old[name] != old[name]):
                setattr(msg, name, v)
                n += 1
        return n


def _ms(t_us: int) -> int:
    return int(t_us // 1000) & 0xFFFFFFFF


def _attitude(msg, state) -> list[float]:
    return [msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed]


def _attitude_fields(v, t_us) -> dict:
    return {"time_boot_ms": _ms(t_us), **{k: _f32(v[i]) for i, k in enumerate(
        ("roll", "pitch", "yaw", "rollspeed", "pitchspeed", "yawspeed"))}}


_IMU = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag", "abs_pressure",
        "pressure_alt", "temperature")


def _imu(msg, state) -> list[float]:
    return [getattr(msg, k) for k in _IMU]


def _imu_fields(v, t_us) -> dict:
    return {"time_usec": int(t_us), **{k: _f32(v[i]) for i, k in enumerate(_IMU)}}


def _gpi(msg, state) -> list[float]:
    state.vz = msg.vz / 100.0
    return [msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0, msg.relative_alt / 1000.0, msg.vx / 100.0,
            msg.vy / 100.0, msg.vz / 100.0, _rad_from_cdeg(msg.hdg)]


def _gpi_fields(v, t_us) -> dict:
    i32 = (-(2**31), 2**31 - 1)
    return {"time_boot_ms": _ms(t_us), "lat": _deg_e7(v[0]), "lon": _deg_e7(v[1]),
            "alt": _int(v[2] * 1000, *i32), "relative_alt": _int(v[3] * 1000, *i32),
            "vx": _int(v[4] * 100, -32768, 32767), "vy": _int(v[5] * 100, -32768, 32767),
            "vz": _int(v[6] * 100, -32768, 32767), "hdg": _cdeg(v[7])}


_LPN = ("x", "y", "z", "vx", "vy", "vz")


def _lpn(msg, state) -> list[float]:
    return [getattr(msg, k) for k in _LPN]


def _lpn_fields(v, t_us) -> dict:
    return {"time_boot_ms": _ms(t_us), **{k: _f32(v[i]) for i, k in enumerate(_LPN)}}


def _gps(msg, state) -> list[float]:
    vel = msg.vel / 100.0 if msg.vel != UINT16_MAX else float("nan")
    cog = _rad_from_cdeg(msg.cog)
    c = 0.0 if math.isnan(cog) else cog
    return [msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0,
            msg.eph / 100.0 if msg.eph != UINT16_MAX else float("nan"),
            msg.epv / 100.0 if msg.epv != UINT16_MAX else float("nan"),
            vel, cog, vel * math.cos(c), vel * math.sin(c), state.vz, float(msg.fix_type),
            float(msg.satellites_visible) if msg.satellites_visible != 255 else float("nan")]


def _gps_fields(v, t_us) -> dict:
    return {"time_usec": int(t_us), "lat": _deg_e7(v[0]), "lon": _deg_e7(v[1]),
            "alt": _int(v[2] * 1000, -(2**31), 2**31 - 1),
            "eph": _int(v[3] * 100, 0, UINT16_MAX - 1, UINT16_MAX), "epv": _int(v[4] * 100, 0, UINT16_MAX - 1, UINT16_MAX),
            "vel": _int(v[5] * 100, 0, UINT16_MAX - 1, UINT16_MAX), "cog": _cdeg(v[6]),
            "fix_type": _int(v[10], 0, 255), "satellites_visible": _int(v[11], 0, 254, 255),
            "h_acc": _int(v[3] * 1000, 0, 2**32 - 1), "v_acc": _int(v[4] * 1000, 0, 2**32 - 1)}


def _press(msg, state) -> list[float]:
    return [msg.press_abs, msg.temperature / 100.0]


def _press_fields(v, t_us) -> dict:
    return {"time_boot_ms": _ms(t_us), "press_abs": _f32(v[0]), "temperature": _int(v[1] * 100, -32768, 32767)}


def _alt(msg, state) -> list[float]:
    return [msg.altitude_amsl, msg.altitude_local, msg.altitude_relative]


def _alt_fields(v, t_us) -> dict:
    return {"time_usec": int(t_us), "altitude_monotonic": _f32(v[0]), "altitude_amsl": _f32(v[0]),
            "altitude_local": _f32(v[1]), "altitude_relative": _f32(v[2])}


def _battery(msg, state) -> list[float]:
    mv = msg.voltages[0]
    if mv == UINT16_MAX:
        volt = float("nan")
    else:
        volt = (mv + (msg.voltages[1] if mv == UINT16_MAX - 1 and msg.voltages[1] != UINT16_MAX else 0)) / 1000.0
    cur = msg.current_battery / 100.0 if msg.current_battery != -1 else float("nan")
    rem = msg.battery_remaining / 100.0 if msg.battery_remaining != -1 else float("nan")
    return [volt, cur, rem]


def _battery_fields(v, t_us) -> dict:
    mv = _int(v[0] * 1000, 0, 2 * (UINT16_MAX - 1), UINT16_MAX)
    cells = [UINT16_MAX] * 10
    if mv > UINT16_MAX - 1 and mv != UINT16_MAX:
        cells[0], cells[1] = UINT16_MAX - 1, mv - (UINT16_MAX - 1)
    else:
        cells[0] = mv
    return {"voltages": cells, "current_battery": _int(v[1] * 100, -32768, 32767, -1),
            "battery_remaining": _int(v[2] * 100, 0, 100, -1)}


#: SET_POSITION_TARGET_LOCAL_NED type_mask: velocity and yaw used; position, acceleration, yaw rate ignored
VELOCITY_YAW_MASK = 0b0000_1001_1100_0111


def _setpoint(msg, state) -> list[float]:
    return [msg.vx, msg.vy, msg.vz, msg.yaw, state.seq, state.armed]


def _setpoint_fields(v, t_us) -> dict:
    return {"time_boot_ms": _ms(t_us), "vx": _f32(v[0]), "vy": _f32(v[1]), "vz": _f32(v[2]), "yaw": _f32(v[3])}


_DEFAULTS = {
    "highres_imu": {"diff_pressure": 0.0, "fields_updated": 0x1FFF, "id": 0},
    "scaled_pressure": {"press_diff": 0.0},
    "altitude": {"altitude_terrain": float("nan"), "bottom_clearance": float("nan")},
    "battery_status": {"id": 0, "battery_function": mavlink.MAV_BATTERY_FUNCTION_ALL,
                       "type": mavlink.MAV_BATTERY_TYPE_LIPO, "temperature": 32767, "current_consumed": -1,
                       "energy_consumed": -1},
    "gps_raw_int": {},
    "setpoint": {"target_system": 1, "target_component": 1, "coordinate_frame": mavlink.MAV_FRAME_LOCAL_NED,
                 "type_mask": VELOCITY_YAW_MASK, "x": 0.0, "y": 0.0, "z": 0.0, "afx": 0.0, "afy": 0.0,
                 "afz": 0.0, "yaw_rate": 0.0},
}


def _codec(topic: str, message: str, time_field: str | None, scale: int, decode, fields) -> TopicCodec:
    msgid = getattr(mavlink, f"MAVLINK_MSG_ID_{message}")
    return TopicCodec(topic, message, msgid, time_field, scale, decode, fields)


#: topic -> codec, for every link topic of scart_bench.dataset.schema
CODECS: dict[str, TopicCodec] = {c.topic: c for c in (
    _codec("attitude", "ATTITUDE", "time_boot_ms", 1000, _attitude, _attitude_fields),
    _codec("highres_imu", "HIGHRES_IMU", "time_usec", 1, _imu, _imu_fields),
    _codec("global_position_int", "GLOBAL_POSITION_INT", "time_boot_ms", 1000, _gpi, _gpi_fields),
    _codec("local_position_ned", "LOCAL_POSITION_NED", "time_boot_ms", 1000, _lpn, _lpn_fields),
    _codec("gps_raw_int", "GPS_RAW_INT", "time_usec", 1, _gps, _gps_fields),
    _codec("scaled_pressure", "SCALED_PRESSURE", "time_boot_ms", 1000, _press, _press_fields),
    _codec("altitude", "ALTITUDE", "time_usec", 1, _alt, _alt_fields),
    _codec("battery_status", "BATTERY_STATUS", None, 1, _battery, _battery_fields),
    _codec("setpoint", "SET_POSITION_TARGET_LOCAL_NED", "time_boot_ms", 1000, _setpoint, _setpoint_fields),
)}
BY_MSGID: dict[int, TopicCodec] = {c.msgid: c for c in CODECS.values()}
assert set(CODECS) == set(TOPICS), "every link topic has a MAVLink codec"
#: the messages that feed LinkState (decoded when the setpoint topic is in use)
STATE_MESSAGES = frozenset({MISSION_CURRENT_ID, COMMAND_LONG_ID})


class Packer:
    """Packs messages with a chosen header (system, component, sequence) and protocol version."""

    def __init__(self) -> None:
        self._mav = mavlink.MAVLink(None)
        self._mav.robust_parsing = True

    def decode(self, frame: bytes):
        """A pymavlink message from one complete frame (raises pymavlink's MAVError when invalid)."""
        return self._mav.decode(bytearray(frame))

    def pack(self, msg, system: int, component: int, seq: int, version: int = 2) -> bytes:
        self._mav.srcSystem, self._mav.srcComponent, self._mav.seq = system, component, seq & 0xFF
        return msg.pack(self._mav, force_mavlink1=version == 1)

    def repack(self, msg, version: int) -> bytes:
        """``msg`` (decoded from a frame, possibly altered) packed again with its own header."""
        h = msg.get_header()
        return self.pack(msg, h.srcSystem, h.srcComponent, h.seq, version)


