"""Flight profiles as TOML files: what ``generate --like`` writes and ``generate --profile FILE.toml`` reads.

A profile file maps onto the generator's own pieces, section by section, field by field:

- ``[profile]``: ``base`` (a built-in profile: its flight counts, split and attack grid) and any
  other field of :class:`scart_bench.generator.profiles.Profile` (``gps_accuracy``, ``sensor_profile``,
  ``timing``, and what the profile gains later), applied first;
- ``[sensors]``, ``[estimator]``, ``[mission]``, ``[controller]``, ``[vehicle]``: fields of
  :class:`SensorParams`, :class:`EstimatorParams`, :class:`MissionParams`, :class:`ControllerParams`,
  :class:`VehicleParams` (any field the dataclass has: a new one is accepted as soon as it exists),
  over the base profile's values; ``mission.missions`` lists mission files (``.plan`` or WPL), relative
  to the TOML file, flown as ``generate --missions`` flies them;
- ``[timing]``: per link topic, ``topic = {cv = ..., drop = ..., late = ..., spread = ...}`` in place of that topic's
  entry of the "realistic" timing table (``FlightConfig.timing_table``,
  :func:`scart_bench.generator.telemetry.timing.check_timing_table`; a key left out keeps the table's);
- ``[measured]`` and ``[not_expressible]``: what the logs showed that the generator cannot take yet,
  for the reader; not applied.

Every value is checked against its field's default (a number for a number, a list of as many numbers
for a tuple, true/false for a flag, one of the allowed names for a level); a bad one raises
:class:`ProfileFileError` naming the file, the key and what was expected.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from scart_bench.errors import ScartBenchError

#: informational sections: written by ``--like``, never applied
INFO_SECTIONS = ("measured", "not_expressible", "logs")
MAX_FILE_BYTES = 1024 * 1024


class ProfileFileError(ScartBenchError):
    """A profile TOML that cannot be used: the file, the key and what was expected."""


def _sections():
    from scart_bench.generator.params import (
        ControllerParams,
        EstimatorParams,
        MissionParams,
        SensorParams,
        VehicleParams,
    )

    return {"sensors": SensorParams, "estimator": EstimatorParams, "mission": MissionParams,
            "controller": ControllerParams, "vehicle": VehicleParams}


#: FlightConfig attribute of each section
CONFIG_ATTR = {"sensors": "sensors", "estimator": "estimator", "mission": "mission", "controller": "controller",
               "vehicle": "vehicle"}


@dataclass(frozen=True)
class ProfileFile:
    """A profile file read and checked: the built-in profile it is based on (with its [profile] fields)
    and the FlightConfig its flights are flown with."""

    path: str
    profile: object  # generator.profiles.Profile
    config: object  # generator.engine.flight_batch.FlightConfig


def _fail(path, key: str, expected: str, got) -> ProfileFileError:
    return ProfileFileError(f"{path}: {key}: expected {expected}, got {got!r}")


def _check_value(path, key: str, value, default):
    """``value`` as the type of ``default`` (a field's default), or ProfileFileError."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise _fail(path, key, "true or false", value)
        return value
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _fail(path, key, "a finite number", value)
        if value < 0 and default >= 0:
            raise _fail(path, key, "a number >= 0", value)
        if isinstance(default, int) and not isinstance(default, bool):
            if float(value) != int(value):
                raise _fail(path, key, "a whole number", value)
            return int(value)
        return float(value)
    if isinstance(default, tuple):
        if not isinstance(value, list) or (default and len(value) != len(default)):
            n = f"{len(default)} " if default else ""
            raise _fail(path, key, f"a list of {n}values", value)
        proto = default[0] if default else None
        if isinstance(proto, tuple):
            return tuple(_check_value(path, f"{key}[{i}]", v, proto) for i, v in enumerate(value))
        if isinstance(proto, (int, float)):
            return tuple(_check_value(path, f"{key}[{i}]", v, -1.0) for i, v in enumerate(value))
        return _tuples(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise _fail(path, key, "a string", value)
        return value
    return value


#: fields with a range of their own beyond their default's type: key -> (least, most, what it is)
RANGES = {"sensors.imu_offset_m": (-1.0, 1.0, "m from the centre of gravity, body frame"),
          "sensors.vibration_levels": (0.0, 1000.0, "multiples of the vibration"),
          "mission.rocking_levels": (0.0, 1000.0, "rad/s^2 per step"),
          "mission.rocking_flow_levels": (0.0, 1000.0, "rad/s^2 at full speed"),
          "mission.rocking_flow_hz": (0.01, 100.0, "Hz, the forward-flight rocking's low-pass"),
          "mission.rocking_flow_full_m_s": (0.1, 100.0, "m/s, the speed of the full forward-flight rocking"),
          "mission.rocking_flow_from_m_s": (0.0, 50.0, "m/s, the speed the forward-flight rocking starts from"),
          # the forward-flight baro noise ramps from 1 m/s (physics.sensors.BARO_FLOW_FROM) to full at this speed
          "sensors.baro_speed_full_m_s": (1.1, 100.0, "m/s, above the 1 m/s where the noise starts"),
          "sensors.baro_wander_tau_s": (0.05, 3600.0, "s, the wander's time constant")}
#: fields whose value is a list of any length of same-length number lists (their default, (), says no element type):
#: key -> the element's prototype
PAIRS = {"sensors.vibration_levels": (1.0,) * 6, "mission.rocking_levels": (0.0,) * 3,
         "mission.rocking_flow_levels": (0.0,) * 2}


def _check_range(path, key: str, value) -> None:
    """ProfileFileError when a field of :data:`RANGES` (each element of a list) is out of its range."""
    if key not in RANGES:
        return
    lo, hi, what = RANGES[key]
    for i, v in enumerate(value if isinstance(value, tuple) else (value,)):
        if isinstance(v, tuple):  # a list of lists (sensors.vibration_levels)
            for j, x in enumerate(v):
                _fail_if(path, f"{key}[{i}][{j}]", lo, hi, what, x)
        else:
            _fail_if(path, f"{key}[{i}]" if isinstance(value, tuple) else key, lo, hi, what, v)


def _fail_if(path, key: str, lo: float, hi: float, what: str, v) -> None:
    if not lo <= v <= hi:
        raise _fail(path, key, f"a number in [{lo:g}, {hi:g}] ({what})", v)


def _tuples(value):
    """TOML lists as tuples, nested ones too (``families = [["survey", 0.5], ...]``)."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def read_profile(path: str | Path) -> ProfileFile:
    """Read and check a profile TOML (see the module docstring); nothing is flown or written."""
    from scart_bench.generator.profiles import PROFILES, Profile

    p = Path(path)
    try:
        if p.stat().st_size > MAX_FILE_BYTES:
            raise ProfileFileError(f"{path}: expected a profile TOML of at most 1 MiB")
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ProfileFileError(f"{path}: no such file (expected a profile TOML, e.g. one `generate --like` wrote)") from None
    except UnicodeDecodeError:
        raise ProfileFileError(f"{path}: expected a UTF-8 TOML file") from None
    except tomllib.TOMLDecodeError as e:
        raise ProfileFileError(f"{path}: expected TOML: {e}") from None
    except OSError as e:
        raise ProfileFileError(f"{path}: cannot read the profile ({e.strerror or e})") from None
    sections = _sections()
    known = ("profile", *sections, "timing", *INFO_SECTIONS)
    for name, value in doc.items():
        if name not in known:
            raise _fail(path, name, f"one of the sections [{'], ['.join(known)}]", name)
        if not isinstance(value, dict):
            raise _fail(path, name, "a [section] (a table of keys)", value)
    head = dict(doc.get("profile", {}))
    base = head.pop("base", "quick")
    if base not in PROFILES:
        raise _fail(path, "profile.base", f"one of {', '.join(PROFILES)}", base)
    profile = PROFILES[base]
    pfields = {f.name: f for f in dataclasses.fields(Profile)}
    changes = {}
    for key, value in head.items():
        if key not in pfields or key == "name":
            raise _fail(path, f"profile.{key}", f"base or a Profile field ({', '.join(k for k in pfields if k != 'name')})",
                        key)
        changes[key] = _check_value(path, f"profile.{key}", value, getattr(profile, key))
    _check_levels(path, changes)
    profile = dataclasses.replace(profile, **changes)
    try:
        config = profile.flight_config()
    except ValueError as e:
        raise ProfileFileError(f"{path}: [profile]: {e}") from None
    missions = ()
    for section, cls in sections.items():
        table = doc.get(section, {})
        names = {f.name for f in dataclasses.fields(cls)}
        current = getattr(config, CONFIG_ATTR[section])
        edits = {}
        for key, value in table.items():
            if section == "mission" and key == "missions":
                missions = _missions(path, value)
                continue
            if key not in names:
                raise _fail(path, f"{section}.{key}", f"a field of {cls.__name__} ({', '.join(sorted(names))})", key)
            if f"{section}.{key}" in PAIRS:  # a list of number lists (an empty default says no element type)
                if not isinstance(value, list):
                    raise _fail(path, f"{section}.{key}", f"a list of lists of {len(PAIRS[f'{section}.{key}'])} numbers",
                                value)
                edits[key] = tuple(_check_value(path, f"{section}.{key}[{i}]", v, PAIRS[f"{section}.{key}"])
                                   for i, v in enumerate(value))
            else:
                edits[key] = _check_value(path, f"{section}.{key}", value, getattr(current, key))
            _check_range(path, f"{section}.{key}", edits[key])
        config = dataclasses.replace(config, **{CONFIG_ATTR[section]: dataclasses.replace(current, **edits)})
    if config.airframes:  # each airframe of a mix flies its own vehicle and gains: these would be ignored
        for section in ("vehicle", "controller"):
            if doc.get(section):
                key = next(iter(doc[section]))
                raise _fail(path, f"{section}.{key}", f"no [{section}] keys while profile.airframes mixes airframes "
                            "(each airframe flies its own vehicle and controller gains; set airframes = {} to fly "
                            f"the [{section}] section)", doc[section][key])
    m = config.mission
    if m.rocking_flow_levels and m.rocking_flow_full_m_s <= m.rocking_flow_from_m_s:
        raise _fail(path, "mission.rocking_flow_full_m_s", f"a speed above rocking_flow_from_m_s "
                    f"({m.rocking_flow_from_m_s:g} m/s, where the forward-flight rocking starts)", m.rocking_flow_full_m_s)
    if missions:
        from scart_bench.generator.flight_software.mission_files import with_missions

        config = with_missions(config, missions)
    if doc.get("timing"):
        if config.timing != "realistic":
            raise _fail(path, "timing", f'profile.timing = "realistic" (a [timing] table changes its entries; '
                        f'timing {config.timing!r} stamps nothing)', config.timing)
        config = dataclasses.replace(config, timing_table=_timing_table(path, doc["timing"]))
    return ProfileFile(str(path), profile, config)


def _timing_table(path, table: dict) -> tuple:
    """The ``[timing]`` section as ``FlightConfig.timing_table``: per topic, the given fields over the
    realistic table's entry."""
    from scart_bench.generator.telemetry.timing import (
        REALISTIC,
        TABLE_FIELDS,
        TABLE_RANGE,
        check_timing_table,
    )

    entries = []
    for topic, fields in table.items():
        key = f"timing.{topic}"
        if topic not in REALISTIC:
            raise _fail(path, key, f"a topic of the timing table ({', '.join(sorted(REALISTIC))})", topic)
        if not isinstance(fields, dict):
            raise _fail(path, key, "an inline table {cv = ..., drop = ..., late = ..., spread = ...}", fields)
        values = dict(zip(TABLE_FIELDS, (*REALISTIC[topic], 1.0), strict=True))
        for name, v in fields.items():
            if name not in TABLE_FIELDS:
                raise _fail(path, f"{key}.{name}", f"one of {', '.join(TABLE_FIELDS)}", name)
            lo, hi = TABLE_RANGE[name]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise _fail(path, f"{key}.{name}", f"a number in [{lo:g}, {hi:g}]", v)
            values[name] = float(v)
        if values["drop"] + values["late"] > 1.0:
            raise _fail(path, key, "drop + late at most 1", values["drop"] + values["late"])
        entries.append((topic, *values.values()))
    return check_timing_table(entries)


def _check_levels(path, changes: dict) -> None:
    from scart_bench.generator.params import GPS_ACCURACY, SENSOR_PROFILES
    from scart_bench.generator.telemetry.timing import TIMINGS

    for key, allowed in (("gps_accuracy", tuple(GPS_ACCURACY)), ("sensor_profile", tuple(SENSOR_PROFILES)),
                         ("timing", TIMINGS)):
        if key in changes and changes[key] not in allowed:
            raise _fail(path, f"profile.{key}", f"one of {', '.join(allowed)}", changes[key])


def _missions(path, value) -> tuple:
    from scart_bench.generator.flight_software.mission_files import read_missions

    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise _fail(path, "mission.missions", "a list of mission file names (.plan or .waypoints, relative to the "
                    "profile)", value)
    folder = Path(path).parent
    return read_missions([p if Path(p).is_absolute() else folder / p for p in value])


# --- writing ---------------------------------------------------------------------------------------------------
def toml_value(v) -> str:
    """A TOML literal of a number, string, flag or list of them."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return repr(round(v, 6)) if abs(v) >= 1e-3 or v == 0 else f"{v:.6g}"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML literal for {v!r}")


def _comment(text: str) -> str:
    return " ".join(text.split())


def render(header: list[str], sections: dict[str, dict[str, tuple[object, str]]]) -> str:
    """A TOML document: ``header`` comment lines, then each section's ``key = value  # comment``."""
    out = [f"# {line}" if line else "#" for line in header]
    for name, table in sections.items():
        if not table:
            continue
        out.append("")
        out.append(f"[{name}]")
        for key, (value, comment) in table.items():
            line = f"{key} = {toml_value(value)}"
            out.append(f"{line}  # {_comment(comment)}" if comment else line)
    return "\n".join(out) + "\n"
