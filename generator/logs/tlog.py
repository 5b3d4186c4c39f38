"""MAVLink telemetry logs (``.tlog``): per-message topic tables, read with pymavlink's mavutil.

A tlog is what a ground station (QGroundControl, Mission Planner, MAVProxy) received on its link:
each MAVLink frame preceded by the 8-byte big-endian time (microseconds since 1970) at which it
arrived. The rules (docs/own_logs.md):

- **Topics**: one per MAVLink message, in snake case: the names the project's own link topics
  have (``GLOBAL_POSITION_INT`` -> ``global_position_int``), so scenarios written for generated
  flights name the same topics. Array fields become ``name_0``, ``name_1`` ...; text fields are
  dropped.
- **Vehicle**: the messages of the autopilot only: the system and component of the first
  HEARTBEAT whose autopilot is not ``MAV_AUTOPILOT_INVALID`` (else the source that sent most
  messages). Messages of other sources (the ground station's own heartbeats, a second vehicle)
  are dropped; their count is in ``attrs["other_sources_dropped"]``.
- **Time**: the tlog's receive time; time zero is the first frame of the file. The vehicle's own
  clocks (``time_boot_ms``, ``time_usec``) stay fields.
- **Units**: MAVLink's scaled integers become the project's units (docs/topics.md), from each
  field's unit in the MAVLink definition (:data:`UNIT_SCALES`): ``degE7`` -> degrees, ``mm`` and
  ``cm`` -> m, ``cm/s`` -> m/s, ``cdeg`` and ``deg`` -> rad (latitudes and longitudes stay in
  degrees), ``mG`` -> m/s^2, ``mgauss`` -> gauss, ``mV`` -> V, ``cA`` -> A, ``%`` -> 0..1,
  ``cdegC`` -> degC, ``Pa`` -> hPa. ``attrs["units"]`` gives each converted field's unit.
- **No value**: a field holding the value its MAVLink definition declares ``invalid`` (unused battery
  cells' ``UINT16_MAX`` mV, ``-1`` for a current not measured, ``UINT16_MAX`` for an unknown
  heading, ``NaN`` ...; :func:`invalid_values`) becomes a missing value (NaN), element by element
  in arrays; ``attrs["no_value"]`` counts them per field.
- **Damage**: frames that fail their checksum (pymavlink's BAD_DATA) or a last frame cut by the
  end of the file are refused unless ``allow_corrupt``.
"""

from __future__ import annotations

import contextlib
import functools
import io
import logging
import math
import re
from collections import Counter
from pathlib import Path

import numpy as np

from scart_bench.dataset import DatasetError
from scart_bench.generator.logs.tables import RawTopics, sanitize_field_name, sanitize_topic_name

logger = logging.getLogger(__name__)

_DEG = math.pi / 180.0
#: MAVLink field unit -> (the project's unit, factor).
UNIT_SCALES: dict[str, tuple[str, float]] = {
    "degE7": ("deg", 1e-7), "degE5": ("deg", 1e-5),
    "mm": ("m", 1e-3), "cm": ("m", 1e-2), "dm": ("m", 0.1), "dam": ("m", 10.0),
    "mm/s": ("m/s", 1e-3), "cm/s": ("m/s", 1e-2), "dm/s": ("m/s", 0.1),
    "cdeg": ("rad", _DEG / 100), "deg": ("rad", _DEG), "deg/2": ("rad", _DEG / 2),
    "deg/s": ("rad/s", _DEG), "ddeg/s": ("rad/s", _DEG / 10), "mrad/s": ("rad/s", 1e-3),
    "mG": ("m/s^2", 9.80665e-3), "mgauss": ("gauss", 1e-3),
    "mV": ("V", 1e-3), "cV": ("V", 1e-2), "mA": ("A", 1e-3), "cA": ("A", 1e-2),
    "%": ("1", 1e-2), "c%": ("1", 1e-4), "d%": ("1", 1e-3),
    "cdegC": ("degC", 1e-2), "Pa": ("hPa", 1e-2), "kPa": ("hPa", 10.0), "mbar": ("hPa", 1.0),
}
#: Field names that are latitudes or longitudes: kept in degrees (the project's unit for them).
LATLON = frozenset({"lat", "lon", "latitude", "longitude", "lat_int", "lon_int"})
#: MAV_AUTOPILOT_INVALID: a heartbeat from something that is not a flight controller (a ground station).
AUTOPILOT_INVALID = 8


def _scale(field: str, unit: str | None) -> tuple[str | None, float]:
    if unit is None or unit not in UNIT_SCALES:
        return unit, 1.0
    if field in LATLON and unit in ("deg", "degE7", "degE5"):
        return "deg", UNIT_SCALES[unit][1] if unit != "deg" else 1.0
    return UNIT_SCALES[unit]


#: MAVLink's names for the limits of its integer types (the ``invalid`` attribute's words).
_LIMITS = {"UINT8_MAX": 2**8 - 1, "UINT16_MAX": 2**16 - 1, "UINT32_MAX": 2**32 - 1, "UINT64_MAX": 2**64 - 1,
           "INT8_MAX": 2**7 - 1, "INT16_MAX": 2**15 - 1, "INT32_MAX": 2**31 - 1, "INT64_MAX": 2**63 - 1}


def _marker(text: str) -> float | None:
    """The number an ``invalid`` attribute names (``UINT16_MAX``, ``-1``, ``0xFFFF``, ``NaN``), or None."""
    text = text.strip()
    if text in _LIMITS:
        return float(_LIMITS[text])
    try:
        return float(int(text, 0)) if re.fullmatch(r"-?(0x[0-9a-fA-F]+|\d+)", text) else float(text)
    except ValueError:
        return None  # an enum's name: not a number to compare with


@functools.lru_cache(maxsize=1)
def invalid_values() -> dict[str, dict[str, float]]:
    """MAVLink message -> field -> the raw value that means "no value", from the ``invalid``
    attributes of the message definitions pymavlink ships (ardupilotmega.xml and what it includes;
    ``[X]`` for an array applies to each element). Empty when the definitions are not installed."""
    try:
        from pymavlink.generator import mavparse
    except ImportError:  # pragma: no cover - pymavlink without its generator
        return {}
    root = Path(mavparse.__file__).resolve().parent.parent / "dialects" / "v20"
    out: dict[str, dict[str, float]] = {}
    todo, seen = ["ardupilotmega.xml"], set()
    while todo:
        name = todo.pop()
        if name in seen or not (root / name).is_file():
            continue
        seen.add(name)
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # its remarks on other dialects' enums
                xml = mavparse.MAVXML(str(root / name), "2.0")
        except Exception as exc:  # pragma: no cover - a damaged installation
            logger.debug("%s: not read (%s); its invalid markers are not applied", root / name, exc)
            continue
        todo.extend(xml.include)
        for m in xml.message:
            for f in m.fields:
                value = _marker(str(getattr(f, "invalid", "") or "").strip("[]").rstrip(":"))
                if value is not None and not math.isnan(value):  # NaN is missing already
                    out.setdefault(m.name, {})[f.name] = value
    return out


def _fields(msg) -> list[tuple[str, float, str | None]]:
    """(column, value in the project's unit, unit) for a message's numeric fields, arrays expanded;
    a field holding its definition's "no value" marker is NaN."""
    out = []
    units = getattr(msg, "fieldunits_by_name", {}) or {}
    invalid = invalid_values().get(msg.get_type(), {})
    for name in msg.get_fieldnames():
        value = getattr(msg, name)
        unit, factor = _scale(name, units.get(name))
        marker = invalid.get(name)
        if isinstance(value, (list, tuple)):
            for k, v in enumerate(value):
                if isinstance(v, (int, float)):
                    out.append((f"{sanitize_field_name(name)}_{k}", _value(v, factor, marker), unit))
        elif isinstance(value, (int, float)):  # bool too
            out.append((sanitize_field_name(name), _value(value, factor, marker), unit))
    return out


def _value(raw: float, factor: float, marker: float | None) -> float:
    return math.nan if marker is not None and raw == marker else _times(raw, factor)


def _times(value: float, factor: float) -> float:
    """value x factor; by division when the factor is 1/n (473977421 / 1e7 is the nearest double to
    47.3977421; x 1e-7 is one ulp off)."""
    inv = 1.0 / factor
    return float(value) / round(inv) if factor < 1 and abs(inv - round(inv)) < 1e-9 * inv else float(value) * factor


class _Frames:
    """The valid frames of a tlog, read once: (receive time us, source, message)."""

    def __init__(self, path: Path):
        try:
            from pymavlink import mavutil
        except ImportError as exc:
            raise DatasetError(f"{path}: reading MAVLink telemetry logs needs the 'pymavlink' package (pip install "
                               "'scart-bench[mavlink]')") from exc

        try:
            self.conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega", notimestamps=False)
        except Exception as exc:
            raise DatasetError(f"{path}: not a readable MAVLink telemetry log ({type(exc).__name__}: {exc})") from exc
        self.frames: list[tuple[int, tuple[int, int], object]] = []
        self.bad = 0
        self.end = 0  # file position after the last valid frame
        while True:
            try:
                msg = self.conn.recv_msg()
            except Exception:  # a frame pymavlink cannot decode at all
                self.bad += 1
                continue
            if msg is None:
                break
            if msg.get_type() == "BAD_DATA":
                self.bad += 1
                continue
            self.end = self.conn.f.tell()
            self.frames.append((int(round(msg._timestamp * 1e6)), (msg.get_srcSystem(), msg.get_srcComponent()), msg))
        self.size = path.stat().st_size
        self.conn.close()

    def vehicle(self) -> tuple[int, int]:
        """The autopilot's (system, component): see the module doc."""
        for _, src, msg in self.frames:
            if msg.get_type() == "HEARTBEAT" and msg.autopilot != AUTOPILOT_INVALID:
                return src
        return Counter(src for _, src, _ in self.frames).most_common(1)[0][0]


def _check_damage(path: Path, frames: _Frames, allow_corrupt: bool) -> dict:
    cut = frames.size - frames.end
    if not frames.frames:
        raise DatasetError(f"{path}: no valid MAVLink frame found in {frames.size} bytes; expected a .tlog telemetry "
                           "log (each frame preceded by its 8-byte receive time)")
    if not frames.bad and not cut:
        return {}
    what = (f"{frames.bad} frame(s) failed their checksum" if frames.bad else "") + \
        (" and " if frames.bad and cut else "") + (f"the last {cut} byte(s) are a cut frame" if cut else "")
    seconds = (frames.frames[-1][0] - frames.frames[0][0]) / 1e6
    if not allow_corrupt:
        raise DatasetError(f"{path}: the tlog is damaged: {what}; {len(frames.frames)} valid frame(s), {seconds:.1f} s "
                           "readable; pass --allow-corrupt (allow_corrupt=True) to use them")
    logger.warning("%s: the tlog is damaged (%s); using the %d valid frame(s)", path, what, len(frames.frames))
    return {"file_corruption": True}


def read_tlog(path: Path, topics: list[str] | None = None, allow_corrupt: bool = False) -> tuple[RawTopics, int]:
    """(raw topics, time zero in microseconds since 1970) of a tlog; see the module doc."""
    frames = _Frames(path)
    damage = _check_damage(path, frames, allow_corrupt)
    origin = min(t for t, _, _ in frames.frames)
    vehicle = frames.vehicle()
    rows: dict[str, list] = {}
    times: dict[str, list[int]] = {}
    columns: dict[str, list[tuple[str, str | None]]] = {}
    others = 0
    for t, src, msg in frames.frames:
        if src != vehicle:
            others += 1
            continue
        topic = sanitize_topic_name(msg.get_type())
        if topics is not None and topic not in topics:
            columns.setdefault(topic, [])
            continue
        fields = _fields(msg)
        columns.setdefault(topic, [(c, u) for c, _, u in fields])
        rows.setdefault(topic, []).append([v for _, v, _ in fields])
        times.setdefault(topic, []).append(t)
    if topics is not None:
        missing = [t for t in topics if t not in columns]
        if missing:
            raise DatasetError(f"{path}: topic(s) {missing} not found in the tlog (system {vehicle[0]}, component "
                               f"{vehicle[1]}); it has: {sorted(columns)}")
    raw: RawTopics = {}
    for topic in sorted(rows):
        values = np.asarray(rows[topic], dtype=np.float64)
        cols = columns[topic]
        notes = {"mavlink_message": topic.upper(), "system": vehicle[0], "component": vehicle[1],
                 "units": {c: u for c, u in cols if u}, "other_sources_dropped": others, **damage}
        missing = {c: int(n) for (c, _), n in zip(cols, np.isnan(values).sum(axis=0)) if n}
        if missing:
            notes["no_value"] = missing
        raw[topic] = (np.asarray(times[topic], dtype=np.int64), {c: values[:, j] for j, (c, _) in enumerate(cols)},
                      notes)
    return raw, origin
